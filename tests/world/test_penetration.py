"""``World.penetrations``: bodies' vertices inside the obstacles beyond a tolerance (issue 17, part 2: no vertex
inside an obstacle beyond the stated tolerance). The expected counts and depths come from the meshes' rest points
and the obstacles' analytic geometry, not from ``signed_distance``."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.errors import InputError
from modalfem.mesh import box

SIZE = 0.06  # [m] the cube's edge


@pytest.fixture(scope="module")
def cube():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(SIZE, SIZE, SIZE), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))


def _world(cube, obstacles, position=(0.0, 0.0, 0.0)):
    return mw.World(bodies=[mw.Tet(cube, name="cube", position=position)], obstacles=obstacles)


def _surface_rest(cube, position):
    from modalfem.mesh.surface import boundary_surface

    return cube.rest_points[boundary_surface(cube.mesh).mesh_vertices] + np.asarray(position)


def test_a_cube_placed_3_mm_into_the_ground_has_its_bottom_face_counted_at_3_mm(cube):
    pos = (0.0, 0.0, -0.003)
    w = _world(cube, [mw.Ground(0.0)], pos)
    s = w.state()
    bottom = int(np.sum(_surface_rest(cube, pos)[:, 2] < 0.0))
    (p,) = w.penetrations(s, tolerance=1e-3)
    assert (p.body, p.obstacle, p.count) == ("cube", 0, bottom) and bottom > 0
    assert p.depth == pytest.approx(0.003, abs=1e-12)
    assert w.penetrations(s, tolerance=0.0031) == []  # within the tolerance: not counted


def test_a_cube_resting_on_the_ground_and_a_tilted_plane_is_not_inside_them(cube):
    w = _world(cube, [mw.Ground(0.0), mw.Plane(normal=(1.0, 0.0, 1.0), point=(-0.5, 0.0, 0.0))])
    assert w.penetrations(w.state(), tolerance=0.0) == []


def test_a_corner_inside_a_sphere_and_a_box_is_counted_with_its_depth(cube):
    # the cube spans [0, SIZE]^3: a sphere of radius 1 cm centred on its corner (SIZE, SIZE, SIZE) holds that corner
    # 1 cm deep; a box whose face is 2 mm inside the face x = 0 holds that face's vertices 2 mm deep
    sphere = mw.Sphere((SIZE, SIZE, SIZE), 0.01)
    wall = mw.Box((-0.05 + 0.002, SIZE / 2, SIZE / 2), (0.05, 0.5, 0.5))
    w = _world(cube, [sphere, wall])
    got = {p.obstacle: p for p in w.penetrations(w.state(), tolerance=1e-4)}
    xs = _surface_rest(cube, (0.0, 0.0, 0.0))
    in_sphere = np.linalg.norm(xs - SIZE, axis=1) < 0.01 - 1e-4
    assert got[0].count == int(in_sphere.sum()) and got[0].depth == pytest.approx(0.01, abs=1e-12)
    assert got[1].count == int(np.sum(xs[:, 0] < 0.002 - 1e-4)) and got[1].depth == pytest.approx(0.002, abs=1e-12)


def test_a_triangle_mesh_obstacle_is_not_measured(cube):
    V = np.array([[-1.0, -1.0, 0.03], [1.0, -1.0, 0.03], [0.0, 1.0, 0.03]])
    w = _world(cube, [mw.TriangleMesh(V, [[0, 1, 2]])])
    assert w.penetrations(w.state(), tolerance=0.0) == []


@pytest.mark.parametrize("bad", [-1e-3, float("nan"), "1 mm", None])
def test_a_bad_tolerance_is_one_clear_error(cube, bad):
    w = _world(cube, [mw.Ground(0.0)])
    with pytest.raises(InputError, match="penetration tolerance"):
        w.penetrations(w.state(), tolerance=bad)
