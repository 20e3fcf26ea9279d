"""Compiled kernels of the cloth solver on 3x3-block sparse matrices (numba, compiled on first call, cached).

A block matrix is the block-CSR triple ``indptr`` (n + 1,), ``indices`` (nnzb,) (block columns, sorted per
block row) and ``data`` (nnzb, 3, 3) over vertices, node-major DOFs (3 i + component). Constraints are per
vertex: ``kind[i]`` 0 free, 1 the normal component along the unit ``normal[i]`` prescribed (a contact),
2 all three components prescribed (a handle); ``S_i`` is the projection on the free components
(``I``, ``I - n n^T`` or 0).

``pcg`` is the Baraff-Witkin modified (filtered) preconditioned conjugate gradient method, three parallel
passes per iteration: over the matrix (product, projection and dot product together), over the vectors
(update, residual norm, and the additive multilevel preconditioner's block Jacobi with the prolongation of
the levels' correction, projection, dot product) and the new search direction; between the first two the
levels' correction (restriction of the updated residual up the aggregation levels, their block-Jacobi and
coarsest solves) runs serially; ``aggregate`` and ``level_matrices`` build its levels. The passes over vertices run in
parallel (:mod:`modalfem._threads`) on chunks of ``CHUNK`` vertices or more whose bounds depend on the
vertex count only; dot products add the chunks' partial sums in chunk order, so a solve gives the same
bits on any number of threads.
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem._threads import apply as _apply_threads
from modalfem._threads import chunk_bounds, chunk_count

#: vertices per chunk of the parallel loops (fewer chunks than threads on small cloths: a parallel
#: launch costs more than a few hundred vertices' work)
CHUNK = 256

#: weight of the aggregation levels' corrections against the fine block Jacobi in the additive
#: preconditioner (the piecewise-constant corrections of the overlapping levels add up and over-correct
#: smooth errors). Mean CG iterations of the last 12 solves of a run at weights 1 / 0.7 / 0.5 / 0.3:
#: pile 64x64 (25 steps) 62.2 / 57.9 / 55.1 / 53.4, twist 64x64 without collisions (10) 22.2 / 21.9 /
#: 22.0 / 24.8, drape 128x128 (12) 20.5 / 20.7 / 21.2 / 23.8, pile 128x128 (12) 73.1 / 71.5 / 70.7 / 76.4
COARSE_WEIGHT = 0.5

#: most chunks of ``level_matrices`` (each sums into its own copy of the level matrices, added at the end)
LEVEL_CHUNKS = 4

__all__ = ["aggregate", "bsr_matvec", "gather_stiffness", "level_matrices", "pcg", "scale_plus_diagonal",
           "scatter_blocks"]

_apply_threads()


@numba.njit(cache=True)
def _row_product(indptr, indices, data, x, i):
    """Block row ``i`` of ``A`` times ``x`` (n, 3): the three components of ``(A x)_i``."""
    a0 = 0.0
    a1 = 0.0
    a2 = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        j = indices[p]
        x0, x1, x2 = x[j, 0], x[j, 1], x[j, 2]
        a0 += data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
        a1 += data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
        a2 += data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
    return a0, a1, a2


@numba.njit(cache=True, parallel=True)
def bsr_matvec(indptr, indices, data, x, out):
    """``out = A x`` for block ``A`` and ``x``, ``out`` (n, 3) (chunks of rows in parallel)."""
    n = len(indptr) - 1
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            out[i, 0], out[i, 1], out[i, 2] = _row_product(indptr, indices, data, x, i)


@numba.njit(cache=True, parallel=True)
def gather_stiffness(indptr, mptr, moff, mblocks, bptr, bh, boff, w, g, out):
    """``out`` (nnzb, 3, 3) = the block matrix of the triangles' 9x9 blocks ``mblocks`` (m, 9, 9) plus the
    hinges' Gauss-Newton blocks ``w[h] g_a g_b^T`` (``w`` (h,), ``g`` (h, 12)), gathered per block: block
    ``p`` sums the triangle sub-blocks ``q`` in ``mptr[p]:mptr[p+1]`` (flat offset ``moff[q]`` of the
    sub-block's first entry in ``mblocks``; in triangle order), then the hinge sub-blocks ``q`` in
    ``bptr[p]:bptr[p+1]`` (hinge ``bh[q]``, flat offsets ``boff[q, 0]``, ``boff[q, 1]`` of ``g_a``, ``g_b``
    in ``g``; in hinge order): the additions of a serial scatter over the triangles then the hinges, in the
    same order, so the same bits, with the block rows in parallel chunks (``CHUNK`` vertices)."""
    n = len(indptr) - 1
    mb = mblocks.reshape(-1)
    gf = g.reshape(-1)
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for p in range(indptr[start], indptr[stop]):
            a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
            for q in range(mptr[p], mptr[p + 1]):
                o = moff[q]
                a00 += mb[o]
                a01 += mb[o + 1]
                a02 += mb[o + 2]
                a10 += mb[o + 9]
                a11 += mb[o + 10]
                a12 += mb[o + 11]
                a20 += mb[o + 18]
                a21 += mb[o + 19]
                a22 += mb[o + 20]
            for q in range(bptr[p], bptr[p + 1]):
                wh = w[bh[q]]
                oa = boff[q, 0]
                ob = boff[q, 1]
                g0, g1, g2 = gf[ob], gf[ob + 1], gf[ob + 2]
                t = wh * gf[oa]
                a00 += t * g0
                a01 += t * g1
                a02 += t * g2
                t = wh * gf[oa + 1]
                a10 += t * g0
                a11 += t * g1
                a12 += t * g2
                t = wh * gf[oa + 2]
                a20 += t * g0
                a21 += t * g1
                a22 += t * g2
            out[p, 0, 0] = a00
            out[p, 0, 1] = a01
            out[p, 0, 2] = a02
            out[p, 1, 0] = a10
            out[p, 1, 1] = a11
            out[p, 1, 2] = a12
            out[p, 2, 0] = a20
            out[p, 2, 1] = a21
            out[p, 2, 2] = a22


@numba.njit(cache=True, parallel=True)
def scale_plus_diagonal(K, indptr, diag, scale, d, out):
    """``out = scale K + diag(d)`` for block matrices (nnzb, 3, 3) and ``d`` (n, 3) (block rows in parallel
    chunks; the same operations as ``K * scale`` then adding ``d`` on the diagonal)."""
    n = len(indptr) - 1
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for p in range(indptr[start], indptr[stop]):
            for r in range(3):
                for c in range(3):
                    out[p, r, c] = K[p, r, c] * scale
        for i in range(start, stop):
            for c in range(3):
                out[diag[i], c, c] += d[i, c]


@numba.njit(cache=True)
def scatter_blocks(data, maps, blocks, scale):
    """``data[maps[e, a, b]] += scale * blocks[e, 3a:3a+3, 3b:3b+3]`` for element blocks (m, 3k, 3k) and
    their block positions ``maps`` (m, k, k)."""
    m, k = maps.shape[0], maps.shape[1]
    for e in range(m):
        for a in range(k):
            for b in range(k):
                p = maps[e, a, b]
                for r in range(3):
                    for c in range(3):
                        data[p, r, c] += scale * blocks[e, 3 * a + r, 3 * b + c]


@numba.njit(cache=True)
def _project(kind, normal, i, u0, u1, u2):
    """``S_i u`` for the vertex ``i``."""
    if kind[i] == 0:
        return u0, u1, u2
    if kind[i] == 2:
        return 0.0, 0.0, 0.0
    n0, n1, n2 = normal[i, 0], normal[i, 1], normal[i, 2]
    d = n0 * u0 + n1 * u1 + n2 * u2
    return u0 - d * n0, u1 - d * n1, u2 - d * n2


@numba.njit(cache=True)
def _inverse3(D, out):
    """``out = D^-1`` for a 3x3 ``D`` (identity for a singular one)."""
    c00 = D[1, 1] * D[2, 2] - D[1, 2] * D[2, 1]
    c01 = D[1, 2] * D[2, 0] - D[1, 0] * D[2, 2]
    c02 = D[1, 0] * D[2, 1] - D[1, 1] * D[2, 0]
    det = D[0, 0] * c00 + D[0, 1] * c01 + D[0, 2] * c02
    scale = 0.0
    for r in range(3):
        for c in range(3):
            scale = max(scale, abs(D[r, c]))
    if not abs(det) > 1e-300 + 1e-14 * scale**3:
        for r in range(3):
            for c in range(3):
                out[r, c] = 1.0 if r == c else 0.0
        return
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (D[0, 2] * D[2, 1] - D[0, 1] * D[2, 2]) / det
    out[1, 1] = (D[0, 0] * D[2, 2] - D[0, 2] * D[2, 0]) / det
    out[2, 1] = (D[0, 1] * D[2, 0] - D[0, 0] * D[2, 1]) / det
    out[0, 2] = (D[0, 1] * D[1, 2] - D[0, 2] * D[1, 1]) / det
    out[1, 2] = (D[0, 2] * D[1, 0] - D[0, 0] * D[1, 2]) / det
    out[2, 2] = (D[0, 0] * D[1, 1] - D[0, 1] * D[1, 0]) / det


@numba.njit(cache=True, parallel=True)
def _preconditioner(data, diag, kind, normal):
    """(n, 3, 3) ``S_i B_i^-1 S_i`` with ``B_i`` the diagonal block, for a contact ``S D S + tr(D)/3 n n^T``
    (its inverse keeps range(S)). Chunks of vertices in parallel."""
    n = len(diag)
    P = np.zeros((n, 3, 3))
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        D = np.empty((3, 3))
        S = np.empty((3, 3))
        inv = np.empty((3, 3))
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            _preconditioner_block(data, diag, kind, normal, i, D, S, inv, P)
    return P


@numba.njit(cache=True)
def _preconditioner_block(data, diag, kind, normal, i, D, S, inv, P):
    """``P[i]`` of :func:`_preconditioner` (``D``, ``S``, ``inv``: 3x3 scratch)."""
    if kind[i] != 2:
        for a in range(3):
            for b in range(3):
                D[a, b] = data[diag[i], a, b]
        if kind[i] == 1:
            _projector(kind, normal, i, S)
            tr = (D[0, 0] + D[1, 1] + D[2, 2]) / 3.0
            _sandwich(S, D, inv)
            for a in range(3):
                for b in range(3):
                    D[a, b] = inv[a, b] + tr * normal[i, a] * normal[i, b]
            _inverse3(D, inv)
            _sandwich(S, inv, P[i])
        else:
            _inverse3(D, P[i])


@numba.njit(cache=True)
def _sandwich(S, D, out):
    """``out = S D S`` (3x3, S symmetric)."""
    for a in range(3):
        for b in range(3):
            t = 0.0
            for u in range(3):
                for v in range(3):
                    t += S[a, u] * D[u, v] * S[v, b]
            out[a, b] = t


@numba.njit(cache=True, parallel=True)
def _residual(indptr, indices, data, kind, normal, b, y, r):
    """``r = S (b - A y)``; returns ``|r|^2`` (chunks in parallel, partial sums added in chunk order)."""
    n = len(indptr) - 1
    chunks = chunk_count(n, CHUNK)
    part = np.zeros(chunks)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        rr = 0.0
        for i in range(start, stop):
            a0, a1, a2 = _row_product(indptr, indices, data, y, i)
            a0, a1, a2 = _project(kind, normal, i, b[i, 0] - a0, b[i, 1] - a1, b[i, 2] - a2)
            r[i, 0] = a0
            r[i, 1] = a1
            r[i, 2] = a2
            rr += a0 * a0 + a1 * a1 + a2 * a2
        part[ch] = rr
    return _sum(part)


@numba.njit(cache=True)
def _sum(part):
    """Sum in index order (the chunks' partial sums: the same order for every thread count)."""
    s = 0.0
    for v in part:
        s += v
    return s


@numba.njit(cache=True, parallel=True)
def _product(indptr, indices, data, kind, normal, c, q):
    """``q = S A c`` (c in range(S)); returns ``c . q`` (chunks in parallel, partial sums in chunk order)."""
    n = len(indptr) - 1
    chunks = chunk_count(n, CHUNK)
    part = np.zeros(chunks)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        cq = 0.0
        for i in range(start, stop):
            a0, a1, a2 = _row_product(indptr, indices, data, c, i)
            a0, a1, a2 = _project(kind, normal, i, a0, a1, a2)
            q[i, 0] = a0
            q[i, 1] = a1
            q[i, 2] = a2
            cq += c[i, 0] * a0 + c[i, 1] * a1 + c[i, 2] * a2
        part[ch] = cq
    return _sum(part)


@numba.njit(cache=True, parallel=True)
def _direction(c, z, beta):
    """``c = z + beta c`` (chunks of rows in parallel)."""
    n = len(c)
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            for a in range(3):
                c[i, a] = z[i, a] + beta * c[i, a]


@numba.njit(cache=True)
def aggregate(indptr, indices):
    """Greedy aggregation of a graph (CSR adjacency): each vertex not yet taken starts an aggregate with
    its untaken neighbours. Returns (aggregate of each vertex (n,), aggregate count)."""
    n = len(indptr) - 1
    agg = np.full(n, -1, np.int64)
    k = 0
    for i in range(n):
        if agg[i] >= 0:
            continue
        agg[i] = k
        for p in range(indptr[i], indptr[i + 1]):
            if agg[indices[p]] < 0:
                agg[indices[p]] = k
        k += 1
    return agg, k


@numba.njit(cache=True, parallel=True)
def level_matrices(indptr, indices, data, kind, normal, agg, up, off):
    """Galerkin matrices of the aggregation levels, ``P_l^T S A S P_l`` with ``P_l`` the piecewise-constant
    prolongation (3 translations per aggregate) of level ``l``: the aggregates of all levels are numbered
    together, level ``l`` from ``off[l]``; ``agg`` (n,): each vertex's level-0 aggregate, ``up`` (off[L-1],):
    each aggregate's parent on the next level. Returns the inverses (off[L-1], 3, 3) of the diagonal blocks
    of levels 0..L-2 and the full matrix (3 nc, 3 nc) of the coarsest level.

    The block rows run in ``LEVEL_CHUNKS`` (at most) parallel chunks fixed by the vertex count, each into
    its own sums, added in chunk order: the same bits on any thread count.

    A block singular because its vertices are constrained (``S P u = 0``) is inverted after adding
    ``1e-10 tr / 3`` to its diagonal (a zero one as the identity): restricted residuals have no component
    along such ``u`` and the prolongation removes it, so any generalised inverse gives the same result.
    """
    n = len(indptr) - 1
    L = len(off) - 1
    nd = off[L - 1]
    nc = off[L] - nd
    chunks = min(chunk_count(n, CHUNK), LEVEL_CHUNKS)
    Dp = np.zeros((chunks, nd, 3, 3))
    Cp = np.zeros((chunks, 3 * nc, 3 * nc))
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        _level_rows(indptr, indices, data, kind, normal, agg, up, nd, start, stop, Dp[ch], Cp[ch])
    D = Dp[0]
    C = Cp[0]
    for ch in range(1, chunks):
        D += Dp[ch]
        C += Cp[ch]
    Dinv = np.empty((nd, 3, 3))
    for g in range(nd):
        tr = (D[g, 0, 0] + D[g, 1, 1] + D[g, 2, 2]) / 3.0
        for a in range(3):
            D[g, a, a] += 1e-10 * tr
        _inverse3(D[g], Dinv[g])
    return Dinv, C


@numba.njit(cache=True)
def _level_rows(indptr, indices, data, kind, normal, agg, up, nd, start, stop, D, C):
    """The contributions of block rows ``start..stop-1`` to ``level_matrices``' D (nd, 3, 3) and C."""
    T = np.empty((3, 3))
    Si = np.empty((3, 3))
    Sj = np.empty((3, 3))
    for i in range(start, stop):
        if kind[i] == 2:
            continue
        _projector(kind, normal, i, Si)
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if kind[j] == 2:
                continue
            if kind[i] == 0 and kind[j] == 0:
                for a in range(3):
                    for b in range(3):
                        T[a, b] = data[p, a, b]
            else:
                _projector(kind, normal, j, Sj)
                for a in range(3):
                    for b in range(3):
                        t = 0.0
                        for u in range(3):
                            for v in range(3):
                                t += Si[a, u] * data[p, u, v] * Sj[v, b]
                        T[a, b] = t
            gi = agg[i]
            gj = agg[j]
            while gi < nd:  # up the levels while i and j share a block-Jacobi level's aggregate
                if gi == gj:
                    for a in range(3):
                        for b in range(3):
                            D[gi, a, b] += T[a, b]
                gi = up[gi]
                gj = up[gj]
            I = gi - nd
            J = gj - nd
            for a in range(3):
                for b in range(3):
                    C[3 * I + a, 3 * J + b] += T[a, b]


@numba.njit(cache=True)
def _projector(kind, normal, i, S):
    for a in range(3):
        for b in range(3):
            S[a, b] = (1.0 if a == b else 0.0) - (normal[i, a] * normal[i, b] if kind[i] == 1 else 0.0)


@numba.njit(cache=True)
def _precondition(P, r, z, kind, normal, agg, up, off, Dinv, Cinv, w, e):
    """``z = B r`` (block Jacobi plus the aggregation levels' corrections, additive); returns ``r . z``."""
    L = len(off) - 1
    if L > 0:
        _levels(r, r, 0.0, agg, up, off, Dinv, Cinv, w, e)
    return _fine(P, r, z, kind, normal, agg, e, L > 0)


@numba.njit(cache=True)
def _levels(r, q, alpha, agg, up, off, Dinv, Cinv, w, e):
    """The levels' correction ``e`` of the residual ``r - alpha q`` (formed here, the same bits as the update
    ``r -= alpha q`` gives): restriction to level 0 (the residual is in range(S)), up the levels, the coarsest
    solve and each level's block Jacobi, summed down the levels. Serial (a few thousand additions)."""
    n = len(r)
    L = len(off) - 1
    nd = off[L - 1]
    w.fill(0.0)
    for i in range(n):
        g = agg[i]
        w[g, 0] += r[i, 0] - alpha * q[i, 0]
        w[g, 1] += r[i, 1] - alpha * q[i, 1]
        w[g, 2] += r[i, 2] - alpha * q[i, 2]
    for g in range(nd):
        w[up[g], 0] += w[g, 0]
        w[up[g], 1] += w[g, 1]
        w[up[g], 2] += w[g, 2]
    nc3 = 3 * (off[L] - nd)
    for u in range(nc3):
        s = 0.0
        for v in range(nc3):
            s += Cinv[u, v] * w[nd + v // 3, v % 3]
        e[nd + u // 3, u % 3] = COARSE_WEIGHT * s
    for g in range(nd - 1, -1, -1):  # block Jacobi on each level, summed down the levels
        for a in range(3):
            e[g, a] = (COARSE_WEIGHT * (Dinv[g, a, 0] * w[g, 0] + Dinv[g, a, 1] * w[g, 1] + Dinv[g, a, 2] * w[g, 2])
                       + e[up[g], a])


@numba.njit(cache=True, parallel=True)
def _update_fine(y, r, c, q, alpha, P, z, kind, normal, agg, e, levels):
    """One pass of a CG iteration: ``y += alpha c``, ``r -= alpha q`` and the preconditioned residual ``z``
    (``_fine``, with the levels' correction ``e`` of the updated ``r``); returns ``(|r|^2, r . z)`` (chunks in
    parallel, partial sums in chunk order; the same bits as ``_update`` then ``_fine``)."""
    n = len(r)
    chunks = chunk_count(n, CHUNK)
    part_rr = np.zeros(chunks)
    part_rz = np.zeros(chunks)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        rr = 0.0
        rz = 0.0
        for i in range(start, stop):
            for a in range(3):
                y[i, a] += alpha * c[i, a]
                r[i, a] -= alpha * q[i, a]
                rr += r[i, a] * r[i, a]
            rz = _fine_row(P, r, z, kind, normal, agg, e, levels, i, rz)
        part_rr[ch] = rr
        part_rz[ch] = rz
    return _sum(part_rr), _sum(part_rz)


@numba.njit(cache=True, inline="always")
def _fine_row(P, r, z, kind, normal, agg, e, levels, i, rz):
    """Row ``i`` of ``_fine``; returns ``rz`` plus its terms of ``r . z``."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    if levels:
        g = agg[i]
        s0, s1, s2 = _project(kind, normal, i, e[g, 0], e[g, 1], e[g, 2])
    for a in range(3):
        t = P[i, a, 0] * r[i, 0] + P[i, a, 1] * r[i, 1] + P[i, a, 2] * r[i, 2]
        t += s0 if a == 0 else (s1 if a == 1 else s2)
        z[i, a] = t
        rz += r[i, a] * t
    return rz


@numba.njit(cache=True, parallel=True)
def _fine(P, r, z, kind, normal, agg, e, levels):
    """``z = P r`` plus the projected prolongation of the levels' correction ``e`` (when ``levels``);
    returns ``r . z`` (chunks in parallel, partial sums in chunk order)."""
    n = len(r)
    chunks = chunk_count(n, CHUNK)
    part = np.zeros(chunks)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        rz = 0.0
        for i in range(start, stop):  # block Jacobi plus the projected prolongation
            rz = _fine_row(P, r, z, kind, normal, agg, e, levels, i, rz)
        part[ch] = rz
    return _sum(part)


@numba.njit(cache=True)
def pcg(indptr, indices, data, diag, kind, normal, b, y, rtol, maxiter, agg, up, off, Dinv, Cinv):
    """Solve ``A y = b`` on the free components (filtered PCG).

    The preconditioner adds to block Jacobi (the inverses of the vertices' diagonal blocks, projected)
    the corrections of aggregation levels (additive multilevel, weighted by ``COARSE_WEIGHT``):
    ``S P_l D_l^+ P_l^T S`` for levels 0..L-2 (``D_l`` the diagonal blocks of the level's Galerkin
    matrix) and ``S P_c C^+ P_c^T S`` for the coarsest (its full matrix); ``L`` = 0 is block Jacobi
    alone.

    Args:
        indptr, indices, data: the SPD block matrix ``A``; ``diag`` (n,): position of each diagonal block.
        kind, normal: the constraints (module docstring).
        b: right-hand side (n, 3).
        y: (n, 3), updated in place: on entry the start, whose constrained components are the prescribed
            ones (they are kept); on exit the solution.
        rtol: relative residual: stop when ``|S (b - A y)| <= rtol |b'|``, ``b'`` the right-hand side of
            the system with the constrained components eliminated (handle rows replaced by identity rows):
            ``S (b - A z)`` plus the handles' prescribed values, ``z`` = ``y`` at entry with its free
            components zeroed.
        maxiter: iteration cap.
        agg, up, off: the levels (``level_matrices``); ``off`` = [0] for none.
        Dinv: (off[L-1], 3, 3) inverses of the levels' diagonal blocks (``level_matrices``).
        Cinv: (3 nc, 3 nc) inverse of the coarsest matrix.

    Returns:
        (iterations, relative residual reached); iterations = -1 if ``maxiter`` was not enough.
    """
    n = len(diag)
    r = np.empty((n, 3))
    z = np.empty((n, 3))
    c = np.empty((n, 3))
    q = np.empty((n, 3))
    w = np.empty((off[-1], 3))
    e = np.empty((off[-1], 3))
    for i in range(n):  # z: the constrained part of the start
        u0, u1, u2 = _project(kind, normal, i, y[i, 0], y[i, 1], y[i, 2])
        z[i, 0] = y[i, 0] - u0
        z[i, 1] = y[i, 1] - u1
        z[i, 2] = y[i, 2] - u2
    nb2 = _residual(indptr, indices, data, kind, normal, b, z, r)
    for i in range(n):  # the prescribed values of the handles count in the right-hand side's norm
        if kind[i] == 2:
            nb2 += z[i, 0] ** 2 + z[i, 1] ** 2 + z[i, 2] ** 2
    nb = np.sqrt(nb2)
    if nb == 0.0:
        for i in range(n):
            for a in range(3):
                y[i, a] = z[i, a]
        return 0, 0.0
    rn = np.sqrt(_residual(indptr, indices, data, kind, normal, b, y, r))
    if rn <= rtol * nb:
        return 0, rn / nb
    P = _preconditioner(data, diag, kind, normal)
    rz = _precondition(P, r, c, kind, normal, agg, up, off, Dinv, Cinv, w, e)
    levels = len(off) > 1
    # three parallel passes per iteration: q = S A c (c is in range(S)) and c . q; then (after the levels'
    # correction of r - alpha q, serial) y += alpha c, r -= alpha q, |r|^2 with z = B r and r . z in one pass;
    # c = z + beta c. The arithmetic of the four-pass order (product, update, preconditioner, direction)
    # Tried and dropped (64x64 pile's smoothing system, 4096 vertices, 30 iterations; fastest of 200 interleaved
    # calls, Intel Xeon, machine loaded (load ~7), so one-thread figures only): the direction formed inside the
    # product (each block forming its neighbour's z + beta c, a second buffer for c; the same bits), saving a
    # pass of ~9 us (1 and 2 threads alike on the loaded machine; an empty parallel region costs 1.5-1.9 us
    # called from Python, tbb): product + direction 181 + 9 -> 247 us,
    # the product being bound by arithmetic here, not memory; the level-0 restriction as a parallel pass over
    # the aggregates (each one's vertices in increasing order: the same bits): the levels' correction 23.5 ->
    # 27.3 us on one thread (the pass 13.6 us, about what the serial scatter cost).
    for k in range(1, maxiter + 1):
        cq = _product(indptr, indices, data, kind, normal, c, q)
        if not cq > 0.0:
            return -1, rn / nb
        alpha = rz / cq
        if levels:
            _levels(r, q, alpha, agg, up, off, Dinv, Cinv, w, e)
        rr, rz_new = _update_fine(y, r, c, q, alpha, P, z, kind, normal, agg, e, levels)
        rn = np.sqrt(rr)
        if rn <= rtol * nb:
            return k, rn / nb
        beta = rz_new / rz
        rz = rz_new
        _direction(c, z, beta)
    return -1, rn / nb
