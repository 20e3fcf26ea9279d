"""A modal body resting across the edges of a box narrower than it (runtime contact, one body): after settling, no
step is split by the energy guard and the energy never rises, at dt = 1e-4 ... 0.1 s.

The steel block of the runtime fixtures (0.2 x 0.1 x 0.05 m, 8 modes, all faster than 1 / dt here) lies on a box
0.1 m wide in x and 0.06 m in y: its bottom vertices at x = -0.05, 0, 0.05 (the row y = 0) carry it, those at
x = +-0.05 right above the box's edges. Impacts excite its modes; their swing (faster than the step, left out of
the sustained solve) put vertices a few nanometres into the box, and lifting the 7.85 kg body out of them cost more
than its vibration held: the push-out zeroed the velocities and kept the deformation, which the next step released
again, so every 1 ms step was halved seven levels deep (127 sub-steps, ~39 ms per step)."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
import modalfem.runtime.contact as C
from modalfem.runtime.rotation import quat_from_axis_angle
from modalfem.runtime.solver import ENERGY_RTOL

G = 9.81  # [m/s^2]
SETTLE = 0.5  # [s] the landing from 0.1 mm and its rocking


def _across_box(body, dt, monkeypatch, *, half=(0.05, 0.03), centre_x=0.0, start=(3e-7, 2e-7), turn=1e-5,
                drop=1e-4, duration=2.0, exhausted=None):
    """Step the body lying across a box (top at z = 0, centre at x = ``centre_x`` [m], half extents ``half`` [m] in
    x and y) for ``duration`` [s], from ``start`` (x, y) [m], turned by ``turn`` [rad] about z (not exactly square
    to the edges) and ``drop`` [m] above the box; per step: the guard's energy [J] and the number of Python contact
    sub-steps (``step_with_contacts`` calls: 0 when the fused step did it, 1 on the Python path, more when the
    energy guard split the step). With ``exhausted`` (a list), the rises [J] the energy guard accepted because it
    had no halving left are appended."""
    box = rt.Box((centre_x, 0.0, -0.05), (*half, 0.05))
    solver = rt.ModalSolver(body, effects=[rt.Gravity((0, 0, -G)), rt.Obstacles([box], friction=0.5)])
    st = solver.state(orientation=quat_from_axis_angle((0.0, 0.0, 1.0), turn))
    st.position[:] = (*start, 0.0)
    st.position[2] -= body.positions(st, precise=True)[:, 2].min() - drop
    calls = [0]
    real = C.step_with_contacts

    def counted(*a, **kw):
        calls[0] += 1
        return real(*a, **kw)

    monkeypatch.setattr(C, "step_with_contacts", counted)
    if exhausted is not None:  # the guard's last level: a step it must accept whatever its energy
        guarded = rt.ModalSolver._contact_step_without_gain

        def last_level(self, s, contacts, loads, h, depth):
            if depth > 0:
                return guarded(self, s, contacts, loads, h, depth)
            own0, e0 = C.guard_energy(self, s, loads)
            p0 = s.position.copy()
            guarded(self, s, contacts, loads, h, depth)
            own1, e1 = C.guard_energy(self, s, loads)  # the guard's own test (ModalSolver._contact_step_without_gain)
            scale = own0 + own1 + float(np.linalg.norm(loads.force)) * (float(np.linalg.norm(s.position - p0))
                                                                          + self.body.radius)
            if e1 > e0 + ENERGY_RTOL * scale:
                exhausted.append(e1 - e0)

        monkeypatch.setattr(rt.ModalSolver, "_contact_step_without_gain", last_level)
    energy, sub, lowest = [], [], []
    for _ in range(int(round(duration / dt))):
        before = calls[0]
        solver.step(st, st, None, solver.collide(st, dt), dt)
        sub.append(calls[0] - before)
        energy.append(solver.energy(st) + body.mass * G * st.position[2])
        lowest.append(box.signed_distance(body.positions(st, precise=True))[0].min())
    return np.array(energy), np.array(sub), np.array(lowest), st


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2, 0.1])
def test_a_body_across_box_edges_takes_no_split_steps_and_never_gains_energy(small_body, monkeypatch, dt):
    energy, sub, lowest, st = _across_box(small_body, dt, monkeypatch)
    settled = int(round(SETTLE / dt))
    assert sub[settled:].max() <= 1, f"energy guard split {np.count_nonzero(sub[settled:] > 1)} steps after settling"
    # the guard's tolerance: ENERGY_RTOL of its energy scale, m g (|shift| + radius) for a body at rest
    tol = ENERGY_RTOL * small_body.mass * G * (2.0 * small_body.radius)
    gains = np.diff(energy)
    assert gains.max() <= tol, f"energy rose by {gains.max():.3g} J in one step"
    assert lowest.min() >= -1e-12, f"a vertex ended {-lowest.min():.3g} m inside the box"
    assert abs(st.position[0]) < 0.01 and st.position[2] > 0.0  # still lying across the box


def _steel_plate(size, cells):
    """A steel plate of ``size`` [m] (P1 on ``cells`` hexahedra, 8 undamped modes), float64."""
    import modalfem
    from modalfem.mesh import box
    from modalfem.model import ModalModel

    mesh = box(size=size, cells=cells)
    res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
    return rt.ModalBody(ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 0.0)), dtype=np.float64)


@pytest.fixture(scope="module")
def plate_body():
    """A steel plate 0.2 x 0.2 x 0.025 m (P1, 4 x 4 x 1 hexahedra, 8 modes from ~5.9 kHz), float64."""
    return _steel_plate((0.2, 0.2, 0.025), (4, 4, 1))


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2, 0.1])
def test_a_plate_on_a_smaller_box_never_exhausts_the_energy_guard_nor_gains_energy(plate_body, monkeypatch, dt):
    """The plate lies on a box 0.1 x 0.1 m: its bottom vertices at x, y in {-0.05, 0, 0.05} carry it, the outer ones
    right above the box's edges and corners (some a few tenths of a micrometre outside). Its fast modes (faster
    than every step here) swing the contact vertices about the rest shape. The sustained solve, which leaves
    them out, held the deformed vertices out of the box: while a mode held the centre vertex up, the body sank
    (~10 nm below its rest shape), and when the swing turned the push-out had to lift the whole body with no
    energy left to pay (the vibration that had held it was gone): at dt = 1 ms the guard halved steps to its last
    level and accepted rises of ~6e-7 J (of 0.97 J). Now the solve holds the rest shape out (the modes it leaves
    out swing about it) and the push-out's lift is paid by shrinking the swing."""
    exhausted: list = []
    energy, sub, lowest, st = _across_box(plate_body, dt, monkeypatch, half=(0.05, 0.05), duration=1.0,
                                          exhausted=exhausted)
    assert not exhausted, f"the energy guard accepted {len(exhausted)} rises up to {max(exhausted):.3g} J"
    tol = ENERGY_RTOL * plate_body.mass * G * (2.0 * plate_body.radius)  # as above
    gains = np.diff(energy)
    assert gains.max() <= tol, f"energy rose by {gains.max():.3g} J in one step"
    settled = int(round(SETTLE / dt))
    assert sub[settled:].max() <= 1, f"energy guard split {np.count_nonzero(sub[settled:] > 1)} steps after settling"
    assert lowest.min() >= -1e-12, f"a vertex ended {-lowest.min():.3g} m inside the box"
    assert np.hypot(*st.position[:2]) < 0.01 and st.position[2] > 0.0  # still on the box


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 0.1])
def test_a_bar_with_its_centre_of_mass_over_the_last_supported_row_takes_no_split_steps(small_body, monkeypatch, dt):
    """The block lies touching a box as wide as it or more (y half 0.1 m) that ends at x = 0.025 m, its centre of
    mass at x = -1 mm right over its last supported row of vertices (x = -1 mm; the next row, x = 49 mm, is beyond
    the edge). Measured: at dt = 1 ms every step is split once (3 contact sub-steps) and the guard's last level
    accepted rises of up to ~7e-8 J; at 10 ms 511 sub-steps per step (not run here: ~0.4 s a step); at 0.1 ms one
    accepted rise of ~1e-7 J; at 0.1 s the bar tips off the box.

    Cause (seen at 1 ms): the rigid sustained solve starts from one common impulse at all 9 contacts (3 rows), whose
    torque the sweeps must undo (the answer loads only the row under the centre of mass); after its 10 sweeps a
    pivot vertex is still left ~20 nm short of its end gap, and the push-out's lift of the resting bar (m g 23 nm,
    ~1.8e-6 J) has nothing to pay it, so the guard halves the step. Sweeping on while a contact falls short by more
    than the guard's allowance (2 ENERGY_RTOL max|r| / dt; ~100 sweeps here) makes this test pass at all four dt,
    but the block across the narrow box above (resting on its one row y = 0, as the vertices at y = +-0.05 m are
    beyond the box's sides) then tipped over that row as over a knife edge and gained 1.9e-9 J at 10 ms: the
    unconverged solve had been holding it. Now the box's edges carry the body's faces (box-edge contacts,
    ``_contact_edge_kernels``) and the rigid sustained solve sweeps to convergence (``RIGID_SWEEPS``)."""
    exhausted: list = []
    energy, sub, lowest, st = _across_box(small_body, dt, monkeypatch, half=(0.15, 0.1), centre_x=0.025 - 0.15,
                                          start=(-1e-3, 0.0), turn=0.0, drop=0.0, duration=1.0, exhausted=exhausted)
    assert abs(st.position[0] + 1e-3) < 1e-3 and st.position[2] > 0.0  # still on the box
    assert not exhausted, f"the energy guard accepted {len(exhausted)} rises up to {max(exhausted):.3g} J"
    settled = int(round(SETTLE / dt))
    assert sub[settled:].max() <= 1, f"energy guard split {np.count_nonzero(sub[settled:] > 1)} steps after settling"
    tol = ENERGY_RTOL * small_body.mass * G * (2.0 * small_body.radius)
    assert np.diff(energy).max() <= tol, f"energy rose by {np.diff(energy).max():.3g} J in one step"


def test_the_push_out_of_a_vibrating_body_at_rest_shrinks_the_vibration_instead_of_adding_energy(small_body):
    """A body at rest on the ground whose mode-0 deformation puts a vertex 1 um below it: lifting the body by
    ~1 um costs m g 1e-6 (~8e-5 J) that no motion pays (it is at rest); the push-out takes it from the vibration
    (which holds more), ends with no vertex inside and no energy gained (before: the lift was unpaid)."""
    solver = rt.ModalSolver(small_body, effects=[rt.Gravity((0, 0, -G)), rt.Obstacles([rt.Ground(0.0)])])
    st = solver.state()
    st.position[2] -= small_body.positions(st, precise=True)[:, 2].min()  # the rest shape touching the ground
    drop = small_body.positions(st, precise=True)[:, 2]
    st.q[0] = 1.0
    dz = small_body.positions(st, precise=True)[:, 2] - drop  # mode 0's vertical displacement per unit q
    st.q[0] = -1e-6 / dz.max() if dz.max() > -dz.min() else 1e-6 / -dz.min()  # ~1 um under
    depth = -small_body.positions(st, precise=True)[:, 2].min()
    assert 0.5e-6 < depth < 2e-6
    lift_cost = small_body.mass * G * depth
    vibration = small_body.modal_energy(st)
    assert vibration > lift_cost  # the vibration can pay; the (zero) motion cannot
    e0 = solver.energy(st) + small_body.mass * G * st.position[2]
    q0 = abs(st.q[0])
    C.push_out(solver, st, solver.collide(st, 1e-3), accel=np.array([0.0, 0.0, -G]))
    e1 = solver.energy(st) + small_body.mass * G * st.position[2]
    assert small_body.positions(st, precise=True)[:, 2].min() >= 0.0
    assert e1 <= e0 + 1e-12 * e0, (e1 - e0, lift_cost)
    assert abs(st.q[0]) < q0  # the vibration shrank (it paid for the lift)


@pytest.fixture(scope="module")
def thin_plate():
    """A steel plate 0.2 x 0.1 x 0.01 m (P1, 4 x 2 x 1 hexahedra, 8 modes), float64."""
    return _steel_plate((0.2, 0.1, 0.01), (4, 2, 1))


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2, 0.1])
def test_a_thin_plate_across_a_narrow_box_rests_on_its_edges(thin_plate, monkeypatch, dt):
    """The plate lies across the narrow box (0.1 x 0.06 m) as the block above: only its middle row of bottom
    vertices (y = 0) is over the box, the rows y = +-0.05 m are beyond the box's sides, so what keeps it from
    rocking about that row are the box's edges y = +-0.03 m under its bottom faces. With vertex contact alone
    (measured before the box-edge contacts): 15 contact sub-steps per step at 1 ms, 63 at 10 ms, ~1,790 at 0.1 s,
    the guard's last level reached ~4,400 times (rises up to 3e-8 J). Now: after settling no step is split, the
    guard never runs out of halvings, the energy never rises and no vertex ends inside the box."""
    exhausted: list = []
    energy, sub, lowest, st = _across_box(thin_plate, dt, monkeypatch, duration=1.0, exhausted=exhausted)
    assert not exhausted, f"the energy guard accepted {len(exhausted)} rises up to {max(exhausted):.3g} J"
    settled = int(round(SETTLE / dt))
    assert sub[settled:].max() <= 1, f"energy guard split {np.count_nonzero(sub[settled:] > 1)} steps after settling"
    tol = ENERGY_RTOL * thin_plate.mass * G * (2.0 * thin_plate.radius)  # as above
    assert np.diff(energy).max() <= tol, f"energy rose by {np.diff(energy).max():.3g} J in one step"
    assert lowest.min() >= -1e-12, f"a vertex ended {-lowest.min():.3g} m inside the box"
    assert abs(st.position[0]) < 0.01 and abs(st.position[1]) < 0.01 and st.position[2] > 0.0  # still on the box
