"""Modal dynamic response: displacement history after an impulse, by superposition of r modes.

With mass-normalised modes ``phi_j`` (``Phi^T M Phi = I``) and angular frequencies ``omega_j``
[rad/s], an impulse ``P`` [N s] at a point gives each modal coordinate an initial velocity
``v_j = phi_j(x_load) . P`` [sqrt(kg) m/s] (and zero initial displacement). Each mode then evolves
independently as a damped oscillator ``q'' + 2 zeta_j omega_j q' + omega_j^2 q = 0``:

* under-damped (zeta < 1): ``q = v / omega_d exp(-zeta omega t) sin(omega_d t)``,
  ``omega_d = omega sqrt(1 - zeta^2)``;
* critically damped: ``q = v t exp(-omega t)``; over-damped: the two real exponentials;
* rigid (omega = 0): ``q = v t`` (undamped drift).

Damping is Rayleigh damping ``C = alpha M + beta K`` (``RayleighDamping``), which is diagonal in the
modes with ``zeta_j = alpha / (2 omega_j) + beta omega_j / 2``. The output displacement [m] at a point
and direction is ``u(t) = sum_j phi_j(x_out) . d q_j(t)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = ["RayleighDamping", "impulse_response", "relative_rms_error"]


@dataclass(frozen=True)
class RayleighDamping:
    """Rayleigh damping ``C = alpha M + beta K``.

    Attributes:
        alpha: mass-proportional coefficient [1/s].
        beta: stiffness-proportional coefficient [s].
    """

    alpha: float = 0.0
    beta: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.alpha) and np.isfinite(self.beta)) or self.alpha < 0 or self.beta < 0:
            raise InputError(f"Rayleigh coefficients must be finite and >= 0, got alpha={self.alpha!r}, beta={self.beta!r}")

    @classmethod
    def from_ratios(cls, zeta: float, omega_1: float, omega_2: float) -> RayleighDamping:
        """Coefficients giving damping ratio ``zeta`` [-] at both ``omega_1`` and ``omega_2`` [rad/s]."""
        if not (0 < omega_1 < omega_2) or not zeta >= 0:
            raise InputError(f"need 0 < omega_1 < omega_2 [rad/s] and zeta >= 0, got {omega_1!r}, {omega_2!r}, {zeta!r}")
        return cls(alpha=2 * zeta * omega_1 * omega_2 / (omega_1 + omega_2), beta=2 * zeta / (omega_1 + omega_2))

    def ratios(self, omega: np.ndarray) -> np.ndarray:
        """Modal damping ratios ``alpha / (2 omega) + beta omega / 2`` [-] (0 for omega = 0)."""
        w = np.asarray(omega, dtype=np.float64)
        with np.errstate(divide="ignore"):
            z = np.where(w > 0, self.alpha / (2 * np.where(w > 0, w, 1.0)) + 0.5 * self.beta * w, 0.0)
        return z


def _modal_histories(omega: np.ndarray, v0: np.ndarray, zeta: np.ndarray, t: np.ndarray) -> np.ndarray:
    """q_j(t) (k, nt) of damped oscillators with q(0) = 0, q'(0) = v0."""
    w = omega[:, None]
    z = zeta[:, None]
    v = v0[:, None]
    tt = t[None, :]
    q = np.zeros((len(omega), len(t)))
    rigid = omega == 0
    under = (~rigid) & (zeta < 1)
    crit = (~rigid) & (zeta == 1)
    over = (~rigid) & (zeta > 1)
    q[rigid] = v[rigid] * tt
    if under.any():
        wd = w[under] * np.sqrt(1 - z[under] ** 2)
        q[under] = v[under] / wd * np.exp(-z[under] * w[under] * tt) * np.sin(wd * tt)
    if crit.any():
        q[crit] = v[crit] * tt * np.exp(-w[crit] * tt)
    if over.any():
        r = w[over] * np.sqrt(z[over] ** 2 - 1)
        s1, s2 = -z[over] * w[over] + r, -z[over] * w[over] - r
        q[over] = v[over] / (2 * r) * (np.exp(s1 * tt) - np.exp(s2 * tt))
    return q


def impulse_response(
    omega: np.ndarray,
    phi_load: np.ndarray,
    phi_out: np.ndarray,
    impulse: np.ndarray,
    direction: np.ndarray,
    times: np.ndarray,
    *,
    damping: RayleighDamping | None = None,
) -> np.ndarray:
    """Displacement history at an output point after an impulse, by modal superposition.

    Args:
        omega: angular frequencies of the r retained modes (r,) [rad/s] (0 for rigid modes).
        phi_load: mass-normalised mode shapes at the load point (3, r) [1/sqrt(kg)].
        phi_out: mode shapes at the output point (3, r) [1/sqrt(kg)].
        impulse: impulse vector (3,) [N s], applied at t = 0.
        direction: output direction (3,) [-] (unit vector).
        times: sample times (nt,) [s], >= 0.
        damping: ``RayleighDamping`` (default none).

    Returns:
        displacement along ``direction`` (nt,) [m].

    Raises:
        InputError: inconsistent shapes, negative times or frequencies.
    """
    omega = np.asarray(omega, dtype=np.float64).ravel()
    phi_load = np.asarray(phi_load, dtype=np.float64).reshape(3, -1)
    phi_out = np.asarray(phi_out, dtype=np.float64).reshape(3, -1)
    t = np.asarray(times, dtype=np.float64).ravel()
    if phi_load.shape[1] != len(omega) or phi_out.shape[1] != len(omega):
        raise InputError(f"need (3, {len(omega)}) mode shapes at the load and output points")
    if np.any(omega < 0) or np.any(t < 0):
        raise InputError("frequencies [rad/s] and times [s] must be >= 0")
    zeta = (damping or RayleighDamping()).ratios(omega)
    v0 = np.asarray(impulse, dtype=np.float64) @ phi_load
    gain = np.asarray(direction, dtype=np.float64) @ phi_out
    return gain @ _modal_histories(omega, v0, zeta, t)


def relative_rms_error(u: np.ndarray, u_ref: np.ndarray) -> float:
    """RMS of ``u - u_ref`` over RMS of ``u_ref`` [-] (same sample times)."""
    u, r = np.asarray(u, dtype=np.float64), np.asarray(u_ref, dtype=np.float64)
    if u.shape != r.shape:
        raise InputError(f"histories differ in shape: {u.shape} vs {r.shape}")
    den = np.sqrt(np.mean(r**2))
    if den == 0:
        raise InputError("reference history is identically zero")
    return float(np.sqrt(np.mean((u - r) ** 2)) / den)
