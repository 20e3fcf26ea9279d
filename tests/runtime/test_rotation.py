"""Rigid part: quaternions, torque-free tumbling (symplectic splitting), free flight with vibration."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.runtime.rotation import (
    quat_from_axis_angle,
    quat_from_matrix,
    quat_multiply,
    quat_to_matrix,
)


def test_quaternion_round_trips():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q *= np.sign(q[0])
        R = quat_to_matrix(q)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-14) and np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(quat_from_matrix(R), q, atol=1e-13)
    a, b = quat_from_axis_angle([0, 0, 1], 0.3), quat_from_axis_angle([1, 0, 0], -1.1)
    assert np.allclose(quat_to_matrix(quat_multiply(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-15)


def _euler_reference(I, w0, t_end, n):
    """Body angular velocity of a torque-free body: Euler's equations I w' = (I w) x w by RK4."""
    Iinv = np.linalg.inv(I)

    def f(w):
        return Iinv @ np.cross(I @ w, w)

    w, h = w0.copy(), t_end / n
    for _ in range(n):
        k1 = f(w)
        k2 = f(w + 0.5 * h * k1)
        k3 = f(w + 0.5 * h * k2)
        k4 = f(w + h * k3)
        w = w + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return w


def _tumbling(body):
    solver = rt.ModalSolver(body)
    # spin mostly about the intermediate axis: the unstable, strongly tumbling case
    axes = body.principal_axes
    w0 = 6.0 * axes[:, 1] + 0.3 * axes[:, 0] + 0.2 * axes[:, 2]
    st = solver.state(orientation=quat_from_axis_angle([0.6, 0, 0.8], 0.4), angular_velocity=w0)
    return solver, st


def test_torque_free_tumbling_conserves_angular_momentum_and_bounds_energy(small_body):
    solver, st = _tumbling(small_body)
    assert len(set(np.round(small_body.principal_moments, 6))) == 3  # non-symmetric inertia
    L0, e0 = st.angular_momentum.copy(), solver.energy(st)
    errs, lb = [], []
    for _ in range(8000):  # 20 s
        solver.step(st, st, None, None, 2.5e-3)
        errs.append(solver.energy(st) / e0 - 1)
        lb.append(np.linalg.norm(st.rotation().T @ st.angular_momentum))
    assert np.linalg.norm(st.angular_momentum - L0) <= 1e-10 * np.linalg.norm(L0)
    assert np.ptp(lb) <= 1e-10 * np.linalg.norm(L0)  # body-frame |L| too (rotation stays orthonormal)
    errs = np.abs(errs)
    assert errs.max() < 2e-3  # symplectic: bounded energy error ...
    assert errs[-2000:].max() < 2 * errs[:2000].max()  # ... with no drift over 20 s of tumbling
    w_body = small_body.inertia_inv @ (st.rotation().T @ st.angular_momentum)
    assert np.linalg.norm(w_body) > 1.0


def test_tumbling_follows_eulers_equations_to_second_order(small_body):
    t_end = 1.0
    I = small_body.inertia
    errs = []
    _, st0 = _tumbling(small_body)
    w0 = small_body.inertia_inv @ (st0.rotation().T @ st0.angular_momentum)
    w_ref = _euler_reference(I, w0, t_end, 4000)  # RK4 error ~ (2.5e-4 s * 6 rad/s)^4: negligible
    for dt in (4e-3, 2e-3, 1e-3):
        solver, st = _tumbling(small_body)
        for _ in range(round(t_end / dt)):
            solver.step(st, st, None, None, dt)
        w = small_body.inertia_inv @ (st.rotation().T @ st.angular_momentum)
        errs.append(np.linalg.norm(w - w_ref))
    rates = np.log2(np.array(errs[:-1]) / errs[1:])
    assert np.all(rates > 1.8), (errs, rates)


def test_free_flight_conserves_momentum_while_the_body_vibrates(small_body):
    solver = rt.ModalSolver(small_body)
    st = solver.state(position=(1.0, 2.0, 3.0), velocity=(0.3, -0.2, 1.0), angular_velocity=(2.0, -5.0, 3.0))
    st.q[:] = 1e-5
    st.qdot[:] = np.linspace(-0.5, 0.5, small_body.mode_count)
    p0, l0 = solver.momentum(st)
    c0, v0, em0 = st.position.copy(), st.velocity.copy(), small_body.modal_energy(st)
    dt, n = 7e-4, 3000
    for _ in range(n):
        solver.step(st, st, None, None, dt)
    p1, l1 = solver.momentum(st)
    assert np.allclose(p1, p0, rtol=1e-14, atol=0)
    assert np.linalg.norm(l1 - l0) <= 1e-10 * np.linalg.norm(l0)
    assert np.allclose(st.position, c0 + v0 * n * dt, rtol=1e-12)
    assert abs(small_body.modal_energy(st) / em0 - 1) < 1e-10  # the vibration goes on (no damping)
    assert np.abs(st.q).max() > 1e-6


def test_gravity_is_free_fall_without_deformation(small_body):
    g = np.array([0.0, -1.0, -9.81])
    solver = rt.ModalSolver(small_body, effects=[rt.Gravity(g)])
    st = solver.state(position=(0, 0, 10.0), velocity=(1.0, 0, 2.0))
    for _ in range(100):
        solver.step(st, st, None, None, 0.01)
    assert np.allclose(st.position, [1.0, -0.5, 10.0 + 2.0 - 0.5 * 9.81], rtol=1e-12)
    assert np.allclose(st.velocity, [1.0, -1.0, 2.0 - 9.81], rtol=1e-12)
    assert not st.q.any() and not st.qdot.any()


@pytest.mark.parametrize("bad", [(0, 0, 0, 0), (np.nan, 0, 0, 1)])
def test_bad_orientation_is_refused(small_body, bad):
    from modalfem.errors import SimulationError

    with pytest.raises(SimulationError):
        rt.State(np.zeros(small_body.mode_count), np.zeros(small_body.mode_count), orientation=bad)
