"""WAV files for the modal sound: 16-bit PCM mono, normalised with headroom, written atomically.

Standard library ``wave`` and numpy only (the runtime must not import scipy).
"""

from __future__ import annotations

import math
import wave

import numpy as np

from modalfem.atomic import write_atomic
from modalfem.errors import InputError
from modalfem.runtime.synthesis import SAMPLE_RATE, _sample_rate

__all__ = ["read_wav", "write_wav"]


def write_wav(path, signal, *, sample_rate: int = SAMPLE_RATE, headroom_db: float = 3.0,
              fade_out_s: float = 0.01) -> float:
    """Write a mono 16-bit PCM WAV file atomically (temporary file in the same directory + rename).

    The signal is normalised so that its peak sits ``headroom_db`` below full scale; the last
    ``fade_out_s`` seconds are faded out with a raised cosine (no click where a ringing sound is
    cut off).

    Args:
        path: target ``.wav`` file; its directory must exist.
        signal: samples (n,) in any unit, finite, n >= 1.
        sample_rate: [1/s].
        headroom_db: peak level below full scale [dB], >= 0.
        fade_out_s: fade-out length [s], >= 0.

    Returns:
        The gain applied: full-scale units per signal unit (0 for a silent signal).

    Raises:
        InputError: empty or non-finite signal, bad sample rate/headroom/fade, or the file cannot
            be written.
    """
    fs = _sample_rate(sample_rate)
    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1 or len(x) == 0:
        raise InputError(f"WAV signal must be a non-empty 1-D array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError("WAV signal holds NaN/inf samples")
    if not (math.isfinite(headroom_db) and headroom_db >= 0):
        raise InputError(f"headroom_db must be >= 0 dB, got {headroom_db!r}")
    if not (math.isfinite(fade_out_s) and fade_out_s >= 0):
        raise InputError(f"fade_out_s must be >= 0 s, got {fade_out_s!r}")
    x = x.copy()
    m = min(len(x), int(round(fade_out_s * fs)))
    if m > 0:
        x[-m:] *= 0.5 * (1 + np.cos(np.pi * np.arange(1, m + 1) / m))
    peak = float(np.abs(x).max())
    gain = 10 ** (-headroom_db / 20) / peak if peak > 0 else 0.0
    pcm = np.round(np.clip(x * gain, -1.0, 1.0) * 32767).astype("<i2")

    def write(f) -> None:
        with wave.open(f, "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(fs)
            w.writeframes(pcm.tobytes())

    write_atomic(path, write, error=InputError, kind="WAV")
    return gain


def read_wav(path) -> tuple[np.ndarray, int]:
    """Read a mono 16-bit PCM WAV file.

    Args:
        path: the ``.wav`` file.

    Returns:
        ``(samples (n,) float64 in [-1, 1), sample_rate [1/s])``.

    Raises:
        InputError: missing file, not a WAV file, or not mono 16-bit PCM.
    """
    try:
        with wave.open(str(path), "rb") as w:
            if w.getnchannels() != 1 or w.getsampwidth() != 2:
                raise InputError(f"WAV file {str(path)!r} is not mono 16-bit PCM "
                                 f"({w.getnchannels()} channels, {8 * w.getsampwidth()} bit)")
            fs = w.getframerate()
            data = w.readframes(w.getnframes())
    except (OSError, EOFError, wave.Error) as exc:
        raise InputError(f"cannot read WAV file {str(path)!r}: {exc}") from None
    return np.frombuffer(data, dtype="<i2").astype(np.float64) / 32768.0, int(fs)
