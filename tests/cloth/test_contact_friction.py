"""Coulomb friction of the cloth's contact constraints acts inside the implicit step (``ImplicitEuler.step_velocity``'s
``friction``: tangential damping bounded by mu J), and triangle-mesh obstacles (a World's boxes) get the same constraint filtering as
planes and spheres (``ClothScene.contacts``).

An upright sheet whose bottom edge lands on the ground while sliding along it (cloth-pile's second sheet): the
edge's normal impulse J = m |v_n| allows a tangential impulse up to mu J. Applied to the edge vertices alone
(the friction pass before) it stopped them within the step while the row above moved on: the shear came back
as elastic energy and the stage raised the sheet's total energy. Friction removes energy; the stage must not
add any."""

from __future__ import annotations

import numpy as np

from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel
from modalfem.cloth.scene import ClothScene
from modalfem.collision.obstacles import Plane, TriangleMeshObstacle
from modalfem.collision.pipeline import CollisionConfig

H = 2e-3  # collision thickness [m]
DT = 0.01  # [s]
MAT = ClothMaterial(areal_density=0.1, young=1e5, poisson=0.3, thickness=3e-4, bending_stiffness=2e-6)


def _energy(model: ClothModel, x: np.ndarray, v: np.ndarray) -> float:
    """Kinetic + elastic energy [J] (no gravity in these scenes)."""
    return 0.5 * float(np.sum(model.masses * np.sum(v * v, axis=1))) + model.elastic_energy(x)


def _landing_edge(friction: float) -> tuple[ClothScene, np.ndarray]:
    # vertical sheet (x along the edge, z up), its bottom row H above the ground, sliding at 1 m/s along x and
    # coming down at 1 m/s: the bottom row's constraint stops 1 m/s normal, so mu J / m = mu * 1 m/s
    model = ClothModel(grid((0.2, 0.2), (12, 12), origin=(0.0, 0.0, H), plane="xz"), MAT)
    n = model.mesh.point_count
    v0 = np.tile([1.0, 0.0, -1.0], (n, 1))
    sc = ClothScene(model, collisions=CollisionConfig(thickness=H, friction=friction),
                    obstacles=[Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))], v0=v0)
    bottom = np.flatnonzero(np.isclose(model.mesh.points[:, 2], H))
    return sc, bottom


def test_friction_through_the_system_never_adds_energy():
    sc, bottom = _landing_edge(friction=1.0)
    e0 = _energy(sc.model, sc.x, sc.v)
    v_new, _, _ = sc.implicit_velocity(DT)
    e1 = _energy(sc.model, sc.x + DT * v_new, v_new)
    # friction acted: the sheet lost x momentum (about mu J, spread over the sheet by its stiffness)
    m = sc.model.masses
    assert float(np.sum(m * (1.0 - v_new[:, 0]))) > 0.5 * float(np.sum(m[bottom]))
    # the stage removes energy (the bottom row's normal stop alone removes 0.5 m_row 1 m/s^2); the CG
    # tolerances (1e-4, 1e-2 relative) perturb the step's energy by far less than the friction's own work
    assert e1 < e0, (e1, e0)

    # the pass before: the step without friction, then each contact vertex's tangential velocity cut by up to
    # mu J / m alone (J: the constraint's impulse) stores the shear and gains energy
    from modalfem.cloth.scene import StepStats

    sc2, _ = _landing_edge(friction=0.0)
    st = StepStats()
    v_old, _, _ = sc2.implicit_velocity(DT, st)
    idx, j = bottom, np.maximum(st.linear.contact_impulses, 0.0)
    m = sc2.model.masses[idx]
    vt = v_old[idx].copy()
    vt[:, 2] = 0.0
    speed = np.linalg.norm(vt, axis=1)
    v_old[idx] -= (np.minimum(speed, 1.0 * j / m) / speed)[:, None] * vt
    e_old = _energy(sc2.model, sc2.x + DT * v_old, v_old)
    assert e_old > e0 > e1, (e_old, e0, e1)


def test_friction_cannot_exceed_coulomb_on_the_edge():
    # friction's impulse on the sheet (the x momentum it takes) is positive and at most mu times the normal one
    sc, bottom = _landing_edge(friction=0.3)
    con = sc.contacts(sc.x, sc.v, 0.0, DT)
    assert con is not None and set(con[0]) == set(bottom)
    v_f, _, _ = sc.implicit_velocity(DT)
    sc0, _ = _landing_edge(friction=0.0)
    v_0, _, _ = sc0.implicit_velocity(DT)
    m = sc.model.masses
    lost = float(np.sum(m * (v_0[:, 0] - v_f[:, 0])))  # x momentum friction took [N s]
    from modalfem.cloth.scene import StepStats

    st = StepStats()
    sc0.implicit_velocity(DT, st)
    J = float(np.sum(np.maximum(st.linear.contact_impulses, 0.0)))  # the edge's normal impulse [N s]
    # the bound holds for the damping's impulse k |v_t,end| <= mu J_i with J_i the vertex-alone estimate; the
    # solve's normal impulse is at least that here (the whole sheet pushes down on the edge): 1e-3 for CG
    assert 0.0 < lost <= 0.3 * J * (1 + 1e-3), (lost, 0.3 * J)


def _box_mesh(center, half):
    c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    return np.asarray(center) + c * np.asarray(half), f


def test_triangle_mesh_obstacles_constrain_vertices_resting_on_them():
    V, F = _box_mesh((0.0, 0.0, 0.05), (0.05, 0.05, 0.05))
    model = ClothModel(grid((0.3, 0.3), (16, 16), origin=(-0.15, -0.15, 0.1 + H)), MAT)
    n = model.mesh.point_count
    sc = ClothScene(model, gravity=(0.0, 0.0, -9.81), collisions=CollisionConfig(thickness=H),
                    obstacles=[TriangleMeshObstacle(V, F)], v0=np.tile([0.0, 0.0, -1.0], (n, 1)))
    con = sc.contacts(sc.x, sc.v, 0.0, DT)
    over = np.flatnonzero(np.all(np.abs(model.mesh.points[:, :2]) <= 0.05 + 1e-9, axis=1))  # grid spacing 2 cm
    assert con is not None and set(con[0]) == set(over)  # the vertices over the box top, no others
    assert np.allclose(con[1], [0.0, 0.0, 1.0]) and np.allclose(con[2], 0.0) and np.allclose(con[3], 0.0)
    v_new, _, _ = sc.implicit_velocity(DT)
    assert np.allclose(v_new[over, 2], 0.0, atol=1e-12)  # held by the box top inside the solve
    # a vertex behind a face (inside the box, H under its top, 1 cm or more from its sides) is not constrained:
    # the pipeline's to handle
    inner = np.flatnonzero(np.all(np.abs(model.mesh.points[:, :2]) <= 0.04 + 1e-9, axis=1))
    x = sc.x.copy()
    x[inner, 2] = 0.1 - H
    con = sc.contacts(x, sc.v, 0.0, DT)
    assert len(inner) == 16 and (con is None or not set(con[0]) & set(inner))
