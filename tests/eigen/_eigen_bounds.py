"""Eigenvalue error bounds derived from the computation, for tests that compare eigenvalues.

Two results are compared by the sum of their own error bounds, never by a fixed relative tolerance: the
rounding of a dense LAPACK solve and of MKL's or OpenBLAS's kernels depends on the code path the CPU
selects (AVX-512 on this Intel Xeon, AVX2 or SSE on AMD CPUs), and a tolerance read off one machine's
numbers fails on another (``MKL_ENABLE_INSTRUCTIONS=AVX2 OPENBLAS_CORETYPE=Zen`` did here: 3.2e-9 relative
against a fixed 1e-9 on a square beam's first bending pair).

* :func:`residual_bounds`: Kahan's theorem for the pencil (K, M) (Parlett, *The Symmetric Eigenvalue
  Problem*, Thm 11.5.1 in the M-inner product): for M-orthonormal X and diagonal Lambda there are k
  eigenvalues, one per column and in order, within ``||K X - M X Lambda||_{M^-1}`` (2-norm of the block,
  bounded here by its Frobenius norm). Added: the rounding of forming the residual in double precision
  (``eps sqrt(nnz per row) ||(|K| |X| + |M| |X| |Lambda|)||_{M^-1}``, the probabilistic model of
  Higham and Mary 2019) and the departure from M-orthonormality (``||X^T M X - I||_2 |lambda_i|``).
* :func:`dense_bounds`: LAPACK's error bound for ``xSYGV`` (LAPACK Users' Guide, "Error Bounds for the
  Generalized Symmetric Definite Eigenproblem": ``eps (||A|| ||B^-1|| + kappa(B) |lambda_i|)`` with
  p(n) = 1 there), on the diagonally scaled pencil the guide recommends (D = diag(M)^-1/2), with
  p(n) = sqrt(n) (probabilistic rounding).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

EPS = float(np.finfo(float).eps)


def _minv_norms(M, R: np.ndarray) -> np.ndarray:
    """sqrt(r^T M^-1 r) per column of R (M sparse or dense SPD)."""
    if sp.issparse(M):
        Y = spla.splu(sp.csc_matrix(M)).solve(np.ascontiguousarray(R))
    else:
        Y = sla.cho_solve(sla.cho_factor(M), R)
    return np.sqrt(np.maximum(np.sum(R * Y, axis=0), 0.0))


def residual_bounds(K, M, X: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Bound (k,) [same unit as lam] on |lam_i - lambda_i|, lambda_i the matched true eigenvalues.

    Args:
        K, M: the pencil (sparse or dense, M SPD).
        X: (n, k) approximate eigenvectors, M-orthonormal up to rounding.
        lam: (k,) their approximate eigenvalues.
    """
    X = np.asarray(X, dtype=float)
    lam = np.asarray(lam, dtype=float)
    R = np.asarray(K @ X) - np.asarray(M @ X) * lam
    absK, absM = abs(K), abs(M)
    F = np.asarray(absK @ np.abs(X)) + np.asarray(absM @ np.abs(X)) * np.abs(lam)
    nnz_row = int(np.max(np.diff(sp.csr_matrix(K).indptr))) if sp.issparse(K) else K.shape[1]
    rounding = EPS * np.sqrt(nnz_row) * _minv_norms(M, F)
    kahan = float(np.sqrt(np.sum(_minv_norms(M, R) ** 2)) + np.sqrt(np.sum(rounding**2)))
    G = X.T @ np.asarray(M @ X)
    orth = float(np.linalg.norm(G - np.eye(len(lam)), 2))
    return kahan * (1.0 + orth) + orth * np.abs(lam)


def dense_bounds(K, M, w: np.ndarray) -> np.ndarray:
    """LAPACK's bound (see module doc) on the error of dense generalized eigenvalues ``w`` of (K, M)."""
    Kd = K.toarray() if sp.issparse(K) else np.asarray(K)
    Md = M.toarray() if sp.issparse(M) else np.asarray(M)
    d = 1.0 / np.sqrt(np.diag(Md))
    Ks, Ms = Kd * d[:, None] * d[None, :], Md * d[:, None] * d[None, :]
    ks = np.abs(np.linalg.eigvalsh(Ks))
    ms = np.linalg.eigvalsh(Ms)
    n = Kd.shape[0]
    return np.sqrt(n) * EPS * (ks.max() / ms[0] + ms[-1] / ms[0] * np.abs(np.asarray(w, dtype=float)))
