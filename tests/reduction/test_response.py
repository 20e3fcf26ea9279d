"""Modal impulse response: against direct time integration of a small damped system."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import solve_ivp

from modalfem.errors import InputError
from modalfem.reduction.response import (
    RayleighDamping,
    impulse_response,
    relative_rms_error,
)


def _chain(n: int = 4):
    """A spring-mass chain fixed at one end: masses [kg] on the diagonal, springs [N/m]."""
    m = np.linspace(1.0, 2.0, n)
    k = np.linspace(400.0, 900.0, n)
    K = np.diag(k + np.append(k[1:], 0.0)) - np.diag(k[1:], 1) - np.diag(k[1:], -1)
    return np.diag(m), K


@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.6])
def test_modal_superposition_matches_direct_integration(zeta):
    M, K = _chain()
    lam, Phi = sla.eigh(K, M)  # mass-normalised
    omega = np.sqrt(lam)
    damping = RayleighDamping.from_ratios(zeta, omega[0], omega[-1]) if zeta else RayleighDamping()
    C = damping.alpha * M + damping.beta * K
    n = len(M)
    # the chain's DOFs are 1D: embed them as the x component of 3D shapes at one load/output node
    load, out, P = 3, 0, 0.7
    phi3 = lambda i: np.vstack([Phi[i], np.zeros((2, n))])
    t = np.linspace(0.0, 2.0, 801)
    u = impulse_response(omega, phi3(load), phi3(out), np.array([P, 0, 0]), np.array([1.0, 0, 0]), t, damping=damping)
    v0 = np.linalg.solve(M, np.eye(n)[load] * P)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    sol = solve_ivp(lambda _t, y: A @ y, (0, 2.0), np.concatenate([np.zeros(n), v0]), t_eval=t, rtol=1e-10, atol=1e-13)
    assert relative_rms_error(u, sol.y[out]) < 1e-6


def test_single_mode_closed_form_and_damping_branches():
    t = np.linspace(0, 1, 101)
    w = 2 * np.pi * 3.0
    one = np.array([[1.0], [0.0], [0.0]])
    d = np.array([1.0, 0, 0])
    u = impulse_response([w], one, one, 2.0 * d, d, t)
    np.testing.assert_allclose(u, 2.0 / w * np.sin(w * t), atol=1e-14)
    # critical damping (zeta = 1) and over-damping stay continuous in zeta
    crit = impulse_response([w], one, one, d, d, t, damping=RayleighDamping(alpha=2 * w))
    near = impulse_response([w], one, one, d, d, t, damping=RayleighDamping(alpha=2 * w * (1 - 1e-7)))
    over = impulse_response([w], one, one, d, d, t, damping=RayleighDamping(alpha=2 * w * (1 + 1e-7)))
    np.testing.assert_allclose(crit, near, atol=1e-8)
    np.testing.assert_allclose(crit, over, atol=1e-8)
    # a rigid mode drifts
    np.testing.assert_allclose(impulse_response([0.0], one, one, d, d, t), t)


def test_rayleigh_ratios_and_validation():
    dmp = RayleighDamping.from_ratios(0.01, 10.0, 50.0)
    np.testing.assert_allclose(dmp.ratios(np.array([10.0, 50.0])), 0.01)
    assert dmp.ratios(np.array([25.0]))[0] < 0.01  # lower between the two anchors
    with pytest.raises(InputError):
        RayleighDamping(alpha=-1.0)
    with pytest.raises(InputError):
        RayleighDamping.from_ratios(0.01, 50.0, 10.0)
    with pytest.raises(InputError):
        impulse_response([1.0], np.zeros((3, 2)), np.zeros((3, 1)), np.ones(3), np.ones(3), [0.0])
    assert relative_rms_error(np.ones(3), np.ones(3)) == 0.0
