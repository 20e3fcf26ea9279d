"""One thread count for modalfem's compiled kernels (cloth, collision, tet, runtime).

The parallel kernels are numba ``prange`` loops. Their thread count is, in order of precedence:
``set_threads(n)`` (or the ``thread_count(n)`` block), the ``MODALFEM_THREADS`` environment variable, and
otherwise every core this process may run on (``os.sched_getaffinity``). ``threads()`` reads it back::

    import modalfem
    modalfem.set_threads(1)        # serial kernels, e.g. when running several scenes side by side
    with modalfem.thread_count(2):
        scene.step(0.01)

Results do not depend on the count: every parallel loop splits its work into chunks whose number and
bounds depend only on the problem size (``chunk_count``), per-chunk results (partial sums, candidate
buffers) are combined in chunk order, so 1 and N threads give bit-identical numbers and pair lists. numba
splits a loop's chunks evenly between the threads (its default static schedule); its dynamic schedule
(``numba.set_parallel_chunksize(1)``) would let a running thread take the chunks of one waiting for a core
on a busy machine, but it made the cloth CG 50 % slower even on one thread (22 -> 33 ms per solve, 64x64
pile), so it is not used.

Threading layer: numba's TBB layer when ``libtbb`` can be loaded (the ``tbb`` wheel, a dependency on x86-64:
it is the layer numba calls both thread-safe and fork-safe), else OpenMP (thread-safe; GNU OpenMP is not
fork-safe: a process forked without ``exec`` after a parallel region must not launch one), else numba's
workqueue (neither: never call modalfem kernels from two Python threads at once there). A
``NUMBA_THREADING_LAYER`` set by the user is left alone. ``threading_layer()`` names the layer in use.
Measured here (Intel Xeon, 2 cores, 2026-11-27): a parallel loop over ~6.7k rows in 13 chunks costs per
launch on 2 threads TBB 9.6 us, OpenMP 3.9 us, workqueue 104 us (load ~1); but replays of the 10k-tet
Newton step on a machine shared with other busy processes (load 5) took on 2 threads 74 ms (fastest) with
TBB and 124 ms (fastest; median 439 ms, 248 ms CPU per step) with OpenMP, whose threads spin while
waiting for a core. TBB stays the first choice; the kernels keep launches few instead (the tet CG: 3 per
iteration).
numba's thread count is per Python thread: the count is applied to the thread that imports the kernels
and to the one calling ``set_threads``; a kernel called from another Python thread runs on numba's pool size
(every core) unless that thread calls ``set_threads`` (or ``apply()``) first.

BLAS: the kernels never call BLAS inside a parallel loop, so numba's and OpenBLAS's thread pools do not
nest. A cloth, collision or tet step holds OpenBLAS at one thread while it runs (``serial_blas``: its BLAS
calls are tiny, and threaded they cost ~10x more), and so does the eigen solve while MKL PARDISO
factorises (:mod:`modalfem.eigen.blas_threads`); elsewhere OpenBLAS keeps its own count
(``OPENBLAS_NUM_THREADS``), which ``MODALFEM_THREADS`` does not change. On a machine shared with other
busy processes, fewer threads than cores can be faster (a thread waiting for a core holds every chunk behind it).
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import sys
import threading

import numba

from modalfem.errors import InputError

__all__ = ["serial_blas", "set_threads", "thread_count", "threading_layer", "threads"]

#: most chunks a parallel loop is split into: enough for load balance on 16-32 cores, independent of the
#: thread count so that results are (bit-)identical for every count
MAX_CHUNKS = 64


def _cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _preload_tbb() -> bool:
    """Make ``libtbb.so.12`` of the ``tbb`` wheel (in ``sys.prefix/lib``, off the loader path) visible to
    numba's TBB pool; True if numba's TBB pool imports."""
    for d in {os.path.join(sys.prefix, "lib"), os.path.join(sys.base_prefix, "lib")}:
        for path in sorted(glob.glob(os.path.join(d, "libtbb.so.12*"))):
            try:
                ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
                break
            except OSError:
                continue
    try:
        from numba.np.ufunc import parallel, tbbpool  # noqa: F401

        parallel._check_tbb_version_compatible()  # numba needs TBB 2021.6 or later
    except (ImportError, OSError, AttributeError):
        return False
    return True


def _has_omp() -> bool:
    try:
        from numba.np.ufunc import omppool  # noqa: F401
    except (ImportError, OSError):
        return False
    return True


def _choose_layer() -> str:
    if os.environ.get("NUMBA_THREADING_LAYER"):
        return numba.config.THREADING_LAYER
    layer = "tbb" if _preload_tbb() else ("omp" if _has_omp() else "workqueue")
    numba.config.THREADING_LAYER = layer
    return layer


def _parse(value: str) -> int:
    try:
        n = int(value.strip())
    except ValueError:
        n = 0
    if n < 1:
        raise InputError(f"MODALFEM_THREADS must be a whole number >= 1, got {value!r}")
    return n


_LAYER = _choose_layer()
_lock = threading.Lock()
_count: int | None = None  # None: not chosen yet (the environment or every core)
_applied = threading.local()


def _check(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, int) and not hasattr(n, "__index__"):
        raise InputError(f"thread count must be a whole number >= 1, got {n!r}")
    n = int(n)
    top = int(numba.config.NUMBA_NUM_THREADS)
    if n < 1 or n > top:
        raise InputError(f"thread count must be between 1 and {top} (numba's pool size, NUMBA_NUM_THREADS), "
                         f"got {n}")
    return n


def threads() -> int:
    """The thread count of modalfem's parallel kernels (``set_threads``, else ``MODALFEM_THREADS``, else
    every core this process may use, at most numba's pool size).

    Raises:
        InputError: ``MODALFEM_THREADS`` is not a whole number >= 1.
    """
    global _count
    if _count is None:
        env = os.environ.get("MODALFEM_THREADS", "").strip()
        top = int(numba.config.NUMBA_NUM_THREADS)
        _count = min(_parse(env), top) if env else min(_cores(), top)
    return _count


def set_threads(n: int | None = None) -> int:
    """Set the thread count of modalfem's parallel kernels for the whole process.

    Args:
        n: threads (1 = serial); None: back to the default (``MODALFEM_THREADS`` or every core).

    Returns:
        The count now in force.

    Raises:
        InputError: ``n`` is not a whole number between 1 and numba's pool size.
    """
    global _count
    with _lock:
        _count = None if n is None else _check(n)
        count = threads()
    apply()
    return count


@contextlib.contextmanager
def thread_count(n: int):
    """``with thread_count(n):`` runs the block's kernels on ``n`` threads, then restores the previous
    count (``set_threads`` semantics)."""
    global _count
    previous = _count
    set_threads(n)
    try:
        yield
    finally:
        with _lock:
            _count = previous
        apply()


def apply() -> None:
    """Give numba the package's thread count in the calling Python thread (a no-op when it is already set
    there). The kernel modules call it when imported."""
    n = threads()
    if getattr(_applied, "n", None) != n:
        numba.set_num_threads(n)
        _applied.n = n


try:  # the importing thread gets the count at once; a bad MODALFEM_THREADS is reported by threads()
    apply()
except InputError:
    pass


def serial_blas(fn):
    """Decorator: run ``fn`` with OpenBLAS held at one thread (:mod:`modalfem.eigen.blas_threads`).

    The steps of cloth, collision and tet bodies make many tiny BLAS calls (a (4096, 3) matrix times a
    3-vector, dot products of a few thousand entries); with OpenBLAS on two threads such a call cost
    10x more CPU (45 against 5 us, measured here) and the 64x64 pile's step ~14 % more. Their parallel
    work is in the numba kernels instead."""
    import functools

    from modalfem.eigen.blas_threads import one_openblas_thread

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with one_openblas_thread():
            return fn(*args, **kwargs)

    return wrapper


def threading_layer() -> str:
    """The numba threading layer modalfem asked for (``"tbb"``, ``"omp"`` or ``"workqueue"``); numba's
    own answer (``numba.threading_layer()``) exists only after the first parallel launch."""
    return _LAYER


#: one-thread work [us] below which a pass over all vertices runs serially instead of as a parallel region. A region
#: started after serial Python waits for the pool's sleeping workers: on an idle 2-vCPU host (Intel Xeon, KVM,
#: ``python -m modalfem.bench.threads_bench --wake``) a ~100 us region right after another took 1/1.74 of its
#: one-thread time, after 2 ms of Python 1/1.11: ~33 us of wake-up. A region of W us of work then pays on two threads
#: when W / 1.74 + 33 < W, i.e. W > ~78 us. The kernels turn this into an item count from their cost per item, and
#: run the same chunks in the same order either way (the same bits).
SERIAL_WORK_US = 80.0


@numba.njit(cache=True, inline="always")
def chunk_count(n: int, min_chunk: int) -> int:
    """Chunks of a parallel loop over ``n`` items, at least ``min_chunk`` items each (at most
    ``MAX_CHUNKS``): a function of the problem size only, never of the thread count."""
    return max(1, min(MAX_CHUNKS, n // max(min_chunk, 1)))


@numba.njit(cache=True, inline="always")
def chunk_bounds(n: int, chunks: int, c: int) -> tuple:
    """Items ``[start, stop)`` of chunk ``c`` of ``chunks`` over ``n`` items (contiguous, in order)."""
    return (c * n) // chunks, ((c + 1) * n) // chunks
