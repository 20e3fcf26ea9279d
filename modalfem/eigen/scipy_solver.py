"""SciPy eigen solver: ARPACK (or block Krylov-Schur) shift-invert on a PARDISO or SuperLU factor, plus a
Sylvester inertia count.

Where MKL PARDISO loads (``modalfem.eigen.pardiso``, the ``mkl`` wheel on x86-64) it factorises
K - shift M (LDL^T, METIS ordering) for the solves and, numerically only on the same analysis,
K - sigma M for the inertia count: at 138,720 DOFs that is ~2 s per factorisation and 0.07 s per
solve, where SuperLU needs minutes. A count from a factorisation with perturbed pivots is not
trusted: the SuperLU path below then decides.

Measured here (ENVIRONMENT.md): SuperLU with ``permc_spec='MMD_AT_PLUS_A'`` (minimum degree on
A^T + A, a fill-reducing ordering suited to symmetric FE matrices) was 4x+ faster than the default
COLAMD, so K - shift M is factorised once with it (diagonal pivoting in SymmetricMode: another 5x
and half the fill at 19,683 DOFs) and handed to ``eigsh`` as ``OPinv``.

Inertia (how many eigenvalues lie below sigma) uses the same SuperLU as an LDL^T: with
``SymmetricMode=True``, ``diag_pivot_thresh=0`` and a symmetric ordering, SuperLU pivots on the
diagonal only, so P A P^T = L U with U = D L^T and the signs of diag(U) are the inertia of A
(Sylvester's law). That is only proven when no off-diagonal pivot happened (``perm_r == perm_c``) and
the factor is accurate (a solve's backward error is checked); otherwise a dense Bunch-Kaufman LDL^T
(``scipy.linalg.ldl``) is used for small problems, or sigma is moved slightly. If nothing works a
SolverError is raised: an unproven count is never reported.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from modalfem.eigen.base import RawModes
from modalfem.eigen.rigid import Deflation
from modalfem.eigen.spmm import spmm
from modalfem.errors import SolverError

__all__ = ["ZERO_RTOL", "extra_count", "inertia_count", "residual_floor", "residuals", "solve_scipy"]

#: eigenvalues with |lambda| <= ZERO_RTOL * |shift| are "zero" (rigid): residuals divide by ||K|| ||x||.
ZERO_RTOL = 1e-3
#: backward error a factorisation used for an inertia count must reach on a test solve.
_FACTOR_BACKWARD_TOL = 1e-10
#: largest size for the dense Bunch-Kaufman fallback (6000^2 doubles = 288 MB).
_DENSE_LDL_MAX = 6000


def extra_count(nev: int) -> int:
    """Eigenpairs computed beyond nev so the certificate sees the next eigenvalue(s)."""
    return max(4, nev // 5)


def residuals(K, M, X: np.ndarray, lam: np.ndarray, *, shift: float, KX=None, MX=None, absK=None,
              rigid: int | None = None) -> np.ndarray:
    """Relative residuals ||K x - lam M x|| / ||K x|| (m,); for rigid pairs, / (||K||_inf ||x||).

    ``rigid``: the number of leading columns that are zero-energy fields by construction (known from
    the mesh's structure, see ``modalfem.eigen.rigid``); None (direct calls on a bare pencil) treats
    |lam| <= ZERO_RTOL |shift| as rigid. ``KX``, ``MX`` (products already computed) and ``absK`` (|K|)
    are optional."""
    KX = spmm(K, X) if KX is None else KX
    R = KX - (spmm(M, X) if MX is None else MX) * lam
    rn = np.linalg.norm(R, axis=0)
    kx = np.linalg.norm(KX, axis=0)
    knorm = float(np.max(spmm(_abs(K) if absK is None else absK, np.ones(K.shape[1])))) if K.shape[0] else 0.0
    zero = np.abs(lam) <= ZERO_RTOL * abs(shift) if rigid is None else np.arange(len(lam)) < rigid
    den = np.where(zero, knorm * np.linalg.norm(X, axis=0), kx)
    return rn / np.maximum(den, np.finfo(float).tiny)


def _abs(K) -> sp.csr_matrix:
    K = sp.csr_matrix(K)
    return sp.csr_matrix((np.abs(K.data), K.indices, K.indptr), shape=K.shape)


def residual_floor(K, X: np.ndarray, *, KX=None, absK=None) -> np.ndarray:
    """sqrt(r) eps || |K| |x| || / ||K x|| per column (m,): the roundoff floor of the relative residual
    (r = the most nonzeros in a row of K; Higham and Mary 2019), what double precision can certify.
    ``KX`` (= K X) and ``absK`` (|K|) are optional, to reuse."""
    K = sp.csr_matrix(K)
    eps = np.finfo(float).eps * np.sqrt(int(np.max(np.diff(K.indptr))) if K.shape[0] else 0)
    num = spmm(_abs(K) if absK is None else absK, np.abs(X))
    den = spmm(K, X) if KX is None else KX
    return eps * np.linalg.norm(num, axis=0) / np.maximum(np.linalg.norm(den, axis=0), np.finfo(float).tiny)


def _pair_numbers(K, M, X, lam, shift, absK, rigid=None):
    """(residuals, roundoff floors, M X) of M-normalised pairs, with one product by K and one by M."""
    KX, MX = spmm(K, X), spmm(M, X)
    res = residuals(K, M, X, lam, shift=shift, KX=KX, MX=MX, absK=absK, rigid=rigid)
    return res, residual_floor(K, X, KX=KX, absK=absK), MX


def _elastic_floor(lam: np.ndarray, floor: np.ndarray, nev: int, shift: float, deflated: bool) -> float:
    """Largest roundoff floor among the lowest ``nev`` pairs that are not rigid (0 if all are); with a
    deflated rigid subspace every computed pair is elastic."""
    elastic = np.ones(nev, dtype=bool) if deflated else np.abs(lam[:nev]) > ZERO_RTOL * abs(shift)
    return float(np.max(floor[:nev][elastic])) if elastic.any() else 0.0


def _splu(A, what: str, **kw):
    from scipy.sparse.linalg import splu

    try:
        return splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", **kw)
    except (RuntimeError, MemoryError, ValueError) as exc:
        raise SolverError(f"SuperLU could not factorise {what}: {exc}") from None


def _backward_error(A, solve) -> float:
    rng = np.random.default_rng(0)
    b = rng.standard_normal(A.shape[0])
    x = solve(b)
    if getattr(A, "format", None) == "csr":  # ||A||_inf without a copy of A (reduceat over the non-empty rows)
        starts = A.indptr[:-1][np.diff(A.indptr) > 0]
        anorm = float(np.max(np.add.reduceat(np.abs(A.data), starts))) if len(starts) else 0.0
    else:
        anorm = float(abs(A).sum(axis=1).max())
    return float(np.linalg.norm(spmm(A, x) - b, np.inf) / (anorm * np.linalg.norm(x, np.inf) + np.linalg.norm(b, np.inf)))


def _inertia_superlu(A) -> int | None:
    """Negative pivots of a diagonal-pivoting SuperLU LDL^T of symmetric A, or None if unproven."""
    try:
        lu = _splu(A, "K - sigma M", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except SolverError:
        return None
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return None
    d = lu.U.diagonal()
    if not np.all(np.isfinite(d)) or np.any(d == 0) or _backward_error(A, lu.solve) > _FACTOR_BACKWARD_TOL:
        return None
    return int(np.sum(d < 0))


def _inertia_dense(A) -> int:
    """Negative eigenvalues of the block-diagonal D of a Bunch-Kaufman LDL^T (scipy.linalg.ldl)."""
    from scipy.linalg import ldl

    _, D, _ = ldl(A.toarray(), lower=True)
    n, i, neg = D.shape[0], 0, 0
    while i < n:
        if i + 1 < n and D[i + 1, i] != 0.0:
            neg += int(np.sum(np.linalg.eigvalsh(D[i : i + 2, i : i + 2]) < 0))
            i += 2
        else:
            neg += int(D[i, i] < 0)
            i += 1
    return neg


def inertia_count(K, M, sigma: float, *, lower: float | None = None, upper: float | None = None):
    """Number of eigenvalues of K x = lam M x below sigma (Sylvester count of K - sigma M).

    Args:
        K, M: symmetric sparse matrices on the free DOFs [N/m], [kg].
        sigma: the shift [rad^2/s^2].
        lower, upper: the eigenvalue gap (lower < sigma < upper) containing sigma; if the first
            factorisation is not a proven LDL^T, sigma is moved within it (to 1/4 and 3/4 of the gap).

    Returns:
        (count, sigma_used, method) with method ``"superlu-ldlt"`` or ``"dense-bunch-kaufman"``.

    Raises:
        SolverError: no proven LDL^T could be made.
    """
    n = K.shape[0]
    tried = [sigma]
    if lower is not None and upper is not None:
        tried += [lower + 0.25 * (upper - lower), lower + 0.75 * (upper - lower)]
    for s in tried:
        A = (K - s * M).tocsc()
        c = _inertia_superlu(A)
        if c is not None:
            return c, float(s), "superlu-ldlt"
        if n <= _DENSE_LDL_MAX:
            return _inertia_dense(A), float(s), "dense-bunch-kaufman"
    raise SolverError(
        f"could not certify the eigenvalue count: SuperLU pivoted off the diagonal of K - sigma M at "
        f"sigma = {sigma:.6g} rad^2/s^2 and nearby shifts (n = {n} free DOFs, too large for dense LDL^T)"
    )


def _dense_solve(K, M, m: int, defl=None):
    """Lowest m pairs by dense eigh, in the M-orthogonal complement of the deflated fields if any."""
    from scipy.linalg import eigh

    Q = None if defl is None or not defl.count else defl.complement()
    Kd, Md = K.toarray(), M.toarray()
    if Q is not None:
        Kd, Md = Q.T @ Kd @ Q, Q.T @ Md @ Q
    try:
        lam, X = eigh(0.5 * (Kd + Kd.T), 0.5 * (Md + Md.T), subset_by_index=[0, m - 1])
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise SolverError(f"dense eigh failed: {exc}") from None
    return lam, (X if Q is None else Q @ X)


def _rayleigh_ritz(K, M, Y: np.ndarray):
    """Rayleigh-Ritz on span(Y): ascending Ritz values and M-orthonormal Ritz vectors."""
    from scipy.linalg import eigh

    MY = spmm(M, Y)  # the one product by M (scaling Y's columns scales M Y's alike)
    mn = np.einsum("ij,ij->j", Y, MY)
    if not np.all(mn > 0):
        raise SolverError("the mass matrix is not positive definite on the computed eigenvectors")
    scale = np.sqrt(mn)  # equal column scales keep Mr well conditioned
    Y = Y / scale
    Kr = Y.T @ spmm(K, Y)
    Mr = Y.T @ (MY / scale)
    try:
        # M-orthonormalise first (the block may be nearly dependent), then a standard eigenproblem
        sm, U = np.linalg.eigh(0.5 * (Mr + Mr.T))
        keep = sm > 1e-13 * sm.max()
        T = U[:, keep] / np.sqrt(sm[keep])
        lam, Q = eigh(T.T @ (0.5 * (Kr + Kr.T)) @ T)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise SolverError(f"Rayleigh-Ritz on the computed eigenvectors failed: {exc}") from None
    C = T @ Q
    X = Y @ C
    X /= np.sqrt(np.einsum("ij,ij->j", C, Mr @ C))  # x^T M x = c^T (Y^T M Y) c: no product by M
    return lam, X


def _pardiso_inertia(factor, K, M, sigma: float, groups=None) -> int | None:
    """Negative pivots of PARDISO's LDL^T of K - sigma M (numeric refactorisation of ``factor`` when the
    pattern is the one it analysed), or None when the count is not proven (perturbed or zero pivots).

    The count uses diagonal pivots (15-30 % faster, see ``PardisoLDLT``); their factor of this indefinite
    matrix is trusted only when a solve's backward error is at most ``_FACTOR_BACKWARD_TOL``, otherwise it
    is redone with Bunch-Kaufman pivots. ``factor`` is left with its pivoting set to the one used."""
    from modalfem.eigen.pardiso import PardisoLDLT

    A = (K - sigma * M).tocsr()
    A.sort_indices()
    if factor.same_pattern(A):
        factor.pivoting = "diagonal"
        factor.refactor(A.data)
        f = factor
    else:
        f = PardisoLDLT(A, groups=groups, pivoting="diagonal").refactor()
    try:
        if f.pivoting_used == "diagonal" and _backward_error(A, f.solve) > _FACTOR_BACKWARD_TOL:
            f.pivoting = "bunch-kaufman"
            f.refactor()
        neg, zero, _ = f.inertia
        return None if f.perturbed_pivots or zero else neg
    finally:
        if f is not factor:
            f.close()


def _use_pardiso(factor: str) -> bool:
    from modalfem.eigen.pardiso import have_pardiso

    if factor not in ("auto", "pardiso", "superlu"):
        raise SolverError(f"factor must be 'auto', 'pardiso' or 'superlu', got {factor!r}")
    if factor == "pardiso" and not have_pardiso():
        raise SolverError("factor='pardiso' needs MKL PARDISO (pip install mkl)")
    return factor == "pardiso" or (factor == "auto" and have_pardiso())


def solve_scipy(K_ff, M_ff, *, nev: int, shift: float, tol: float = 1e-10, ncv: int | None = None,
                factor: str = "auto", start: np.ndarray | None = None, groups: np.ndarray | None = None,
                method: str = "arpack", deflate: np.ndarray | None = None) -> RawModes:
    """Lowest ``nev`` (+ a few) eigenpairs of K x = lam M x by shift-invert at a negative shift.

    Args:
        K_ff: stiffness on the free DOFs [N/m], symmetric sparse (n, n).
        M_ff: mass on the free DOFs [kg], symmetric positive definite sparse (n, n).
        nev: number of wanted eigenpairs (rigid included), >= 1.
        shift: sigma [rad^2/s^2] < 0 (K - shift M is then positive definite even for a free body).
        tol: target relative residual; ARPACK is run to machine precision (tol=0) when tol < 1e-8.
        ncv: Lanczos basis size (default max(2 m + 1, 20) for m computed pairs).
        factor: ``"pardiso"`` (MKL), ``"superlu"``, or ``"auto"`` (PARDISO where it loads).
        start: optional start vector (n,), e.g. approximate eigenvectors from a coarser space.
        groups: optional node of each free DOF (n,), for PARDISO's ordering (see ``PardisoLDLT``).
        method: ``"arpack"`` (``eigsh``, one solve per Lanczos vector) or ``"block"`` (block
            Krylov-Schur, ``modalfem.eigen.block``: 4 right-hand sides per solve, ~2x faster on a
            PARDISO factor).
        deflate: optional M-orthonormal basis (n, r) of the rigid (zero-energy) fields, r < nev. The
            iteration runs in their M-orthogonal complement for the nev - r elastic pairs; the
            returned pairs are Z (first, eigenvalues = Rayleigh quotients ~ 0) then the elastic ones.

    Returns:
        RawModes with m = nev + ``extra_count(nev)`` eigenpairs (fewer if n is tiny: then a dense
        solve is used), M-orthonormal vectors, residuals and the inertia count.

    Raises:
        SolverError: the factorisation or the iteration failed, or the inertia count could not be proven.
    """
    from scipy.sparse.linalg import (
        ArpackError,
        ArpackNoConvergence,
        LinearOperator,
        eigsh,
    )

    from modalfem.eigen.certify import choose_inertia_shift

    if method not in ("block", "arpack"):
        raise SolverError(f"method must be 'block' or 'arpack', got {method!r}")
    K = sp.csr_matrix(K_ff)
    M = sp.csr_matrix(M_ff)
    n = K.shape[0]
    if shift >= 0:
        raise SolverError(f"solve_scipy needs a negative shift, got {shift:g} rad^2/s^2")
    if not 1 <= nev <= n:
        raise SolverError(f"nev={nev} must lie in [1, {n}] for {n} free DOFs")
    defl = Deflation(deflate, M)
    r = defl.count
    if r >= nev:
        raise SolverError(f"nev={nev} must exceed the {r} deflated rigid modes")
    m = min(nev - r + extra_count(nev), n - r)  # elastic pairs computed
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    info = {"solver": "scipy", "shift": float(shift), "nev": int(nev), "computed": int(m + r), "deflated": r}
    pardiso = None
    if n - r <= max(200, 3 * m):  # ARPACK needs ncv < n; tiny problems are solved densely
        lam, X = _dense_solve(K, M, m, defl)
        lu = None
        info["method"] = "dense eigh"
        timings["factor"] = 0.0
        timings["solve"] = time.perf_counter() - t0
    elif _use_pardiso(factor):
        from modalfem.eigen.pardiso import PardisoLDLT

        A = (K - shift * M).tocsr()
        A.sort_indices()
        # Bunch-Kaufman pivots for the solves even where K - shift M is positive definite: diagonal pivots
        # were 15-30 % faster but left the lowest pair of a slender beam at 0.1 x its roundoff floor instead
        # of 0.04 x (20 x 4 x 4 P2 cantilever); the inertia count alone uses them (see _pardiso_inertia)
        pardiso = lu = PardisoLDLT(A, groups=groups).refactor()
        timings["factor"] = time.perf_counter() - t0
        info.update(factor="pardiso-ldlt", **pardiso.info())
    else:
        # K - shift M is SPD: diagonal pivots (a Cholesky-like LDL^T) are stable and keep the MMD
        # ordering's sparsity; measured 5x faster with half the fill of the pivoting default (19,683 DOFs).
        A = (K - shift * M).tocsc()
        what = f"K - shift M at shift {shift:g} rad^2/s^2 (is M positive definite?)"
        lu = _splu(A, what, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        if _backward_error(A, lu.solve) > _FACTOR_BACKWARD_TOL:
            lu = _splu(A, what)
        timings["factor"] = time.perf_counter() - t0
        info.update(factor="superlu", ordering="MMD_AT_PLUS_A", factor_nnz=int(lu.nnz))
    v0 = None if start is None else defl.project(np.asarray(start, dtype=np.float64).reshape(n, -1))
    if lu is not None and method == "block":
        # one multi-RHS PARDISO solve per block of vectors (see modalfem.eigen.block)
        from modalfem.eigen.block import block_krylov_schur

        t1 = time.perf_counter()
        theta, X, binfo = block_krylov_schur(lu.solve, M, m, tol=max(tol * 1e-2, 1e-14), start=v0,
                                             strict=nev - r, deflate=(defl.Z, defl.MZ) if r else None)
        timings["solve"] = time.perf_counter() - t1
        order = np.argsort(shift + 1.0 / theta)
        lam, X = (shift + 1.0 / theta)[order], X[:, order]
        info.update(method="block krylov-schur shift-invert", **{f"block_{k}": v for k, v in binfo.items()
                                                                 if k != "residual_estimates"})
    elif lu is not None:
        def opinv(b):
            return defl.project(np.asarray(lu.solve(b)).reshape(n, -1)).reshape(np.shape(b))

        op = LinearOperator((n, n), matvec=opinv, matmat=opinv, dtype=np.float64)
        ncv = ncv or min(n - r - 1, max(2 * m + 1, 20))
        t1 = time.perf_counter()
        rng = np.random.default_rng(12345)
        try:
            mu, X = eigsh(
                K, k=m, M=M, sigma=shift, which="LM", OPinv=op, ncv=ncv,
                tol=0.0 if tol < 1e-8 else tol * 1e-2, maxiter=max(1000, 50 * m),
                v0=(defl.project(rng.standard_normal((n, 1))) if v0 is None else v0[:, :1]).ravel(),
            )
        except ArpackNoConvergence as exc:
            raise SolverError(
                f"ARPACK did not converge: {len(exc.eigenvalues)} of {m} eigenpairs after its iteration limit"
            ) from None
        except (ArpackError, RuntimeError, ValueError) as exc:
            raise SolverError(f"ARPACK shift-invert solve failed: {exc}") from None
        timings["solve"] = time.perf_counter() - t1
        order = np.argsort(mu)
        lam, X = mu[order], X[:, order]
        info.update(method="arpack shift-invert", ncv=int(ncv))
    t2 = time.perf_counter()
    lam, X = _rayleigh_ritz(K, M, defl.project(X))
    absK = _abs(K)
    res, floor, MX = _pair_numbers(K, M, X, lam, shift, absK, rigid=0 if r else None)
    refinements = 0
    # the iteration's Ritz vectors carry errors ~ eps * lam / |shift|; one subspace-iteration step with
    # the same factor plus Rayleigh-Ritz (m solves) removes them (measured: 3e-9 -> 8e-12 at shift -1e4).
    # Refine while a wanted pair is above 0.1 tol and above the largest roundoff floor of the wanted
    # elastic pairs: the certificate's bound is FLOOR_FACTOR x that floor (certify.build_certificate)
    want = nev - r
    while lu is not None and refinements < 2 and np.max(res[:want]) > max(
            0.1 * tol, _elastic_floor(lam, floor, want, shift, deflated=bool(r))):
        lam, X = _rayleigh_ritz(K, M, defl.project(np.asarray(lu.solve(np.asarray(MX)))))
        res, floor, MX = _pair_numbers(K, M, X, lam, shift, absK, rigid=0 if r else None)
        refinements += 1
    info["refinements"] = refinements
    if r:  # the rigid pairs are the deflated fields themselves: first, with their Rayleigh quotients
        Z, MZ = defl.Z, defl.MZ
        KZ = spmm(K, Z)
        lam_z = np.einsum("ij,ij->j", Z, KZ)
        res_z = residuals(K, M, Z, lam_z, shift=shift, KX=KZ, MX=MZ, absK=absK, rigid=r)
        floor_z = residual_floor(K, Z, KX=KZ, absK=absK)
        lam, X = np.concatenate([lam_z, lam]), np.hstack([Z, X])
        res, floor, MX = np.concatenate([res_z, res]), np.concatenate([floor_z, floor]), np.hstack([MZ, MX])
    info["residual_floor"] = [float(f) for f in floor]
    G = X.T @ MX
    orth = float(np.max(np.abs(G - np.eye(len(lam)))))
    timings["residuals"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    count = None
    sigma = choose_inertia_shift(lam, nev, floor=ZERO_RTOL * abs(shift) if not r else 0.0, complete=len(lam) == n)
    j = min(int(np.searchsorted(lam, sigma)), len(lam) - 1)
    if pardiso is not None:
        try:
            count, inertia_method = _pardiso_inertia(pardiso, K, M, sigma, groups), "pardiso-ldlt"
        finally:
            pardiso.close()
    if count is None:
        count, sigma, inertia_method = inertia_count(K, M, sigma, lower=float(lam[j - 1]), upper=float(lam[j]))
    timings["inertia"] = time.perf_counter() - t3
    timings["certificate"] = timings["residuals"] + timings["inertia"]
    info["inertia_method"] = inertia_method
    return RawModes(
        eigenvalues=lam, vectors=X, residuals=res, orthonormality_error=orth,
        inertia_shift=float(sigma), inertia_count=int(count), timings=timings, info=info,
    )
