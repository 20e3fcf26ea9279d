"""Exact modal integration: closed form in every damping regime, any dt, energy behaviour."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.errors import SimulationError
from modalfem.runtime.integrator import ModalIntegrator, transition


def _reference(lam, mu, h, y0, v0, f):
    """Independent solution from the two characteristic roots (complex arithmetic), lam > 0,
    away from critical damping: y = f/lam + A e^{s1 t} + B e^{s2 t}."""
    a = 0.5 * mu
    disc = np.sqrt(complex(a * a - lam))
    s1, s2 = -a + disc, -a - disc
    z0 = y0 - f / lam
    A = (v0 - s2 * z0) / (s1 - s2)
    B = z0 - A
    y = f / lam + A * np.exp(s1 * h) + B * np.exp(s2 * h)
    v = s1 * A * np.exp(s1 * h) + s2 * B * np.exp(s2 * h)
    return y.real, v.real


def _apply(c, y0, v0, f):
    a11, a12, a21, a22, b1, b2 = (x[0] for x in c)
    return a11 * y0 + a12 * v0 + b1 * f, a21 * y0 + a22 * v0 + b2 * f


REGIMES = [  # (lam [1/s^2], mu [1/s]) away from critical damping
    (1.0, 0.0), (4e6, 0.0), (100.0, 0.3), (100.0, 19.0), (100.0, 25.0), (1.0, 1e3), (1e-4, 5.0), (3e8, 2e2)]


@pytest.mark.parametrize("lam,mu", REGIMES)
@pytest.mark.parametrize("periods", [1e-6, 1e-2, 0.37, 3.0, 1e3, 1e6])
def test_matches_the_analytic_solution_for_any_dt(lam, mu, periods):
    h = periods * 2 * np.pi / np.sqrt(lam)
    y0, v0, f = 0.7, -1.3 * np.sqrt(lam), 2.1 * lam
    scale = abs(y0) + abs(v0) / np.sqrt(lam) + abs(f) / lam  # state in displacement units
    y, v = _apply(transition([lam], [mu], h), y0, v0, f)
    yr, vr = _reference(lam, mu, h, y0, v0, f)
    assert abs(y - yr) <= 1e-12 * scale
    assert abs(v - vr) <= 1e-12 * scale * np.sqrt(lam)


@pytest.mark.parametrize("mu", [0.0, 1e-3, 0.5, 7.0])
@pytest.mark.parametrize("h", [1e-9, 1e-3, 0.2, 50.0])
def test_zero_frequency_mode(mu, h):
    """y'' + mu y' = f: v = v0 e^{-mu h} + f (1 - e^{-mu h}) / mu, y = y0 + int v (mu = 0: uniform acceleration)."""
    y0, v0, f = 0.3, -2.0, 1.5
    y, v = _apply(transition([0.0], [mu], h), y0, v0, f)
    if mu == 0:
        yr, vr = y0 + v0 * h + 0.5 * f * h * h, v0 + f * h
    else:
        g = -np.expm1(-mu * h) / mu  # int_0^h e^{-mu t} dt
        vr = v0 * np.exp(-mu * h) + f * g
        yr = y0 + v0 * g + f * (h - g) / mu
    scale = abs(y0) + abs(v0) * h + abs(f) * h * h + abs(v0) / max(mu, 1e-300) * (mu > 0)
    assert abs(y - yr) <= 1e-12 * max(scale, abs(yr))
    assert abs(v - vr) <= 1e-12 * (abs(v0) + abs(f) * h)


def _matrix(lam, mu, h):
    a11, a12, a21, a22, b1, b2 = (x[0] for x in transition([lam], [mu], h))
    return np.array([[a11, a12, b1], [a21, a22, b2], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("rel", [0.0, 1e-14, -1e-14, 1e-9, -1e-9, 1e-6, -1e-6, 1e-3, -1e-3])
def test_near_critical_damping_is_exact_and_continuous(rel):
    """Near mu^2 = 4 lam the solution is the semigroup exp(h A): T(h1 + h2) = T(h1) T(h2), and it
    tends to the critically damped closed form e^{-a h}(z0 + (v0 + a z0) h) as rel -> 0."""
    lam = 400.0
    mu = 2 * np.sqrt(lam) * (1 + rel)
    for h1, h2 in [(1e-4, 3e-3), (0.01, 0.02), (0.3, 0.5), (2.0, 7.0)]:
        T12 = _matrix(lam, mu, h1) @ _matrix(lam, mu, h2)
        T = _matrix(lam, mu, h1 + h2)
        assert np.allclose(T, T12, rtol=1e-12, atol=1e-12 * np.abs(T).max())
    a, h = 0.5 * mu, 0.05
    z0, v0 = 1.0, -3.0
    T = _matrix(lam, mu, h)
    crit = np.exp(-a * h) * (z0 + (v0 + a * z0) * h)
    assert abs(T[0, 0] * z0 + T[0, 1] * v0 - crit) <= 1e-12 + 10 * abs(rel) * abs(crit)


def test_step_response_has_no_cancellation_for_tiny_steps():
    """b1 = int_0^h S(t) dt ~ h^2 / 2 to relative accuracy 1e-10 when lam h^2 and mu h are tiny."""
    lam = np.array([1.0, 1e8, 4e8])
    mu = np.array([0.0, 1.0, 4e4])
    for h in (1e-9, 1e-7):
        b1 = transition(lam, mu, h)[4]
        # Taylor series of the step response: c_n = y^(n)(0), c_1 = 1, c_2 = -mu, ...
        expect = h * h / 2 - mu * h**3 / 6 + (mu * mu - lam) * h**4 / 24 + (2 * lam * mu - mu**3) * h**5 / 120
        assert np.allclose(b1, expect, rtol=1e-10, atol=0)


@pytest.mark.parametrize("steps", [100_000, pytest.param(1_000_000, marks=pytest.mark.slow)])
def test_undamped_energy_is_conserved_over_many_steps(steps):
    omega = np.array([3.0, 170.0, 2.3e3, 4.1e4, 9.9e4])
    integ = ModalIntegrator(omega, 0.0)
    rng = np.random.default_rng(1)
    q, v = rng.normal(size=5), rng.normal(size=5) * omega
    e0 = integ.energy(q, v)
    dt = 1.7e-4  # beyond the period of the three stiffest modes
    for _ in range(steps):
        q, v = integ.step(q, v, None, dt)
    assert np.all(np.abs(integ.energy(q, v) / e0 - 1) < 1e-9)


def test_damped_energy_decays_at_the_predicted_rate():
    """Free decay of y'' + mu y' + lam y = 0: after each damped period T_d = 2 pi / w_d the state is
    e^{-mu T_d / 2} times itself, so the energy falls by exactly e^{-mu T_d} per period."""
    omega, zeta = np.array([50.0, 700.0]), np.array([0.01, 0.2])
    mu = 2 * zeta * omega
    wd = omega * np.sqrt(1 - zeta**2)
    for i in range(2):
        integ = ModalIntegrator(omega[i : i + 1], mu[i : i + 1])
        Td = 2 * np.pi / wd[i]
        q, v = np.array([1.0]), np.array([0.3 * omega[i]])
        e_prev = integ.energy(q, v)[0]
        for _period in range(10):
            for _ in range(16):
                q, v = integ.step(q, v, None, Td / 16)
            e = integ.energy(q, v)[0]
            assert abs(e / e_prev - np.exp(-mu[i] * Td)) < 1e-10
            e_prev = e


def test_constant_force_gives_the_static_deflection():
    integ = ModalIntegrator([10.0, 200.0], [4.0, 60.0])
    q, v = np.zeros(2), np.zeros(2)
    f = np.array([3.0, -8.0])
    q, v = integ.step(q, v, f, 100.0)  # one huge step: settled
    assert np.allclose(q, f / integ.lam, rtol=1e-12) and np.allclose(v, 0.0, atol=1e-12)


@pytest.mark.parametrize("dt", [0.0, -1e-3, float("nan"), float("inf"), "x"])
def test_bad_dt_is_a_simulation_error(dt):
    with pytest.raises(SimulationError, match="dt"):
        transition([1.0], [0.0], dt)


def test_coefficients_are_cached_per_dt():
    integ = ModalIntegrator([1.0, 2.0], 0.1)
    c1 = integ.coefficients(1e-3)
    assert integ.coefficients(1e-3) is c1 and integ.coefficients(2e-3) is not c1
