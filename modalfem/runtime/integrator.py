"""Exact per-mode integration of damped oscillators with a force held constant over a step.

Each mode obeys ``y'' + mu y' + lam y = f`` (lam = omega^2 [rad^2/s^2], mu [1/s], f held constant
over the step [sqrt(kg) m / s^2]). Over a step h [s] the exact solution is affine in the state::

    y1 = a11 y0 + a12 v0 + b1 f
    v1 = a21 y0 + a22 v0 + b2 f

``transition(lam, mu, h)`` returns the six coefficient arrays in closed form for every regime,
vectorised over modes:

* underdamped (mu^2 < 4 lam): e^{-a h} (cos, sin / w_d) with a = mu / 2, w_d = sqrt(lam - a^2);
  ``sin(w_d h) / w_d`` is evaluated as ``h * sinc`` so it stays exact as w_d -> 0;
* critically damped (mu^2 = 4 lam): the limit of both formulas (e^{-a h}, h e^{-a h});
* overdamped: written with the two real roots s1 = -lam / (a + k), s2 = -(a + k), k = sqrt(a^2 - lam),
  as e^{s1 h} (1 + e^{-2 k h}) / 2 and e^{s1 h} (-expm1(-2 k h)) / (2 k): no overflow for any h and
  no cancellation near critical damping or for lam << a^2;
* zero frequency (lam = 0): ``y'' + mu y' = f`` with (1 - e^{-mu h}) / mu as -expm1(-mu h) / mu.

The particular (constant-force) coefficients are b2 = S and the step response b1 = int_0^h S dt:
``(1 - a11) / lam`` for lam h^2 > 1e-2, otherwise (where that would cancel) its Taylor series for
mu h <= 0.5, the zero-frequency closed form, or the overdamped slow-root form with expm1.
"""

from __future__ import annotations

import math

import numpy as np

from modalfem.errors import SimulationError

__all__ = ["ModalIntegrator", "check_dt", "transition"]


def check_dt(dt) -> float:
    """``dt`` as a float [s], or ``SimulationError`` when it is not finite and positive."""
    try:
        h = float(dt)
    except (TypeError, ValueError):
        raise SimulationError(f"time step dt must be a number [s], got {dt!r}") from None
    if not math.isfinite(h) or h <= 0.0:
        raise SimulationError(f"time step dt must be finite and > 0 [s], got {dt!r}")
    return h


def _sinhc(x: np.ndarray) -> np.ndarray:
    """sinh(x) / x, accurate near 0."""
    small = np.abs(x) < 1e-3
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 + x * x / 6.0 + x**4 / 120.0, np.sinh(xs) / xs)


def _step_series(lam: np.ndarray, mu: np.ndarray, h: float, terms: int = 24) -> np.ndarray:
    """Step response b1 = int_0^h y(t) dt of the impulse response y by its Taylor series.

    With c_n = y^{(n)}(0) (c_0 = 0, c_1 = 1, c_n = -mu c_{n-1} - lam c_{n-2}),
    b1 = sum_n c_n h^{n+1} / (n+1)!. Used for lam h^2 <= 1e-2 and mu h <= 0.5 (fast convergence).
    """
    c_prev, c = np.zeros_like(lam), np.ones_like(lam)
    term = h * h / 2.0
    b1 = c * term
    for n in range(2, terms):
        c_prev, c = c, -mu * c - lam * c_prev
        term = term * h / (n + 1)
        b1 = b1 + c * term
    return b1


def transition(lam, mu, h: float):
    """Exact one-step coefficients of ``y'' + mu y' + lam y = f`` over a step ``h``.

    Args:
        lam: stiffness per unit modal mass lam = omega^2 >= 0 (r,) [rad^2/s^2].
        mu: damping mu >= 0 (r,) [1/s].
        h: time step [s], > 0 (any size: beyond the period and the damping time too).

    Returns:
        ``(a11, a12, a21, a22, b1, b2)``, each (r,): a11 [-], a12 [s], a21 [1/s^2], a22 [-],
        b1 [s^2], b2 [s] such that y1 = a11 y0 + a12 v0 + b1 f, v1 = a21 y0 + a22 v0 + b2 f.

    Raises:
        SimulationError: h not finite and positive, or lam / mu negative or not finite.
    """
    h = check_dt(h)
    lam = np.atleast_1d(np.asarray(lam, dtype=np.float64))
    mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), lam.shape).copy()
    if not (np.all(np.isfinite(lam)) and np.all(np.isfinite(mu))) or np.any(lam < 0) or np.any(mu < 0):
        raise SimulationError("modal stiffness lam and damping mu must be finite and >= 0")
    a = 0.5 * mu
    d = lam - a * a  # > 0 underdamped, < 0 overdamped
    under = d > 0
    # underdamped: C = e^{-ah} cos(w h), S = e^{-ah} sin(w h) / w
    w = np.sqrt(np.where(under, d, 0.0))
    ea = np.exp(-a * h)
    C_u = ea * np.cos(w * h)
    S_u = ea * h * np.sinc(w * h / np.pi)
    # overdamped / critical / zero-frequency: real roots s1 = -lam/(a+k), s2 = -(a+k)
    k = np.sqrt(np.where(under, 0.0, -d))
    apk = a + k
    s1 = np.where(apk > 0, -lam / np.where(apk > 0, apk, 1.0), 0.0)
    e1 = np.exp(s1 * h)
    e2k = np.exp(-2.0 * k * h)
    C_o = e1 * 0.5 * (1.0 + e2k)
    # (1 - e^{-2kh}) / (2k) -> h as k -> 0
    kk = np.where(k > 0, k, 1.0)
    kh = k * h
    kh_small = np.where(kh > 1e-3, 0.0, kh)
    ratio = np.where(kh > 1e-3, -np.expm1(-2.0 * kh) / (2.0 * kk), h * np.exp(-kh_small) * _sinhc(kh_small))
    S_o = e1 * ratio
    C = np.where(under, C_u, C_o)
    S = np.where(under, S_u, S_o)
    a11 = C + a * S
    a12 = S
    a21 = -lam * S
    a22 = C - a * S
    b2 = S
    # b1 = (1 - a11) / lam where that has no cancellation; otherwise closed forms / series
    muh = mu * h
    small = lam * h * h <= 1e-2
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (1.0 - a11) / np.where(small, 1.0, lam)
        ser = small & (muh <= 0.5)
        if np.any(ser):
            b1 = np.where(ser, _step_series(lam, mu, h), b1)
        zero = small & ~ser & (lam == 0)  # y'' + mu y' = f, mu h > 0.5
        msafe = np.where(mu > 0, mu, 1.0)
        b1 = np.where(zero, (h + np.expm1(-muh) / msafe) / msafe, b1)
        over = small & ~ser & (lam > 0)  # overdamped (a h > 0.25 > sqrt(lam) h): slow root + fast part
        lsafe = np.where(lam > 0, lam, 1.0)
        b1 = np.where(over, -np.expm1(s1 * h) / lsafe - e1 * ratio / np.where(apk > 0, apk, 1.0), b1)
    return a11, a12, a21, a22, b1, b2


class ModalIntegrator:
    """Exact stepper for r decoupled damped oscillators, coefficients cached per dt.

    Args:
        omega: angular frequencies (r,) [rad/s], >= 0.
        mu: modal damping (r,) [1/s], >= 0 (Rayleigh: ``alpha + beta * omega**2``).

    A step is six fused multiply-adds over the r modes (``step``). The coefficients of the last
    few distinct dt values are kept (``cache_size``).
    """

    cache_size = 8

    def __init__(self, omega, mu) -> None:
        self.omega = np.asarray(omega, dtype=np.float64).copy()
        self.lam = self.omega**2
        self.mu = np.broadcast_to(np.asarray(mu, dtype=np.float64), self.omega.shape).copy()
        self._cache: dict[float, tuple] = {}

    def coefficients(self, dt: float) -> tuple:
        """``transition(lam, mu, dt)`` from the cache (computed on first use of this dt)."""
        h = check_dt(dt)
        c = self._cache.get(h)
        if c is None:
            if len(self._cache) >= self.cache_size:
                self._cache.pop(next(iter(self._cache)))
            c = transition(self.lam, self.mu, h)
            self._cache[h] = c
        return c

    def step(self, q, qdot, f, dt: float, q_out=None, qdot_out=None):
        """Advance modal coordinates by dt with a constant modal force.

        Args:
            q: modal displacements (r,) [sqrt(kg) m].
            qdot: modal velocities (r,) [sqrt(kg) m/s].
            f: modal force (r,) [sqrt(kg) m/s^2] held constant over the step, or None for zero.
            dt: step [s], > 0.
            q_out, qdot_out: optional output arrays (may alias the inputs).

        Returns:
            ``(q1, qdot1)``.
        """
        a11, a12, a21, a22, b1, b2 = self.coefficients(dt)
        q1 = a11 * q + a12 * qdot
        v1 = a21 * q + a22 * qdot
        if f is not None:
            q1 += b1 * f
            v1 += b2 * f
        if q_out is None:
            return q1, v1
        q_out[...] = q1
        qdot_out[...] = v1
        return q_out, qdot_out

    def energy(self, q, qdot) -> np.ndarray:
        """Per-mode mechanical energy 0.5 (qdot^2 + omega^2 q^2) (r,) [J]."""
        return 0.5 * (np.asarray(qdot) ** 2 + self.lam * np.asarray(q) ** 2)
