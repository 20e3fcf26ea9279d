"""SLEPc eigen solver: Krylov-Schur, shift-and-invert at a negative shift (PARDISO, MUMPS or CHOLMOD).

K - shift M is factorised by MKL PARDISO LDL^T (METIS ordering; ``modalfem.eigen.pardiso``, plugged in
as a petsc4py python preconditioner) on one process where the mkl wheel loads, otherwise (and in
parallel) by MUMPS LDL^T (PORD ordering); CHOLMOD (METIS) is an option for one process. See
``SlepcOptions.factor`` for the measured trade-off.

``solve_slepc`` solves K x = lambda M x on the free DOFs for the lowest ``nev`` eigenpairs (plus a
few extra so the certificate sees the next eigenvalue) and computes the certificate numbers with
PETSc, distributed when the matrices are:

* per-pair relative residuals ||K x - lambda M x|| / ||K x|| (``||K||_inf ||x||`` for rigid-like
  pairs, see ``RIGID_KX_RTOL``), M-orthonormality ``max |X^T M X - I|``;
* the Sylvester inertia count of K - sigma M, sigma from ``certify.choose_inertia_shift``. With MUMPS
  as the solve factorisation the certificate REUSES the solve's MUMPS analysis: the shifted operator A = K - shift M that SLEPc
  factorised is turned into K - sigma M in place (same nonzero pattern), so the count costs one
  numeric LDL^T factorisation, not a new ordering and symbolic analysis.

Each step has one home, a method of ``_SlepcRun`` (which holds the PETSc objects and counters), and
``solve_slepc`` drives them: argument checks (``__init__``), ``convert`` (to PETSc), ``choose_factor``
(and the PETSc options), ``set_up`` (the EPS, its deflation space, the shift-and-invert ST),
``factorise``, ``iterate`` (Krylov-Schur and its continuation rounds), ``extract`` (M-normalised
vectors), ``residuals``, ``refine``, ``pair_numbers`` (order, rigid fields first, orthonormality),
``count_inertia``, ``retry`` (when the count shows missed eigenvalues), ``gather`` and ``info``. A
PETSc error in any of them becomes a ``SolverError`` naming the stage.

Configuration (measured at 139,587 DOFs, P2 cantilever, nev = 10, on a 2-core machine; see
``SlepcOptions``): MUMPS symmetric-indefinite LDL^T (PCCHOLESKY without the SPD flag, so sym = 2:
needed for the inertia anyway) with the PORD ordering. Debian's MUMPS 5.5 is built with neither
METIS nor SCOTCH (ICNTL(7) = 3 or 5 silently falls back to PORD); PORD needs 99 GFlop and 91M
factor entries, AMF 155 GFlop, AMD/QAMD 267 GFlop; LU (the dolfinx tutorial recipe) takes ~2x the
Cholesky numeric time. Krylov-Schur requests nev + 3 pairs (continuing with more only if all of
them above the nev-th sit in one cluster) with ``ncv = max(2 * nreq, nreq + 8)``; target = shift with
``TARGET_MAGNITUDE``; no purification (it costs one solve per vector). In parallel MUMPS needs
ICNTL(13) = 1 (no ScaLAPACK root) for a correct inertia; it is set from the start because it is an
analysis-phase parameter. ICNTL(24) = 1 (null-pivot detection) is switched on for the certificate
factorisation only (PETSc's MatGetInertia requires it).
"""

from __future__ import annotations

import functools
import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from modalfem.eigen.base import RawModes
from modalfem.eigen.pardiso import PardisoLDLT, have_pardiso
from modalfem.errors import BackendUnavailableError, InputError, SolverError

__all__ = ["RIGID_KX_RTOL", "SlepcOptions", "solve_slepc"]

#: A pair is "rigid-like" (its residual is divided by ||K||_inf ||x|| instead of ||K x||) when
#: ||K x|| <= RIGID_KX_RTOL * ||K||_inf * ||x||. Rigid modes found at a negative shift have
#: ||K x|| / (||K|| ||x||) ~ 1e-14; the lowest elastic mode of a body is far above 1e-10 unless the
#: mesh resolves a spectrum spanning 10 decades, so elastic pairs keep the stricter ||K x|| measure.
RIGID_KX_RTOL = 1e-10
#: a pair is refined when its residual exceeds max(tol, REFINE_FLOOR_FACTOR * its roundoff floor)
REFINE_FLOOR_FACTOR = 10.0

_ORDERINGS = {0: "AMD", 1: "user", 2: "AMF", 3: "SCOTCH", 4: "PORD", 5: "METIS", 6: "QAMD", 7: "auto"}
_counter = itertools.count()


@dataclass(frozen=True)
class SlepcOptions:
    """Tuning knobs of ``solve_slepc`` (the defaults are the measured fastest robust choice).

    Attributes:
        factor: factorisation of the SPD solve operator K - shift M: ``"pardiso"`` (MKL LDL^T,
            METIS ordering, one process; ``"auto"`` picks it when it loads and the solve is serial:
            at 138,720 DOFs its numeric factorisation takes ~2 s and a solve 0.07 s, 3-4x faster
            than MUMPS, and the certificate refactorises on the same analysis), ``"mumps"`` (LDL^T,
            PORD ordering, serial or distributed; ``"auto"`` in parallel) or ``"cholmod"``
            (SuiteSparse supernodal Cholesky with the better of AMD and METIS orderings, serial
            only). The inertia count always uses MUMPS LDL^T (CHOLMOD's supernodal factorisation is
            LL^T and fails on the indefinite K - sigma M). Measured at 139k DOFs (P2 cantilever,
            2-core machine, paired runs): alone, CHOLMOD factors in 7.4-8.0 s against 9.2-10.0 s
            for MUMPS/PORD and solves in 0.11 s against 0.19 s (METIS's smaller fill), but inside
            SLEPc the whole solve took 31-32 s with CHOLMOD against 25-29 s with MUMPS, whose
            certificate reuses the solve's analysis (6.1 s numeric LDL^T against 9.6-13 s for a
            fresh MUMPS analysis + factorisation).
        extra: eigenpairs requested beyond ``nev`` in the first round (the certificate needs the
            next eigenvalue). If no computed eigenvalue above the nev-th is separated from its
            predecessor by a relative gap >= ``certify.CLEAR_GAP`` (the nev-th sits in a degenerate
            cluster), the solve continues from the current Ritz vectors with ``extra_step`` more,
            at most ``max_rounds`` times, reusing the factorisation. Measured at 139k DOFs, nev =
            10 (the 10th and 11th modes are a degenerate pair there): extra = 3 took 44
            shift-invert solves in one round, extra = 1 needed a continuation (71 in all).
        extra_step: eigenpairs added per continuation round.
        max_rounds: continuation rounds allowed.
        max_retries: new searches allowed when the Sylvester count shows that Krylov-Schur missed
            eigenvalues below the inertia shift (a many-fold cluster such as the 12 rigid modes of
            two pieces): each restores K - shift M (one numeric factorisation), solves again with
            the found pairs as a deflation space, and redoes the count (one more).
        ncv: Krylov subspace size; None = ``max(2 * nreq, nreq + 8)`` with nreq = nev + extra.
        mpd: maximum projected dimension; None = SLEPc's default (ncv).
        ordering: MUMPS ICNTL(7): 4 = PORD (default), 0 = AMD, 2 = AMF, 6 = QAMD, 7 = auto.
        mem_relax: MUMPS ICNTL(14), percent of extra workspace (LDL^T pivoting can need more at the
            indefinite certificate shift than at the definite solve shift).
        max_it: Krylov-Schur restarts allowed.
        tol_factor: SLEPc's tolerance is ``tol * tol_factor``. SLEPc bounds the residual of the
            shift-inverted problem relative to 1 / (lambda - shift); the certified residual
            ||K x - lambda M x|| / ||K x|| can exceed it (seen: 1.6e-9 at SLEPc tol 1e-10 on a
            spring chain). At 139k DOFs 1e-10, 1e-11 and 1e-12 all took the same 3 restarts.
        purify: SLEPc eigenvector purification (one extra solve per vector; only useful when M is
            singular, which a mass matrix is not).
        petsc_options: extra PETSc/SLEPc options (name without prefix -> value), e.g.
            ``{"st_mat_mumps_icntl_35": 1}``; applied under this solve's private prefix.
        pardiso_ordering: PARDISO's fill-reducing ordering (``"auto"``, ``"metis-parallel"``, ``"metis"``, ``"amd"``);
            at 139k DOFs the OpenMP nested dissection analysed in 2.7 s against 3.6-4.3 s for serial
            METIS (same fill, 75M entries) and AMD took 2.3 s but left 11 % more fill and 2x slower solves.
    """

    factor: str = "auto"
    extra: int = 3
    extra_step: int = 4
    max_rounds: int = 3
    max_retries: int = 2
    ncv: int | None = None
    mpd: int | None = None
    ordering: int = 4
    mem_relax: int = 50
    max_it: int = 200
    purify: bool = False
    tol_factor: float = 1e-2
    pardiso_ordering: str = "auto"
    petsc_options: dict = field(default_factory=dict)


def _import_petsc():
    try:
        from petsc4py import PETSc
        from slepc4py import SLEPc
    except ImportError as exc:  # pragma: no cover - depends on the machine
        raise BackendUnavailableError(
            "the SLEPc solver needs petsc4py and slepc4py (Debian: apt-get install python3-slepc4py "
            f"python3-petsc4py); import failed: {exc}"
        ) from exc
    return PETSc, SLEPc


_HAVE_CHOLMOD: bool | None = None


_FACTOR_NAMES = {"mumps": "MUMPS LDL^T", "cholmod": "CHOLMOD Cholesky", "pardiso": "PARDISO LDL^T"}


class _PardisoPC:
    """petsc4py python-PC context: applies (the PC operator)^-1 with a ``PardisoLDLT`` (serial).

    ``setUp`` is called by PETSc whenever the operator changed (new shift, or K - sigma M for the
    inertia): the first call orders and analyses the pattern, later ones refactorise numerically.
    """

    def __init__(self, ordering: str, groups=None) -> None:
        self.ordering = ordering
        self.groups = groups
        self.factor: PardisoLDLT | None = None

    def setUp(self, pc) -> None:
        import scipy.sparse as sp

        A = pc.getOperators()[1]
        indptr, indices, data = A.getValuesCSR()
        if self.factor is None:
            self.factor = PardisoLDLT(sp.csr_matrix((data, indices, indptr), shape=A.getSize()), ordering=self.ordering,
                                      groups=self.groups)
        self.factor.refactor(data)

    def apply(self, pc, x, y) -> None:
        y.setArray(self.factor.solve(x.getArray(readonly=True)))

    def close(self) -> None:
        if self.factor is not None:
            self.factor.close()


def _have_cholmod(PETSc) -> bool:
    """True when this PETSc build can factorise with CHOLMOD (checked once on a 2x2 matrix)."""
    global _HAVE_CHOLMOD
    if _HAVE_CHOLMOD is None:
        A = PETSc.Mat().createAIJ((2, 2), csr=([0, 1, 2], [0, 1], [2.0, 3.0]), comm=PETSc.COMM_SELF)
        ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        try:
            ksp.setOperators(A)
            ksp.setType(PETSc.KSP.Type.PREONLY)
            ksp.getPC().setType(PETSc.PC.Type.CHOLESKY)
            ksp.getPC().setFactorSolverType("cholmod")
            ksp.setUp()
            _HAVE_CHOLMOD = True
        except PETSc.Error:
            _HAVE_CHOLMOD = False
        finally:
            ksp.destroy()
            A.destroy()
    return _HAVE_CHOLMOD


def _mumps_inertia(K, M, sigma: float, settings: dict, prefix: str, PETSc, mpi_comm):
    """((negative, zero, positive) pivot counts, MUMPS info) of a fresh MUMPS LDL^T of K - sigma M."""
    A = K.duplicate(copy=True)
    ksp = PETSc.KSP().create(K.getComm())
    db = PETSc.Options()
    try:
        same = _same_pattern(K, M, mpi_comm)
        A.axpy(-sigma, M, PETSc.Mat.Structure.SAME if same else PETSc.Mat.Structure.DIFFERENT)
        for k, v in settings.items():
            if k.startswith("st_mat_mumps"):
                db[prefix + "cert_" + k[len("st_"):]] = v
        ksp.setOptionsPrefix(prefix + "cert_")
        ksp.setOperators(A)
        ksp.setType(PETSc.KSP.Type.PREONLY)
        pc = ksp.getPC()
        pc.setType(PETSc.PC.Type.CHOLESKY)
        pc.setFactorSolverType("mumps")
        ksp.setFromOptions()
        pc.setFactorSetUpSolverType()
        F = pc.getFactorMatrix()
        F.setMumpsIcntl(24, 1)  # null-pivot detection: PETSc needs it to report zero pivots
        ksp.setUp()
        F = pc.getFactorMatrix()
        return F.getInertia(), _mumps_info(F)
    finally:
        for k in list(settings):
            if k.startswith("st_mat_mumps"):
                db.delValue(prefix + "cert_" + k[len("st_"):])
        ksp.destroy()
        A.destroy()


def _max_row_nnz(K) -> int:
    """Most stored entries in a row of the PETSc matrix K (over all ranks)."""
    indptr = K.getValuesCSR()[0]
    local = int(np.max(np.diff(indptr))) if len(indptr) > 1 else 0
    comm = K.getComm().tompi4py()
    return int(comm.allreduce(local, op=_mpi_max())) if comm.Get_size() > 1 else local


def _mpi_max():
    from mpi4py import MPI

    return MPI.MAX


def _abs_matrix(K, PETSc):
    """|K| entrywise, same layout (for the roundoff floor of the residuals)."""
    indptr, indices, data = K.getValuesCSR()
    sizes = K.getSizes()
    A = PETSc.Mat().createAIJ(sizes, csr=(indptr, indices, np.abs(data)), comm=K.getComm())
    A.assemble()
    return A


def _pair_stats(K, Kabs, X, MX, PETSc, rigid=None):
    """Rayleigh quotients, relative residuals and their roundoff floors of M-normalised pairs.

    residual_j = ||K x - lambda M x|| / ||K x|| (``||K||_inf ||x||`` for rigid-like pairs);
    floor_j = sqrt(r) eps ||(|K| |x|)|| / (same denominator), r the most nonzeros in a row of K: the
    probabilistic bound on the roundoff of computing K x (Higham and Mary 2019: sqrt(r) u |K| |x|
    per row), i.e. what double precision allows for that pair. ``rigid``: how many leading pairs are
    rigid fields by construction (None: pairs with ||K x|| <= RIGID_KX_RTOL ||K|| ||x|| count as rigid).
    """
    m = len(X)
    lam, res, floor = np.empty(m), np.empty(m), np.empty(m)
    knorm = K.norm(PETSc.NormType.INFINITY)
    kx, r, ax, kax = K.createVecLeft(), K.createVecLeft(), K.createVecRight(), K.createVecLeft()
    eps = np.finfo(float).eps * np.sqrt(_max_row_nnz(K))
    for j, (x, mx) in enumerate(zip(X, MX)):
        K.mult(x, kx)
        lam[j] = x.dot(kx)  # Rayleigh quotient (x is M-normalised): second-order accurate
        kxn = kx.norm()
        kx.copy(r)
        r.axpy(-lam[j], mx)
        xn = x.norm()
        is_rigid = kxn <= RIGID_KX_RTOL * knorm * xn if rigid is None else j < rigid
        den = knorm * xn if is_rigid else kxn
        x.copy(ax)
        ax.abs()
        Kabs.mult(ax, kax)
        res[j] = r.norm() / den if den > 0 else np.inf
        floor[j] = eps * kax.norm() / den if den > 0 else np.inf
    for v in (kx, r, ax, kax):
        v.destroy()
    return lam, res, floor


class _SerialStats:
    """``_pair_stats`` for one process, vectorised over the pairs with scipy (one sparse product with
    K and one with |K| for all pairs instead of two PETSc products per pair: 0.56 -> ~0.1 s at 61k DOFs)."""

    def __init__(self, K) -> None:
        import scipy.sparse as sp

        indptr, indices, data = K.getValuesCSR()
        n = K.getSize()[0]
        self.K = sp.csr_matrix((data, indices, indptr), shape=(n, n))
        self.Kabs = sp.csr_matrix((np.abs(data), indices, indptr), shape=(n, n))
        self.knorm = float(np.max(self.Kabs @ np.ones(n))) if n else 0.0
        self.eps = np.finfo(float).eps * np.sqrt(int(np.max(np.diff(indptr))) if n else 0)

    def __call__(self, X, MX, rigid=None):
        Xa = np.column_stack([x.getArray(readonly=True) for x in X])
        MXa = np.column_stack([mx.getArray(readonly=True) for mx in MX])
        KX = self.K @ Xa
        lam = np.einsum("ij,ij->j", Xa, KX)
        kxn, xn = np.linalg.norm(KX, axis=0), np.linalg.norm(Xa, axis=0)
        is_rigid = kxn <= RIGID_KX_RTOL * self.knorm * xn if rigid is None else np.arange(len(kxn)) < rigid
        den = np.where(is_rigid, self.knorm * xn, kxn)
        safe = np.where(den > 0, den, 1.0)
        res = np.where(den > 0, np.linalg.norm(KX - MXa * lam, axis=0) / safe, np.inf)
        floor = np.where(den > 0, self.eps * np.linalg.norm(self.Kabs @ np.abs(Xa), axis=0) / safe, np.inf)
        return lam, res, floor


def _short_of_floor(lam, res, floor, nev: int, tol: float, *, factor: float = REFINE_FLOOR_FACTOR) -> bool:
    """True if one of the lowest ``nev`` pairs has a residual above max(tol, factor x its floor)."""
    low = np.argsort(lam, kind="stable")[:nev]
    return bool(np.any(res[low] > np.maximum(tol, factor * floor[low])))


def _refine(ksp, K, M, X, MX, *, deflate=((), ())):
    """One block inverse-iteration step Y = (K - shift M)^{-1} M X, kept M-orthogonal to the deflated
    fields ``deflate`` = (Z, M Z) (lists of vectors), then Rayleigh-Ritz on span(Y)."""
    Y = []
    for mx in MX:
        y = mx.duplicate()
        ksp.solve(mx, y)
        for _ in range(2):  # M-orthogonal to the rigid fields, twice
            for z, mz in zip(*deflate):
                y.axpy(-mz.dot(y), z)
        Y.append(y)
    m = len(Y)
    B = Y
    nb = len(B)
    KB = [K.createVecLeft() for _ in range(nb)]
    MB = [K.createVecLeft() for _ in range(nb)]
    for b, kb, mb in zip(B, KB, MB):
        K.mult(b, kb)
        M.mult(b, mb)
    Kr, Mr = np.empty((nb, nb)), np.empty((nb, nb))
    for j in range(nb):
        for i in range(j + 1):
            Kr[i, j] = Kr[j, i] = B[i].dot(KB[j])
            Mr[i, j] = Mr[j, i] = B[i].dot(MB[j])
    from scipy.linalg import eigh

    # M-orthonormalise the (possibly nearly dependent) block first, then a standard eigenproblem
    d = 1.0 / np.sqrt(np.abs(np.diag(Mr)))
    sm, U = np.linalg.eigh(Mr * d[:, None] * d[None, :])
    keep = sm > 1e-13 * sm.max()
    T = (d[:, None] * U[:, keep]) / np.sqrt(sm[keep])
    _, Q = eigh(T.T @ Kr @ T)
    V = T @ Q[:, :m]
    Y = B
    MY = MB
    Xn, MXn = [], []
    for j in range(m):
        x, mx = Y[0].duplicate(), Y[0].duplicate()
        x.zeroEntries()
        mx.zeroEntries()
        x.maxpy(V[:, j], Y)
        mx.maxpy(V[:, j], MY)
        s = x.dot(mx)
        x.scale(1.0 / np.sqrt(s))
        mx.scale(1.0 / np.sqrt(s))
        Xn.append(x)
        MXn.append(mx)
    for v in B + KB + MB:
        v.destroy()
    return Xn, MXn


def _mumps_info(F) -> dict:
    """Ordering, flops, factor entries and memory of a MUMPS factor matrix."""
    return {
        "mumps_ordering": _ORDERINGS.get(int(F.getMumpsInfog(7)), str(F.getMumpsInfog(7))),
        "mumps_factor_flops": float(F.getMumpsRinfog(3)),
        "mumps_factor_entries": int(F.getMumpsInfog(29)),
        "mumps_memory_mb": int(F.getMumpsInfog(22)),
    }


def _to_petsc(A, PETSc, comm, name: str):
    """scipy sparse -> PETSc AIJ on ``comm`` (rows split in contiguous blocks); returns (Mat, rows)."""
    import scipy.sparse as sp

    if not sp.issparse(A):
        raise InputError(f"{name} must be a scipy.sparse matrix or a petsc4py Mat, got {type(A).__name__}")
    A = A.tocsr()
    if A.shape[0] != A.shape[1]:
        raise InputError(f"{name} must be square, got shape {A.shape}")
    n = A.shape[0]
    size, rank = comm.getSize(), comm.getRank()
    lo, hi = (n * rank) // size, (n * (rank + 1)) // size
    block = A[lo:hi] if size > 1 else A
    block.sort_indices()
    ival = PETSc.IntType
    csr = (block.indptr.astype(ival, copy=False), block.indices.astype(ival, copy=False),
           np.asarray(block.data, dtype=PETSc.ScalarType))
    M = PETSc.Mat().createAIJ(((hi - lo, n), (hi - lo, n)), csr=csr, comm=comm)
    M.assemble()
    return M, np.arange(lo, hi, dtype=np.int64)


def _gather(local: np.ndarray, rows: np.ndarray, n: int, mpi_comm) -> np.ndarray:
    """Gather (n_local, m) row blocks from every rank into a full (n, m) array on every rank."""
    m = local.shape[1]
    if mpi_comm is None or mpi_comm.Get_size() == 1:
        out = np.empty((n, m))
        out[rows] = local
        return out
    counts = np.asarray(mpi_comm.allgather(len(rows)), dtype=np.int64)
    all_rows = np.empty(int(counts.sum()), dtype=np.int64)
    mpi_comm.Allgatherv(np.ascontiguousarray(rows, dtype=np.int64), [all_rows, counts])
    all_vals = np.empty((int(counts.sum()), m))
    mpi_comm.Allgatherv(np.ascontiguousarray(local, dtype=np.float64), [all_vals, counts * m])
    if len(all_rows) != n or len(np.unique(all_rows)) != n:
        raise InputError(f"rows must list each of the {n} free DOFs exactly once over the ranks")
    out = np.empty((n, m))
    out[all_rows] = all_vals
    return out


class _SlepcRun:
    """One ``solve_slepc`` call: the PETSc objects, the pairs found so far and the counters, with one
    method per stage of the pipeline. ``stage`` names the step under way (for the SolverError of a
    failed PETSc call); ``cleanup`` releases what the run created, whatever stage it reached."""

    def __init__(self, PETSc, SLEPc, opt: SlepcOptions, nev, shift, tol) -> None:
        """Argument checks (nev, shift, tol) and the empty state."""
        self.PETSc, self.SLEPc, self.opt = PETSc, SLEPc, opt
        self.timings: dict[str, float] = {}
        self.cpu: dict[str, float] = {}  # process CPU seconds (all threads of this rank): robust on a busy machine
        if not (isinstance(nev, (int, np.integer)) and nev >= 1):
            raise InputError(f"nev must be a positive integer, got {nev!r}")
        if not (np.isfinite(shift) and shift < 0):
            raise InputError(f"shift must be negative and finite (K - shift M positive definite), got {shift!r}")
        if not (np.isfinite(tol) and 0 < tol < 1):
            raise InputError(f"tol must be in (0, 1), got {tol!r}")
        self.nev, self.shift, self.tol = nev, shift, tol
        self.stage = "setting up the eigensolver"
        self.is_mat = True  # until convert() made K and M (then: destroy them at the end unless given)
        self.K = self.M = self.eps = self.pardiso = self.Kabs = self.stats = None
        self.settings: dict = {}
        self.Zv, self.MZv = [], []  # the rigid fields as PETSc vectors (this rank's rows), and M times them
        self.rounds, self.its, self.attempts, self.refinements = 0, 0, 0, 0
        self.factorisations = 0  # numeric factorisations of a shifted K (solve and inertia), for provenance
        self.factor_is_solve_operator = True  # False once the factor holds K - sigma M (until refactorised)
        self.prev_lam = np.empty(0)  # eigenvalues found by earlier attempts
        self.X, self.MX = [], []  # eigenvectors found so far (M-normalised) and M times them

    def convert(self, K_ff, M_ff, rows, comm, deflate) -> None:
        """The matrices as PETSc Mats on one communicator, the sizes, rows and deflation basis checked,
        and the first request (nreq pairs, ncv, SLEPc's tolerance)."""
        PETSc, opt, nev = self.PETSc, self.opt, self.nev
        t0 = time.perf_counter()
        self.is_mat = is_mat = isinstance(K_ff, PETSc.Mat)
        if is_mat != isinstance(M_ff, PETSc.Mat):
            raise InputError("K_ff and M_ff must both be scipy.sparse or both petsc4py Mats")
        try:
            if is_mat:
                K, M = K_ff, M_ff
                pcomm = K.getComm()
                lo, hi = K.getOwnershipRange()
                rows = np.arange(lo, hi, dtype=np.int64) if rows is None else np.asarray(rows, dtype=np.int64)
                if len(rows) != hi - lo:
                    raise InputError(f"rows has {len(rows)} entries but this rank owns {hi - lo} rows")
            else:
                if comm is None:
                    pcomm = PETSc.COMM_SELF
                elif isinstance(comm, PETSc.Comm):
                    pcomm = comm
                else:
                    pcomm = PETSc.Comm(comm)
                K, rows = _to_petsc(K_ff, PETSc, pcomm, "K_ff")
                M, _ = _to_petsc(M_ff, PETSc, pcomm, "M_ff")
        except PETSc.Error as exc:
            raise SolverError(f"SLEPc solver: converting the matrices to PETSc failed: {_petsc_reason(exc)}") from exc
        n = K.getSize()[0]
        if K.getSize() != (n, n) or M.getSize() != (n, n):
            raise InputError(f"K_ff {K.getSize()} and M_ff {M.getSize()} must be square and of one size")
        if K.getOwnershipRange() != M.getOwnershipRange():
            raise InputError("K_ff and M_ff must have the same row distribution")
        if nev >= n:
            raise InputError(f"nev = {nev} must be below the number of free DOFs ({n})")
        self.K, self.M, self.pcomm, self.rows, self.n = K, M, pcomm, rows, n
        self.mpi_comm = pcomm.tompi4py()
        self.nproc = pcomm.getSize()
        self.Zg = np.zeros((n, 0)) if deflate is None else np.asarray(deflate, dtype=np.float64).reshape(n, -1)
        self.r = r = int(self.Zg.shape[1])
        if r >= nev:
            raise InputError(f"nev = {nev} must exceed the {r} deflated rigid fields")
        self.nreq = nreq = int(min(nev - r + max(int(opt.extra), 1), n - 1 - r))
        self.slepc_tol = float(self.tol * opt.tol_factor)
        self.ncv = int(min(opt.ncv if opt.ncv else max(2 * nreq, nreq + 8), n))
        self.timings["convert"] = time.perf_counter() - t0

    def choose_factor(self, groups) -> None:
        """The factorisation of K - shift M (``SlepcOptions.factor``, "auto" resolved) and the PETSc
        options, set under this solve's private prefix (``cleanup`` removes them)."""
        PETSc, opt = self.PETSc, self.opt
        if opt.factor not in ("auto", "pardiso", "cholmod", "mumps"):
            raise InputError(f"factor must be 'auto', 'pardiso', 'cholmod' or 'mumps', got {opt.factor!r}")
        factor = opt.factor
        if factor == "auto":
            factor = "pardiso" if self.nproc == 1 and have_pardiso() else "mumps"
        elif factor == "cholmod" and (self.nproc > 1 or not _have_cholmod(PETSc)):
            raise InputError("factor='cholmod' needs one process and a PETSc built with SuiteSparse")
        elif factor == "pardiso" and (self.nproc > 1 or not have_pardiso()):
            raise InputError("factor='pardiso' needs one process and MKL PARDISO (pip install mkl)")
        self.factor = factor
        self.prefix = f"modalfem_slepc{next(_counter)}_"
        self.db = PETSc.Options()
        settings = {
            "st_mat_mumps_icntl_7": int(opt.ordering),
            "st_mat_mumps_icntl_14": int(opt.mem_relax),
        }
        if factor == "cholmod":
            settings["st_mat_cholmod_nmethods"] = 2  # AMD and METIS, keep the smaller fill
        if self.nproc > 1:
            settings["st_mat_mumps_icntl_13"] = 1  # inertia is wrong with a ScaLAPACK root (MUMPS doc)
        settings.update({str(k): v for k, v in opt.petsc_options.items()})
        for k, v in settings.items():
            self.db[self.prefix + k] = v
        self.settings = settings
        self.eps = self.SLEPc.EPS()
        self.pardiso = _PardisoPC(opt.pardiso_ordering, groups) if factor == "pardiso" else None

    def set_up(self, start) -> None:
        """The Krylov-Schur EPS (GHEP, target = shift), its deflation space (the rigid fields Z) and
        optional start vector, and the shift-and-invert ST with its direct solver (PREONLY)."""
        PETSc, SLEPc, opt, eps, K, M = self.PETSc, self.SLEPc, self.opt, self.eps, self.K, self.M
        self.stage = "setting up the eigensolver"
        eps.create(self.pcomm)
        eps.setOptionsPrefix(self.prefix)
        eps.setOperators(K, M)
        eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
        eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
        eps.setDimensions(self.nreq, self.ncv, opt.mpd if opt.mpd else PETSc.DECIDE)
        eps.setTolerances(self.slepc_tol, int(opt.max_it))
        target = self.shift
        eps.setTarget(target)
        eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
        eps.setPurify(bool(opt.purify))
        for j in range(self.r):
            z = K.createVecRight()
            z.setArray(self.Zg[self.rows, j])
            mz = z.duplicate()
            M.mult(z, mz)
            self.Zv.append(z)
            self.MZv.append(mz)
        if self.Zv:
            eps.setDeflationSpace(self.Zv)
        self.v0 = None
        if start is not None and self.nproc == 1:
            self.v0 = K.createVecRight()
            self.v0.setArray(np.asarray(start, dtype=np.float64)[self.rows])
            eps.setInitialSpace([self.v0])
        self.st = st = eps.getST()
        st.setType(SLEPc.ST.Type.SINVERT)
        st.setShift(target)
        self.ksp = ksp = st.getKSP()
        ksp.setType(PETSc.KSP.Type.PREONLY)
        self.pc = pc = ksp.getPC()
        if self.pardiso is not None:
            pc.setType(PETSc.PC.Type.PYTHON)
            pc.setPythonContext(self.pardiso)
        else:
            pc.setType(PETSc.PC.Type.CHOLESKY)
            pc.setFactorSolverType(self.factor)
        eps.setFromOptions()

    def factorise(self) -> None:
        """``EPSSetUp``: the numeric factorisation of the solve operator A = K - shift M, which the
        inertia count later turns into K - sigma M in place (``struct``: M's pattern within A's)."""
        PETSc, timings, cpu = self.PETSc, self.timings, self.cpu
        self.stage = f"factorising K - shift M ({_FACTOR_NAMES[self.factor]})"
        t1, c1 = time.perf_counter(), time.process_time()
        self.eps.setUp()
        timings["factor"] = time.perf_counter() - t1
        cpu["factor"] = time.process_time() - c1
        self.factorisations = 1
        self.F = self.pc.getFactorMatrix() if self.pardiso is None else None
        self.A = self.ksp.getOperators()[1]
        timings["inertia_factor"] = 0.0
        same = _same_pattern(self.A, self.M, self.mpi_comm)
        self.struct = PETSc.Mat.Structure.SAME if same else PETSc.Mat.Structure.SUBSET
        timings["solve"] = timings["extract"] = timings["residuals"] = 0.0
        cpu["solve"] = cpu["inertia_factor"] = 0.0

    def iterate(self) -> None:
        """Krylov-Schur, continued from the current Ritz vectors with ``extra_step`` more pairs (same
        factorisation) while the eigenvalues above the nev-th form one cluster (``max_rounds``)."""
        PETSc, opt, eps, nev, r, n = self.PETSc, self.opt, self.eps, self.nev, self.r, self.n
        nX = len(self.X)
        self.stage = "the Krylov-Schur iteration"
        t1, c1 = time.perf_counter(), time.process_time()
        while True:
            eps.solve()
            nconv = eps.getConverged()
            self.its += eps.getIterationNumber()
            # one more than nev, for the certificate's gap
            if nconv + nX + r < nev + 1:
                raise SolverError(
                    f"SLEPc Krylov-Schur converged only {nconv + nX} of the {self.nreq + nX} eigenpairs "
                    f"requested (nev = {nev}) after {self.its} restarts (tol {self.slepc_tol:g}, ncv {self.ncv}); "
                    "try a larger ncv or max_it"
                )
            lam_new = [eps.getEigenvalue(i).real for i in range(nconv)]
            lam_all = np.sort(np.concatenate([np.zeros(r), self.prev_lam, lam_new]))
            done = _clear_gap_above(lam_all, nev)
            if done or self.rounds >= opt.max_rounds or self.nreq + nX + r >= n - 1:
                break
            # the eigenvalues above the nev-th form a cluster: continue with more, from the current
            # Ritz vectors (the factorisation is kept: same operators)
            start = [self.K.createVecRight() for _ in range(nconv)]
            for i, v in enumerate(start):
                eps.getEigenvector(i, v)
            self.nreq = int(min(self.nreq + max(int(opt.extra_step), 1), n - 1 - nX - r))
            self.ncv = int(min(max(2 * self.nreq, self.nreq + 8, self.ncv), n - nX - r))
            eps.setDimensions(self.nreq, self.ncv, opt.mpd if opt.mpd else PETSc.DECIDE)
            eps.setInitialSpace(start)
            self.rounds += 1
        self.nconv = nconv
        self.timings["solve"] += time.perf_counter() - t1
        self.cpu["solve"] += time.process_time() - c1

    def extract(self) -> None:
        """The converged eigenvectors, M-normalised, appended to ``X`` (and M x to ``MX``)."""
        self.stage = "extracting the eigenvectors"
        t1 = time.perf_counter()
        for i in range(self.nconv):
            x = self.K.createVecRight()
            self.eps.getEigenvector(i, x)
            mx = x.duplicate()
            self.M.mult(x, mx)
            s = x.dot(mx)  # M-normalise (SLEPc's normalisation depends on the version)
            if not s > 0:
                raise SolverError(f"SLEPc returned an eigenvector with x^T M x = {s:g} (M not positive definite?)")
            x.scale(1.0 / np.sqrt(s))
            mx.scale(1.0 / np.sqrt(s))
            self.X.append(x)
            self.MX.append(mx)
        self.timings["extract"] += time.perf_counter() - t1

    def residuals(self) -> None:
        """Rayleigh quotients, residuals and roundoff floors of the pairs in ``X`` (scipy on one
        process, PETSc products with K and |K| in parallel)."""
        self.stage = "computing residuals and M-orthonormality"
        t1 = time.perf_counter()
        if self.stats is None:
            if self.nproc == 1:
                self.stats = _SerialStats(self.K)
            else:
                self.Kabs = _abs_matrix(self.K, self.PETSc)
                self.stats = functools.partial(_pair_stats, self.K, self.Kabs, PETSc=self.PETSc)
        self.lam, self.res, self.floor = self.stats(self.X, self.MX, rigid=0 if self.r else None)
        self.timings["residuals"] += time.perf_counter() - t1

    def refine(self) -> None:
        """At most two refinement steps in all while a low pair is short of its roundoff floor."""
        r = self.r
        while (_short_of_floor(self.lam, self.res, self.floor, self.nev - r, self.tol)
               and self.factor_is_solve_operator and self.refinements < 2):
            # one of the lowest nev pairs stopped short of what double precision allows (SLEPc's
            # criterion is on the shift-inverted problem): one block inverse-iteration step with
            # the factorisation in hand, then Rayleigh-Ritz over all pairs (keeps M-orthonormality)
            self.stage = "refining the eigenpairs (one inverse-iteration + Rayleigh-Ritz step)"
            t1 = time.perf_counter()
            self.X, self.MX = _refine(self.st.getKSP(), self.K, self.M, self.X, self.MX, deflate=(self.Zv, self.MZv))
            self.lam, self.res, self.floor = self.stats(self.X, self.MX, rigid=0 if r else None)
            self.refinements += 1
            self.timings["refine"] = self.timings.get("refine", 0.0) + time.perf_counter() - t1

    def pair_numbers(self) -> None:
        """The pairs in ascending order with the deflated rigid fields first (their numbers prepended),
        and the M-orthonormality error max |X^T M X - I| over all of them."""
        t1 = time.perf_counter()
        lam, res, floor = self.lam, self.res, self.floor
        perm = np.argsort(lam, kind="stable")
        lam, res, floor = lam[perm], res[perm], floor[perm]
        self.X, self.MX = [self.X[i] for i in perm], [self.MX[i] for i in perm]
        if self.r:  # the rigid pairs are the deflated fields themselves, first
            lam_z, res_z, floor_z = self.stats(self.Zv, self.MZv, rigid=self.r)
            lam, res, floor = (np.concatenate([lam_z, lam]), np.concatenate([res_z, res]),
                               np.concatenate([floor_z, floor]))
        self.lam, self.res, self.floor = lam, res, floor
        XA, MXA = self.Zv + self.X, self.MZv + self.MX
        m = len(XA)
        G = np.empty((m, m))
        for j, mx in enumerate(MXA):
            for i in range(j + 1):
                G[i, j] = G[j, i] = XA[i].dot(mx)
        self.ortho = float(np.max(np.abs(G - np.eye(m))))
        self.timings["residuals"] += time.perf_counter() - t1

    def count_inertia(self) -> None:
        """The Sylvester count at sigma (``certify.choose_inertia_shift``): negative and zero pivots
        of an LDL^T of K - sigma M, by the solve's own factor where it can (PARDISO or MUMPS: one
        numeric refactorisation on the same analysis), by a fresh MUMPS for CHOLMOD."""
        from modalfem.eigen.certify import choose_inertia_shift

        self.stage = "choosing the inertia shift"
        self.sigma = choose_inertia_shift(self.lam, self.nev)
        t1, c1 = time.perf_counter(), time.process_time()
        self.factorisations += 1
        if self.factor == "cholmod":
            self.stage = "factorising K - sigma M for the inertia count (MUMPS LDL^T)"
            (neg, zero, _pos), self.cert_info = self._fresh_mumps_inertia()
        elif self.pardiso is not None:
            neg, zero = self._pardiso_inertia()
        else:
            neg, zero = self._mumps_reused_inertia()
        self.neg, self.zero = neg, zero
        self.timings["inertia_factor"] += time.perf_counter() - t1
        self.cpu["inertia_factor"] += time.process_time() - c1

    def _fresh_mumps_inertia(self):
        return _mumps_inertia(self.K, self.M, self.sigma, self.settings, self.prefix, self.PETSc, self.mpi_comm)

    def _pardiso_inertia(self):
        """Inertia from PARDISO refactorised at K - sigma M; MUMPS recounts if a pivot was perturbed."""
        self.stage = "factorising K - sigma M for the inertia count (PARDISO LDL^T, reused analysis)"
        self.A.axpy(self.shift - self.sigma, self.M, self.struct)
        self.A.stateIncrease()
        self.pc.setUp()
        self.factor_is_solve_operator = False
        pf = self.pardiso.factor
        neg, zero, _pos = pf.inertia
        self.cert_info = {**pf.info(), "inertia_factor": "pardiso-ldlt"}
        if pf.perturbed_pivots:
            # a perturbed pivot makes the count unproven: redo it with MUMPS (threshold pivoting)
            self.stage = "factorising K - sigma M for the inertia count (MUMPS LDL^T, PARDISO perturbed pivots)"
            (neg, zero, _pos), mumps_info = self._fresh_mumps_inertia()
            self.cert_info.update(mumps_info, inertia_factor="mumps-ldlt")
            self.factorisations += 1
        return neg, zero

    def _mumps_reused_inertia(self):
        """Inertia from the solve's MUMPS factor, refactorised at K - sigma M on the same analysis."""
        self.stage = "factorising K - sigma M for the inertia count (MUMPS LDL^T, reused analysis)"
        self.A.axpy(self.shift - self.sigma, self.M, self.struct)
        self.F.setMumpsIcntl(24, 1)  # null-pivot detection: PETSc needs it to report zero pivots
        # MatAXPY(SAME) on MPIAIJ does not bump the matrix state in PETSc 3.18, so PCSetUp would
        # skip the refactorisation (seen: inertia 0 on 2 ranks): bump it by hand. The nonzero
        # state is unchanged, so PCSetUp does a numeric factorisation only, on the same analysis.
        self.A.stateIncrease()
        self.pc.setUp()
        self.factor_is_solve_operator = False
        self.F = self.pc.getFactorMatrix()
        neg, zero, _pos = self.F.getInertia()
        self.cert_info = _mumps_info(self.F)
        return neg, zero

    def retry(self) -> bool:
        """True, with the next search set up, when the count shows eigenvalues below sigma that
        Krylov-Schur missed (and ``max_retries`` allows another search)."""
        opt, n, r, nX = self.opt, self.n, self.r, len(self.X)
        missing = int(self.neg) - int(np.sum(self.lam < self.sigma))
        if missing <= 0 or self.attempts >= opt.max_retries:
            return False
        # Krylov-Schur missed `missing` eigenvalues below sigma (a many-fold cluster, e.g. the rigid
        # modes of several pieces): restore K - shift M (numeric refactorisation) and solve again
        # with the pairs found so far as a deflation space.
        if self.factor in ("mumps", "pardiso"):
            self.stage = "refactorising K - shift M to search for missed eigenvalues"
            t1 = time.perf_counter()
            self.A.axpy(self.sigma - self.shift, self.M, self.struct)
            self.A.stateIncrease()
            self.pc.setUp()
            self.factorisations += 1
            self.factor_is_solve_operator = True
            self.F = self.pc.getFactorMatrix() if self.pardiso is None else None
            self.timings["factor"] += time.perf_counter() - t1
        self.attempts += 1
        self.prev_lam = self.lam[r:]
        self.nreq = int(min(missing + max(int(opt.extra), 1), n - 1 - nX - r))
        self.ncv = int(min(max(2 * self.nreq, self.nreq + 8), n - nX - r))
        self.eps.setDeflationSpace(self.Zv + self.X)
        self.eps.setDimensions(self.nreq, self.ncv, opt.mpd if opt.mpd else self.PETSc.DECIDE)
        return True

    def gather(self) -> None:
        """The vectors (rigid fields first) on every rank in canonical free order."""
        self.timings["certificate"] = self.timings["residuals"] + self.timings["inertia_factor"]
        self.stage = "gathering the eigenvectors"
        t1 = time.perf_counter()
        local = np.column_stack([x.getArray(readonly=True) for x in self.Zv + self.X])
        self.vectors = _gather(local, self.rows, self.n, self.mpi_comm)
        self.timings["gather"] = time.perf_counter() - t1

    def info(self) -> dict:
        """Provenance: solver settings, counters, factor statistics, versions."""
        PETSc, SLEPc, eps = self.PETSc, self.SLEPc, self.eps
        return {
            "solver": "slepc",
            "eps_type": "krylovschur",
            "st": "sinvert",
            "which": "target_magnitude",
            "deflated": self.r,
            "shift": float(self.shift),
            "nev": int(self.nev),
            "nev_requested": self.nreq,
            "nconv": len(self.X) + self.r,
            "retries": int(self.attempts),
            "factorisations": int(self.factorisations),
            "refinements": int(self.refinements),
            "residual_floor": [float(f) for f in self.floor],
            "iterations": int(self.its),
            "rounds": int(self.rounds) + 1,
            "ncv": int(eps.getDimensions()[1]),
            "mpd": int(eps.getDimensions()[2]),
            "tol": float(self.tol),
            "slepc_tol": self.slepc_tol,
            "factor": {"cholmod": "cholmod-llt", "pardiso": "pardiso-ldlt"}.get(self.factor, "mumps-ldlt"),
            "inertia_factor": "mumps-ldlt",
            **self.cert_info,
            "mumps_options": {k: v for k, v in self.settings.items()},
            "inertia_zero_pivots": int(self.zero),
            "nprocs": int(self.nproc),
            "cpu_seconds": self.cpu,
            "petsc_version": ".".join(map(str, PETSc.Sys.getVersion())),
            "slepc_version": ".".join(map(str, SLEPc.Sys.getVersion())),
        }

    def cleanup(self) -> None:
        """Remove the prefixed options; destroy |K|, the EPS, PARDISO's factor and converted matrices."""
        for k in self.settings:
            self.db.delValue(self.prefix + k)
        try:  # after a failed stage SLEPc's internal state may refuse a clean destroy
            if self.Kabs is not None:
                self.Kabs.destroy()
            self.eps.destroy()
            if self.pardiso is not None:
                self.pardiso.close()
            if not self.is_mat:
                self.K.destroy()
                self.M.destroy()
        except self.PETSc.Error:
            pass


def solve_slepc(
    K_ff,
    M_ff,
    *,
    nev: int,
    shift: float,
    rows=None,
    comm=None,
    tol: float = 1e-10,
    options: SlepcOptions | None = None,
    start: np.ndarray | None = None,
    groups: np.ndarray | None = None,
    deflate: np.ndarray | None = None,
) -> RawModes:
    """Lowest ``nev`` eigenpairs of K x = lambda M x with SLEPc, and the certificate numbers.

    Args:
        K_ff: stiffness on the free DOFs [N/m], symmetric: scipy.sparse (serial, or split by
            contiguous rows over ``comm``) or a petsc4py Mat (possibly distributed).
        M_ff: mass on the free DOFs [kg], symmetric positive definite, same type and layout.
        nev: number of wanted eigenpairs (rigid included), 1 <= nev < n.
        shift: negative shift [rad^2/s^2] below the spectrum, so K - shift M is positive definite.
        rows: for PETSc Mats, the canonical free-DOF index of each locally owned row (n_local,);
            default: the natural order (the ownership range).
        comm: petsc4py or mpi4py communicator for scipy inputs (default: serial ``COMM_SELF``);
            ignored for PETSc Mats, which carry their own.
        tol: wanted bound on the relative residuals; SLEPc runs at ``tol * options.tol_factor``.
        options: ``SlepcOptions`` tuning knobs (defaults are the measured fastest robust choice).
        start: optional Krylov start vector (n,) in the canonical free order (serial only), e.g.
            approximate eigenvectors from a coarser space; default SLEPc's random vector.
        groups: optional node of each free DOF (n,), for PARDISO's ordering (see ``PardisoLDLT``).
        deflate: optional M-orthonormal basis (n, r) of the rigid (zero-energy) fields in canonical free
            order, r < nev: SLEPc's deflation space, so Krylov-Schur computes the nev - r elastic pairs
            in its M-orthogonal complement; the returned pairs are Z (first) then the elastic ones.

    Returns:
        ``RawModes`` with nev + extra (or every converged, if SLEPc returns more) eigenpairs in
        ascending order, M-normalised vectors (n, m) in canonical free order on every rank, the
        residuals, orthonormality error, inertia shift/count, timings (``convert``, ``factor``,
        ``solve``, ``gather``, ``certificate``, ``inertia_factor``) and info.

    Raises:
        InputError: bad shapes, types, nev, shift or rows.
        BackendUnavailableError: petsc4py/slepc4py missing.
        SolverError: a PETSc/SLEPc/MUMPS stage failed (named), or too few pairs converged.
    """
    PETSc, SLEPc = _import_petsc()
    run = _SlepcRun(PETSc, SLEPc, options or SlepcOptions(), nev, shift, tol)
    run.convert(K_ff, M_ff, rows, comm, deflate)
    run.choose_factor(groups)
    try:
        run.set_up(start)
        run.factorise()
        while True:
            run.iterate()
            run.extract()
            run.residuals()
            run.refine()
            run.pair_numbers()
            run.count_inertia()
            if not run.retry():
                break
        run.gather()
        info = run.info()
    except PETSc.Error as exc:
        raise SolverError(f"SLEPc solver failed while {run.stage}: {_petsc_reason(exc)}") from exc
    finally:
        run.cleanup()
    return RawModes(
        eigenvalues=run.lam,
        vectors=run.vectors,
        residuals=run.res,
        orthonormality_error=run.ortho,
        inertia_shift=float(run.sigma),
        inertia_count=int(run.neg),
        timings=run.timings,
        info=info,
    )


def _clear_gap_above(lam: np.ndarray, nev: int) -> bool:
    """True if some eigenvalue above the nev-th is clearly separated from its predecessor."""
    from modalfem.eigen.certify import CLEAR_GAP

    tail = np.asarray(lam[nev - 1 :], dtype=float)
    if len(tail) < 2:
        return False
    gaps = np.diff(tail) / np.maximum(np.abs(tail[1:]), np.finfo(float).tiny)
    return bool(np.any(gaps >= CLEAR_GAP))


def _petsc_reason(exc) -> str:
    """One line from a PETSc.Error: its code and the last message line (no traceback)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    msg = [ln for ln in lines[1:] if not ln.endswith(")") or " at " not in ln]
    tail = msg[-1].lstrip("[0123456789] ") if msg else ""
    code = getattr(exc, "ierr", None)
    return f"PETSc error {code}" + (f": {tail}" if tail else "")


def _same_pattern(A, B, mpi_comm) -> bool:
    """True if B has as many local nonzeros as A on every rank (B's pattern is a subset of A's)."""
    try:
        same = int(A.getInfo()["nz_used"]) == int(B.getInfo()["nz_used"])
    except (AttributeError, KeyError, TypeError):  # pragma: no cover - exotic matrix types
        same = False
    if mpi_comm is not None and mpi_comm.Get_size() > 1:
        same = bool(mpi_comm.allreduce(same, op=_mpi_land()))
    return same


def _mpi_land():
    from mpi4py import MPI

    return MPI.LAND
