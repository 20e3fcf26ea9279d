"""Modal versus corotational on the same bar: under a small impulse the tet module (linearised step,
BDF2) follows the linear modal model integrated exactly (RMS displacement difference < 2 %); under a
large rotation the linear model inflates the volume by 1 + theta^2 while the corotational body keeps it.

The modal reference is ``modalfem.tet.modal_compare.modal_response`` (modes from ``modalfem.modes`` with
P1 elements and the same lumped mass, closed-form integration), not ``modalfem.runtime``."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet.effects import Pins
from modalfem.tet.modal_compare import (
    linearised_rotation,
    modal_response,
    rms_difference,
    volume_ratio,
)
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetSolver, TetState

MAT = Material(E=1e6, nu=0.3, rho=1000.0)


@pytest.fixture(scope="module")
def bar():
    return box(size=(0.4, 0.04, 0.04), cells=(10, 2, 2))


def _impulse_run(bar, integrator, steps_per_half_period=400):
    res = modalfem.modes(bar, MAT, k=8, degree=1, fixed="x0", lumped=True, backend="skfem", solver="scipy")
    model = tet_model(bar, MAT)
    m = np.repeat(model.masses, 3)
    assert np.abs(res.shapes.T @ (m[:, None] * res.shapes) - np.eye(8)).max() < 1e-10  # same mass matrix
    v = np.zeros((model.point_count, 3))
    v[bar.tag_points("x1"), 2] = 1e-3  # a small tip impulse: 1 mm/s on the free end (strain ~1e-5)
    v0 = (res.shapes @ (res.shapes.T @ (m * v.ravel()))).reshape(-1, 3)  # its part in the 8 modes
    dt = np.pi / res.omega[0] / steps_per_half_period
    times = dt * np.arange(1, steps_per_half_period + 1)
    ref = modal_response(res.shapes, res.omega, model.masses, np.zeros_like(v0), v0, times)
    solver = TetSolver(model, effects=[Pins(bar.tag_points("x0"))], newton_max=1, linear_solver="splu",
                       integrator=integrator)
    state = TetState.at_rest(model)
    state.v = v0.copy()
    u = []
    for _ in times:
        solver.step(state, state, dt)
        u.append(state.x - model.rest_points)
    return rms_difference(np.array(u), ref), np.abs(ref).max()


@pytest.mark.slow
def test_small_impulse_agrees_with_modal_superposition(bar):
    err, umax = _impulse_run(bar, "bdf2")
    assert 1e-7 < umax < 1e-4  # small: tens of micrometres on a 0.4 m bar
    assert err < 0.02
    err_be, _ = _impulse_run(bar, "backward_euler")
    assert err < err_be  # the remaining difference is time discretisation (BE damps the higher modes)


def test_large_rotation_linear_modal_inflates_volume_corotational_keeps_it(bar):
    model = tet_model(bar, MAT)
    w = np.array([0.0, 0.0, 2 * np.pi])  # one turn per second about z (the bar lies along x)
    c = bar.points.mean(axis=0)
    v0 = np.cross(w, bar.points - c)
    t_end, steps = 0.25, 50  # a quarter turn
    # linear modal model: the rigid modes of modes() carry the motion linearly
    res = modalfem.modes(bar, MAT, k=1, degree=1, lumped=True, backend="skfem", solver="scipy")
    u = modal_response(res.shapes, res.omega, model.masses, np.zeros_like(v0), v0, np.array([t_end]),
                       rigid_shapes=res.rigid_shapes)[0]
    np.testing.assert_allclose(bar.points + u, linearised_rotation(bar.points, w, t_end), atol=1e-9)
    theta = np.linalg.norm(w) * t_end
    modal_ratio = volume_ratio(bar.points + u, bar.cells, bar.volume)
    assert modal_ratio == pytest.approx(1 + theta**2, rel=1e-6)  # +247 % volume
    # corotational tet body
    solver = TetSolver(model)
    state = TetState.at_rest(model)
    state.v = v0.copy()
    for _ in range(steps):
        solver.step(state, state, t_end / steps)
    tet_ratio = volume_ratio(state.x, bar.cells, bar.volume)
    assert abs(tet_ratio - 1) < 0.01
    axis = state.x[bar.tag_points("x1")].mean(axis=0) - state.x[bar.tag_points("x0")].mean(axis=0)
    turned = np.degrees(np.arctan2(axis[1], axis[0]))
    assert 60 < turned < 95  # it really turned (backward Euler loses a little angular velocity)


def test_modal_response_is_the_exact_oscillator():
    """Two vertices, each DOF its own mode: u(t) = u0 cos(w t) + v0 / w sin(w t) exactly."""
    masses = np.array([2.0, 0.5])
    m = np.repeat(masses, 3)
    shapes = np.diag(1 / np.sqrt(m))  # mass-normalised unit modes
    omega = np.linspace(1.0, 6.0, 6)
    rng = np.random.default_rng(0)
    u0, v0 = rng.standard_normal((2, 3)), rng.standard_normal((2, 3))
    t = np.array([0.0, 0.3, 1.7])
    u = modal_response(shapes, omega, masses, u0, v0, t)
    expected = u0.ravel() * np.cos(np.outer(t, omega)) + v0.ravel() / omega * np.sin(np.outer(t, omega))
    np.testing.assert_allclose(u.reshape(3, -1), expected, atol=1e-14)
    assert rms_difference(u, u) == 0.0
