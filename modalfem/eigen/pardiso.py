"""Intel MKL PARDISO (through ctypes): symmetric indefinite LDL^T, its inertia, multi-RHS solves.

PARDISO is the factorisation that makes the shift-and-invert solves fast on one machine: measured at
138,720 free DOFs (P2 cantilever, 2-core AVX-512 Xeon), the numeric LDL^T of K - shift M takes
about 2 s (95 GFlop with METIS ordering, ~50 GFlop/s from MKL's kernels) against 6-10 s for
Debian's MUMPS (PORD ordering, OpenBLAS), and a solve takes 0.07 s against 0.19 s. The backward
error of a solve is ~4e-16 (no iterative refinement needed).

The library comes from the ``mkl`` wheel on PyPI (a modalfem dependency on x86-64), found as
``libmkl_rt`` next to the interpreter (``sys.prefix/lib``), by the dynamic loader, or at the path in
``MODALFEM_MKL_RT``. ``have_pardiso()`` says whether it loads; callers fall back to MUMPS or SuperLU.

The factorisation is Bunch-Kaufman LDL^T (matrix type -2, real symmetric indefinite) of the upper
triangle, so the same handle serves the positive definite solve operator K - shift M (shift below
the spectrum) and the indefinite K - sigma M of the certificate: the ordering and symbolic analysis
are done once per pattern, each new shift costs one numeric factorisation. Sylvester's law gives the
number of eigenvalues below sigma as the count of negative pivots, valid when no pivot was perturbed
(``perturbed_pivots == 0``; PARDISO replaces tiny pivots by +-1e-8 ||A|| otherwise, and the count
is then not a proof: callers check it).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import sys

import numpy as np

from modalfem.errors import SolverError

__all__ = ["AMD_BELOW", "SERIAL_BELOW", "SUPERVARIABLE_AMD_BELOW", "PardisoLDLT", "have_pardiso"]

_LIB = None
_LOAD_ERROR: str | None = None

_ERRORS = {
    -1: "input inconsistent",
    -2: "not enough memory",
    -3: "reordering problem",
    -4: "zero pivot, numerical factorisation or iterative refinement problem",
    -5: "unclassified (internal) error",
    -6: "reordering failed",
    -7: "diagonal matrix is singular",
    -8: "32-bit integer overflow problem",
    -9: "not enough memory for out-of-core",
    -10: "error opening out-of-core files",
    -11: "read/write error with out-of-core files",
}
_MTYPE_SYM_INDEF = -2
_ORDERINGS = {"amd": 0, "metis": 2, "metis-parallel": 3}
_PIVOTING = {"diagonal": 0, "bunch-kaufman": 1}
#: matrices with fewer rows are ordered and factorised on one thread (see ``PardisoLDLT._call``).
#: Measured on the 19,440-row cantilever systems (P1 80x8x8 and P2 40x4x4, 2 free cores): two threads
#: took the numeric factorisation from 0.12-0.13 s to 0.06-0.07 s and a 4-vector solve from 0.011 s to
#: 0.006 s; at 3,000 rows the gain (a few ms) is below the cost of waking a thread pool on a busy machine.
SERIAL_BELOW = 10_000
#: ``ordering="auto"``: AMD below this many rows, parallel METIS from it on. Measured on the cantilever
#: systems (one thread; analysis + two numeric factorisations + 14 four-vector solves, the work of one
#: modes() call): 3,000 rows 0.027-0.031 s with AMD against 0.037-0.058 s with METIS (P1 and P2);
#: 19,440 rows 0.45 against 0.50-0.53 s (P1) and 0.51-0.56 against 0.55-0.57 s (P2); 60,840 rows (P2)
#: 3.24 against 3.16 s; 138,720 rows (P2) METIS 11.2 s, AMD 26.7 s (77M against 96M factor entries).
#: Minimum degree orders small graphs as well as nested dissection does, in a fraction of the time. With MKL
#: forced to its AVX2 kernels (the proxy for AMD CPUs) at 19,683 DOFs (P2) both took the same PARDISO time
#: in one modes() call (medians 1.93 s AMD, 1.93 s METIS, 5 interleaved runs, load ~8).
AMD_BELOW = 50_000
#: order the supervariable quotient graph (see ``PardisoLDLT``) from this many rows on, when it has at
#: least this many times fewer vertices. Measured at 138,720 DOFs (P2 cantilever, 46,240 nodes, one
#: thread): METIS on the node graph 0.6 s + symbolic analysis with that ordering 1.2 s, against 4.3-4.7 s
#: for METIS on the DOF graph; the factor has 6 % more entries (77.2M against 72.8M).
SUPERVARIABLE_MIN_ROWS = 2_000
SUPERVARIABLE_MIN_RATIO = 1.5
#: with the AMD ordering the quotient graph is used below this many rows only; from it on AMD orders the
#: DOF graph (MKL's AMD merges indistinguishable rows itself, and its own choice left less fill). Factor
#: entries (deterministic), quotient graph against DOF graph, P2, 3 DOFs per node: cantilever 3,000 rows
#: 249,642 against 264,760 (the quotient graph 6 % better); cantilever 19,440 rows 4.82M against 4.18M,
#: cube 26,460 rows 14.2M against 11.9M, plate 24,600 rows 7.62M against 6.33M (the DOF graph 13-17 %
#: better). One modes() call's PARDISO work at 19,440 rows (analysis + 2 numeric factorisations + 13
#: four-vector solves, one thread, CPU seconds, min of 5, load ~4.5): 0.57 -> 0.47 s (default MKL path),
#: 0.52 -> 0.47 s (MKL_ENABLE_INSTRUCTIONS=AVX2).
SUPERVARIABLE_AMD_BELOW = 10_000


def busy_elsewhere(samples: int = 5) -> float:
    """Runnable threads of other processes right now (median of a few /proc/loadavg samples, 2 ms
    apart, less this process's own runnable threads); 0 where /proc is not available."""
    import time

    counts = []
    for _ in range(samples):
        try:
            with open("/proc/loadavg") as f:
                total = int(f.read().split()[3].split("/")[0])
            own = 0
            for tid in os.listdir("/proc/self/task"):
                try:
                    with open(f"/proc/self/task/{tid}/stat") as f:
                        own += f.read().rsplit(")", 1)[1].split()[0] == "R"
                except OSError:  # the thread ended meanwhile
                    pass
        except (OSError, ValueError, IndexError):
            return 0.0
        counts.append(max(total - own, 0))
        time.sleep(0.002)
    return float(np.median(counts))


def thread_count(n: int) -> int:
    """MKL threads for a PARDISO handle of ``n`` rows: 0 (all cores), or fewer when cores are taken.

    One thread below ``SERIAL_BELOW`` rows. Otherwise the cores not taken by other processes right
    now (``busy_elsewhere``): OpenMP threads that share a core with other work wait at every barrier.
    Measured at 61k DOFs with a load of ~5 on 2 cores: 44 shift-invert solves took 8.4-8.9 s on two
    threads against 4.4-5.0 s on one. (A load average would count this process's own recent work.)
    """
    if n < SERIAL_BELOW:
        return 1
    others = busy_elsewhere()
    if others < 0.5:
        return 0
    return max(1, (os.cpu_count() or 1) - round(others))


def supervariables_of(A) -> np.ndarray | None:
    """Group id (n,) of each row of the CSR matrix ``A`` (sorted indices): consecutive rows with the
    same column pattern share a group (the displacement DOFs of one node), ids ascending; None if
    no two consecutive rows share a pattern.

    Rows are compared by length and two checksums of their column indices; a collision can only
    merge two rows whose patterns differ, which changes the fill of the ordering, never a result.
    """
    n = A.shape[0]
    if n < 2:
        return None
    indptr = np.asarray(A.indptr, dtype=np.int64)
    length = np.diff(indptr)
    if np.any(length == 0):
        return None
    idx = np.asarray(A.indices, dtype=np.int64)
    s1 = np.add.reduceat(idx, indptr[:-1])
    s2 = np.add.reduceat((idx * idx) % 1_000_003, indptr[:-1])
    same = (length[1:] == length[:-1]) & (s1[1:] == s1[:-1]) & (s2[1:] == s2[:-1])
    if not same.any():
        return None
    return np.concatenate([[0], np.cumsum(~same)])


def _check_groups(groups, n: int) -> np.ndarray:
    """``groups`` renumbered 0..g-1 in row order; consecutive rows of one group required."""
    g = np.asarray(groups)
    if g.shape != (n,) or not np.issubdtype(g.dtype, np.integer):
        raise SolverError(f"PARDISO groups must be ({n},) integers, got {g.dtype} {g.shape}")
    change = np.concatenate([[False], g[1:] != g[:-1]])
    ids = np.cumsum(change)
    if n and len(np.unique(g)) != int(ids[-1]) + 1:
        raise SolverError("PARDISO groups: the rows of a group must be consecutive")
    return ids


def _quotient_ordering(A, groups: np.ndarray, ordering: str) -> np.ndarray:
    """PARDISO's fill-reducing ordering (position of each group) of the quotient graph of ``A``."""
    import scipy.sparse as sp

    ng = int(groups[-1]) + 1
    lead = np.concatenate([[0], np.flatnonzero(np.diff(groups)) + 1])  # first row of each group
    start, stop = A.indptr[lead], A.indptr[lead + 1]
    counts = stop - start
    pos = np.repeat(start - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
    rows = np.repeat(np.arange(ng), counts)
    cols = groups[A.indices[pos]]
    keep = np.ones(len(cols), dtype=bool)
    keep[1:] = (cols[1:] != cols[:-1]) | (rows[1:] != rows[:-1])
    rows, cols = rows[keep], cols[keep]
    deg = np.bincount(rows, minlength=ng).astype(np.float64)
    vals = np.where(rows == cols, deg[rows] + 1.0, -1.0 / np.maximum(deg[rows], 1.0))
    Q = sp.csr_matrix((vals, cols, np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=ng))])), shape=(ng, ng))
    with PardisoLDLT(Q, ordering=ordering, supervariables=False, _return_ordering=True) as q:
        return q._perm.copy()


def _expand_ordering(groups: np.ndarray, group_position: np.ndarray, n: int) -> np.ndarray:
    """Row positions (n,) from group positions: a group's rows stay together, in their order."""
    order = np.lexsort((np.arange(n), group_position[groups]))
    perm = np.empty(n, dtype=np.int32)
    perm[order] = np.arange(n, dtype=np.int32)
    return perm


def _candidates():
    """Paths to try, lazily: ``find_library`` (which runs ``ldconfig -p``, ~40 ms) only when the
    library next to the interpreter did not load."""
    env = os.environ.get("MODALFEM_MKL_RT")
    if env:
        yield env
        return
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        yield from sorted(glob.glob(os.path.join(prefix, "lib", "libmkl_rt.so*")), key=len)
        yield from sorted(glob.glob(os.path.join(prefix, "Library", "bin", "mkl_rt*.dll")), key=len)
    name = ctypes.util.find_library("mkl_rt")
    if name:
        yield name


def _library():
    """The loaded ``libmkl_rt`` with ``pardiso`` typed, or None (reason in ``_LOAD_ERROR``)."""
    global _LIB, _LOAD_ERROR
    if _LIB is not None or _LOAD_ERROR is not None:
        return _LIB
    for path in _candidates():
        try:
            lib = ctypes.CDLL(path)
            fn = lib.pardiso
        except (OSError, AttributeError) as exc:
            _LOAD_ERROR = f"{path}: {exc}"
            continue
        p, i32 = ctypes.POINTER, ctypes.c_int32
        lib.MKL_Set_Num_Threads_Local.restype = ctypes.c_int
        lib.MKL_Set_Num_Threads_Local.argtypes = [ctypes.c_int]
        fn.restype = None
        fn.argtypes = [p(ctypes.c_int64), p(i32), p(i32), p(i32), p(i32), p(i32), ctypes.c_void_p, p(i32), p(i32),
                       p(i32), p(i32), p(i32), p(i32), ctypes.c_void_p, ctypes.c_void_p, p(i32)]
        _LIB, _LOAD_ERROR = lib, None
        return _LIB
    if _LOAD_ERROR is None:
        _LOAD_ERROR = "libmkl_rt not found (pip install mkl, or set MODALFEM_MKL_RT)"
    return None


def have_pardiso() -> bool:
    """True when MKL PARDISO can be loaded in this process."""
    return _library() is not None


class PardisoLDLT:
    """LDL^T factorisation of a real symmetric sparse matrix with MKL PARDISO.

    Args:
        A: symmetric scipy.sparse matrix (n, n); only its upper triangle is read. Its sparsity
            pattern is fixed for the life of the object (``refactor`` takes new values).
        ordering: fill-reducing ordering, ``"auto"`` (default: ``"amd"`` below ``AMD_BELOW`` rows, else
            ``"metis-parallel"``), ``"metis-parallel"`` (OpenMP nested dissection), ``"metis"`` or ``"amd"``.
        supervariables: order the quotient graph of consecutive rows with identical patterns (the
            three displacement DOFs of a node) and expand that ordering to the rows, when it is at
            least ``SUPERVARIABLE_MIN_RATIO`` times smaller (with ``"amd"``: below
            ``SUPERVARIABLE_AMD_BELOW`` rows only); else (or False) order the rows' graph.
        groups: optional supervariable of each row (n,) ints, rows of a group consecutive (the node
            of each free DOF, ``free_dofs // 3``): use these instead of detecting identical patterns
            (a sum such as K - shift M drops the entries that cancel, so the three rows of a node
            can differ there). The quotient graph takes each group's first row's pattern.
        pivoting: ``"bunch-kaufman"`` (1x1 and 2x2 pivots, stable for any symmetric A) or
            ``"diagonal"`` (1x1 pivots on the diagonal: an LDL^T that is a Cholesky up to signs;
            measured 15-30 % faster numerically at 138,720 DOFs). With diagonal pivoting a
            factorisation that had to perturb a pivot is redone with Bunch-Kaufman, so the factor
            is never a perturbed one when an unperturbed one exists (``pivoting_used`` says which).
            Diagonal pivots are backward stable for positive definite A; for an indefinite A the
            caller checks a solve's backward error before trusting the factor.

    Raises:
        SolverError: PARDISO is not available, or a phase failed (named, with PARDISO's reason).
    """

    def __init__(self, A, *, ordering: str = "auto", supervariables: bool = True, groups=None,
                 pivoting: str = "bunch-kaufman", _return_ordering: bool = False) -> None:
        import scipy.sparse as sp

        lib = _library()
        if lib is None:
            raise SolverError(f"MKL PARDISO is not available: {_LOAD_ERROR}")
        if ordering == "auto":
            ordering = "amd" if A.shape[0] < AMD_BELOW else "metis-parallel"
        if ordering not in _ORDERINGS:
            raise SolverError(f"unknown PARDISO ordering {ordering!r}; use one of auto, "
                              f"{', '.join(sorted(_ORDERINGS))}")
        if pivoting not in _PIVOTING:
            raise SolverError(f"unknown PARDISO pivoting {pivoting!r}; use one of {sorted(_PIVOTING)}")
        #: requested pivoting, and the one the last numeric factorisation used
        self.pivoting = self.pivoting_used = pivoting
        A = sp.csr_matrix(A)
        if A.shape[0] != A.shape[1]:
            raise SolverError(f"PARDISO needs a square matrix, got shape {A.shape}")
        A.sum_duplicates()
        A.sort_indices()
        self.n = int(A.shape[0])
        rows = np.repeat(np.arange(self.n), np.diff(A.indptr))
        self._upper = np.flatnonzero(A.indices >= rows)  # positions of the upper triangle in A.data
        counts = np.bincount(rows[self._upper], minlength=self.n)
        if np.any(counts == 0):
            raise SolverError(f"PARDISO: row {int(np.argmin(counts))} has no diagonal or upper entry (singular)")
        self._ia = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self._ja = np.ascontiguousarray(A.indices[self._upper], dtype=np.int32)
        self._nnz_full = int(A.nnz)
        self._indptr, self._indices = A.indptr, A.indices
        self._a = np.ascontiguousarray(A.data[self._upper], dtype=np.float64)
        self._lib = lib
        #: MKL threads for every phase of this handle (0 = MKL's default, all cores)
        self.threads = thread_count(self.n)
        self._pt = np.zeros(64, dtype=np.int64)
        ip = self._iparm = np.zeros(64, dtype=np.int32)
        ip[0] = 1  # user-set parameters
        ip[1] = _ORDERINGS[ordering]
        self._perm = np.zeros(self.n, dtype=np.int32)
        #: rows per supervariable when the ordering came from the quotient graph, else 1.0
        self.supervariable_ratio = 1.0
        if _return_ordering:
            ip[4] = 2  # PARDISO writes its ordering into self._perm
        if not supervariables or _return_ordering:
            groups = None
        elif ordering == "amd" and self.n >= SUPERVARIABLE_AMD_BELOW:
            if groups is not None:
                _check_groups(groups, self.n)  # bad input still reported
            groups = None
        elif groups is not None:
            groups = _check_groups(groups, self.n)
        else:
            groups = supervariables_of(A)
        if groups is not None and self.n >= SUPERVARIABLE_MIN_ROWS:
            ng = int(groups[-1]) + 1
            if self.n >= SUPERVARIABLE_MIN_RATIO * ng:
                self._perm[:] = _expand_ordering(groups, _quotient_ordering(A, groups, ordering), self.n)
                ip[4] = 1  # user permutation: the analysis does the symbolic factorisation only
                self.supervariable_ratio = self.n / ng
        ip[9] = 8  # pivot perturbation 1e-8 (reported in iparm[13])
        ip[10] = ip[12] = 0  # no scaling / weighted matching: keeps the inertia of A itself
        ip[17] = ip[18] = -1  # report factor nonzeros and MFlop
        ip[20] = _PIVOTING[pivoting]
        ip[34] = 1  # zero-based indexing
        self._alive = True
        self._call(11)  # ordering and symbolic factorisation
        self.factored = False

    # -------------------------------------------------------------------------------- phases
    def _call(self, phase: int, b: np.ndarray | None = None) -> np.ndarray | None:
        p, i32 = ctypes.POINTER, ctypes.c_int32
        err = i32(0)
        if b is None:
            nrhs, bb, x = 1, None, None
        else:
            bb = np.asfortranarray(b, dtype=np.float64)
            x = np.zeros_like(bb)
            nrhs = 1 if bb.ndim == 1 else bb.shape[1]
        # One thread count for every phase of a handle (PARDISO sizes its workspace for the threads of
        # the analysis; a numeric phase with more threads than an earlier one crashed, seen with MKL
        # 2026). Small problems run on one thread: on a busy machine MKL's OpenMP threads cost more
        # than they give there (measured: 50 ms instead of 3 ms per solve at 3k DOFs, 2 cores).
        previous = self._lib.MKL_Set_Num_Threads_Local(self.threads)
        self._lib.pardiso(
            self._pt.ctypes.data_as(p(ctypes.c_int64)), ctypes.byref(i32(1)), ctypes.byref(i32(1)),
            ctypes.byref(i32(_MTYPE_SYM_INDEF)), ctypes.byref(i32(phase)), ctypes.byref(i32(self.n)),
            self._a.ctypes.data, self._ia.ctypes.data_as(p(i32)), self._ja.ctypes.data_as(p(i32)),
            self._perm.ctypes.data_as(p(i32)),
            ctypes.byref(i32(nrhs)), self._iparm.ctypes.data_as(p(i32)), ctypes.byref(i32(0)),
            None if bb is None else bb.ctypes.data, None if x is None else x.ctypes.data, ctypes.byref(err),
        )
        self._lib.MKL_Set_Num_Threads_Local(previous)
        if err.value != 0:
            what = {11: "analysis", 22: "numeric factorisation", 33: "solve", -1: "release"}.get(phase, str(phase))
            raise SolverError(f"PARDISO {what} failed: error {err.value} ({_ERRORS.get(err.value, 'unknown')})")
        return x

    def same_pattern(self, A) -> bool:
        """True if the CSR matrix ``A`` (sorted indices) has the sparsity pattern this handle analysed."""
        return (A.shape == (self.n, self.n) and A.nnz == self._nnz_full
                and np.array_equal(A.indptr, self._indptr) and np.array_equal(A.indices, self._indices))

    def refactor(self, data: np.ndarray | None = None) -> PardisoLDLT:
        """Numeric LDL^T with the values ``data`` of the full matrix (same pattern, CSR order as given
        to the constructor after sorting), or with the constructor's values when None."""
        if not self._alive:
            raise SolverError("PARDISO factorisation used after close()")
        if data is not None:
            data = np.asarray(data, dtype=np.float64)
            if data.shape != (self._nnz_full,):
                raise SolverError(f"PARDISO refactor: expected {self._nnz_full} values, got {data.shape}")
            self._a = np.ascontiguousarray(data[self._upper])
        self._iparm[20] = _PIVOTING[self.pivoting]
        self.pivoting_used = self.pivoting
        self._call(22)
        if self.pivoting == "diagonal" and self.perturbed_pivots:
            self._iparm[20] = _PIVOTING["bunch-kaufman"]
            self.pivoting_used = "bunch-kaufman"
            self._call(22)
        self.factored = True
        return self

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x with A x = b for b of shape (n,) or (n, m) (several right-hand sides in one pass)."""
        if not self.factored:
            self.refactor()
        b = np.asarray(b, dtype=np.float64)
        if b.shape[0] != self.n:
            raise SolverError(f"PARDISO solve: right-hand side has {b.shape[0]} rows, matrix has {self.n}")
        return np.ascontiguousarray(self._call(33, b))

    # -------------------------------------------------------------------------------- results
    @property
    def inertia(self) -> tuple[int, int, int]:
        """(negative, zero, positive) pivot counts of the last numeric factorisation."""
        if not self.factored:
            raise SolverError("PARDISO inertia asked before a numeric factorisation")
        pos, neg = int(self._iparm[21]), int(self._iparm[22])
        return neg, self.n - pos - neg, pos

    @property
    def perturbed_pivots(self) -> int:
        """Pivots PARDISO perturbed in the last factorisation (0: the LDL^T is of A itself)."""
        return int(self._iparm[13])

    def info(self) -> dict:
        """Ordering, factor entries and flops of the analysis (for provenance and benchmarks)."""
        code = int(self._iparm[1])
        name = {v: k for k, v in _ORDERINGS.items()}.get(code, str(code))
        if self.supervariable_ratio > 1.0:
            name += f" (supervariables, {self.supervariable_ratio:.2f} rows each)"
        return {
            "pardiso_ordering": name,
            "pardiso_factor_entries": int(self._iparm[17]),
            "pardiso_factor_flops": float(self._iparm[18]) * 1e6,
            "pardiso_perturbed_pivots": self.perturbed_pivots,
        }

    def close(self) -> None:
        """Release PARDISO's memory (idempotent)."""
        if self._alive:
            self._alive = False
            try:
                self._call(-1)
            except SolverError:  # pragma: no cover - release errors leave nothing to do
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - garbage-collection timing
        if getattr(self, "_alive", False):
            try:
                self.close()
            except Exception:  # noqa: BLE001, S110 - at interpreter shutdown ctypes may be gone already
                pass
