"""Filtered conjugate gradients preconditioned by symmetric block Gauss-Seidel (SGS), with Eisenstat's trick
(numba, compiled on first call, cached). Same matrices, constraints and stopping rule as
:func:`modalfem.cloth._kernels.pcg` (see that module's docstring).

With the constrained system ``A' = S A S`` on range(S) split into its block parts ``A' = L + D + L^T`` (``D`` the
projected 3x3 diagonal blocks, ``L`` the blocks below the diagonal in vertex order), the SGS preconditioner is
``M = (D + L) D^-1 (D + L^T)``. CG preconditioned by ``M`` is CG on ``Abar = (D + L)^-1 A' (D + L^T)^-1`` (symmetric)
preconditioned by ``D``, and Eisenstat's trick makes its product cost one matrix pass instead of two
(``A' = (D + L) + (D + L^T) - D``): ``Abar c = t + (D + L)^-1 (c - D t)`` with ``t = (D + L^T)^-1 c`` (a backward
sweep over the blocks above the diagonal, then a forward sweep over those below). The solve works on the
correction ``e`` of the start ``y``: ``rbar = (D + L)^-1 S (b - A y)``, ``e = (D + L^T)^-1 xbar``.

The transformed residual ``rbar`` is not the residual ``S (b - A y)`` of the stopping rule (that is
``(D + L) rbar``, another half pass per iteration): its norm times the ratio of the two norms seen so far
predicts the true one, and the true residual is computed (one backward sweep and one product) only when the
prediction says converged; the solve stops when the true residual does. So the stopping rule is
``_kernels.pcg``'s exactly.

The iteration is Chronopoulos and Gear's (1989) form of CG: both inner products (``rbar . u`` and ``u . Abar u``,
``u = D rbar``) come after the one product, and the vector updates (direction, ``Abar`` of it, ``xbar``, ``rbar``)
are done row by row where the next product's backward sweep reaches each row (``_cg_sweeps``): one group of parallel
loops per iteration (``2 colours - 1`` loops), where the textbook order needed a separate pass over the vectors
after the product (one more parallel loop, and the vectors read again). The same iterations in exact arithmetic;
on the 64x64 pile's step-61/62 implicit systems the same iteration counts (35, 34), solutions within 8e-15 of the
textbook order's (relative to their largest entry), and a solve 12.86 -> 11.97 ms on one thread (CPU, fastest of 30
interleaved, Intel Xeon, load ~5); with two threads one parallel launch less per iteration (4 -> 3): measured only
while this process got both cores (400 such moments, both orders and thread counts interleaved, fastest of each,
Intel Xeon) 12.05 / 8.02 ms (1 / 2 threads, 1.50x) before, 11.30 / 6.81 ms (1.66x) after.

Why: block SGS propagates a correction across the whole sheet in one sweep, which block Jacobi plus the additive
aggregation levels cannot: on the 64x64 pile's step-60 systems CG takes 31 iterations instead of 51 (implicit step,
1e-4) and 18 instead of 28 (smoothing, 0.1), for about the cost of one matrix product per iteration as before, and
without the levels' setup (their Galerkin matrices and coarse inverse, twice per step).

Sweep orders (``SweepOrder``): in vertex order a sweep is serial (splitting it into chunks that ignore each
other's blocks, block Jacobi between chunks, lost the gain: 44-48 iterations with 4-16 chunks). A multicolour
order keeps the coupling between chunks and lets the uncoupled ones run in parallel: the sweeps go colour by
colour, and the tasks of one colour (sets of rows no block couples) run in parallel, each task's rows in order.
"colours" colours the vertex graph greedily (7 colours on a triangle mesh with its hinges; each colour's vertices
in chunks), "blocks" colours groups of ``GROUP`` consecutive vertices (two colours of stripes on a grid) and keeps
vertex order inside a group. Either is a symmetric permutation ``Pi A Pi^T``, so the splitting ``L + D + L^T`` and
Eisenstat's trick hold unchanged in the new order; the solve gathers the matrix into it (one pass). The tasks and
their order depend on the pattern only, and the dot products add per-task (per-chunk) partial sums in task order,
so a solve gives the same bits on any number of threads. On the 64x64 pile's step-60 implicit system (1e-4): 31
iterations in vertex order, 32 in "blocks", 39 in "colours" (a sweep in vertex order carries a correction across
the whole sheet, one in a vertex multicolour order at most as many vertices far as there are colours; "blocks" keeps the
long reach inside each group).
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem._threads import chunk_bounds, chunk_count
from modalfem.cloth._kernels import CHUNK, _preconditioner, _project, _residual, _sum
from modalfem.errors import InputError

__all__ = ["ORDERS", "SweepOrder", "greedy_colours", "pcg_sgs", "pcg_sgs_ordered"]

#: a start (the caller's warm start) is dropped for the prescribed part alone when its residual is more than this
#: times the prescribed part's. The last step's velocity change has a larger residual than none in most steps (64x64
#: pile: residual ratio median 1.35, 90 % 2.1, largest 9.4; drape 64x64 median 1.30, 90 % 2.0) because its error
#: lies in stiff, quickly damped components, yet CG from it takes fewer iterations: with the rule "no worse than
#: none" (ratio 1) the pile's warm start was dropped in every step (the same iterations and bits as no warm start).
#: The same implicit systems of a pile run (steps 1-79) solved from the kept start and from none: 38.3 against 39.5
#: iterations per step (fewer in 45 steps, more in 15), 18.2 against 19.2 ms per solve (one thread, CPU, fastest of
#: 3, Intel Xeon, load 3); drape 64x64 (steps 1-99): 36.0 against 39.2 (fewer in 83 steps, more in 4). A start of
#: 1e17 times the right-hand side's residual (a smoothing's warm start against a change of rounding size) is still
#: dropped.
WARM_START_RATIO = 2.0

#: floating-point freedoms of the sweeps: reassociation and fused multiply-adds (no assumptions about NaN or
#: infinity); they let LLVM vectorise the 3x3 block products: a sweep over the 64x64 pile's ~20k blocks on one
#: side of the diagonal 141 -> 100 us
_FAST = {"reassoc", "contract"}


@numba.njit(cache=True, inline="always", fastmath=_FAST)
def _upper_row(indptr, indices, data, diag, P, rhs, t, z, beta, direction, i):
    """Row ``i`` of the backward sweep (``_backward``)."""
    if direction:
        for a in range(3):
            rhs[i, a] = z[i, a] + beta * rhs[i, a]
    s0 = rhs[i, 0]
    s1 = rhs[i, 1]
    s2 = rhs[i, 2]
    for p in range(diag[i] + 1, indptr[i + 1]):
        j = indices[p]
        x0, x1, x2 = t[j, 0], t[j, 1], t[j, 2]
        s0 -= data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
        s1 -= data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
        s2 -= data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
    for a in range(3):
        t[i, a] = P[i, a, 0] * s0 + P[i, a, 1] * s1 + P[i, a, 2] * s2


@numba.njit(cache=True, inline="always", fastmath=_FAST)
def _lower_row(indptr, indices, data, diag, P, rhs, t, u, q, with_t, i):
    """Row ``i`` of the forward sweep (``_forward``); returns its term of ``rhs . q`` (0 without ``t``)."""
    s0 = rhs[i, 0]
    s1 = rhs[i, 1]
    s2 = rhs[i, 2]
    for p in range(indptr[i], diag[i]):
        j = indices[p]
        x0, x1, x2 = u[j, 0], u[j, 1], u[j, 2]
        s0 -= data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
        s1 -= data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
        s2 -= data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
    if with_t:
        d = diag[i]
        x0, x1, x2 = t[i, 0], t[i, 1], t[i, 2]
        s0 -= data[d, 0, 0] * x0 + data[d, 0, 1] * x1 + data[d, 0, 2] * x2
        s1 -= data[d, 1, 0] * x0 + data[d, 1, 1] * x1 + data[d, 1, 2] * x2
        s2 -= data[d, 2, 0] * x0 + data[d, 2, 1] * x1 + data[d, 2, 2] * x2
    for a in range(3):
        u[i, a] = P[i, a, 0] * s0 + P[i, a, 1] * s1 + P[i, a, 2] * s2
    cq = 0.0
    if with_t:
        for a in range(3):
            q[i, a] = t[i, a] + u[i, a]
            cq += rhs[i, a] * q[i, a]
    return cq


@numba.njit(cache=True, parallel=True, fastmath=_FAST)
def _backward(indptr, indices, data, diag, P, rhs, t, z, beta, direction, cptr, tptr):
    """``t = (D + L^T)^-1 rhs`` (``rhs`` in range(S)): colours from last to first, the tasks of one colour in
    parallel, each task's rows from last to first, the blocks right of the diagonal; ``P`` the projected inverses
    of the diagonal blocks (``_kernels._preconditioner``). With ``direction``, ``rhs`` is first updated to
    ``z + beta rhs`` row by row (CG's new search direction)."""
    for c in range(len(cptr) - 2, -1, -1):
        for k in numba.prange(cptr[c], cptr[c + 1]):
            for i in range(tptr[k + 1] - 1, tptr[k] - 1, -1):
                _upper_row(indptr, indices, data, diag, P, rhs, t, z, beta, direction, i)


@numba.njit(cache=True, parallel=True, fastmath=_FAST)
def _forward(indptr, indices, data, diag, P, rhs, t, u, q, with_t, cptr, tptr):
    """``u = (D + L)^-1 rhs`` (``with_t`` False), or (True: ``Abar rhs`` given ``t = (D + L^T)^-1 rhs``)
    ``u = (D + L)^-1 (rhs - D t)`` and ``q = t + u``, returning ``rhs . q`` (per task, added in task order);
    colours from first to last, the tasks of one colour in parallel, each task's rows from first to last, the
    blocks left of the diagonal."""
    part = np.zeros(len(tptr) - 1)
    for c in range(len(cptr) - 1):
        for k in numba.prange(cptr[c], cptr[c + 1]):
            cq = 0.0
            for i in range(tptr[k], tptr[k + 1]):
                cq += _lower_row(indptr, indices, data, diag, P, rhs, t, u, q, with_t, i)
            part[k] = cq
    return _sum(part)


@numba.njit(cache=True, inline="always", fastmath=_FAST)
def _cg_row(indptr, indices, data, diag, P, kind, normal, u, t, p, v, q, xb, rb, alpha, beta, update, i):
    """Row ``i`` of ``_cg_sweeps``' backward sweep: with ``update`` first CG's row-local step (``p = u + beta p``,
    ``v = q + beta v``, ``xb += alpha p``, ``rb -= alpha v``), then ``u = D rb`` (projected) and ``t_i`` of
    ``t = (D + L^T)^-1 u``; returns the row's terms of ``rb . u`` and ``|rb|^2``."""
    if update:
        for a in range(3):
            p[i, a] = u[i, a] + beta * p[i, a]
            v[i, a] = q[i, a] + beta * v[i, a]
            xb[i, a] += alpha * p[i, a]
            rb[i, a] -= alpha * v[i, a]
    d = diag[i]
    x0, x1, x2 = rb[i, 0], rb[i, 1], rb[i, 2]
    a0 = data[d, 0, 0] * x0 + data[d, 0, 1] * x1 + data[d, 0, 2] * x2
    a1 = data[d, 1, 0] * x0 + data[d, 1, 1] * x1 + data[d, 1, 2] * x2
    a2 = data[d, 2, 0] * x0 + data[d, 2, 1] * x1 + data[d, 2, 2] * x2
    a0, a1, a2 = _project(kind, normal, i, a0, a1, a2)
    u[i, 0] = a0
    u[i, 1] = a1
    u[i, 2] = a2
    _upper_row(indptr, indices, data, diag, P, u, t, u, 0.0, False, i)
    return x0 * a0 + x1 * a1 + x2 * a2, x0 * x0 + x1 * x1 + x2 * x2


@numba.njit(cache=True, parallel=True, fastmath=_FAST)
def _cg_sweeps(indptr, indices, data, diag, P, kind, normal, u, t, f, q, p, v, xb, rb, alpha, beta, update, cptr,
               tptr):
    """One CG iteration in the sweeps (Chronopoulos and Gear's order: both inner products after one product):
    (with ``update``) each row's step ``p = u + beta p``, ``v = q + beta v``, ``xb += alpha p``, ``rb -= alpha v``,
    then ``u = D rb`` and ``q = Abar u`` by Eisenstat's trick (``t = (D + L^T)^-1 u``, ``f = (D + L)^-1 (u - D t)``,
    ``q = t + f``), each row's step done where the backward sweep reaches it. Returns ``(rb . u, |rb|^2, u . q)``
    (per task, added in task order). The loops as ``_backward`` then ``_forward``, the first colour's tasks doing
    both (a task's forward rows need only its own and earlier colours' results): ``2 colours - 1`` parallel loops
    per iteration, where the two-pass order (product, then update and preconditioner) took ``2 colours``."""
    nc = len(cptr) - 1
    nt = len(tptr) - 1
    pru = np.zeros(nt)
    prr = np.zeros(nt)
    puq = np.zeros(nt)
    for col in range(nc - 1, 0, -1):
        for k in numba.prange(cptr[col], cptr[col + 1]):
            ru = 0.0
            rr = 0.0
            for i in range(tptr[k + 1] - 1, tptr[k] - 1, -1):
                a, b = _cg_row(indptr, indices, data, diag, P, kind, normal, u, t, p, v, q, xb, rb, alpha, beta, update,
                               i)
                ru += a
                rr += b
            pru[k] = ru
            prr[k] = rr
    for k in numba.prange(cptr[0], cptr[1]):
        ru = 0.0
        rr = 0.0
        for i in range(tptr[k + 1] - 1, tptr[k] - 1, -1):
            a, b = _cg_row(indptr, indices, data, diag, P, kind, normal, u, t, p, v, q, xb, rb, alpha, beta, update, i)
            ru += a
            rr += b
        pru[k] = ru
        prr[k] = rr
        uq = 0.0
        for i in range(tptr[k], tptr[k + 1]):
            uq += _lower_row(indptr, indices, data, diag, P, u, t, f, q, True, i)
        puq[k] = uq
    for col in range(1, nc):
        for k in numba.prange(cptr[col], cptr[col + 1]):
            uq = 0.0
            for i in range(tptr[k], tptr[k + 1]):
                uq += _lower_row(indptr, indices, data, diag, P, u, t, f, q, True, i)
            puq[k] = uq
    return _sum(pru), _sum(prr), _sum(puq)


@numba.njit(cache=True)
def _handles2(kind, z):
    """The squared norm of the handles' prescribed values (part of ``|b'|^2``)."""
    s = 0.0
    for i in range(len(kind)):
        if kind[i] == 2:
            s += z[i, 0] ** 2 + z[i, 1] ** 2 + z[i, 2] ** 2
    return s


@numba.njit(cache=True)
def pcg_sgs(indptr, indices, data, diag, kind, normal, b, y, rtol, maxiter):
    """``pcg_sgs_ordered`` in vertex order (one colour, one serial task): the natural-order SGS CG."""
    cptr = np.array([0, 1], dtype=np.int64)
    tptr = np.array([0, len(diag)], dtype=np.int64)
    return pcg_sgs_ordered(indptr, indices, data, diag, kind, normal, b, y, rtol, maxiter, cptr, tptr)


@numba.njit(cache=True)
def pcg_sgs_ordered(indptr, indices, data, diag, kind, normal, b, y, rtol, maxiter, cptr, tptr):
    """Solve ``A y = b`` on the free components (filtered PCG, SGS preconditioner; module docstring).

    Args and returns as :func:`modalfem.cloth._kernels.pcg` without the levels, plus the sweeps' tasks
    (``SweepOrder``: ``cptr`` (colours + 1,) the tasks of each colour, ``tptr`` (tasks + 1,) each task's rows):
    ``y`` (n, 3) updated in place
    (on entry the start, whose constrained components are kept); returns (iterations, relative residual
    reached), iterations = -1 if ``maxiter`` was not enough. ``|S (b - A y)| <= rtol |b'|`` holds on return
    (it is computed, not predicted).
    """
    n = len(diag)
    r = np.empty((n, 3))
    z = np.empty((n, 3))
    for i in range(n):  # z: the constrained part of the start
        u0, u1, u2 = _project(kind, normal, i, y[i, 0], y[i, 1], y[i, 2])
        z[i, 0] = y[i, 0] - u0
        z[i, 1] = y[i, 1] - u1
        z[i, 2] = y[i, 2] - u2
    rz2 = _residual(indptr, indices, data, kind, normal, b, z, r)  # r: the residual of the start z
    nb = np.sqrt(rz2 + _handles2(kind, z))  # the prescribed values of the handles count in |b'|
    if nb == 0.0:
        for i in range(n):
            for a in range(3):
                y[i, a] = z[i, a]
        return 0, 0.0
    w = np.empty((n, 3))
    rn = np.sqrt(_residual(indptr, indices, data, kind, normal, b, y, w))
    if rn > WARM_START_RATIO * np.sqrt(rz2):  # a start much worse than none (e.g. a warm start against a
        rn = np.sqrt(rz2)  # right-hand side near 0): start from the prescribed part
        for i in range(n):
            for a in range(3):
                y[i, a] = z[i, a]
    else:
        for i in range(n):
            for a in range(3):
                r[i, a] = w[i, a]
    goal = rtol * nb
    if rn <= goal:
        return 0, rn / nb
    P = _preconditioner(data, diag, kind, normal)
    rb = np.empty((n, 3))
    xb = np.zeros((n, 3))
    u = np.empty((n, 3))
    t = np.empty((n, 3))
    f = np.empty((n, 3))
    q = np.empty((n, 3))
    p = np.zeros((n, 3))
    v = np.zeros((n, 3))
    _forward(indptr, indices, data, diag, P, r, t, rb, q, False, cptr, tptr)  # rbar = (D + L)^-1 r
    gamma, rb2, delta = _cg_sweeps(indptr, indices, data, diag, P, kind, normal, u, t, f, q, p, v, xb, rb, 0.0, 0.0,
                                   False, cptr, tptr)  # u = D rbar, q = Abar u
    if not (rb2 > 0.0 and delta > 0.0):
        return -1, rn / nb
    ratio = rn / np.sqrt(rb2)  # |true residual| / |rbar|, updated at every check
    alpha = gamma / delta
    beta = 0.0
    for k in range(1, maxiter + 1):
        # xbar, rbar after k steps; u = D rbar and q = Abar u for the next
        gamma_new, rb2, delta = _cg_sweeps(indptr, indices, data, diag, P, kind, normal, u, t, f, q, p, v, xb, rb,
                                           alpha, beta, True, cptr, tptr)
        if np.sqrt(rb2) * ratio <= goal or k == maxiter:  # predicted converged: compute the true residual
            _backward(indptr, indices, data, diag, P, xb, t, f, 0.0, False, cptr, tptr)  # e = (D + L^T)^-1 xbar
            for i in range(n):
                for a in range(3):
                    w[i, a] = y[i, a] + t[i, a]
            rn = np.sqrt(_residual(indptr, indices, data, kind, normal, b, w, r))
            if rn <= goal:
                for i in range(n):
                    for a in range(3):
                        y[i, a] = w[i, a]
                return k, rn / nb
            if not rb2 > 0.0:
                return -1, rn / nb
            ratio = rn / np.sqrt(rb2)
        beta = gamma_new / gamma
        den = delta - beta * gamma_new / alpha
        if not den > 0.0:
            return -1, rn / nb
        alpha = gamma_new / den
        gamma = gamma_new
    return -1, rn / nb


@numba.njit(cache=True)
def greedy_colours(indptr, indices, group, gptr, gverts):
    """Greedy colouring of the graph of vertex groups (groups ``g`` and ``h`` adjacent when a block couples a vertex
    of ``g`` with one of ``h``): groups in index order, each the smallest colour none of its coloured neighbours has.
    ``group`` (n,) each vertex's group, ``gverts[gptr[g]:gptr[g + 1]]`` group ``g``'s vertices. Returns (groups,)."""
    ng = len(gptr) - 1
    colour = np.full(ng, -1, np.int64)
    mark = np.full(ng + 1, -1, np.int64)
    for g in range(ng):
        for q in range(gptr[g], gptr[g + 1]):
            v = gverts[q]
            for p in range(indptr[v], indptr[v + 1]):
                h = group[indices[p]]
                if h != g and colour[h] >= 0:
                    mark[colour[h]] = g
        c = 0
        while mark[c] == g:
            c += 1
        colour[g] = c
    return colour


@numba.njit(cache=True, parallel=True)
def _gather_blocks(data, src, out):
    """``out[p] = data[src[p]]`` (blocks (nnzb, 3, 3); chunks in parallel)."""
    m = len(src)
    chunks = chunk_count(m, 8 * CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        for p in range(start, stop):
            q = src[p]
            for a in range(3):
                for b in range(3):
                    out[p, a, b] = data[q, a, b]


@numba.njit(cache=True, parallel=True)
def _to_order(perm, src, data, kind, normal, b, y, pdata, pkind, pnormal, pb, py):
    """The matrix (``_gather_blocks``), constraints, right-hand side and start in the new order (one parallel
    pass)."""
    _gather_blocks(data, src, pdata)
    n = len(perm)
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            j = perm[i]
            pkind[i] = kind[j]
            for a in range(3):
                pnormal[i, a] = normal[j, a]
                pb[i, a] = b[j, a]
                py[i, a] = y[j, a]


@numba.njit(cache=True, parallel=True)
def _shifted_to_order(perm, src, pdiag, K, scale, d, kind, normal, b, y, pdata, pkind, pnormal, pb, py):
    """``_to_order`` of the matrix ``scale K + diag(d)`` (``K`` (nnzb, 3, 3) in the pattern's order, ``d`` (n, 3) in
    vertex order, ``pdiag`` the diagonal blocks in the new order) formed on the way: the operations of
    ``_kernels.scale_plus_diagonal`` (product, then the diagonal added), so the same bits, in one pass."""
    m = len(src)
    chunks = chunk_count(m, 8 * CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        for p in range(start, stop):
            q = src[p]
            for a in range(3):
                for c in range(3):
                    pdata[p, a, c] = K[q, a, c] * scale
    n = len(perm)
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            j = perm[i]
            for c in range(3):
                pdata[pdiag[i], c, c] += d[j, c]
            pkind[i] = kind[j]
            for a in range(3):
                pnormal[i, a] = normal[j, a]
                pb[i, a] = b[j, a]
                py[i, a] = y[j, a]


@numba.njit(cache=True, parallel=True)
def _from_order(perm, py, y):
    """``y[perm] = py``."""
    n = len(perm)
    chunks = chunk_count(n, CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for i in range(start, stop):
            for a in range(3):
                y[perm[i], a] = py[i, a]


#: vertices per group of the block multicolour ordering (``SweepOrder("blocks")``)
GROUP = 256

#: the sweep orders: ``"natural"`` (vertex order, serial), ``"colours"`` (vertex multicolour), ``"blocks"`` (block
#: multicolour: groups of ``GROUP`` consecutive vertices coloured, natural order inside a group)
ORDERS = ("natural", "colours", "blocks")


class SweepOrder:
    """The order of the SGS sweeps for one block pattern (built once per pattern; independent of the thread count,
    so a solve gives the same bits on any).

    ``"natural"``: vertex order, one serial task. ``"colours"``: a greedy colouring of the vertex graph (vertices
    sharing a block get different colours); the sweeps go colour by colour, the vertices of one colour (uncoupled)
    in parallel chunks of ``CHUNK``. ``"blocks"``: the vertices cut into groups of ``GROUP`` consecutive indices,
    the groups' graph coloured greedily; the sweeps go colour by colour, the groups of a colour (uncoupled) in
    parallel, each group's vertices in order. Either is a symmetric permutation of the matrix, so the splitting
    ``L + D + L^T`` and Eisenstat's trick hold in the new order; the solve gathers the matrix into it.

    Attributes: ``perm`` (n,) new -> old vertex (None for "natural"), ``indptr``, ``indices``, ``diag`` the pattern
    in the new order, ``src`` (nnzb,) each new block's old position, ``cptr``/``tptr`` the colours' tasks and the
    tasks' rows, ``colours`` the number of colours.
    """

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, diag: np.ndarray, kind: str = "blocks"):
        if kind not in ORDERS:
            raise InputError(f"sweep order must be one of {', '.join(ORDERS)}, got {kind!r}")
        n = len(indptr) - 1
        self.kind = kind
        if kind == "natural":
            self.perm = None
            self.indptr, self.indices, self.diag = indptr, indices, diag
            self.cptr = np.array([0, 1], np.int64)
            self.tptr = np.array([0, n], np.int64)
            self.colours = 1
            return
        if kind == "colours":
            group = np.arange(n, dtype=np.int64)
        else:
            ng = max(1, n // GROUP)
            group = (np.arange(n, dtype=np.int64) * ng) // n
        ng = int(group[-1]) + 1 if n else 0
        gptr = np.searchsorted(group, np.arange(ng + 1)).astype(np.int64)
        gcol = greedy_colours(indptr, indices, group, gptr, np.arange(n, dtype=np.int64))
        vcol = gcol[group]
        perm = np.lexsort((np.arange(n), group, vcol)).astype(np.int64)  # by colour, then group, then index
        self.colours = int(gcol.max()) + 1 if n else 0
        csize = np.bincount(vcol, minlength=self.colours)
        cstart = np.concatenate([[0], np.cumsum(csize)])
        if kind == "colours":  # the uncoupled vertices of a colour in chunks
            counts = [chunk_count(int(s), CHUNK) for s in csize]
            tptr = [0]
            for c, k in enumerate(counts):
                tptr += [int(cstart[c]) + (j * int(csize[c])) // k for j in range(1, k + 1)]
            self.cptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        else:  # one task per group, the groups of a colour together
            gorder = np.lexsort((np.arange(ng), gcol))
            gsize = np.diff(gptr)[gorder]
            tptr = np.concatenate([[0], np.cumsum(gsize)])
            self.cptr = np.concatenate([[0], np.cumsum(np.bincount(gcol, minlength=self.colours))]).astype(np.int64)
        self.tptr = np.asarray(tptr, np.int64)
        inv = np.empty(n, np.int64)
        inv[perm] = np.arange(n)
        rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
        nr, nc = inv[rows], inv[indices]
        self.src = np.lexsort((nc, nr)).astype(np.int64)
        self.indices = np.ascontiguousarray(nc[self.src])
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(nr, minlength=n))]).astype(np.int64)
        self.diag = np.flatnonzero(nr[self.src] == self.indices).astype(np.int64)
        self.perm = perm

    def solve(self, data, kind, normal, b, y, rtol: float, maxiter: int):
        """``pcg_sgs_ordered`` in this order on the pattern's ``data`` (nnzb, 3, 3) with the constraints ``kind``,
        ``normal``, right-hand side ``b`` (n, 3) and start ``y`` (n, 3), updated in place, all in vertex order.
        Returns (iterations, relative residual)."""
        if self.perm is None:
            return pcg_sgs_ordered(self.indptr, self.indices, data, self.diag, kind, normal, b, y, rtol, maxiter,
                                   self.cptr, self.tptr)
        pdata, pkind, pnormal = np.empty_like(data), np.empty_like(kind), np.empty_like(normal)
        pb, py = np.empty_like(b), np.empty_like(y)
        _to_order(self.perm, self.src, data, kind, normal, b, y, pdata, pkind, pnormal, pb, py)
        out = pcg_sgs_ordered(self.indptr, self.indices, pdata, self.diag, pkind, pnormal, pb, py, rtol, maxiter,
                              self.cptr, self.tptr)
        _from_order(self.perm, py, y)
        return out

    def solve_shifted(self, K, scale: float, d, kind, normal, b, y, rtol: float, maxiter: int):
        """``solve`` with the matrix ``scale K + diag(d)`` (``K`` (nnzb, 3, 3) on the pattern, ``d`` (n, 3) in vertex
        order): in a multicolour order formed directly in it (one pass instead of forming it, then gathering it;
        the same bits as ``solve`` on ``_kernels.scale_plus_diagonal``'s matrix)."""
        if self.perm is None:
            from modalfem.cloth._kernels import scale_plus_diagonal

            data = np.empty_like(K)
            scale_plus_diagonal(K, self.indptr, self.diag, float(scale), d, data)
            return self.solve(data, kind, normal, b, y, rtol, maxiter)
        pdata, pkind, pnormal = np.empty_like(K), np.empty_like(kind), np.empty_like(normal)
        pb, py = np.empty_like(b), np.empty_like(y)
        _shifted_to_order(self.perm, self.src, self.diag, K, float(scale), d, kind, normal, b, y, pdata, pkind,
                          pnormal, pb, py)
        out = pcg_sgs_ordered(self.indptr, self.indices, pdata, self.diag, pkind, pnormal, pb, py, rtol, maxiter,
                              self.cptr, self.tptr)
        _from_order(self.perm, py, y)
        return out
