"""Impulse and force projection, opt-in effects (counted calls) and bad input of ``ModalSolver``."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.errors import SimulationError
from modalfem.runtime import contact as contact_mod
from modalfem.runtime import effects as rt_effects
from modalfem.runtime.rotation import quat_from_axis_angle


def _moving_state(solver, rng):
    st = solver.state(position=(0.1, 0.2, 0.3), orientation=quat_from_axis_angle([0, 0.6, 0.8], 0.7),
                      velocity=(0.5, -0.1, 0.2), angular_velocity=(1.0, -2.0, 0.5))
    st.q[:] = rng.normal(size=st.q.size) * 1e-4
    st.qdot[:] = rng.normal(size=st.q.size) * 1e-2
    return st


def _point_velocity(body, st, point):
    R = st.rotation()
    phi = body.point_shapes(point)
    r = R @ (body.point_rest(point) + phi @ st.q)
    return st.velocity + np.cross(body.angular_velocity(st), r) + R @ (phi @ st.qdot), r


def test_impulse_changes_rigid_and_modal_velocities_by_its_projection(small_body, small_model):
    solver = rt.ModalSolver(small_body)
    rng = np.random.default_rng(0)
    st = _moving_state(solver, rng)
    p = small_body.surface_point(7, (0.1, 0.6, 0.3))
    J = np.array([0.02, -0.05, 0.01])
    before = st.copy()
    solver.apply_impulse(st, p, J)
    R = st.rotation()
    tri = small_model.triangles[7]
    phi_p = sum(w * small_model.shapes[3 * v : 3 * v + 3] for w, v in zip((0.1, 0.6, 0.3), tri))  # (3, r)
    x_p = sum(w * small_model.vertices[v] for w, v in zip((0.1, 0.6, 0.3), tri)) - small_model.center_of_mass
    r = R @ (x_p + phi_p @ before.q)
    assert np.allclose(st.velocity - before.velocity, J / small_model.mass, rtol=1e-14, atol=0)
    assert np.allclose(st.angular_momentum - before.angular_momentum, np.cross(r, J), rtol=1e-13, atol=1e-18)
    assert np.allclose(st.qdot - before.qdot, phi_p.T @ (R.T @ J), rtol=1e-13, atol=1e-18)
    assert np.array_equal(st.q, before.q) and np.array_equal(st.position, before.position)


def test_impulse_work_equals_impulse_times_mean_point_velocity(small_body):
    """For an impulse J at a point, the energy change is J . (u_before + u_after) / 2 (u: velocity
    of that material point); true only if the rigid and modal projections are consistent."""
    solver = rt.ModalSolver(small_body)
    st = _moving_state(solver, np.random.default_rng(3))
    p = small_body.surface_point(20, (0.5, 0.25, 0.25))
    J = np.array([-0.3, 0.1, 0.7])
    e0, (u0, _) = solver.energy(st), _point_velocity(small_body, st, p)
    solver.apply_impulse(st, p, J)
    e1, (u1, _) = solver.energy(st), _point_velocity(small_body, st, p)
    assert abs((e1 - e0) - J @ (u0 + u1) / 2) <= 1e-12 * abs(e1 - e0)


def test_a_point_force_projects_like_the_impulse_it_delivers(small_body):
    solver = rt.ModalSolver(small_body)
    st = _moving_state(solver, np.random.default_rng(4))
    p = small_body.surface_point(11)
    F = np.array([3.0, -1.0, 2.0])
    loads = rt.Loads(small_body.mode_count)
    solver.add_point_force(st, p, F, loads)
    kicked = st.copy()
    solver.apply_impulse(kicked, p, F)  # impulse of 1 N s
    assert np.allclose(loads.force * small_body.mass ** -1, kicked.velocity - st.velocity)
    assert np.allclose(loads.torque, kicked.angular_momentum - st.angular_momentum)
    assert np.allclose(loads.modal, kicked.qdot - st.qdot)


def test_control_impulse_in_a_step_equals_impulse_then_step(small_body):
    solver = rt.ModalSolver(small_body)
    st = _moving_state(solver, np.random.default_rng(5))
    p = small_body.surface_point(2)
    a, b = st.copy(), st.copy()
    solver.step(a, a, rt.Control().add_impulse(p, (0, 0, 0.1)), None, 1e-4)
    solver.apply_impulse(b, p, (0, 0, 0.1))
    solver.step(b, b, None, None, 1e-4)
    for name in ("q", "qdot", "position", "orientation", "velocity", "angular_momentum"):
        assert np.allclose(getattr(a, name), getattr(b, name), rtol=1e-14, atol=1e-300), name


def test_step_writes_state_out_and_keeps_state_in(small_body):
    solver = rt.ModalSolver(small_body, effects=[rt.Gravity()])
    st = _moving_state(solver, np.random.default_rng(6))
    keep = st.copy()
    out = st.copy()
    solver.step(st, out, None, None, 1e-3)
    assert np.array_equal(st.q, keep.q) and np.array_equal(st.position, keep.position)
    assert out.time == pytest.approx(1e-3) and not np.array_equal(out.q, keep.q)


class _Counter:
    def __init__(self):
        self.calls = 0


def _spy(monkeypatch, owner, name, counter):
    original = getattr(owner, name)

    def wrapper(*args, **kwargs):
        counter.calls += 1
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, wrapper)


def test_a_step_without_effects_calls_no_effect_code(monkeypatch, small_body):
    """Only what is asked for runs: with no effects, no contacts and an empty control, a step
    calls neither reconstruction, collision, contact resolution, gravity, pseudo-forces nor point
    projections - only the modal and rigid updates."""
    counter = _Counter()
    for owner, name in [(rt.ModalBody, "positions"), (rt.ModalBody, "normals"), (rt.ModalBody, "point_shapes"),
                        (contact_mod, "find_contacts"), (contact_mod, "resolve_contacts"), (contact_mod, "push_out"),
                        (rt_effects.Gravity, "loads"), (rt.PseudoForces, "loads"), (rt.ModalSolver, "add_point_force"),
                        (rt.ModalSolver, "apply_impulse")]:
        _spy(monkeypatch, owner, name, counter)
    modal = _Counter()
    _spy(monkeypatch, rt.ModalIntegrator, "step", modal)
    solver = rt.ModalSolver(small_body)
    st = _moving_state(solver, np.random.default_rng(7))
    assert solver.collide(st, 1e-3) is None
    for _ in range(10):
        solver.step(st, st, rt.Control(), solver.collide(st, 1e-3), 1e-3)
        solver.advance(st, 1e-3)
    assert counter.calls == 0 and modal.calls == 20


def test_effects_run_once_per_step_and_state_dependent_ones_twice(small_body):
    class Spy:
        def __init__(self, dependent):
            self.calls, self.state_dependent = 0, dependent

        def loads(self, solver, state, dt, loads):
            self.calls += 1

    plain, dependent = Spy(False), Spy(True)
    solver = rt.ModalSolver(small_body, effects=[plain, dependent])
    st = solver.state()
    for _ in range(5):
        solver.advance(st, 1e-3)
    assert plain.calls == 5 and dependent.calls == 10


@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan"), float("inf")])
def test_bad_dt_is_refused(small_body, dt):
    solver = rt.ModalSolver(small_body)
    st = solver.state()
    with pytest.raises(SimulationError, match="dt"):
        solver.step(st, st, None, None, dt)


@pytest.mark.parametrize("J", [(np.nan, 0, 0), (0, np.inf, 0), (1, 2)])
def test_nan_impulses_and_forces_are_refused(small_body, J):
    solver = rt.ModalSolver(small_body)
    st = solver.state()
    p = small_body.surface_point(0)
    with pytest.raises(SimulationError, match="impulse"):
        rt.Control().add_impulse(p, J)
    with pytest.raises(SimulationError, match="force"):
        rt.Control().add_force(p, J)
    raw = rt.Control(impulses=[(p, np.array(J, dtype=float))])
    with pytest.raises(SimulationError, match="impulse"):
        solver.step(st, st, raw, None, 1e-3)
    with pytest.raises(SimulationError, match="impulse"):
        solver.apply_impulse(st, p, J)


def test_point_off_the_surface_in_a_control_is_refused(small_body):
    solver = rt.ModalSolver(small_body)
    st = solver.state()
    with pytest.raises(SimulationError, match="off the surface"):
        solver.step(st, st, rt.Control().add_impulse(10**6, (0, 0, 1)), None, 1e-3)
    with pytest.raises(SimulationError, match="off the surface"):
        solver.step(st, st, rt.Control().add_impulse(rt.SurfacePoint(10**6, (1, 0, 0)), (0, 0, 1)), None, 1e-3)


def test_non_finite_state_is_refused(small_body):
    with pytest.raises(SimulationError, match="not finite"):
        rt.State(np.full(small_body.mode_count, np.nan), np.zeros(small_body.mode_count))


def _arrays(st):
    return [a.copy() for a in (st.q, st.qdot, st.position, st.orientation, st.velocity, st.angular_momentum)]


@pytest.mark.parametrize("bad", [
    ("impulse", 10**6, (0, 0, 1)),  # vertex out of range
    ("impulse", 0, (0, np.nan, 1)),  # non-finite
    ("impulse", 0, (0, 1)),  # wrong shape
    ("impulse", "corner", (0, 0, 1)),  # not a point
    ("force", 10**6, (0, 0, 1)),
    ("force", 3, (np.inf, 0, 0)),
    ("body_force", None, (0, np.nan, 0)),
])
def test_a_control_with_a_bad_last_entry_leaves_the_state_untouched(small_body, bad):
    """The whole Control is validated before anything is applied: a good first impulse followed by a
    bad entry (impulse, force or body force) raises one SimulationError naming the entry, and the
    state arrays are bit-identical to before (in place and into a separate output state)."""
    kind, point, vec = bad
    solver = rt.ModalSolver(small_body, effects=[rt.Gravity(), rt.Obstacles([rt.Ground(-1.0)])])
    st = _moving_state(solver, np.random.default_rng(11))
    control = rt.Control(impulses=[(0, np.array([0.0, 0.0, 0.5])), (3, np.array([0.1, 0.0, 0.0]))])
    if kind == "impulse":
        control.impulses.append((point, np.asarray(vec, dtype=float)))
    elif kind == "force":
        control.forces.append((point, np.asarray(vec, dtype=float)))
    else:
        control.body_force = np.asarray(vec, dtype=float)
    before = _arrays(st)
    out = solver.state()
    out_before = _arrays(out)
    with pytest.raises(SimulationError, match=kind.replace("_", " ")) as info:
        solver.advance(st, 1e-3, control)
    assert "\n" not in str(info.value)
    with pytest.raises(SimulationError):
        solver.step(st, out, control, None, 1e-3)
    for a, b in zip(before, _arrays(st)):
        assert np.array_equal(a, b)
    for a, b in zip(out_before, _arrays(out)):
        assert np.array_equal(a, b)
    assert st.time == 0.0


def test_a_step_that_fails_inside_restores_the_state(small_body):
    """An effect raising in the middle of a step (after the impulses were applied) leaves the state
    as it was before the call."""
    class Boom:
        def loads(self, solver, state, dt, loads):
            raise SimulationError("boom")

    solver = rt.ModalSolver(small_body, effects=[Boom()])
    st = _moving_state(solver, np.random.default_rng(12))
    before = _arrays(st)
    with pytest.raises(SimulationError, match="boom"):
        solver.advance(st, 1e-3, rt.Control().add_impulse(0, (0, 0, 1.0)))
    for a, b in zip(before, _arrays(st)):
        assert np.array_equal(a, b)


def test_contacts_of_the_wrong_type_are_refused(small_body):
    solver = rt.ModalSolver(small_body)
    st = solver.state()
    with pytest.raises(SimulationError, match="contacts"):
        solver.step(st, st, None, [1, 2], 1e-3)
