"""The compiled pieces that replaced numpy glue of the modal step (issue 17): the end-of-step settle (tiny modal values
flushed, finiteness), the cached rotation matrix, and the byte fingerprint that lets the step reuse the contacts found
by ``collide`` at its state. Each is checked against what it replaced or against hand-set values."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.errors import SimulationError
from modalfem.runtime import contact as C
from modalfem.runtime._contact_step_kernels import settle
from modalfem.runtime.rotation import quat_to_matrix
from modalfem.runtime.solver import TINY


def test_settle_flushes_only_values_below_tiny_and_keeps_the_rest_bit_for_bit():
    q = np.array([0.5 * TINY, -0.5 * TINY, TINY, -TINY, 1e-3, -2.0, 0.0, 5e-324])
    qdot = np.array([-0.9 * TINY, 2.0 * TINY, 3.0, 1e-160])
    q0, qd0 = q.copy(), qdot.copy()
    assert settle(q, qdot, np.zeros(3), np.zeros(3), np.zeros(3), TINY)
    assert np.array_equal(q, np.where(np.abs(q0) < TINY, 0.0, q0))
    assert np.array_equal(qdot, np.where(np.abs(qd0) < TINY, 0.0, qd0))
    assert q[2] == TINY and q[3] == -TINY and qdot[1] == 2.0 * TINY and q[4] == 1e-3  # at or above: untouched


@pytest.mark.parametrize("which", range(5))
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_settle_reports_a_non_finite_value_in_any_array(which, bad):
    arrays = [np.ones(4), np.ones(4), np.ones(3), np.ones(3), np.ones(3)]
    assert settle(*arrays, TINY)
    arrays[which][1] = bad
    assert not settle(*arrays, TINY)


def test_settle_reports_an_overflowing_sum_like_the_numpy_check_it_replaced():
    big = np.array([1.5e308, 1.5e308, 0.0])
    assert not settle(np.zeros(2), np.zeros(2), big, np.zeros(3), np.zeros(3), TINY)


def test_a_step_that_turns_the_state_non_finite_raises_and_restores_it(small_model):
    body = rt.ModalBody(small_model)
    solver = rt.ModalSolver(body, effects=[rt.Gravity()])
    st = solver.state(position=(0.0, 0.0, 1.0))
    st.velocity[:] = (1e307, 0.0, 0.0)  # finite; the position after 1e3 s is not
    before = C.snapshot(st)
    with pytest.raises(SimulationError, match="non-finite"):
        solver.step(st, st, None, None, 1e3)
    assert all(np.array_equal(a, b) for a, b in zip(C.snapshot(st)[:-1], before[:-1]))


def test_a_free_step_flushes_modes_that_rang_down_below_tiny(small_model):
    body = rt.ModalBody(small_model)
    solver = rt.ModalSolver(body)
    st = solver.state()
    st.q[:] = 1e-12 * TINY  # (omega^2 dt q stays below TINY too)
    st.qdot[0] = 1.0
    solver.step(st, st, None, None, 1e-6)
    assert np.all(st.q[1:] == 0.0) and np.all(st.qdot[1:] == 0.0) and st.qdot[0] != 0.0


def test_the_cached_rotation_is_quat_to_matrix_bit_for_bit_and_follows_the_orientation():
    rng = np.random.default_rng(7)
    st = rt.State(q=np.zeros(2), qdot=np.zeros(2))
    for _ in range(50):
        qt = rng.normal(size=4)
        st.orientation[:] = qt / np.linalg.norm(qt)
        R = C._rotation(st)
        assert np.array_equal(R, quat_to_matrix(st.orientation))
        st.orientation[1] = np.nextafter(st.orientation[1], 1.0)  # one ulp: a new matrix, not the cached one
        assert np.array_equal(C._rotation(st), quat_to_matrix(st.orientation))


def test_contacts_are_reused_only_at_the_very_state_they_were_found_at(small_model, monkeypatch):
    """The byte fingerprint: contacts found by collide are reused by the step at that state, and searched again
    after a change of one ulp of any state array (the old array_equal test had the same answer there)."""
    body = rt.ModalBody(small_model)
    solver = rt.ModalSolver(body, effects=[rt.Gravity(), rt.Obstacles([rt.Ground(0.0)])])
    st = solver.state(position=(0.0, 0.0, 0.0105), velocity=(0.1, 0.0, 0.0))
    accel = np.array([0.0, 0.0, -9.81])
    c = solver.collide(st, 1e-3)
    assert C._fresh(c, st, 1e-3, accel)
    for name in ("q", "position", "orientation", "velocity", "angular_momentum"):  # (qdot: not searched with)
        other = st.copy()
        a = getattr(other, name)
        a[0] = np.nextafter(a[0], np.inf)
        assert not C._fresh(c, other, 1e-3, accel), name
    assert not C._fresh(c, st, 2e-3, accel)


def test_contacts_found_into_the_shared_buffers_are_independent_copies(small_model):
    """find_contacts fills this thread's buffers (KB.find_into) and copies the rows out: contacts of an earlier
    search are not changed by a later one with more contacts, on another body, or at another state; each equals
    the allocating KB.find's answer at its own state."""
    from modalfem.runtime import _contact_body_kernels as KB

    big = rt.ModalBody(small_model)
    solver = rt.ModalSolver(big, effects=[rt.Obstacles([rt.Ground(0.0), rt.Plane(point=(0.0, 0.0, 0.0),
                                                                                   normal=(1.0, 0.0, 0.0))])])
    low = solver.state(position=(0.0, 0.0, 0.0095))
    high = solver.state(position=(0.0, 0.0, 0.0105), orientation=(0.99, 0.1, 0.05, 0.0))
    found = []
    for st in (high, low, high):
        c = solver.collide(st, 1e-3)
        found.append((c, C.snapshot(st), [a.copy() for a in (c.vertex, c.normal, c.gap, c.effect, c.obstacle)]))
    assert found[0][0].count < found[1][0].count  # a later search with more rows wrote over the buffers' first rows
    plan = C._plan(solver._contact_effects)
    for c, _, kept in found:
        assert all(np.array_equal(a, b) for a, b in zip((c.vertex, c.normal, c.gap, c.effect, c.obstacle), kept))
    for (c, _, _), st in zip(found, (high, low, high)):
        margin = plan.margin + 0.0  # (at rest and without loads the step adds no reach)
        vs, og, gap, nrm = KB.find(plan.kinds, plan.params, margin, big.rest, C.vertex_modes(big), st.q,
                                   C._skip(big, st.q), C._rotation(st), st.position, C.deformation_bound(big, st.q))
        assert np.array_equal(c.vertex, vs) and np.array_equal(c.gap, gap) and np.array_equal(c.normal, nrm)
        assert np.array_equal(c.obstacle, plan.obstacle[og])


def test_searches_on_two_threads_do_not_share_buffers(small_model):
    """Two threads searching different states at once each get their own contacts (thread-local buffers)."""
    import threading

    body = rt.ModalBody(small_model)
    solver = rt.ModalSolver(body, effects=[rt.Obstacles([rt.Ground(0.0)])])
    states = [solver.state(position=(0.0, 0.0, 0.0095)), solver.state(position=(0.0, 0.0, 0.0105),
                                                                       orientation=(0.99, 0.1, 0.05, 0.0))]
    want = [solver.collide(st, 1e-3) for st in states]
    bad = []

    def run(i):
        for _ in range(200):
            c = solver.collide(states[i].copy(), 1e-3)
            if not (np.array_equal(c.vertex, want[i].vertex) and np.array_equal(c.gap, want[i].gap)):
                bad.append(i)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not bad
