"""The fused sustained-contact step (``contact.sustained_step``, ``_contact_step_kernels.sustained_step``):
the same state as the Python event loop bit for bit, taken for a body resting, sliding, and held on a slope,
never adding energy, leaving no vertex inside the ground, and declining (state untouched) when an impact or a
friction stop falls in the step or the modes take part in the sustained solve."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
import modalfem.runtime.contact as C
from modalfem.runtime.rotation import quat_from_axis_angle
from modalfem.runtime.solver import ENERGY_RTOL
from modalfem.runtime.state import _FIELDS, snapshot

DT = 1e-3  # [s]
G = 9.81  # [m/s^2]


SLOPE = np.radians(10.0)  # a plane tilted about y: tan 10 deg = 0.18 < friction 0.3, the body stays put
SLOPE_NORMAL = np.array([np.sin(SLOPE), 0.0, np.cos(SLOPE)])


def _solver(body, friction=0.3, slope=False, box=False):
    plane = rt.Plane(SLOPE_NORMAL, (0.0, 0.0, 0.0)) if slope else rt.Ground(0.0)
    if box:  # a box narrower than the body (0.1 x 0.06 m, top at z = 0): it rests across the box's edges
        plane = rt.Box((0.0, 0.0, -0.05), (0.05, 0.03, 0.05))
    return rt.ModalSolver(body, effects=[rt.Gravity((0, 0, -G)), rt.Obstacles([plane], friction=friction)])


def _on_ground(solver, slope=False, box=False, **kwargs):
    """A state with its lowest vertex on the ground (or on the slope, the body turned to lie on it; or on the box,
    centred and turned by 1e-5 rad about z, not exactly square to its edges)."""
    if slope:
        kwargs["orientation"] = quat_from_axis_angle((0.0, 1.0, 0.0), SLOPE)
    if box:
        kwargs["orientation"] = quat_from_axis_angle((0.0, 0.0, 1.0), 1e-5)
        kwargs["position"] = (3e-7, 2e-7, 0.0)
    st = solver.state(**kwargs)
    up = SLOPE_NORMAL if slope else np.array([0.0, 0.0, 1.0])
    st.position -= up * (solver.body.positions(st, precise=True) @ up).min()
    return st


def _run(monkeypatch, body, fast: bool, steps: int, **kwargs):
    """``steps`` collide + step pairs; per step the state's arrays and the step record; the count of steps the
    fused step did (``fast``) or 0 (the fused step switched off: the Python path only); the impact solves."""
    real, real_resolve = C.sustained_step, C.resolve_contacts
    taken = [0]
    impacts = [0]  # impact solves (on the fused path: those of the contacts touching and approaching at the start)

    def fused(*a):
        done = real(*a)
        taken[0] += done
        return done

    def resolve(*a, **kw):
        impacts[0] += not kw.get("sustained", False)
        return real_resolve(*a, **kw)

    monkeypatch.setattr(C, "sustained_step", fused if fast else (lambda *a: False))
    monkeypatch.setattr(C, "resolve_contacts", resolve)
    solver = _solver(body, slope=kwargs.get("slope", False), box=kwargs.get("box", False))
    st = _on_ground(solver, **kwargs)
    out = []
    for _ in range(steps):
        c = solver.collide(st, DT)
        solver.step(st, st, None, c, DT)
        out.append(([getattr(st, f).copy() for f in _FIELDS], c.vertex.copy(), c.impulses.copy(), c.gap.copy(),
                     c.normal.copy()))
    monkeypatch.setattr(C, "sustained_step", real)
    monkeypatch.setattr(C, "resolve_contacts", real_resolve)
    return out, taken[0], impacts[0]


CASES = {"resting": {}, "sliding": {"velocity": (0.5, 0.2, 0.0), "angular_velocity": (0.0, 0.0, 0.5)},
         "on a slope": {"slope": True}, "across a box's edges": {"box": True}}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_fused_step_gives_the_python_paths_state_bit_for_bit(small_model, monkeypatch, case):
    """Both paths do the same floating-point operations in the same order (the decisions on touching, impacts,
    stops and energy from the same numbers), so every state array and the step record are equal bit for bit
    over 300 steps; the fused step did every step of the body resting on the ground and on a slope (held by
    friction against gravity's pull along it), and nearly every step of the sliding one (while it slides, a
    vertex touches and approaches in most steps: the impact solve of those first, then the fused rest; here
    all 300 on an Intel Xeon, 0.9 of them asked: an impact predicted within a step on another machine's
    rounding would leave that step to the Python path). Across a narrow box's edges the box-edge contacts (points
    of the body's faces) take part in both paths' solves and push-outs."""
    body = rt.ModalBody(small_model)  # float32 shapes (the runtime default)
    steps = 300
    fused, taken, impacts = _run(monkeypatch, body, True, steps, **CASES[case])
    python, none, _ = _run(monkeypatch, body, False, steps, **CASES[case])
    assert none == 0
    if case == "sliding":  # the fused steps after an impact solve were taken (and compared) too
        assert impacts > steps // 4, impacts
    assert taken == steps if case != "sliding" else taken >= 0.9 * steps
    for i, (a, b) in enumerate(zip(fused, python)):
        for name, x, y in zip(_FIELDS, a[0], b[0]):
            assert np.array_equal(x, y), (i, name, x - y)
        for x, y in zip(a[1:], b[1:]):
            assert np.array_equal(x, y), i
    moved = np.linalg.norm(fused[-1][0][2] - fused[0][0][2])  # [m] over the run
    if case == "sliding":  # it did slide
        assert moved > 0.01
    if case == "on a slope":  # friction held it (sliding freely it would go g sin(10 deg) t^2 / 2 = 0.08 m)
        assert moved < 1e-6


@pytest.mark.parametrize("case", sorted(CASES))
def test_fused_steps_never_add_energy_nor_leave_a_vertex_below_the_ground(small_model, monkeypatch, case):
    """Every fused step ends with no more kinetic + modal + gravitational energy than it began with, beyond the
    guard's rounding allowance (``ENERGY_RTOL`` of the step's energy scale, as in ``ModalSolver``), computed here
    with the body's own energy functions; no vertex ends below the ground beyond the float64 rounding of a
    position (1e-12 m, as the contact tests)."""
    body = rt.ModalBody(small_model)
    solver = _solver(body, slope=CASES[case].get("slope", False), box=CASES[case].get("box", False))
    st = _on_ground(solver, **CASES[case])
    up = SLOPE_NORMAL if CASES[case].get("slope") else np.array([0.0, 0.0, 1.0])
    real = C.sustained_step
    taken = []

    def fused(*a):
        taken.append(real(*a))
        return taken[-1]

    monkeypatch.setattr(C, "sustained_step", fused)

    def energy(s):
        return body.kinetic_energy_rigid(s) + body.modal_energy(s) + body.mass * G * s.position[2]

    for i in range(200):
        e0, p0 = energy(st), st.position.copy()
        own0 = e0 - body.mass * G * p0[2]
        solver.advance(st, DT)
        if taken[-1]:
            own1 = energy(st) - body.mass * G * st.position[2]
            scale = own0 + own1 + body.mass * G * (np.linalg.norm(st.position - p0) + body.radius)
            assert energy(st) <= e0 + ENERGY_RTOL * scale, i
        assert (body.positions(st, precise=True) @ up).min() >= -1e-12, i
    assert sum(taken) >= (0.9 * 200 if case == "sliding" else 200), sum(taken)  # (see the test above)


def _call(solver, st, dt=DT):
    loads = rt.solver.Loads(solver.body.mode_count)
    for e in solver._load_effects:
        e.loads(solver, st, dt, loads)
    return C.sustained_step(solver, st, solver.collide(st, dt), loads, dt)


def test_the_fused_step_declines_an_impact_or_a_stop_and_leaves_the_state_untouched(small_model):
    body = rt.ModalBody(small_model)
    solver = _solver(body, friction=0.5)
    # resting: it does the step
    st = _on_ground(solver)
    assert _call(solver, st)
    # landing: 0.2 mm above the ground at 1 m/s, the impact falls inside the step
    st = _on_ground(solver, velocity=(0.0, 0.0, -1.0))
    st.position[2] += 2e-4
    before = snapshot(st)
    assert not _call(solver, st)
    assert all(np.array_equal(a, b) for a, b in zip(snapshot(st), before))
    # sliding so slowly that friction (mu g = 4.9 m/s^2) stops it at about 0.4 of the step
    st = _on_ground(solver, velocity=(0.4 * 0.5 * G * DT, 0.0, 0.0))
    before = snapshot(st)
    assert not _call(solver, st)
    assert all(np.array_equal(a, b) for a, b in zip(snapshot(st), before))
    # the same state on the Python path stops where Coulomb friction does
    solver.advance(st, DT)
    assert abs(st.velocity[0]) < 1e-9


def test_modes_taking_part_keep_the_python_path(small_model):
    """A sub-step longer than the slowest mode's 1 / omega: the sustained solve acts on the modes, which the
    fused (rigid-response) step does not do: it declines."""
    body = rt.ModalBody(small_model)
    solver = _solver(body)
    st = _on_ground(solver)
    dt = 0.5 / body.omega[0]
    assert not _call(solver, st, dt)
