"""Compiled kernels of the tet solver (numba, compiled on first call, cached on disk), parallel over
chunks of elements or rows (:mod:`modalfem._threads`) whose bounds depend on the problem size only:
every value is computed by one thread in a fixed order, so results are bit-identical on any thread count.

* ``hessians_upper``: projected element Hessians (upper triangles) and element forces from the analytic
  eigensystem of an isotropic density (the formulas of :func:`modalfem.tet.energies.element_hessians`);
  ``element_forces`` the forces alone.
* ``csr_matvec``: ``y = A x`` for a CSR matrix, rows in parallel; ``pcg_twolevel`` the solver's whole
  preconditioned CG (two-level or Jacobi), three fused passes per iteration, dot products summed per
  chunk in chunk order.
* ``gather_sum``: element forces summed per vertex DOF as a gather; ``assemble_upper``: the assembly's scatter of element upper triangles written as a gather per upper
  position (no write conflicts), symmetrised in the same pass; ``galerkin`` the two-level
  preconditioner's coarse matrix ``P^T A P``, groups of rows in parallel.
* ``svd_of_positions`` / ``svd_rv``: the rotation-variant SVD by one-sided Jacobi, ``SVD_LANES`` elements of a
  chunk swept side by side (vectorised; the bits of one element at a time).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem._threads import apply as _apply_threads
from modalfem._threads import chunk_bounds, chunk_count

__all__ = ["assemble_upper", "compact_unsigned", "csr_matvec", "element_forces", "galerkin", "gather_sum", "hessians_upper", "mirror_upper", "pcg_twolevel",
           "svd_of_positions", "svd_rv", "unsigned"]

_apply_threads()

#: elements per chunk of ``hessians_upper``; rows per chunk of ``csr_matvec`` / ``gather_sum`` and the CG
#: passes: small enough for ~50 chunks at ~6k rows (10k tets), so that numba's even split of the chunks
#: between threads is balanced (13 chunks of 512 rows left one of 2 threads 7 chunks, the other 6)
ELEMENT_CHUNK = 128
ROW_CHUNK = 129
#: (i, j) of the three pair modes, as in ``modalfem.tet.energies.PAIRS``
_PI = (1, 0, 0)
_PJ = (2, 2, 1)


@numba.njit(cache=True, parallel=True)
def hessians_upper(Ut, Vt, D2, lam, gt, vol, d1, H, f, forces: bool, project: bool) -> None:
    """Element Hessians (projected, or exact) and forces (see module docstring), element index last for
    the inputs, first for the Hessians (each element's 78 values written together).

    Args:
        Ut, Vt: U and V of the rotation-variant SVD (3, 3, m).
        D2: d^2 psi / d sigma^2 (3, 3, m) [Pa] (projected by the caller, if wanted).
        lam: twist and flip eigenvalues (6, m) [Pa].
        gt: shape-function gradients (4, 3, m) [1/m].
        vol: rest volumes (m,) [m^3].
        d1: d psi / d sigma (3, m) [Pa] (read only with ``forces``).
        H: out, (m, 78) upper triangles [N/m] in the order of ``np.triu_indices(12)``.
        f: out with ``forces``, (4, 3, m) [N]: ``V0 U diag(d1) V^T grad_a``.
        forces: compute ``f``.
        project: clamp negative twist and flip eigenvalues at 0 (else they are kept: the exact Hessian
            when ``D2`` is not projected either).
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
            _element(e, Ut, Vt, D2, lam, gt, vol, d1, H, f, forces, project, b, c, K, Gv, R)


@numba.njit(cache=True)
def _element(e, Ut, Vt, D2, lam, gt, vol, d1, H, f, forces, project, b, c, K, Gv, R) -> None:
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
                f[a + 1, i, e] = V0 * (d1[0, e] * b[0, r] + d1[1, e] * b[1, r] + d1[2, e] * b[2, r])
        for i in range(3):
            f[0, i, e] = -(f[1, i, e] + f[2, i, e] + f[3, i, e])
    for p in range(3):  # c = (V0 d2 mixing the first 3 modes; V0 lambda / 2 for the pair modes) b
        for r in range(9):
            c[p, r] = V0 * (D2[p, 0, e] * b[0, r] + D2[p, 1, e] * b[1, r] + D2[p, 2, e] * b[2, r])
    for k in range(6):
        w = 0.5 * V0 * lam[k, e]
        if project and w < 0.0:
            w = 0.0
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
            H[e, pos] = R[i, k] + R[i, 3 + k] + R[i, 6 + k]
            pos += 1
        for s in range(9):
            H[e, pos] = -R[i, s]
            pos += 1
    for r in range(9):
        for s in range(r, 9):
            H[e, pos] = K[r, s]
            pos += 1


@numba.njit(cache=True, parallel=True)
def element_forces(Ut, Vt, d1, gt, vol, f) -> None:
    """Element forces alone, ``f[a, :, e] = V0 U diag(d1) V^T grad_a`` (4, 3, m) [N] (as ``hessians_upper``
    with ``forces``, summed in another order), element index last; arguments as there (``d1`` (3, m))."""
    m = Ut.shape[2]
    chunks = chunk_count(m, ELEMENT_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        P = np.empty((3, 3))
        for e in range(start, stop):
            for i in range(3):
                for j in range(3):
                    P[i, j] = (Ut[i, 0, e] * d1[0, e] * Vt[j, 0, e] + Ut[i, 1, e] * d1[1, e] * Vt[j, 1, e]
                               + Ut[i, 2, e] * d1[2, e] * Vt[j, 2, e])
            V0 = vol[e]
            for i in range(3):
                s0 = 0.0
                for a in range(1, 4):
                    t = V0 * (P[i, 0] * gt[a, 0, e] + P[i, 1] * gt[a, 1, e] + P[i, 2] * gt[a, 2, e])
                    f[a, i, e] = t
                    s0 += t
                f[0, i, e] = -s0


def compact_unsigned(index: np.ndarray) -> np.ndarray:
    """Non-negative indices as a new ``uint32`` array when they fit (else ``uint64``): half the memory
    traffic of 64-bit indices in a gather through them (the assembly's scatter over the 10k-tet bar's
    786k Hessian entries: 1.24 -> 1.05 ms on one thread), and no wrap-around test (:func:`unsigned`)."""
    index = np.asarray(index)
    if index.size and int(index.min()) < 0:
        raise ValueError("negative index")
    fits = index.size == 0 or int(index.max()) <= np.iinfo(np.uint32).max
    return index.astype(np.uint32 if fits else np.uint64)


@numba.njit(cache=True)
def mirror_upper(a) -> None:
    """``a[i, j] = a[j, i]`` for ``i > j``: a square matrix made symmetric from its upper triangle, in place
    (LAPACK's ``potri`` output; was two ``np.triu`` copies and a sum, ~0.4 ms at 324 x 324)."""
    n = a.shape[0]
    for i in range(n):
        for j in range(i):
            a[i, j] = a[j, i]


def unsigned(index: np.ndarray) -> np.ndarray:
    """The same non-negative indices viewed as unsigned integers: numba then skips the negative-index
    wrap-around test of every array access through them (a CSR product ~30 % faster)."""
    return index.view(np.uint32 if index.dtype.itemsize == 4 else np.uint64)


@numba.njit(cache=True, parallel=True)
def csr_matvec(indptr, indices, data, x, y) -> None:
    """``y = A x`` for the CSR matrix ``(indptr, indices, data)`` (``indices`` best ``unsigned``); rows in
    parallel chunks."""
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
    """``out[p] = sum of values[order[ptr[p]:ptr[p + 1]]]`` (in that order: a scatter-add written as a
    gather, no write conflicts); entries in parallel chunks."""
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
def assemble_upper(ptr, order, values, owner, mirror, out) -> None:
    """The assembly's scatter as a gather, symmetrised in the same pass: for each position ``k`` of the
    upper triangle (diagonal included), ``t = sum of values[order[ptr[k]:ptr[k + 1]]]`` (in that order: the
    element entries landing on it or on its transpose) is written to ``out[owner[k]]`` and
    ``out[mirror[k]]`` (its transpose; the same position on the diagonal). Positions in parallel chunks;
    each entry of ``out`` is written by one position only."""
    n = len(ptr) - 1
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for k in range(start, stop):
            t = 0.0
            for s in range(ptr[k], ptr[k + 1]):
                t += values[order[s]]
            out[owner[k]] = t
            out[mirror[k]] = t


#: elements whose Jacobi sweeps run side by side (SIMD lanes; see :func:`_svd_lanes`)
SVD_LANES = 16


@numba.njit(cache=True, parallel=True)
def svd_rv(Ft, V0t, warm: bool, U, s, V, lanes: int = SVD_LANES) -> None:
    """Rotation-variant SVD of every element (:func:`modalfem.tet.kinematics.svd_rv_t`), elements in
    parallel chunks: ``Ft`` (3, 3, m), warm start ``V0t`` (3, 3, m) if ``warm``; outputs ``U`` (3, 3, m),
    ``s`` (m, 3), ``V`` (3, 3, m). ``lanes`` (1..``SVD_LANES``): elements swept together
    (:func:`_svd_lanes`; the same bits for any value)."""
    m = Ft.shape[2]
    chunks = chunk_count(m, ELEMENT_CHUNK)
    nl = max(1, min(lanes, SVD_LANES))
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        AV = np.empty((6, 3))
        F = np.empty((3, 3))
        AVl = np.empty((6, 3, SVD_LANES))
        Fl = np.empty((3, 3, SVD_LANES))
        flags = np.empty((2, SVD_LANES), dtype=np.bool_)
        for e0 in range(start, stop, nl):
            k = min(nl, stop - e0)
            for l in range(k):
                for i in range(3):
                    for j in range(3):
                        Fl[i, j, l] = Ft[i, j, e0 + l]
            _svd_lanes(Fl, V0t, warm, e0, k, U, s, V, AVl, AV, F, flags)


@numba.njit(cache=True, parallel=True)
def svd_of_positions(x, cells, grad_t, V0t, warm: bool, U, s, V, lanes: int = SVD_LANES) -> None:
    """:func:`svd_rv` of the deformation gradients ``F = sum_a x_a grad_a^T`` of positions ``x`` (n, 3) [m],
    ``cells`` (m, 4), shape gradients ``grad_t`` (4, 3, m) [1/m] (the sums in the order of
    :func:`modalfem.tet.kinematics.deformation_gradient_t`: the same F), formed per element inside."""
    m = cells.shape[0]
    chunks = chunk_count(m, ELEMENT_CHUNK)
    nl = max(1, min(lanes, SVD_LANES))
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        AV = np.empty((6, 3))
        F = np.empty((3, 3))
        AVl = np.empty((6, 3, SVD_LANES))
        Fl = np.empty((3, 3, SVD_LANES))
        flags = np.empty((2, SVD_LANES), dtype=np.bool_)
        for e0 in range(start, stop, nl):
            k = min(nl, stop - e0)
            for l in range(k):
                e = e0 + l
                c0, c1, c2, c3 = cells[e, 0], cells[e, 1], cells[e, 2], cells[e, 3]
                for i in range(3):
                    for j in range(3):
                        t = x[c0, i] * grad_t[0, j, e]
                        t += x[c1, i] * grad_t[1, j, e]
                        t += x[c2, i] * grad_t[2, j, e]
                        t += x[c3, i] * grad_t[3, j, e]
                        Fl[i, j, l] = t
            _svd_lanes(Fl, V0t, warm, e0, k, U, s, V, AVl, AV, F, flags)


@numba.njit(cache=True, error_model="numpy")
def _svd_lanes(Fl, V0t, warm, e0, nl, U, s, V, AVl, AV, F, flags) -> None:
    """:func:`_svd_element` of elements ``e0 .. e0 + nl - 1`` (their F in lanes ``0 .. nl - 1`` of ``Fl``
    (3, 3, lanes)), their sweeps side by side: every lane takes each sweep's three rotations with the same
    operations as :func:`_svd_element`, a lane whose pair needs no rotation keeps its columns (selected, not
    multiplied by 1), and the sweeps stop when no lane rotated (a lane whose sweep rotated nothing is
    converged and stays unchanged): the same bits as one element at a time, with independent lanes the
    compiler vectorises (and the CPU overlaps: the sweeps are chains of square roots and divisions). A
    batch in which a rotation needs ``math.hypot`` (squares out of range) is redone element by element.
    ``nl`` is a run-time value (a constant trip count is unrolled instead of vectorised); ``flags``
    (2, lanes) scratch, ``AV`` (6, 3) and ``F`` (3, 3) the element-wise path's scratch."""
    for i in range(3):
        for j in range(3):
            for l in range(nl):
                AVl[3 + i, j, l] = V0t[i, j, e0 + l] if warm else (1.0 if i == j else 0.0)
    for i in range(3):
        for j in range(3):
            for l in range(nl):
                if warm:
                    AVl[i, j, l] = Fl[i, 0, l] * AVl[3, j, l] + Fl[i, 1, l] * AVl[4, j, l] + Fl[i, 2, l] * AVl[5, j, l]
                else:
                    AVl[i, j, l] = Fl[i, j, l]
    for l in range(nl):
        flags[1, l] = False
    for _ in range(12):
        r0 = _rotate_lanes(AVl, 0, 1, nl, flags)
        r1 = _rotate_lanes(AVl, 0, 2, nl, flags)
        r2 = _rotate_lanes(AVl, 1, 2, nl, flags)
        if not (r0 or r1 or r2):
            break
    extreme = False
    for l in range(nl):
        extreme |= flags[1, l]
    if extreme:
        for l in range(nl):
            for i in range(3):
                for j in range(3):
                    F[i, j] = Fl[i, j, l]
            _svd_element(e0 + l, F, V0t, warm, U, s, V, AV)
        return
    _finish_lanes(AVl, e0, nl, U, s, V, flags)
    for l in range(nl):
        if flags[0, l]:  # a (near) rank-one F: its second column of U by the element-wise path
            for r in range(6):
                for j in range(3):
                    AV[r, j] = AVl[r, j, l]
            _svd_finish(e0 + l, AV, U, s, V)


@numba.njit(cache=True, error_model="numpy")
def _finish_lanes(AVl, e0, nl, U, s, V, flags) -> None:
    """:func:`_svd_finish` of lanes ``0 .. nl - 1`` of ``AVl`` into elements ``e0 ..`` (the same operations,
    branches as selects; ``AVl`` is not changed). A lane whose second column of ``U`` needs the
    cross-product fallback (``F`` of rank <= 1) is marked in ``flags[0]`` (its outputs then wrong: the caller
    redoes it with :func:`_svd_finish`)."""
    for l in range(nl):
        a0, a1, a2, a3, a4, a5 = AVl[0, 0, l], AVl[1, 0, l], AVl[2, 0, l], AVl[3, 0, l], AVl[4, 0, l], AVl[5, 0, l]
        b0, b1, b2, b3, b4, b5 = AVl[0, 1, l], AVl[1, 1, l], AVl[2, 1, l], AVl[3, 1, l], AVl[4, 1, l], AVl[5, 1, l]
        c0, c1, c2, c3, c4, c5 = AVl[0, 2, l], AVl[1, 2, l], AVl[2, 2, l], AVl[3, 2, l], AVl[4, 2, l], AVl[5, 2, l]
        n0 = math.sqrt(a0 ** 2 + a1 ** 2 + a2 ** 2)
        n1 = math.sqrt(b0 ** 2 + b1 ** 2 + b2 ** 2)
        n2 = math.sqrt(c0 ** 2 + c1 ** 2 + c2 ** 2)
        # the sorting network of _svd_finish: columns (0, 1), (1, 2), (0, 1)
        sw = n1 > n0
        a0, b0 = (b0, a0) if sw else (a0, b0)
        a1, b1 = (b1, a1) if sw else (a1, b1)
        a2, b2 = (b2, a2) if sw else (a2, b2)
        a3, b3 = (b3, a3) if sw else (a3, b3)
        a4, b4 = (b4, a4) if sw else (a4, b4)
        a5, b5 = (b5, a5) if sw else (a5, b5)
        n0, n1 = (n1, n0) if sw else (n0, n1)
        sw = n2 > n1
        b0, c0 = (c0, b0) if sw else (b0, c0)
        b1, c1 = (c1, b1) if sw else (b1, c1)
        b2, c2 = (c2, b2) if sw else (b2, c2)
        b3, c3 = (c3, b3) if sw else (b3, c3)
        b4, c4 = (c4, b4) if sw else (b4, c4)
        b5, c5 = (c5, b5) if sw else (b5, c5)
        n1, n2 = (n2, n1) if sw else (n1, n2)
        sw = n1 > n0
        a0, b0 = (b0, a0) if sw else (a0, b0)
        a1, b1 = (b1, a1) if sw else (a1, b1)
        a2, b2 = (b2, a2) if sw else (a2, b2)
        a3, b3 = (b3, a3) if sw else (a3, b3)
        a4, b4 = (b4, a4) if sw else (a4, b4)
        a5, b5 = (b5, a5) if sw else (a5, b5)
        n0, n1 = (n1, n0) if sw else (n0, n1)
        det = a3 * (b4 * c5 - b5 * c4) + a4 * (b5 * c3 - b3 * c5) + a5 * (b3 * c4 - b4 * c3)
        neg = det < 0
        c0 = -c0 if neg else c0
        c1 = -c1 if neg else c1
        c2 = -c2 if neg else c2
        c3 = -c3 if neg else c3
        c4 = -c4 if neg else c4
        c5 = -c5 if neg else c5
        e = e0 + l
        V[0, 0, e], V[0, 1, e], V[0, 2, e] = a3, b3, c3
        V[1, 0, e], V[1, 1, e], V[1, 2, e] = a4, b4, c4
        V[2, 0, e], V[2, 1, e], V[2, 2, e] = a5, b5, c5
        tiny = n0 <= 1e-300
        u00 = 1.0 if tiny else a0 / n0
        u01 = 0.0 if tiny else a1 / n0
        u02 = 0.0 if tiny else a2 / n0
        d = u00 * b0 + u01 * b1 + u02 * b2
        w0, w1, w2 = b0 - u00 * d, b1 - u01 * d, b2 - u02 * d
        s1 = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        flags[0, l] = not s1 > 1e-14 * max(n0, 1e-300)
        w0, w1, w2 = w0 / s1, w1 / s1, w2 / s1
        u20, u21, u22 = u01 * w2 - u02 * w1, u02 * w0 - u00 * w2, u00 * w1 - u01 * w0
        U[0, 0, e], U[1, 0, e], U[2, 0, e] = u00, u01, u02
        U[0, 1, e], U[1, 1, e], U[2, 1, e] = w0, w1, w2
        U[0, 2, e], U[1, 2, e], U[2, 2, e] = u20, u21, u22
        s[e, 0] = n0
        s[e, 1] = w0 * b0 + w1 * b1 + w2 * b2
        s[e, 2] = u20 * c0 + u21 * c1 + u22 * c2


@numba.njit(cache=True, error_model="numpy")
def _rotate_lanes(AVl, p, q, nl, flags) -> bool:
    """The rotation of columns ``p``, ``q`` of :func:`_svd_element`'s sweep in lanes ``0 .. nl - 1`` of
    ``AVl`` (6, 3, lanes); ``flags[0]`` the lanes that rotated, ``flags[1]`` or-ed with the lanes whose
    rotation needs ``math.hypot``. Returns whether any lane rotated."""
    for l in range(nl):
        a0p, a1p, a2p = AVl[0, p, l], AVl[1, p, l], AVl[2, p, l]
        a0q, a1q, a2q = AVl[0, q, l], AVl[1, q, l], AVl[2, q, l]
        al = a0p * a0p + a1p * a1p + a2p * a2p
        be = a0q * a0q + a1q * a1q + a2q * a2q
        ga = a0p * a0q + a1p * a1q + a2p * a2q
        rot = abs(ga) > 1e-15 * math.sqrt(al * be)
        tau, g2 = be - al, 2.0 * ga
        big = max(abs(tau), abs(g2))
        flags[1, l] |= rot and not (1e-140 < big < 1e140)
        hyp = math.sqrt(tau * tau + g2 * g2)
        t = math.copysign(1.0, tau) * g2 / (abs(tau) + hyp)  # inf or nan where rot is False: not used
        c = 1.0 / math.sqrt(1.0 + t * t)
        for r in range(6):
            mp, mq = AVl[r, p, l], AVl[r, q, l]
            np_ = c * (mp - t * mq)
            nq = c * (mq + t * mp)
            AVl[r, p, l] = np_ if rot else mp
            AVl[r, q, l] = nq if rot else mq
        flags[0, l] = rot
    anyrot = False
    for l in range(nl):
        anyrot |= flags[0, l]
    return anyrot


@numba.njit(cache=True)
def _svd_element(e, F, V0t, warm, U, s, V, AV) -> None:
    """One-sided Jacobi on the columns of ``F V0`` (``F`` 3x3), rows 0..2 of ``AV`` (A = F V) and 3..5
    (V); results into element ``e`` of ``U``, ``s``, ``V``."""
    for i in range(3):
        for j in range(3):
            if warm:
                AV[3 + i, j] = V0t[i, j, e]
            else:
                AV[3 + i, j] = 1.0 if i == j else 0.0
    for i in range(3):
        for j in range(3):
            if warm:
                AV[i, j] = F[i, 0] * AV[3, j] + F[i, 1] * AV[4, j] + F[i, 2] * AV[5, j]
            else:
                AV[i, j] = F[i, j]
    for _ in range(12):
        done = True
        for k in range(3):
            p, q = (0, 0, 1)[k], (1, 2, 2)[k]
            al = AV[0, p] * AV[0, p] + AV[1, p] * AV[1, p] + AV[2, p] * AV[2, p]
            be = AV[0, q] * AV[0, q] + AV[1, q] * AV[1, q] + AV[2, q] * AV[2, q]
            ga = AV[0, p] * AV[0, q] + AV[1, p] * AV[1, q] + AV[2, p] * AV[2, q]
            if not abs(ga) > 1e-15 * math.sqrt(al * be):
                continue
            done = False
            # t = tan of the rotation angle = sign(z) / (|z| + sqrt(1 + z^2)), z = (be - al) / (2 ga)
            tau, g2 = be - al, 2.0 * ga
            big = max(abs(tau), abs(g2))
            if 1e-140 < big < 1e140:  # the squares neither overflow nor underflow: sqrt of their sum, a
                hyp = math.sqrt(tau * tau + g2 * g2)  # quarter of the SVD's time less than math.hypot
            else:
                hyp = math.hypot(tau, g2)
            t = math.copysign(1.0, tau) * g2 / (abs(tau) + hyp)
            c = 1.0 / math.sqrt(1.0 + t * t)
            for r in range(6):
                mp, mq = AV[r, p], AV[r, q]
                AV[r, p] = c * (mp - t * mq)
                AV[r, q] = c * (mq + t * mp)
        if done:
            break
    _svd_finish(e, AV, U, s, V)


@numba.njit(cache=True)
def _svd_finish(e, AV, U, s, V) -> None:
    """The end of :func:`_svd_element` after its sweeps (``AV`` rows 0..2 = F V, 3..5 = V): columns sorted by
    norm, a reflection moved onto the last, ``U`` from the normalised columns (Gram-Schmidt, the third a
    cross product), the signed singular values; into element ``e`` of ``U``, ``s``, ``V``."""
    n0 = math.sqrt(AV[0, 0] ** 2 + AV[1, 0] ** 2 + AV[2, 0] ** 2)
    n1 = math.sqrt(AV[0, 1] ** 2 + AV[1, 1] ** 2 + AV[2, 1] ** 2)
    n2 = math.sqrt(AV[0, 2] ** 2 + AV[1, 2] ** 2 + AV[2, 2] ** 2)
    for k in range(3):  # sorting network: column norms descending
        p, q = (0, 1, 0)[k], (1, 2, 1)[k]
        np_, nq = (n0, n1, n0)[k], (n1, n2, n1)[k]
        if nq > np_:
            for r in range(6):
                AV[r, p], AV[r, q] = AV[r, q], AV[r, p]
            if k == 1:
                n1, n2 = n2, n1
            else:
                n0, n1 = n1, n0
    det = (AV[3, 0] * (AV[4, 1] * AV[5, 2] - AV[5, 1] * AV[4, 2])
           + AV[4, 0] * (AV[5, 1] * AV[3, 2] - AV[3, 1] * AV[5, 2])
           + AV[5, 0] * (AV[3, 1] * AV[4, 2] - AV[4, 1] * AV[3, 2]))
    if det < 0:
        for r in range(6):
            AV[r, 2] = -AV[r, 2]
    for i in range(3):
        for j in range(3):
            V[i, j, e] = AV[3 + i, j]
    if n0 <= 1e-300:
        u00, u01, u02 = 1.0, 0.0, 0.0
    else:
        u00, u01, u02 = AV[0, 0] / n0, AV[1, 0] / n0, AV[2, 0] / n0
    d = u00 * AV[0, 1] + u01 * AV[1, 1] + u02 * AV[2, 1]
    w0, w1, w2 = AV[0, 1] - u00 * d, AV[1, 1] - u01 * d, AV[2, 1] - u02 * d
    s1 = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    if s1 > 1e-14 * max(n0, 1e-300):
        w0, w1, w2 = w0 / s1, w1 / s1, w2 / s1
    else:  # a unit vector orthogonal to u0: u0 x e, e the axis of u0's smallest component
        a0, a1, a2 = abs(u00), abs(u01), abs(u02)
        ax = 0 if (a0 <= a1 and a0 <= a2) else (1 if a1 <= a2 else 2)
        e0, e1, e2 = (1.0 if ax == 0 else 0.0), (1.0 if ax == 1 else 0.0), (1.0 if ax == 2 else 0.0)
        w0, w1, w2 = u01 * e2 - u02 * e1, u02 * e0 - u00 * e2, u00 * e1 - u01 * e0
        wn = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        w0, w1, w2 = w0 / wn, w1 / wn, w2 / wn
    u20, u21, u22 = u01 * w2 - u02 * w1, u02 * w0 - u00 * w2, u00 * w1 - u01 * w0
    U[0, 0, e], U[1, 0, e], U[2, 0, e] = u00, u01, u02
    U[0, 1, e], U[1, 1, e], U[2, 1, e] = w0, w1, w2
    U[0, 2, e], U[1, 2, e], U[2, 2, e] = u20, u21, u22
    s[e, 0] = n0
    s[e, 1] = w0 * AV[0, 1] + w1 * AV[1, 1] + w2 * AV[2, 1]
    s[e, 2] = u20 * AV[0, 2] + u21 * AV[1, 2] + u22 * AV[2, 2]


@numba.njit(cache=True, parallel=True)
def _dot(a, b, part) -> float:
    """``a . b`` from per-chunk partial sums added in chunk order (the same bits on any thread count)."""
    n = len(a)
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        t = 0.0
        for i in range(start, stop):
            t += a[i] * b[i]
        part[ch] = t
    s = 0.0
    for ch in range(chunks):
        s += part[ch]
    return s


@numba.njit(cache=True, parallel=True)
def _search(indptr, indices, data, z, p, Ap, beta: float, part) -> float:
    """The next search direction and its product in one pass: ``p = z + beta p`` and ``Ap = A z + beta Ap``
    (``A p`` by linearity from the previous product: the CSR product reads ``z``, which no row changes
    here, so the direction update needs no pass of its own); returns ``p . Ap``. ``beta = 0`` starts
    (``p = z``, ``Ap = A z``; the old values are not read)."""
    n = len(p)
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        t = 0.0
        for i in range(start, stop):
            s = 0.0
            for q in range(indptr[i], indptr[i + 1]):
                s += data[q] * z[indices[q]]
            if beta == 0.0:
                pi, api = z[i], s
            else:
                pi, api = z[i] + beta * p[i], s + beta * Ap[i]
            p[i] = pi
            Ap[i] = api
            t += pi * api
        part[ch] = t
    s = 0.0
    for ch in range(chunks):
        s += part[ch]
    return s


@numba.njit(cache=True, parallel=True)
def _search3(indptr, indices, data, z, p, Ap, beta: float, part) -> float:
    """:func:`_search` for a matrix of full 3x3 vertex blocks (rows ``3i..3i+2`` have the same columns,
    in triples ``3j..3j+2``: every matrix of ``HessianPattern``): each vertex's three rows in one sweep of
    row ``3i``'s block columns, reading each column index and ``z`` triple once (the index traffic of a
    CSR product cut 9-fold); every row summed in the same order as :func:`_search`, so the same bits."""
    nv = (len(indptr) - 1) // 3
    chunks = chunk_count(nv, ROW_CHUNK // 3)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(nv, chunks, ch)
        t = 0.0
        for v in range(start, stop):
            i = 3 * v
            q0 = indptr[i]
            L = indptr[i + 1] - q0
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            for q in range(q0, q0 + L, 3):
                j = indices[q]
                z0 = z[j]
                z1 = z[j + 1]
                z2 = z[j + 2]
                s0 += data[q] * z0
                s0 += data[q + 1] * z1
                s0 += data[q + 2] * z2
                s1 += data[q + L] * z0
                s1 += data[q + L + 1] * z1
                s1 += data[q + L + 2] * z2
                s2 += data[q + 2 * L] * z0
                s2 += data[q + 2 * L + 1] * z1
                s2 += data[q + 2 * L + 2] * z2
            for c in range(3):
                s = s0 if c == 0 else (s1 if c == 1 else s2)
                if beta == 0.0:
                    pi, api = z[i + c], s
                else:
                    pi, api = z[i + c] + beta * p[i + c], s + beta * Ap[i + c]
                p[i + c] = pi
                Ap[i + c] = api
                t += pi * api
        part[ch] = t
    s = 0.0
    for ch in range(chunks):
        s += part[ch]
    return s


@numba.njit(cache=True)
def is_blocked3(indptr, indices) -> bool:
    """The CSR pattern is made of full 3x3 vertex blocks (what :func:`_search3` needs): rows ``3i..3i+2``
    of equal length with the same columns, which come in triples ``3j, 3j+1, 3j+2``."""
    n = len(indptr) - 1
    if n % 3 != 0:
        return False
    for v in range(n // 3):
        i = 3 * v
        q0 = indptr[i]
        L = indptr[i + 1] - q0
        if L % 3 != 0 or indptr[i + 2] - indptr[i + 1] != L or indptr[i + 3] - indptr[i + 2] != L:
            return False
        for q in range(q0, q0 + L, 3):
            j = indices[q]
            if j % 3 != 0 or indices[q + 1] != j + 1 or indices[q + 2] != j + 2:
                return False
            for c in (1, 2):
                if indices[q + c * L] != j or indices[q + c * L + 1] != j + 1 or indices[q + c * L + 2] != j + 2:
                    return False
    return True


@numba.njit(cache=True, parallel=True)
def _update(x, r, p, Ap, alpha: float, Pp, Pi, Pd, Ac_inv, gptr, grows, cr, cz, part) -> float:
    """``x += alpha p``, ``r -= alpha Ap`` and the coarse part of the next preconditioning in the same pass:
    ``cr = P^T r`` (rows visited group by group, ``grows[gptr[g]:gptr[g + 1]]``, a vertex's three DOFs
    together; each group's 6 coarse entries summed in registers by one thread: no partial arrays, no
    write conflicts, no chain of stores through memory; ``P`` in :class:`modalfem.tet.precond.TwoLevel`'s
    layout: row ``3v + k`` holds the group's translation ``k`` and its rotations ``a < b`` other than
    ``k``, in that order), then ``cz = Ac_inv cr`` (serial:
    O(nc^2), a column sweep of the symmetric ``Ac_inv``, vectorised). Without a coarse part rows go in
    chunks. Returns ``r . r`` (per group or chunk, added in order). ``alpha = 0`` with zero ``p`` and
    ``Ap``: only the restriction of ``r``."""
    n = len(x)
    nc = len(cr)
    if nc > 0:
        groups = len(gptr) - 1
        for g in numba.prange(groups):
            t = 0.0
            a0 = a1 = a2 = a3 = a4 = a5 = 0.0  # the group's 6 coarse entries, summed in registers
            for k in range(gptr[g], gptr[g + 1], 3):
                i = grows[k]  # vertex DOFs i, i + 1, i + 2; P entries q..q + 8 (TwoLevel's layout)
                q = Pp[i]
                x[i] += alpha * p[i]
                x[i + 1] += alpha * p[i + 1]
                x[i + 2] += alpha * p[i + 2]
                r0 = r[i] - alpha * Ap[i]
                r1 = r[i + 1] - alpha * Ap[i + 1]
                r2 = r[i + 2] - alpha * Ap[i + 2]
                r[i] = r0
                r[i + 1] = r1
                r[i + 2] = r2
                t += r0 * r0
                t += r1 * r1
                t += r2 * r2
                a0 += Pd[q] * r0  # row x: translation x, rotations about y and z
                a4 += Pd[q + 1] * r0
                a5 += Pd[q + 2] * r0
                a1 += Pd[q + 3] * r1  # row y: translation y, rotations about x and z
                a3 += Pd[q + 4] * r1
                a5 += Pd[q + 5] * r1
                a2 += Pd[q + 6] * r2  # row z: translation z, rotations about x and y
                a3 += Pd[q + 7] * r2
                a4 += Pd[q + 8] * r2
            if gptr[g + 1] > gptr[g]:
                c0 = Pi[Pp[grows[gptr[g]]]]  # the group's first coarse column (translation x)
                cr[c0] = a0
                cr[c0 + 1] = a1
                cr[c0 + 2] = a2
                cr[c0 + 3] = a3
                cr[c0 + 4] = a4
                cr[c0 + 5] = a5
            part[g] = t
        s = 0.0
        for g in range(groups):
            s += part[g]
        for j in range(nc):
            cz[j] = 0.0
        for j in range(nc):  # cz = Ac_inv cr by columns (Ac_inv symmetric): cz[i] summed over j in order
            c = cr[j]
            for i in range(nc):
                cz[i] += Ac_inv[j, i] * c
        return s
    chunks = chunk_count(n, ROW_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        t = 0.0
        for i in range(start, stop):
            x[i] += alpha * p[i]
            ri = r[i] - alpha * Ap[i]
            r[i] = ri
            t += ri * ri
        part[ch] = t
    s = 0.0
    for ch in range(chunks):
        s += part[ch]
    return s


@numba.njit(cache=True, parallel=True)
def _precondition(r, inv, Pp, Pi, Pd, cz, z, part) -> float:
    """``z = inv * r + P cz`` (``cz = Ac_inv P^T r`` from :func:`_update`; ``P`` with 3 entries per row,
    vertices in parallel chunks; no coarse part when ``cz`` is empty: rows in chunks); returns ``r . z``."""
    nc = len(cz)
    n = len(r)
    if nc > 0:
        nv = n // 3
        chunks = chunk_count(nv, ROW_CHUNK // 3)
        for ch in numba.prange(chunks):
            start, stop = chunk_bounds(nv, chunks, ch)
            t = 0.0
            for v in range(start, stop):
                for k in range(3):
                    i = 3 * v + k
                    q = Pp[i]
                    zi = inv[i] * r[i] + (Pd[q] * cz[Pi[q]] + Pd[q + 1] * cz[Pi[q + 1]] + Pd[q + 2] * cz[Pi[q + 2]])
                    z[i] = zi
                    t += r[i] * zi
            part[ch] = t
    else:
        chunks = chunk_count(n, ROW_CHUNK)
        for ch in numba.prange(chunks):
            start, stop = chunk_bounds(n, chunks, ch)
            t = 0.0
            for i in range(start, stop):
                zi = inv[i] * r[i]
                z[i] = zi
                t += r[i] * zi
            part[ch] = t
    s = 0.0
    for ch in range(chunks):
        s += part[ch]
    return s


@numba.njit(cache=True)
def pcg_twolevel(indptr, indices, data, b, x, warm: bool, inv, Pp, Pi, Pd, Ac_inv, gptr, grows, rtol: float,
                 maxiter: int, blocked: bool):
    """Preconditioned CG for ``A x = b`` (CSR ``A``) with ``M^-1 r = inv * r + P Ac_inv P^T r`` (P as CSR
    ``(Pp, Pi, Pd)``, whose row ``i`` has its columns in the coarse block of the group listing ``i`` in
    ``grows[gptr[g]:gptr[g + 1]]``; Jacobi alone when ``Ac_inv`` is (0, 0)), compiled: three parallel passes per
    iteration (thread launches cost ~5-10 us each here, a pass over the vectors a few tens): the direction
    update with the CSR product and ``p . Ap`` (:func:`_search`), the vector updates with ``r . r`` and the
    coarse restriction (:func:`_update`), the preconditioner with ``r . z`` (:func:`_precondition`); dot
    products summed per chunk in chunk order, so any thread count gives the same bits.

    ``blocked``: ``A`` is made of full 3x3 vertex blocks (:func:`is_blocked3`; its products then by
    :func:`_search3`, the same bits). ``x`` (len(b),) is the start when ``warm`` (else set to 0) and the
    solution on return. Stops when
    ``|r| <= rtol |b|``. Returns ``(iterations, definite)``: ``definite`` False when a search direction
    ``p != 0`` had ``p^T A p <= 0`` (``A`` not positive definite) before the tolerance was reached.
    """
    n = len(b)
    chunks = chunk_count(n, ROW_CHUNK)
    part = np.empty(max(chunks, chunk_count(n // 3, ROW_CHUNK // 3), len(gptr) - 1))
    r = np.empty(n)
    Ap = np.zeros(n)
    p = np.zeros(n)
    z = np.empty(n)
    nc = Ac_inv.shape[0]
    cr = np.empty(nc)
    cz = np.empty(nc)
    if warm:
        csr_matvec(indptr, indices, data, x, Ap)
        for i in range(n):
            r[i] = b[i] - Ap[i]
            Ap[i] = 0.0
    else:
        for i in range(n):
            x[i] = 0.0
            r[i] = b[i]
    stop = rtol * rtol * _dot(b, b, part)
    # the restriction of the first residual (alpha = 0 with p = Ap = 0 leaves x and r unchanged)
    if _update(x, r, p, Ap, 0.0, Pp, Pi, Pd, Ac_inv, gptr, grows, cr, cz, part) <= stop:
        return 0, True  # already solved (e.g. b = 0: every DOF held, nothing to move)
    rz = _precondition(r, inv, Pp, Pi, Pd, cz, z, part)
    beta = 0.0
    for it in range(1, maxiter + 1):
        if blocked:
            pAp = _search3(indptr, indices, data, z, p, Ap, beta, part)
        else:
            pAp = _search(indptr, indices, data, z, p, Ap, beta, part)
        if not pAp > 0.0:  # a zero search direction (exactly solved) or lost definiteness: stop here
            return it, not _dot(p, p, part) > 0.0
        alpha = rz / pAp
        if _update(x, r, p, Ap, alpha, Pp, Pi, Pd, Ac_inv, gptr, grows, cr, cz, part) <= stop:
            return it, True
        rz_new = _precondition(r, inv, Pp, Pi, Pd, cz, z, part)
        beta = rz_new / rz
        rz = rz_new
    return maxiter, True


@numba.njit(cache=True, parallel=True)
def galerkin(indptr, indices, data, Pp, Pi, Pd, group_ptr, group_rows, Ac) -> None:
    """``Ac += P^T A P`` (dense (nc, nc), zero on entry) for CSR ``A`` and a prolongation ``P`` (CSR ``(Pp, Pi,
    Pd)``) whose row ``r`` has its columns in the coarse block of one group: ``group_rows[group_ptr[g]:
    group_ptr[g + 1]]`` lists the rows (DOFs) of group ``g`` in increasing order, and only they write the
    rows of ``Ac`` of that group. Groups in parallel (no write conflicts), each entry summed over its group's
    rows in order: the same bits on any thread count. Per row, ``w = A[r, :] P`` is gathered on the coarse
    columns it touches only."""
    nc = Ac.shape[0]
    groups = len(group_ptr) - 1
    for g in numba.prange(groups):
        w = np.zeros(nc)
        touched = np.empty(nc, dtype=np.int64)
        mark = np.zeros(nc, dtype=np.bool_)
        for k in range(group_ptr[g], group_ptr[g + 1]):
            r = group_rows[k]
            cnt = 0
            for q in range(indptr[r], indptr[r + 1]):
                c = indices[q]
                a = data[q]
                for t in range(Pp[c], Pp[c + 1]):
                    j = Pi[t]
                    if not mark[j]:
                        mark[j] = True
                        touched[cnt] = j
                        cnt += 1
                    w[j] += a * Pd[t]
            for t in range(Pp[r], Pp[r + 1]):
                i = Pi[t]
                v = Pd[t]
                for u in range(cnt):
                    j = touched[u]
                    Ac[i, j] += v * w[j]
            for u in range(cnt):
                j = touched[u]
                w[j] = 0.0
                mark[j] = False


@numba.njit(cache=True, parallel=True)
def stable_corotated(s, mu: float, lam: float, order: int, psi, d1, d2, twist, flip) -> None:
    """:class:`modalfem.tet.energies.StableCorotated` with scalar moduli at signed singular values ``s``
    (m, 3): ``psi`` (m,) [Pa], with ``order`` >= 1 ``d1`` (3, m), with ``order`` 2 also ``d2`` (3, 3, m),
    ``twist``, ``flip`` (3, m) [Pa], element index last; the operations of its NumPy form in the same order (the same
    numbers), elements in parallel chunks."""
    m = s.shape[0]
    chunks = chunk_count(m, ELEMENT_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        for e in range(start, stop):
            s0, s1, s2 = s[e, 0], s[e, 1], s[e, 2]
            e0, e1_, e2 = s0 - 1.0, s1 - 1.0, s2 - 1.0
            p = e0 * e0
            p += e1_ * e1_
            p += e2 * e2
            p *= mu
            if order == 0:
                jm = s0 * s1 * s2 - 1.0
                psi[e] = p + 0.5 * lam * jm * jm
                continue
            dj0, dj1, dj2 = s1 * s2, s0 * s2, s0 * s1
            jm = s0 * dj0 - 1.0
            g = lam * jm
            psi[e] = p + 0.5 * lam * jm * jm
            d1[0, e] = e0 * (2.0 * mu) + g * dj0
            d1[1, e] = e1_ * (2.0 * mu) + g * dj1
            d1[2, e] = e2 * (2.0 * mu) + g * dj2
            if order == 1:
                continue
            d2[0, 0, e] = dj0 * dj0 * lam + 2.0 * mu
            d2[1, 1, e] = dj1 * dj1 * lam + 2.0 * mu
            d2[2, 2, e] = dj2 * dj2 * lam + 2.0 * mu
            o0, o1, o2 = g * s0, g * s1, g * s2  # pair k = (1, 2), (0, 2), (0, 1) couples with sigma_k
            t = dj1 * dj2 * lam + o0
            d2[1, 2, e] = t
            d2[2, 1, e] = t
            t = dj0 * dj2 * lam + o1
            d2[0, 2, e] = t
            d2[2, 0, e] = t
            t = dj0 * dj1 * lam + o2
            d2[0, 1, e] = t
            d2[1, 0, e] = t
            for k in range(3):
                i, j = (1, 0, 0)[k], (2, 2, 1)[k]
                o = o0 if k == 0 else (o1 if k == 1 else o2)
                pair = s[e, i] + s[e, j]
                if pair < 1e-12:  # kept >= _EPS (as np.maximum; a NaN stays NaN)
                    pair = 1e-12
                twist[k, e] = 2.0 * mu - 4.0 * mu / pair + o
                flip[k, e] = 2.0 * mu - o
