"""Damped-sinusoid synthesis of modal impacts (numpy only): band limit, contact pulses, exact sampling.

* Each impact k at time ``t_k`` with modal velocity change ``A_ki`` makes mode i ring as the
  underdamped impulse response ``y_ki(t) = A_ki / omega_d_i * exp(-mu_i (t - t_k) / 2)
  sin(omega_d_i (t - t_k))`` for ``t >= t_k``, ``omega_d_i = sqrt(omega_i^2 - mu_i^2 / 4)``, with the
  modal damping ``mu_i`` [1/s] (``q'' + mu q' + omega^2 q = f``). Modes with ``mu_i / 2 >= omega_i``
  (overdamped, they do not ring) are dropped.
* Band limit (``band_limit``): modes with ``f_i >= f_max`` (20 kHz by default, the limit of
  hearing) or at/above the Nyquist frequency ``sample_rate / 2`` are dropped and reported.
* Contact duration (optional, per impact): a real contact spreads the velocity change over a
  fraction of a millisecond; with a half-sine force pulse of length tau each mode's amplitude is
  multiplied by ``pulse_factor`` (a low-pass above about ``1 / tau``). Default 0: ideal impulses.

Synthesis is exact on the sample grid: each mode is the imaginary part of a complex amplitude
times ``exp(lambda_i t)`` with ``lambda_i = -mu_i / 2 + i omega_d_i``. An impact between two samples
enters at the next sample with its phase and decay advanced exactly. Two evaluations are
implemented: ``"recursive"`` (default) advances the complex mode states block by block, each
block one matrix product with a precomputed ``exp(lambda_i m / fs)`` table, and ``"direct"``
evaluates every damped sinusoid (exp, sin, cos) per sample. Measured on a 2-core Xeon for 1 s at
44.1 kHz and 100 modes: recursive 9-30 ms, direct 35-170 ms for one impact and 200-800 ms for
five (numpy 1.24 / 2.4, loaded machine), so recursive is the default; direct is kept as an
independent reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError, SimulationError

__all__ = ["F_MAX_HZ", "SAMPLE_RATE", "SoundBand", "band_limit", "pulse_factor", "synthesize"]

#: audio sample rate [1/s]
SAMPLE_RATE = 44100
#: highest mode frequency kept [Hz] (the upper limit of human hearing)
F_MAX_HZ = 20000.0
_BLOCK = 2048
_METHODS = ("recursive", "direct")


@dataclass(frozen=True)
class SoundBand:
    """Which modes of a model sound, and which were dropped and why.

    Attributes:
        kept: indices (k,) int64 of the modes that are synthesised, ascending.
        dropped: ``(index, frequency [Hz], reason)`` for every dropped mode, in mode order.
        f_max_hz: the band limit used [Hz].
        sample_rate: audio sample rate [1/s].
    """

    kept: np.ndarray
    dropped: tuple
    f_max_hz: float
    sample_rate: int

    @property
    def dropped_indices(self) -> np.ndarray:
        """Indices (d,) of the dropped modes."""
        return np.array([d[0] for d in self.dropped], dtype=np.int64)

    @property
    def dropped_hz(self) -> np.ndarray:
        """Frequencies (d,) [Hz] of the dropped modes."""
        return np.array([d[1] for d in self.dropped], dtype=np.float64)

    def describe(self) -> str:
        """One line: how many modes are kept and which were dropped (frequency ranges per reason)."""
        parts = [f"{len(self.kept)} modes kept below {self.f_max_hz:g} Hz"]
        reasons: dict[str, list[float]] = {}
        for _, f, why in self.dropped:
            reasons.setdefault(why, []).append(f)
        for why, fs in reasons.items():
            parts.append(f"{len(fs)} dropped ({why}: {min(fs):.0f}..{max(fs):.0f} Hz)")
        return ", ".join(parts)


def band_limit(omega, mu, *, sample_rate: int = SAMPLE_RATE, f_max_hz: float = F_MAX_HZ) -> SoundBand:
    """Select the audible, ringing modes.

    Args:
        omega: undamped angular frequencies (r,) [rad/s].
        mu: modal damping (r,) [1/s] (``q'' + mu q' + omega^2 q = f``).
        sample_rate: audio sample rate [1/s], >= 1000.
        f_max_hz: band limit [Hz], > 0; modes at or above it are dropped.

    Returns:
        ``SoundBand``. A mode is dropped when ``f >= f_max_hz`` ("above the band limit"), when its
        damped frequency is at or above ``sample_rate / 2`` ("above Nyquist") or when
        ``mu / 2 >= omega`` ("overdamped").

    Raises:
        InputError: bad sample rate, band limit or array shapes.
    """
    fs = _sample_rate(sample_rate)
    f_max = _positive("f_max_hz", f_max_hz, "Hz")
    omega, mu = _modal_arrays(omega, mu)
    zeta = 0.5 * mu
    wd = np.sqrt(np.maximum(omega**2 - zeta**2, 0.0))
    f = omega / (2 * math.pi)
    kept, dropped = [], []
    for i in range(len(omega)):
        if zeta[i] >= omega[i]:
            dropped.append((i, float(f[i]), "overdamped"))
        elif f[i] >= f_max:
            dropped.append((i, float(f[i]), f"above the {f_max:g} Hz band limit"))
        elif wd[i] / (2 * math.pi) >= 0.5 * fs:
            dropped.append((i, float(f[i]), f"above Nyquist {0.5 * fs:g} Hz"))
        else:
            kept.append(i)
    return SoundBand(kept=np.array(kept, dtype=np.int64), dropped=tuple(dropped), f_max_hz=f_max, sample_rate=fs)


def synthesize(omega, mu, times, amplitudes, duration: float, *, contact_times=None, sample_rate: int = SAMPLE_RATE,
               derivative: int = 2, method: str = "recursive") -> np.ndarray:
    """Sum of the damped modal responses to a list of impacts, sampled at ``sample_rate``.

    Sample n (time ``n / sample_rate``) holds ``sum_k sum_i D^derivative y_ki(t_n)`` over the
    impacts k with ``t_k <= t_n``, where ``y_ki(t) = A_ki / omega_d_i * exp(-mu_i (t - t_k) / 2)
    sin(omega_d_i (t - t_k))`` is the underdamped response to a velocity change ``A_ki``.

    Args:
        omega: undamped angular frequencies (r,) [rad/s] of the modes to synthesise (all must be
            underdamped, ``mu_i / 2 < omega_i``; use ``band_limit`` first).
        mu: modal damping (r,) [1/s].
        times: impact times (m,) [s], >= 0, any order.
        amplitudes: velocity changes (m, r) [unit of the modal velocity]; row k belongs to impact k.
        duration: signal length [s], > 0; impacts at or after it are ignored.
        contact_times: per impact (m,) [s], >= 0, or None (all 0): the velocity change is spread
            over a half-sine force pulse of this length starting at ``t_k``, which multiplies mode
            i's complex amplitude by ``G(lambda_i) = int g(s) exp(-lambda_i s) ds`` (exact after
            the pulse; the few samples during it use the same expression).
        sample_rate: [1/s].
        derivative: 0 (displacement), 1 (velocity) or 2 (acceleration, the default).
        method: ``"recursive"`` (block-wise exact complex recursion) or ``"direct"`` (evaluate every
            damped sinusoid); both give the same samples to rounding.

    Returns:
        signal (n,) float64 with ``n = round(duration * sample_rate)``, in the unit of the amplitudes
        per second^derivative.

    Raises:
        InputError: bad shapes, duration, sample rate, derivative, method, or an overdamped mode.
        SimulationError: a non-finite or negative impact time, or a non-finite amplitude.
    """
    fs = _sample_rate(sample_rate)
    duration = _positive("duration", duration, "s")
    if derivative not in (0, 1, 2):
        raise InputError(f"derivative must be 0, 1 or 2, got {derivative!r}")
    if method not in _METHODS:
        raise InputError(f"method must be one of {', '.join(_METHODS)}, got {method!r}")
    omega, mu = _modal_arrays(omega, mu)
    r = len(omega)
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    amps = np.asarray(amplitudes, dtype=np.float64)
    if amps.ndim == 1 and len(times) == 1:
        amps = amps[None, :]
    if amps.shape != (len(times), r):
        raise InputError(f"amplitudes must have shape (impacts, modes) = ({len(times)}, {r}), got {amps.shape}")
    if not np.all(np.isfinite(times)) or np.any(times < 0):
        raise SimulationError("impact times must be finite and >= 0 s")
    if not np.all(np.isfinite(amps)):
        raise SimulationError("impact amplitudes (modal velocity changes) must be finite")
    zeta = 0.5 * mu
    if np.any(zeta >= omega):
        raise InputError("synthesize needs underdamped modes (mu / 2 < omega); select them with band_limit")
    n = int(round(duration * fs))
    out = np.zeros(n)
    if r == 0 or len(times) == 0 or n == 0:
        return out
    lam = -zeta + 1j * np.sqrt(omega**2 - zeta**2)  # (r,) [1/s]
    coef = amps / lam.imag * lam**derivative  # complex amplitude of each (impact, mode) at its own t_k
    if contact_times is not None:
        tau = np.asarray(contact_times, dtype=np.float64).reshape(-1)
        if tau.shape != times.shape or not np.all(np.isfinite(tau)) or np.any(tau < 0):
            raise InputError(f"contact_times must be {len(times)} finite values >= 0 s")
        coef = coef * pulse_factor(lam, tau)
    start = np.ceil(times * fs - 1e-9 * max(1.0, float(times.max()) * fs)).astype(np.int64)
    start = np.maximum(start, 0)
    use = start < n
    start, times, coef = start[use], times[use], coef[use]
    # advance each impact's phase and decay from t_k to its first sample start / fs
    coef = coef * np.exp(np.outer(start / fs - times, lam))
    if method == "direct":
        _direct(out, lam, start, coef, fs)
    else:
        _recursive(out, lam, start, coef, fs)
    return out


def pulse_factor(lam, tau) -> np.ndarray:
    """Amplitude factor of a half-sine force pulse of length tau relative to an ideal impulse.

    ``G = int_0^tau g(s) exp(-lambda s) ds`` with ``g(s) = pi / (2 tau) sin(pi s / tau)`` (unit
    area), in closed form ``a^2 (1 + exp(-lambda tau)) / (2 (lambda^2 + a^2))``, ``a = pi / tau``.
    It is 1 for tau = 0 and falls off like ``(pi / (omega tau))^2`` above ``omega ~ pi / tau``: a
    contact lasting tau hardly excites modes above about ``1 / tau`` Hz.

    Args:
        lam: mode exponents (r,) ``-mu / 2 + i omega_d`` [1/s].
        tau: contact durations (m,) [s], >= 0.

    Returns:
        G (m, r) complex.
    """
    lam = np.asarray(lam, dtype=np.complex128)[None, :]
    tau = np.asarray(tau, dtype=np.float64)[:, None]
    G = np.ones(np.broadcast_shapes(lam.shape, tau.shape), dtype=np.complex128)
    m = np.broadcast_to(tau > 0, G.shape)
    a = np.pi / np.where(tau > 0, tau, 1.0)
    lt = lam * tau
    den = lam**2 + a**2
    near = np.abs(den) < 1e-9 * a**2  # lambda = +-i a: removable singularity, use the limit
    with np.errstate(divide="ignore", invalid="ignore"):
        val = np.where(near, -a**2 * tau * np.exp(-lt) / (4 * lam), a**2 * (1 + np.exp(-lt)) / (2 * den))
    G[m] = np.broadcast_to(val, G.shape)[m]
    return G


def _recursive(out: np.ndarray, lam: np.ndarray, start: np.ndarray, coef: np.ndarray, fs: int) -> None:
    n = len(out)
    table = np.exp(np.outer(lam / fs, np.arange(_BLOCK)))  # (r, B) exp(lambda m / fs)
    t_re, t_im = np.ascontiguousarray(table.real), np.ascontiguousarray(table.imag)
    step = np.exp(lam * (_BLOCK / fs))
    order = np.argsort(start, kind="stable")
    events, first = np.unique(start[order], return_index=True)
    inject = np.add.reduceat(coef[order], first, axis=0)  # (events, r)
    bounds = np.append(events, n)
    state = np.zeros(len(lam), dtype=np.complex128)
    for e in range(len(events)):
        state = state + inject[e]
        a, b = int(bounds[e]), int(bounds[e + 1])
        while a < b:
            m = min(_BLOCK, b - a)
            out[a:a + m] = state.real @ t_im[:, :m] + state.imag @ t_re[:, :m]
            state = state * (step if m == _BLOCK else np.exp(lam * (m / fs)))
            state[np.abs(state) < 1e-250] = 0.0  # rung out: no subnormal arithmetic in long renders
            a += m


def _direct(out: np.ndarray, lam: np.ndarray, start: np.ndarray, coef: np.ndarray, fs: int) -> None:
    n = len(out)
    zeta, wd = -lam.real, lam.imag
    for k in range(len(start)):
        for a in range(int(start[k]), n, _BLOCK):
            tau = (np.arange(a, min(a + _BLOCK, n)) - start[k]) / fs  # (m,) [s]
            ph = np.outer(tau, wd)
            env = np.exp(-np.outer(tau, zeta))
            out[a:a + len(tau)] += (env * (np.sin(ph) * coef[k].real + np.cos(ph) * coef[k].imag)).sum(axis=1)


# ------------------------------------------------------------------------------ validation
def _modal_arrays(omega, mu) -> tuple[np.ndarray, np.ndarray]:
    omega = np.asarray(omega, dtype=np.float64).reshape(-1)
    mu = np.asarray(mu, dtype=np.float64).reshape(-1)
    if mu.shape != omega.shape:
        raise InputError(f"mu must have the shape of omega {omega.shape}, got {mu.shape}")
    if not (np.all(np.isfinite(omega)) and np.all(np.isfinite(mu))) or np.any(omega <= 0) or np.any(mu < 0):
        raise InputError("modal omega must be finite > 0 rad/s and damping mu finite >= 0 1/s")
    return omega, mu


def _sample_rate(fs) -> int:
    if isinstance(fs, bool) or not isinstance(fs, (int, np.integer)) or not 1000 <= int(fs) <= 1_000_000:
        raise InputError(f"sample_rate must be an integer between 1000 and 1000000 [1/s], got {fs!r}")
    return int(fs)


def _positive(name: str, value, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number [{unit}], got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"{name} must be > 0 {unit}, got {value!r}")
    return v
