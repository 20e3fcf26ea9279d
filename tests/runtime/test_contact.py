"""Contact with the ground and static obstacles: no penetration, restitution, Coulomb friction, rest."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.errors import InputError
from modalfem.runtime.rotation import quat_from_axis_angle


def _min_gap(body, st, obstacle):
    return obstacle.signed_distance(body.positions(st))[0].min()


def test_a_dropped_tumbling_body_never_goes_below_the_ground_and_comes_to_rest(small_model):
    body = rt.ModalBody(small_model, damping=(0.0, 2e-6))
    ground = rt.Ground(0.0)
    solver = rt.ModalSolver(body, effects=[rt.Gravity(), rt.Obstacles([ground], restitution=0.4, friction=0.6)])
    st = solver.state(position=(0, 0, 0.15), orientation=quat_from_axis_angle([0.3, 0.9, 0.2] / np.linalg.norm(
        [0.3, 0.9, 0.2]), 0.8), velocity=(0.2, 0.0, -0.5), angular_velocity=(2.0, -3.0, 4.0))
    dt, rang, track = 2e-3, 0.0, []
    for i in range(600):
        solver.advance(st, dt)
        assert _min_gap(body, st, ground) >= -1e-12, i
        rang = max(rang, body.modal_energy(st))
        track.append(st.position.copy())
    assert rang > 1e-7  # the impacts made it ring
    assert np.linalg.norm(track[-1] - track[-100]) < 1e-4  # still over the last 0.2 s
    # at rest: velocities of order g dt (one step of gravity before the contact takes it out)
    assert np.linalg.norm(st.velocity) < 2 * 9.81 * dt
    assert np.linalg.norm(body.angular_velocity(st)) < 0.2
    assert body.modal_energy(st) < 0.1 * rang  # only the small sag of resting contact remains
    x = body.positions(st)
    assert x[:, 2].min() < 1e-6  # lying on the ground, not hovering


def test_restitution_of_a_flat_rigid_impact():
    """A body falling flat (no rotation) bounces with -e times its impact speed (modes off, no friction)."""

    body = _flat_box()
    for e in (0.0, 0.5, 0.9):
        solver = rt.ModalSolver(body, effects=[rt.Obstacles([rt.Ground(0.0)], restitution=e, friction=0.0,
                                                             modal=False, iterations=30)])
        st = solver.state(position=(0, 0, 0.0502), velocity=(0, 0, -1.0))
        for _ in range(10):
            solver.advance(st, 1e-3)
        assert st.velocity[2] == pytest.approx(e * 1.0, abs=1e-6)
        assert np.linalg.norm(body.angular_velocity(st)) < 1e-6


def _flat_box():
    """Rigid unit-mass 0.2 x 0.2 x 0.1 box surface (8 corners, 12 triangles), one dummy stiff mode."""
    from types import SimpleNamespace

    c = np.array([[x, y, z] for z in (-0.05, 0.05) for y in (-0.1, 0.1) for x in (-0.1, 0.1)])
    tris = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                     [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    model = SimpleNamespace(vertices=c, triangles=tris, shapes=np.zeros((24, 1)), omega=np.array([1e4]), mass=1.0,
                            center_of_mass=np.zeros(3), inertia=np.diag([0.0042, 0.0042, 0.0067]), damping=(0.0, 0.0))
    return rt.ModalBody(model)


def test_coulomb_friction_decelerates_a_sliding_body_at_mu_g():
    body = _flat_box()
    mu, g = 0.4, 9.81
    solver = rt.ModalSolver(body, effects=[rt.Gravity((0, 0, -g)), rt.Obstacles(
        [rt.Ground(0.0)], restitution=0.0, friction=mu, modal=False, iterations=30)])
    st = solver.state(position=(0, 0, 0.05), velocity=(2.0, 0.0, 0.0))
    dt, n = 1e-3, 200
    for _ in range(n):
        solver.advance(st, dt)
    # the contact takes out the previous step's gravity velocity m g dt, so friction acts from step 2 on
    assert st.velocity[0] == pytest.approx(2.0 - mu * g * (n - 1) * dt, rel=1e-9)
    assert abs(st.velocity[1]) < 1e-9 and st.position[2] == pytest.approx(0.05, abs=1e-9)


def test_an_impact_makes_the_modes_ring_only_when_modal_contact_is_on(small_model):
    body = rt.ModalBody(small_model)
    energies = []
    for modal in (False, True):
        solver = rt.ModalSolver(body, effects=[rt.Obstacles([rt.Ground(0.0)], modal=modal)])
        st = solver.state(position=(0, 0, 0.0251), orientation=quat_from_axis_angle([1, 0, 0], 0.2),
                          velocity=(0, 0, -1.0))
        for _ in range(20):
            solver.advance(st, 1e-4)
        energies.append(body.modal_energy(st))
    assert energies[0] == 0.0 and energies[1] > 1e-6


@pytest.mark.parametrize("obstacle", [rt.Sphere((0.02, 0.01, -0.3), 0.3),
                                      rt.Box((0.0, 0.0, -0.1), (0.05, 0.3, 0.1)),
                                      rt.Plane((0.2, 0.0, 1.0), (0, 0, 0))])
def test_no_vertex_ends_inside_a_static_obstacle(small_model, obstacle):
    body = rt.ModalBody(small_model, damping=(0.0, 2e-6))
    solver = rt.ModalSolver(body, effects=[rt.Gravity(), rt.Obstacles([obstacle], restitution=0.3, friction=0.3)])
    st = solver.state(position=(0, 0, 0.12), angular_velocity=(1.0, 2.0, 0.0))
    for i in range(250):
        solver.advance(st, 2e-3)
        assert _min_gap(body, st, obstacle) >= -1e-12, i
    assert st.position[2] < 0.1  # it did fall onto the obstacle


def test_signed_distances_of_the_obstacles():
    rng = np.random.default_rng(0)
    x = rng.uniform(-2, 2, size=(500, 3))
    sph = rt.Sphere((0.1, 0.2, 0.3), 0.7)
    gap, n = sph.signed_distance(x)
    assert np.allclose(gap, np.linalg.norm(x - sph.center, axis=1) - 0.7)
    assert np.allclose(sph.center + (0.7 + gap)[:, None] * n, x)
    R = rt.rotation.quat_to_matrix(quat_from_axis_angle([0, 0, 1], 0.5))
    box = rt.Box((0.2, 0.0, -0.1), (0.5, 0.3, 0.8), rotation=R)
    gap, n = box.signed_distance(x)
    p = (x - box.center) @ R
    outside = np.linalg.norm(np.maximum(np.abs(p) - box.half, 0), axis=1)
    inside = np.min(box.half - np.abs(p), axis=1)  # depth below the nearest face
    expect = np.where(outside > 0, outside, -inside)
    assert np.allclose(gap, expect)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    moved = x - gap[:, None] * n  # onto the surface
    assert np.allclose(box.signed_distance(moved)[0], 0.0, atol=1e-12)


def test_bad_obstacles_are_refused():
    with pytest.raises(InputError):
        rt.Sphere((0, 0, 0), -1.0)
    with pytest.raises(InputError):
        rt.Box((0, 0, 0), (1.0, 0.0, 1.0))
    with pytest.raises(InputError):
        rt.Plane((0, 0, 0))
    with pytest.raises(InputError):
        rt.Obstacles([rt.Ground()], restitution=1.5)
    with pytest.raises(InputError):
        rt.Obstacles([])
