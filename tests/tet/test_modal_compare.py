"""Modal versus corotational on the same bar: under a small impulse the real-time modal runtime
(``modalfem.runtime``, driven through ``ModalModel.from_modes``) and the tet module (linearised step,
BDF2) agree (RMS surface displacement difference < 2 %); under a large rotation a linear modal model
inflates the volume by 1 + theta^2 while the corotational body keeps it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import modalfem
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.mesh.surface import boundary_surface
from modalfem.model import ModalModel
from modalfem.tet.effects import Pins
from modalfem.tet.modal_compare import (
    linearised_rotation,
    modal_response,
    rms_difference,
    runtime_response,
    volume_ratio,
)
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetSolver, TetState

MAT = Material(E=1e6, nu=0.3, rho=1000.0)


@pytest.fixture(scope="module")
def bar():
    return box(size=(0.4, 0.04, 0.04), cells=(10, 2, 2))


@pytest.fixture(scope="module")
def runtime_tap(bar):
    """The clamped bar's runtime model, tapped at the top corner of the free end (8 modes, P1, lumped)."""
    res = modalfem.modes(bar, MAT, k=8, degree=1, fixed="x0", lumped=True, backend="skfem", solver="scipy")
    model = ModalModel.from_modes(res, bar, MAT, damping=(0.0, 0.0), rotation_coupling=False)
    surf = boundary_surface(bar)
    assert np.array_equal(model.vertices, bar.points[surf.mesh_vertices])  # runtime vertex i = mesh vertex
    tip = int(np.argmax(model.vertices @ np.array([1.0, 1e-3, 1e-6])))  # max x, then y, then z
    assert np.allclose(model.vertices[tip], [0.4, 0.04, 0.04])
    J = np.array([0.0, 0.0, 1e-6])  # [N s]
    steps = 400  # per half period of the first mode
    dt = np.pi / res.omega[0] / steps
    times = dt * np.arange(1, steps + 1)
    u, qdot0 = runtime_response(model, tip, J, times)
    return SimpleNamespace(res=res, surface=surf.mesh_vertices, tip=tip, J=J, dt=dt, u=u, qdot0=qdot0)


def _tet_tap(bar, tap, integrator):
    """Surface displacements (T, nv, 3) [m] of the clamped tet bar started with the runtime's velocity."""
    res = tap.res
    model = tet_model(bar, MAT)
    m = np.repeat(model.masses, 3)
    assert np.abs(res.shapes.T @ (m[:, None] * res.shapes) - np.eye(8)).max() < 1e-10  # same mass matrix
    solver = TetSolver(model, effects=[Pins(bar.tag_points("x0"))], newton_max=1, linear_solver="splu",
                       integrator=integrator)
    state = TetState.at_rest(model)
    state.v = (res.shapes @ tap.qdot0).reshape(-1, 3)  # the velocity field the runtime holds after the tap
    u = []
    for _ in range(len(tap.u)):
        solver.step(state, state, tap.dt)
        u.append((state.x - model.rest_points)[tap.surface])
    return np.array(u)


def test_runtime_impulse_enters_the_modes(runtime_tap):
    """The runtime's tap sets q' = Phi(p)^T J: 1e-6 N s at a corner gives mm/s at the free end."""
    tap = runtime_tap
    row = 3 * tap.surface[tap.tip]
    phi_tip = tap.res.shapes[row: row + 3]  # full-mesh shapes at the tapped vertex
    np.testing.assert_allclose(tap.qdot0, phi_tip.T @ tap.J, rtol=1e-12)
    v_tip = phi_tip @ tap.qdot0
    assert v_tip[2] > 0 and 1e-5 < v_tip[2] < 1e-2
    assert np.abs(tap.u).max() < 1e-4 * 0.04  # strain-sized: far below the section


@pytest.mark.slow
def test_small_impulse_runtime_and_tet_agree(bar, runtime_tap):
    tap = runtime_tap
    u_rt = tap.u
    u_tet = _tet_tap(bar, tap, "bdf2")
    assert 1e-8 < np.abs(u_rt).max() < 1e-4  # small: a fraction of a micrometre to tens of micrometres
    err = rms_difference(u_tet, u_rt)
    assert err < 0.02
    err_be = rms_difference(_tet_tap(bar, tap, "backward_euler"), u_rt)
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


def test_runtime_response_rejects_bad_times(runtime_tap):
    from modalfem.errors import InputError

    model = ModalModel.from_modes(runtime_tap.res, box(size=(0.4, 0.04, 0.04), cells=(10, 2, 2)), MAT,
                                  rotation_coupling=False)
    for bad in ([0.0, 0.1], [0.2, 0.1], []):
        with pytest.raises(InputError, match="increasing times"):
            runtime_response(model, runtime_tap.tip, runtime_tap.J, np.array(bad))
