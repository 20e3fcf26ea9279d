"""Compiled kernels of the tet solver (numba, compiled on first call, cached on disk), parallel over
chunks of elements or rows (:mod:`modalfem.threads`) whose bounds depend on the problem size only:
every value is computed by one thread in a fixed order, so results are bit-identical on any thread count.

* ``hessians_upper``: projected element Hessians (upper triangles) and element forces from the analytic
  eigensystem of an isotropic density (the formulas of :func:`modalfem.tet.energies.element_hessians`).
* ``csr_matvec``: ``y = A x`` for a CSR matrix, rows in parallel.
* ``gather_sum``: ``out[p] = sum(values[order[ptr[p]:ptr[p + 1]]])``, the assembly's scatter written as
  a gather (no write conflicts), and ``symmetrise`` its completion from upper triangles.
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem.threads import apply as _apply_threads
from modalfem.threads import chunk_bounds, chunk_count

__all__ = ["csr_matvec", "gather_sum", "hessians_upper", "symmetrise"]

_apply_threads()

#: elements per chunk of ``hessians_upper``; rows per chunk of ``csr_matvec`` / ``gather_sum``
ELEMENT_CHUNK = 128
ROW_CHUNK = 512
#: (i, j) of the three pair modes, as in ``modalfem.tet.energies.PAIRS``
_PI = (1, 0, 0)
_PJ = (2, 2, 1)


@numba.njit(cache=True, parallel=True)
def hessians_upper(Ut, Vt, D2, lam, gt, vol, d1, H, f, forces: bool) -> None:
    """Projected element Hessians and forces (see module docstring), element index last.

    Args:
        Ut, Vt: U and V of the rotation-variant SVD (3, 3, m).
        D2: projected d^2 psi / d sigma^2 (m, 3, 3) [Pa].
        lam: clamped twist and flip eigenvalues (m, 6) [Pa].
        gt: shape-function gradients (4, 3, m) [1/m].
        vol: rest volumes (m,) [m^3].
        d1: d psi / d sigma (m, 3) [Pa] (read only with ``forces``).
        H: out, (78, m) upper triangles [N/m] in the order of ``np.triu_indices(12)``.
        f: out with ``forces``, (4, 3, m) [N]: ``V0 U diag(d1) V^T grad_a``.
        forces: compute ``f``.
    """
    m = Ut.shape[2]
    chunks = chunk_count(m, ELEMENT_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        b = np.empty((9, 9))
        c = np.empty((9, 9))
        K = np.empty((9, 9))
        Gv = np.empty((3, 3))
        R = np.empty((3, 9))
        for e in range(start, stop):
            _element(e, Ut, Vt, D2, lam, gt, vol, d1, H, f, forces, b, c, K, Gv, R)


@numba.njit(cache=True)
def _element(e, Ut, Vt, D2, lam, gt, vol, d1, H, f, forces, b, c, K, Gv, R) -> None:
    V0 = vol[e]
    for a in range(3):  # grad_a . v_q for vertices 1..3
        for q in range(3):
            Gv[a, q] = gt[a + 1, 0, e] * Vt[0, q, e] + gt[a + 1, 1, e] * Vt[1, q, e] + gt[a + 1, 2, e] * Vt[2, q, e]
    # the 9 modes as 9-vectors over (vertex a = 1..3, component i): U e_p e_q^T V^T mapped by the gradients
    for a in range(3):
        for i in range(3):
            r = 3 * a + i
            for p in range(3):
                b[p, r] = Gv[a, p] * Ut[i, p, e]
            for k in range(3):
                pi, pj = _PI[k], _PJ[k]
                t0 = Gv[a, pj] * Ut[i, pi, e]
                t1 = Gv[a, pi] * Ut[i, pj, e]
                b[3 + k, r] = t0 - t1
                b[6 + k, r] = t0 + t1
    if forces:
        for a in range(3):
            for i in range(3):
                r = 3 * a + i
                f[a + 1, i, e] = V0 * (d1[e, 0] * b[0, r] + d1[e, 1] * b[1, r] + d1[e, 2] * b[2, r])
        for i in range(3):
            f[0, i, e] = -(f[1, i, e] + f[2, i, e] + f[3, i, e])
    for p in range(3):  # c = (V0 d2 mixing the first 3 modes; V0 lambda / 2 for the pair modes) b
        for r in range(9):
            c[p, r] = V0 * (D2[e, p, 0] * b[0, r] + D2[e, p, 1] * b[1, r] + D2[e, p, 2] * b[2, r])
    for k in range(6):
        w = 0.5 * V0 * lam[e, k]
        for r in range(9):
            c[3 + k, r] = w * b[3 + k, r]
    for r in range(9):  # block of vertices 1..3
        for s in range(r, 9):
            t = 0.0
            for mode in range(9):
                t += b[mode, r] * c[mode, s]
            K[r, s] = t
            K[s, r] = t
    for i in range(3):  # rows of vertex 0: minus the sum over a of rows (a, i)
        for s in range(9):
            R[i, s] = K[i, s] + K[3 + i, s] + K[6 + i, s]
    pos = 0
    for i in range(3):
        for k in range(i, 3):
            H[pos, e] = R[i, k] + R[i, 3 + k] + R[i, 6 + k]
            pos += 1
        for s in range(9):
            H[pos, e] = -R[i, s]
            pos += 1
    for r in range(9):
        for s in range(r, 9):
            H[pos, e] = K[r, s]
            pos += 1


@numba.njit(cache=True, parallel=True)
def csr_matvec(indptr, indices, data, x, y) -> None:
    """``y = A x`` for the CSR matrix ``(indptr, indices, data)``; rows in parallel chunks."""
    n = len(indptr) - 1
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            t = 0.0
            for p in range(indptr[i], indptr[i + 1]):
                t += data[p] * x[indices[p]]
            y[i] = t


@numba.njit(cache=True, parallel=True)
def gather_sum(ptr, order, values, out) -> None:
    """``out[p] = sum of values[order[ptr[p]:ptr[p + 1]]]`` (in that order); entries in parallel chunks."""
    n = len(ptr) - 1
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for p in range(start, stop):
            t = 0.0
            for s in range(ptr[p], ptr[p + 1]):
                t += values[order[s]]
            out[p] = t


@numba.njit(cache=True, parallel=True)
def symmetrise(half, transpose, is_diag, out) -> None:
    """``out = half + half[transpose]``, the diagonal positions (``is_diag``) counted once."""
    n = len(half)
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for p in range(start, stop):
            out[p] = half[p] if is_diag[p] else half[p] + half[transpose[p]]
