"""Keep OpenBLAS on one thread while MKL PARDISO owns the cores.

A serial eigen solve alternates PARDISO phases (MKL OpenMP threads on every core) with small BLAS
calls of SLEPc or ARPACK (orthogonalisation of a few dozen vectors). OpenBLAS worker threads spin
for a while after each call and take the cores from the MKL threads waiting at their barriers.
Measured at 139,587 DOFs (P2 cantilever, 10 modes, 2 cores): 21.4 s with OpenBLAS on its default two
threads against 17.7 s on one. ``one_openblas_thread`` sets one thread for the duration of a block and
restores the previous count; it does nothing where no OpenBLAS is loaded (MKL or reference BLAS).
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os

__all__ = ["one_openblas_thread", "openblas_threads"]

# (library, get, set): Debian's OpenBLAS (numpy, PETSc) and the OpenBLAS bundled with the numpy wheels
_NAMES = ("openblas_get_num_threads", "openblas_set_num_threads")
_WHEEL_NAMES = ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_")
_libraries: list | None = None


def _candidates() -> list[tuple[str, tuple[str, str]]]:
    out = [("libopenblas.so.0", _NAMES)]
    try:
        import numpy

        libs = os.path.join(os.path.dirname(os.path.dirname(numpy.__file__)), "numpy.libs")
        out += [(p, _WHEEL_NAMES) for p in sorted(glob.glob(os.path.join(libs, "libscipy_openblas*.so*")))]
    except ImportError:  # pragma: no cover - numpy is a dependency
        pass
    return out


def _load() -> list:
    global _libraries
    if _libraries is None:
        _libraries = []
        for path, (get, set_) in _candidates():
            try:
                lib = ctypes.CDLL(path)
                g, s = getattr(lib, get), getattr(lib, set_)
            except (OSError, AttributeError):
                continue
            g.restype, s.restype = ctypes.c_int, None
            s.argtypes = [ctypes.c_int]
            _libraries.append((g, s))
    return _libraries


def openblas_threads() -> list[int]:
    """Current thread counts of the OpenBLAS libraries found (empty when there is none)."""
    return [int(g()) for g, _ in _load()]


@contextlib.contextmanager
def one_openblas_thread():
    """Run the block with every loaded OpenBLAS on one thread, then restore the previous counts."""
    libs = _load()
    previous = [int(g()) for g, _ in libs]
    for _, s in libs:
        s(1)
    try:
        yield
    finally:
        for (_, s), n in zip(libs, previous):
            s(n)
