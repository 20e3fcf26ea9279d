"""Compiled conservative CCD (numba ``njit``, cached on disk): one query at a time, breadth-first
subdivision of [0, 1] with at most ``max_intervals`` live intervals. :mod:`modalfem.collision.ccd`
documents the method and its bounds; this module is its only implementation.

numba's disk cache does not notice edits of the other modules a kernel calls: after changing
:mod:`modalfem.collision._distance_kernels`, delete ``modalfem/collision/__pycache__``.

Tried for the pipeline's passes and dropped (64x64 pile, 154 recorded pipeline calls replayed, one thread,
CPU time, Intel Xeon, shared machine): (1) separation certificates kept with the pair store's blocks: each
tested pair's distance lower bound over the step (its trajectory-box gap, the coplanarity bound
``min |b| / (|e1| |e2|)`` of a separated pair, or the least bound of a query's discarded intervals) less its
vertices' deviation from reference trajectories (the step's first CCD), a pair skipped while that bound
less the current deviation exceeds ``eta`` (the distance moves by at most the vertices' displacement). It
skipped 67 % of the re-check's first-pass pairs, but the cheap ones (box or coplanarity rejects): that pass
5.1 -> 3.8 ms, while the flagged passes (pairs of vertices just given impulses) skipped 8-40 % and paid for
the bounds; CCD 30.3 -> 30.0 ms per step. (2) The box test reading one (N, 8) row of trajectory box and
movable flag per vertex instead of ``X0``, ``X1`` and ``movable``: 171 calls of the dense phase 425-438 ms
before, 416-445 after (fastest of 5 each, interleaved runs): not memory-bound.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba.core import types
from numba.extending import intrinsic

from modalfem._threads import apply as _apply_threads
from modalfem.collision._distance_kernels import edge_edge_lb, point_triangle_lb
from modalfem._threads import chunk_bounds, chunk_count

__all__ = ["ccd_batch", "ccd_block", "ccd_candidates", "ccd_segments", "diagonal_gap", "diagonal_intervals",
           "spread_order"]

_apply_threads()

#: relative rounding bound (times the coordinate scale) added to the tolerance [-]
ROUNDING = 1e-12


@numba.njit(cache=True, inline="always")
def _prologue(vf: bool, X0: np.ndarray, X1: np.ndarray, c0: int, c1: int, c2: int, c3: int, eta: float) -> tuple:
    """The depth-0 quantities of one query, vertices ``c0..c3`` of ``X0``/``X1`` (start/end (N, 3) [m]),
    in scalars (the common case, no sign change of the coplanarity function on [0, 1], ends here).

    Positions are taken relative to the query's first start vertex, displacements ``d = x1 - x0``.
    ``f(s) = det[e1(s), e2(s), e3(s)]`` (vertex-face det[b - a, c - a, p - a], edge-edge
    det[a1 - a0, b1 - b0, b0 - a0]) is expanded from ``(A0 + s dA) x (B0 + s dB) . (C0 + s dC)`` into its
    Bernstein coefficients on [0, 1].

    Returns:
        ``(b0, b1, b2, b3, eps, delta, scale)``: the coefficients, the threshold ``eps`` beyond which a
        control value proves no contact, ``delta = eta + rounding`` [m] and the coordinate scale [m].
    """
    ox, oy, oz = X0[c0, 0], X0[c0, 1], X0[c0, 2]
    t10, t11, t12 = X0[c1, 0] - ox, X0[c1, 1] - oy, X0[c1, 2] - oz
    t20, t21, t22 = X0[c2, 0] - ox, X0[c2, 1] - oy, X0[c2, 2] - oz
    t30, t31, t32 = X0[c3, 0] - ox, X0[c3, 1] - oy, X0[c3, 2] - oz
    d00, d01, d02 = X1[c0, 0] - ox, X1[c0, 1] - oy, X1[c0, 2] - oz
    d10, d11, d12 = X1[c1, 0] - X0[c1, 0], X1[c1, 1] - X0[c1, 1], X1[c1, 2] - X0[c1, 2]
    d20, d21, d22 = X1[c2, 0] - X0[c2, 0], X1[c2, 1] - X0[c2, 1], X1[c2, 2] - X0[c2, 2]
    d30, d31, d32 = X1[c3, 0] - X0[c3, 0], X1[c3, 1] - X0[c3, 1], X1[c3, 2] - X0[c3, 2]
    scale = max(abs(d00), abs(d01), abs(d02), abs(t10), abs(t11), abs(t12), abs(t20), abs(t21), abs(t22),
                abs(t30), abs(t31), abs(t32), abs(t10 + d10), abs(t11 + d11), abs(t12 + d12), abs(t20 + d20),
                abs(t21 + d21), abs(t22 + d22), abs(t30 + d30), abs(t31 + d31), abs(t32 + d32)) + 1e-300
    delta = eta + ROUNDING * scale
    if vf:  # e1 = b - a, e2 = c - a, e3 = p - a with (p, a, b, c) = vertices 0..3
        a0, a1, a2, p0, p1, p2 = t20 - t10, t21 - t11, t22 - t12, d20 - d10, d21 - d11, d22 - d12
        b0, b1, b2, q0, q1, q2 = t30 - t10, t31 - t11, t32 - t12, d30 - d10, d31 - d11, d32 - d12
        g0, g1, g2, h0, h1, h2 = -t10, -t11, -t12, d00 - d10, d01 - d11, d02 - d12
    else:  # e1 = a1 - a0, e2 = b1 - b0, e3 = b0 - a0 with (a0, a1, b0, b1) = vertices 0..3
        a0, a1, a2, p0, p1, p2 = t10, t11, t12, d10 - d00, d11 - d01, d12 - d02
        b0, b1, b2, q0, q1, q2 = t30 - t20, t31 - t21, t32 - t22, d30 - d20, d31 - d21, d32 - d22
        g0, g1, g2, h0, h1, h2 = t20, t21, t22, d20 - d00, d21 - d01, d22 - d02
    # |f| = |e1 x e2| * (distance of the point to the plane, or between the lines) <= |e1| |e2| dist; |e(s)|
    # is convex along the straight-line motion, so its largest value on [0, 1] is at an end
    s10 = a0 * a0 + a1 * a1 + a2 * a2
    s11 = (a0 + p0) * (a0 + p0) + (a1 + p1) * (a1 + p1) + (a2 + p2) * (a2 + p2)
    s20 = b0 * b0 + b1 * b1 + b2 * b2
    s21 = (b0 + q0) * (b0 + q0) + (b1 + q1) * (b1 + q1) + (b2 + q2) * (b2 + q2)
    eps = delta * (math.sqrt(max(s10, s11)) * math.sqrt(max(s20, s21)) * (1.0 + 1e-9)) + ROUNDING * 27.0 * scale ** 3
    # cross(A, B) = c0 + s c1 + s^2 c2
    x00, x01, x02 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    x10 = a1 * q2 - a2 * q1 + p1 * b2 - p2 * b1
    x11 = a2 * q0 - a0 * q2 + p2 * b0 - p0 * b2
    x12 = a0 * q1 - a1 * q0 + p0 * b1 - p1 * b0
    x20, x21, x22 = p1 * q2 - p2 * q1, p2 * q0 - p0 * q2, p0 * q1 - p1 * q0
    f0 = x00 * g0 + x01 * g1 + x02 * g2
    f1 = x00 * h0 + x01 * h1 + x02 * h2 + x10 * g0 + x11 * g1 + x12 * g2
    f2 = x10 * h0 + x11 * h1 + x12 * h2 + x20 * g0 + x21 * g1 + x22 * g2
    f3 = x20 * h0 + x21 * h1 + x22 * h2
    return f0, f0 + f1 / 3.0, f0 + (2.0 * f1 + f2) / 3.0, f0 + f1 + f2 + f3, eps, delta, scale


@numba.njit(cache=True, inline="always")
def _separated(vf: bool, X0: np.ndarray, X1: np.ndarray, c0: int, c1: int, c2: int, c3: int, eta: float) -> bool:
    """The common case, decided without :func:`_query`'s scratch arrays: the coplanarity function's control
    values on [0, 1] share a sign beyond ``eps`` (no coplanarity, no contact; ``_query`` would return inf)."""
    b0, b1, b2, b3, eps, _, _ = _prologue(vf, X0, X1, c0, c1, c2, c3, eta)
    return min(min(b0, b1), min(b2, b3)) > eps or max(max(b0, b1), max(b2, b3)) < -eps


@numba.njit(cache=True)
def _query(vf: bool, X0: np.ndarray, X1: np.ndarray, c0: int, c1: int, c2: int, c3: int, eta: float,
           max_depth: int, max_intervals: int, t0: np.ndarray, td: np.ndarray, x: np.ndarray, coef: np.ndarray,
           lo: np.ndarray, hi: np.ndarray, nlo: np.ndarray, nhi: np.ndarray) -> float:
    """Time of impact in [0, 1] of one query (vertices ``c0..c3`` of the start/end positions ``X0``/``X1``
    (N, 3) [m]), inf if none; the remaining arrays are scratch space (``lo``..``nhi`` of length >= 2
    ``max_intervals``)."""
    b0, b1, b2, b3, eps, delta, scale = _prologue(vf, X0, X1, c0, c1, c2, c3, eta)
    coef[0], coef[1], coef[2], coef[3] = b0, b1, b2, b3
    ids = (c0, c1, c2, c3)
    for v in range(4):
        for c in range(3):
            t0[v, c] = X0[ids[v], c] - X0[c0, c]
            td[v, c] = X1[ids[v], c] - X0[ids[v], c]
    d0 = math.sqrt(td[0, 0] ** 2 + td[0, 1] ** 2 + td[0, 2] ** 2)
    d1 = math.sqrt(td[1, 0] ** 2 + td[1, 1] ** 2 + td[1, 2] ** 2)
    d2 = math.sqrt(td[2, 0] ** 2 + td[2, 1] ** 2 + td[2, 2] ** 2)
    d3 = math.sqrt(td[3, 0] ** 2 + td[3, 1] ** 2 + td[3, 2] ** 2)
    lip = d0 + max(d1, d2, d3) if vf else max(d0, d1) + max(d2, d3)
    lip = lip * (1.0 + 1e-9) + ROUNDING * scale
    lo[0], hi[0] = 0.0, 1.0
    count = 1
    toi = math.inf
    for depth in range(max_depth + 1):
        kept = 0
        hit = False
        for k in range(count):
            a, b = lo[k], hi[k]
            if depth == 0:
                b0, b1, b2, b3 = coef[0], coef[1], coef[2], coef[3]
            else:
                # de Casteljau blossoms f(a, a, a), f(a, a, b), f(a, b, b), f(b, b, b)
                ma, mb = 1.0 - a, 1.0 - b
                l0, l1, l2 = ma * coef[0] + a * coef[1], ma * coef[1] + a * coef[2], ma * coef[2] + a * coef[3]
                ll0, ll1 = ma * l0 + a * l1, ma * l1 + a * l2
                r0, r1, r2 = mb * coef[0] + b * coef[1], mb * coef[1] + b * coef[2], mb * coef[2] + b * coef[3]
                rr0, rr1 = mb * r0 + b * r1, mb * r1 + b * r2
                b0, b1, b2, b3 = ma * ll0 + a * ll1, mb * ll0 + b * ll1, ma * rr0 + a * rr1, mb * rr0 + b * rr1
            # the cheap test first: control values of one sign beyond eps (no coplanarity, no contact)
            if min(min(b0, b1), min(b2, b3)) > eps or max(max(b0, b1), max(b2, b3)) < -eps:
                continue
            mid = 0.5 * (a + b)
            for v in range(4):
                for c in range(3):
                    x[v, c] = t0[v, c] + mid * td[v, c]
            lb = point_triangle_lb(x) if vf else edge_edge_lb(x)
            if lb <= delta:
                hit = True
                toi = min(toi, mid)
            elif not hit and lb <= delta + lip * (b - a) * 0.5:
                nlo[kept], nhi[kept] = a, b
                kept += 1
        if hit:
            return toi
        if kept == 0:
            return math.inf
        if depth == max_depth or kept > max_intervals:
            for k in range(kept):
                toi = min(toi, nlo[k])
            return toi
        for k in range(kept):
            a, b = nlo[k], nhi[k]
            m = 0.5 * (a + b)
            lo[2 * k], hi[2 * k] = a, m
            lo[2 * k + 1], hi[2 * k + 1] = m, b
        count = 2 * kept
    return toi


@numba.njit(cache=True)
def ccd_batch(vf: bool, x0: np.ndarray, x1: np.ndarray, eta: float, max_depth: int,
              max_intervals: int) -> np.ndarray:
    """Times of impact (k,) in [0, 1] (inf: no collision) of queries given by their start and end
    positions ``x0``/``x1`` (k, 4, 3) [m]: ``vf`` point-triangle (p, a, b, c), else edge-edge."""
    k = len(x0)
    toi = np.empty(k)
    t0, td, x = np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3))
    coef = np.empty(4)
    n = 2 * max_intervals + 2
    lo, hi, nlo, nhi = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for q in range(k):
        if _separated(vf, x0[q], x1[q], 0, 1, 2, 3, eta):
            toi[q] = math.inf
        else:
            toi[q] = _query(vf, x0[q], x1[q], 0, 1, 2, 3, eta, max_depth, max_intervals, t0, td, x, coef, lo, hi, nlo,
                            nhi)
    return toi


#: candidate pairs per chunk of :func:`ccd_candidates`
CCD_CHUNK = 256

#: vertices below which :func:`trajectory_diagonals` and :func:`diagonal_gap` run their chunks serially: ~11 and
#: ~9.5 ns per vertex on one thread (Intel Xeon, fastest of 7 x 300 calls, 4,096 and 16,384 vertices), so 8192
#: vertices are ~80-90 us, :data:`modalfem._threads.SERIAL_WORK_US` (the 64x64 pile's 4,096: serial)
SERIAL_VERTICES = 8192


@numba.njit(cache=True, inline="always")
def _project(out, i, a0, a1, a2, b0, b1, b2):
    """Row ``i`` of :func:`diagonal_intervals`: the segment from ``a`` to ``b`` on the four box diagonals."""
    p, q = a0 + a1 + a2, b0 + b1 + b2
    out[i, 0], out[i, 4] = min(p, q), max(p, q)
    p, q = a0 + a1 - a2, b0 + b1 - b2
    out[i, 1], out[i, 5] = min(p, q), max(p, q)
    p, q = a0 - a1 + a2, b0 - b1 + b2
    out[i, 2], out[i, 6] = min(p, q), max(p, q)
    p, q = a1 + a2 - a0, b1 + b2 - b0
    out[i, 3], out[i, 7] = min(p, q), max(p, q)


@numba.njit(cache=True, parallel=True)
def diagonal_intervals(X0: np.ndarray, X1: np.ndarray) -> np.ndarray:
    """Per vertex, its trajectory ``X0 -> X1`` ((N, 3) [m]) projected on the four box diagonals ``(1, 1, 1)``,
    ``(1, 1, -1)``, ``(1, -1, 1)``, ``(-1, 1, 1)`` (not normalised): (N, 8) rows ``lo_0..lo_3, hi_0..hi_3`` [m], one
    cache line a vertex. A straight-line motion projects onto an interval between its ends' projections, and a
    primitive (convex hull of its vertices) into the union of its vertices' intervals, at every time of the
    step. Chunks in parallel."""
    N = len(X0)
    out = np.empty((N, 8))
    chunks = chunk_count(N, 1024)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(N, chunks, ch)
        for i in range(start, stop):
            a0, a1, a2 = X0[i, 0], X0[i, 1], X0[i, 2]
            b0, b1, b2 = X1[i, 0], X1[i, 1], X1[i, 2]
            _project(out, i, a0, a1, a2, b0, b1, b2)
    return out


@numba.njit(cache=True, inline="always")
def _gap_of(part: np.ndarray, eta: float) -> float:
    """:func:`diagonal_gap` from the chunks' largest coordinates ``part`` (their maximum is the coordinate scale)."""
    scale = 0.0
    for ch in range(len(part)):
        scale = max(scale, part[ch])
    return eta * math.sqrt(3.0) * (1.0 + 1e-9) + ROUNDING * 3.0 * scale


@numba.njit(cache=True, parallel=True)
def diagonal_gap(X0: np.ndarray, X1: np.ndarray, eta: float) -> float:
    """The gap [m] between two primitives' projections on a diagonal of :func:`diagonal_intervals` beyond which
    they are farther apart than ``eta`` [m] throughout the step: ``eta * sqrt(3)`` (the diagonals' length),
    plus the rounding of the projections (a sum of three coordinates, a few ulps of the coordinate scale
    ``max |X0|, |X1|``: bounded here by ``ROUNDING`` times three times it, as in :func:`_prologue`). The maximum
    over chunks in parallel (a maximum is exact: the same answer for any thread count)."""
    N = len(X0)
    chunks = chunk_count(N, 1024)
    part = np.empty(chunks)  # every chunk writes its own (np.zeros would be a parallel region of its own)
    if N < SERIAL_VERTICES:  # the same chunks, serially: the region would not pay for the pool's wake-up
        for ch in range(chunks):
            start, stop = chunk_bounds(N, chunks, ch)
            part[ch] = _scale_range(X0, X1, start, stop)
    else:
        for ch in numba.prange(chunks):
            start, stop = chunk_bounds(N, chunks, ch)
            part[ch] = _scale_range(X0, X1, start, stop)
    return _gap_of(part, eta)


@numba.njit(cache=True, inline="always")
def _scale_range(X0: np.ndarray, X1: np.ndarray, start: int, stop: int) -> float:
    """The largest ``|X0|``, ``|X1|`` coordinate of the vertices ``start..stop-1``."""
    m = 0.0
    for i in range(start, stop):
        for c in range(3):
            m = max(m, abs(X0[i, c]), abs(X1[i, c]))
    return m


@numba.njit(cache=True, parallel=True)
def trajectory_diagonals(X0: np.ndarray, V: np.ndarray, dt: float, eta: float):
    """The CCD's per-call set-up in one parallel pass: the end positions ``X1 = X0 + dt V`` ((N, 3) [m]), their
    :func:`diagonal_intervals` and :func:`diagonal_gap` (the same floating-point operations, so the same bits as
    the three calls; the gap's maximum is over chunks, exact for any thread count)."""
    N = len(X0)
    X1 = np.empty((N, 3))
    out = np.empty((N, 8))
    chunks = chunk_count(N, 1024)
    part = np.empty(chunks)  # every chunk writes its own (np.zeros would be a parallel region of its own)
    if N < SERIAL_VERTICES:  # the same chunks, serially: the region would not pay for the pool's wake-up
        for ch in range(chunks):
            start, stop = chunk_bounds(N, chunks, ch)
            part[ch] = _trajectory_range(X0, V, dt, X1, out, start, stop)
    else:
        for ch in numba.prange(chunks):
            start, stop = chunk_bounds(N, chunks, ch)
            part[ch] = _trajectory_range(X0, V, dt, X1, out, start, stop)
    return X1, out, _gap_of(part, eta)


@numba.njit(cache=True, inline="always")
def _trajectory_range(X0, V, dt: float, X1, out, start: int, stop: int) -> float:
    """:func:`trajectory_diagonals` of the vertices ``start..stop-1``; returns their largest coordinate."""
    m = 0.0
    for i in range(start, stop):
        a0, a1, a2 = X0[i, 0], X0[i, 1], X0[i, 2]
        b0, b1, b2 = a0 + dt * V[i, 0], a1 + dt * V[i, 1], a2 + dt * V[i, 2]
        X1[i, 0], X1[i, 1], X1[i, 2] = b0, b1, b2
        m = max(m, abs(a0), abs(b0))
        m = max(m, abs(a1), abs(b1))
        m = max(m, abs(a2), abs(b2))
        _project(out, i, a0, a1, a2, b0, b1, b2)
    return m


@numba.njit(cache=True, inline="always")
def _diagonal_apart(vf: bool, diag: np.ndarray, c0: int, c1: int, c2: int, c3: int, gap: float) -> bool:
    """The two primitives' projections on one of :func:`diagonal_intervals`' diagonals are more than ``gap``
    apart (then their distance exceeds ``gap / sqrt(3)`` at every time of the step)."""
    apart = False
    for d in range(4):
        alo, ahi = diag[c0, d], diag[c0, 4 + d]
        blo, bhi = min(diag[c2, d], diag[c3, d]), max(diag[c2, 4 + d], diag[c3, 4 + d])
        if vf:
            blo, bhi = min(blo, diag[c1, d]), max(bhi, diag[c1, 4 + d])
        else:
            alo, ahi = min(alo, diag[c1, d]), max(ahi, diag[c1, 4 + d])
        apart = apart | (alo > bhi + gap) | (blo > ahi + gap)
    return apart


@numba.njit(cache=True)
def ccd_candidates(vf: bool, X0: np.ndarray, X1: np.ndarray, quads: np.ndarray, movable: np.ndarray,
                   roots: np.ndarray, eta: float, max_depth: int, max_intervals: int):
    """The pipeline's CCD of candidate pairs ``quads`` (k, 4) on trajectories ``X0 -> X1`` ((N, 3) [m]):
    pairs without a ``movable`` ((N,) bool) vertex, pairs inside one zone (all four ``roots`` ((N,) int,
    empty: no zones) equal) and pairs whose primitives' trajectory boxes are farther apart than ``eta``
    [m] are skipped; the others get :func:`ccd_batch`'s test. Chunks of pairs run in parallel
    (:mod:`modalfem._threads`); each query is independent, so the result does not depend on the thread count.

    Returns:
        ``(idx, toi)``: (h,) indices into ``quads`` of the colliding pairs (ascending) and their (h,) times
        in [0, 1].
    """
    none = np.zeros(0, dtype=np.bool_)
    return ccd_block(vf, X0, X1, quads, none, none, movable, roots, eta, max_depth, max_intervals,
                     diagonal_intervals(X0, X1), diagonal_gap(X0, X1, eta))


@numba.njit(cache=True)
def spread_order(chunks: int) -> np.ndarray:
    """(chunks,) the order in which a parallel loop visits its ``chunks`` chunks: the chunk indices by their
    bit-reversed value over the next power of two (0, 4, 2, 6, 1, 5, 3, 7 for 8), so that every contiguous range of
    the order, the share numba's static schedule gives one thread, takes chunks from all over the items (a range of
    ``chunks / T`` iterations starting at a multiple of it, ``chunks`` and T powers of two, takes every T-th
    chunk). It depends on ``chunks`` only, never on the thread count."""
    p = 1
    while p < chunks:
        p *= 2
    out = np.empty(chunks, dtype=np.int64)
    n = 0
    for j in range(p):
        r, bit, x = 0, p >> 1, j
        while bit > 0:
            if x & 1:
                r |= bit
            x >>= 1
            bit >>= 1
        if r < chunks:
            out[n] = r
            n += 1
    return out


@numba.njit(cache=True, parallel=True)
def ccd_block(vf: bool, X0: np.ndarray, X1: np.ndarray, quads: np.ndarray, gone: np.ndarray, only: np.ndarray,
              movable: np.ndarray, roots: np.ndarray, eta: float, max_depth: int, max_intervals: int,
              diag: np.ndarray, gap: float):
    """:func:`ccd_candidates` of a block of the pipeline's pair store (:class:`modalfem.collision._system.PairStore`),
    its filters in the same parallel pass as the CCD instead of a compacted copy of the selected pairs first:
    only the pairs still in the store (unless ``gone`` ((N,) bool) is empty: without a vertex flagged in it, one
    searched again since the block was found) and, unless ``only`` ((N,) bool) is empty, holding a flagged
    vertex. A pair whose trajectory boxes come within ``eta`` is next tested on the box diagonals
    (``diag``: :func:`diagonal_intervals` of ``X0``, ``X1``; ``gap``: :func:`diagonal_gap`): projections more
    than ``gap`` apart prove it farther than ``eta`` throughout the step, without the coplanarity test. On the
    64x64 pile's dense phase (171 calls of steps 50-60) this rejects 63 % of the pairs the boxes pass, and 63 %
    of those the coplanarity test cannot reject (points crossing a triangle's plane outside it), which then
    need no subdivision: ``ccd_hits`` of those calls 421-426 -> 377-399 ms (fastest of 5, interleaved runs,
    one thread, Intel Xeon, shared machine), the same hits; the six face diagonals ``(1, +-1, 0)``... too
    (rejecting 76 %) cost more than they saved (401-423 ms).

    The chunks run in :func:`spread_order` (numba hands each thread a contiguous range of the loop's iterations, and
    the store's pairs come in the search's spatial order, so a thread's contiguous chunks would hold one region of
    the cloth, e.g. most of a dense fold's subdivisions); each chunk writes its own slots, so the answer is the same.
    Per-chunk CPU times of the 64x64 pile's 272 calls of steps 59-62 (one thread, fastest of 3, Intel Xeon, load
    11): 33.0 ms per step in all; the busiest of two threads' shares 18.4 ms contiguous (1.79x), 17.1 spread
    (1.93x); of four 10.0 (3.29x) and 9.3 (3.56x).

    Returns:
        ``(idx, toi)``: (h,) indices into ``quads`` (ascending) and times in [0, 1].
    """
    k = len(quads)
    idx = np.empty(k, dtype=np.int64)
    tois = np.empty(k)
    code = _vertex_codes(gone, only, movable)
    chunks = chunk_count(k, CCD_CHUNK)
    counts = np.empty(chunks, dtype=np.int64)  # every chunk writes its own (np.zeros: a parallel region of its own)
    order = spread_order(chunks)
    for j in numba.prange(chunks):
        ch = order[j]
        start, stop = chunk_bounds(k, chunks, ch)
        counts[ch] = _ccd_range(vf, X0, X1, quads, code, roots, eta, max_depth, max_intervals, start, stop, idx,
                                tois, diag, gap)
    n = 0
    for ch in range(chunks):  # compact the chunks' hits (each written from its chunk's start) in order
        start, _ = chunk_bounds(k, chunks, ch)
        for j in range(counts[ch]):
            idx[n], tois[n] = idx[start + j], tois[start + j]
            n += 1
    return idx[:n].copy(), tois[:n].copy()


def ccd_segments(segments: list, X0: np.ndarray, X1: np.ndarray, movable: np.ndarray, roots: np.ndarray, eta: float,
                 max_depth: int, max_intervals: int, diag: np.ndarray, gap: float):
    """:func:`ccd_block` of several blocks in ONE parallel region: ``segments`` a list of ``(vf, q, gone, only)``
    (``q`` (k, 4) int32 pairs, ``gone``/``only`` (N,) bool or empty, as ``ccd_block``'s arguments; the pipeline's
    ``PairStore.segments`` of both kinds). The same hits as one ``ccd_block`` per segment, bit for bit (the same
    chunks, each pair's test the same compiled function). One region instead of one per segment: the 64x64 pile's
    ``ccd_hits`` passes ~4.9 segments per call (11.8 calls per step), and every region started after serial Python
    waits for the pool's sleeping workers (~33 us per region on an idle 2-vCPU host, ``bench threads --wake``).

    The segments' arrays are handed to the kernel by address (numba's typed lists cost ~25 us per item to build,
    a concatenated copy ~1 ms per step): they are checked here (dtype, shape, contiguity, lengths) and held
    referenced in ``segments`` for the call.

    Returns:
        ``[(idx, toi)]`` per segment: (h,) indices into its ``q`` (ascending) and times in [0, 1].
    """
    S = len(segments)
    N = len(movable)
    vf = np.empty(S, dtype=np.bool_)
    addr = np.zeros((S, 3), dtype=np.int64)
    size = np.empty(S, dtype=np.int64)
    for s, (v, q, gone, only) in enumerate(segments):
        if q.dtype != np.int32 or q.ndim != 2 or q.shape[1] != 4 or not q.flags.c_contiguous:
            raise ValueError("ccd_segments: pairs must be C-contiguous (k, 4) int32")
        vf[s], size[s] = v, len(q)
        addr[s, 0] = q.ctypes.data if len(q) else 0
        for c, flags in ((1, gone), (2, only)):
            if len(flags):
                if flags.dtype != np.bool_ or flags.shape != (N,) or not flags.flags.c_contiguous:
                    raise ValueError("ccd_segments: vertex flags must be contiguous (N,) bool")
                addr[s, c] = flags.ctypes.data
    idx, toi, counts = _ccd_segments(vf, addr, size, X0, X1, movable, roots, eta, max_depth, max_intervals, diag, gap)
    out, n = [], 0
    for s in range(S):
        out.append((idx[n:n + counts[s]], toi[n:n + counts[s]]))
        n += counts[s]
    return out


@intrinsic
def _pointer(typingctx, address):
    """The ``voidptr`` at an integer address (for ``numba.carray``)."""
    if not isinstance(address, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return types.voidptr(address), codegen


@numba.njit(cache=True, parallel=True)
def _ccd_segments(vf: np.ndarray, addr: np.ndarray, size: np.ndarray, X0: np.ndarray, X1: np.ndarray,
                  movable: np.ndarray, roots: np.ndarray, eta: float, max_depth: int, max_intervals: int,
                  diag: np.ndarray, gap: float):
    """:func:`ccd_segments`' pass: segment ``s`` has ``size[s]`` pairs at address ``addr[s, 0]`` and its ``gone`` and
    ``only`` flags at ``addr[s, 1]``, ``addr[s, 2]`` (0: empty). Segment ``s`` is split into ``ccd_block``'s chunks;
    all segments' chunks run in one loop in :func:`spread_order`. Returns ``(idx, toi, counts)``: the hits of the
    segments one after the other, ``counts[s]`` of segment ``s``."""
    S = len(size)
    N = len(movable)
    # no array expression or np.zeros outside the prange: numba makes each one a parallel region of its own
    # (launched, and waking the pool, like the loop)
    empty = np.empty(0, dtype=np.bool_)
    first = np.empty(S + 1, dtype=np.int64)  # first chunk of each segment
    base = np.empty(S + 1, dtype=np.int64)  # first pair of each segment in the hit buffers
    first[0], base[0] = 0, 0
    code = np.empty((S, N), dtype=np.uint8)
    for s in range(S):
        first[s + 1] = first[s] + chunk_count(size[s], CCD_CHUNK)
        base[s + 1] = base[s] + size[s]
        gone = numba.carray(_pointer(addr[s, 1]), N, np.bool_) if addr[s, 1] != 0 else empty
        only = numba.carray(_pointer(addr[s, 2]), N, np.bool_) if addr[s, 2] != 0 else empty
        _vertex_codes_into(gone, only, movable, code[s])
    chunks = first[S]
    owner = np.empty(chunks, dtype=np.int64)
    for s in range(S):
        for ch in range(first[s], first[s + 1]):
            owner[ch] = s
    idx = np.empty(base[S], dtype=np.int64)
    tois = np.empty(base[S])
    counts = np.empty(chunks, dtype=np.int64)  # every chunk writes its own
    order = spread_order(chunks)
    for j in numba.prange(chunks):
        ch = order[j]
        s = owner[ch]
        k = size[s]
        start, stop = chunk_bounds(k, first[s + 1] - first[s], ch - first[s])
        q = numba.carray(_pointer(addr[s, 0]), (k, 4), np.int32)
        counts[ch] = _ccd_range(vf[s], X0, X1, q, code[s], roots, eta, max_depth, max_intervals, start, stop,
                                idx[base[s]:base[s + 1]], tois[base[s]:base[s + 1]], diag, gap)
    n = 0
    per = np.empty(S, dtype=np.int64)
    for s in range(S):
        per[s] = 0
    for ch in range(chunks):  # compact the chunks' hits (each written from its chunk's start) in order
        s = owner[ch]
        start, _ = chunk_bounds(size[s], first[s + 1] - first[s], ch - first[s])
        for j in range(counts[ch]):
            idx[n], tois[n] = idx[base[s] + start + j], tois[base[s] + start + j]
            n += 1
        per[s] += counts[ch]
    return idx[:n].copy(), tois[:n].copy(), per


#: bits of :func:`_vertex_codes`: the vertex passes the ``only`` filter, was dropped from the store (``gone``), is
#: movable; a pair is tested when its vertices' codes or-ed are ``_ONLY | _MOVABLE``
_ONLY, _GONE, _MOVABLE = 1, 2, 4


@numba.njit(cache=True)
def _vertex_codes(gone: np.ndarray, only: np.ndarray, movable: np.ndarray) -> np.ndarray:
    """(N,) uint8 per vertex: ``_ONLY`` if ``only`` is empty or flags it, ``_GONE`` if ``gone`` flags it,
    ``_MOVABLE`` if ``movable`` does. The pair filters of :func:`_ccd_range` then read one byte per vertex
    instead of three: replayed 64x64 pile steps 40-60, the filters alone 15.8 -> 11.2 ms per step; all 154
    recorded pipeline calls of the pile (one thread, CPU time, Intel Xeon, load 1.5-1.7, HEAD and this in
    alternating processes, 3 runs each) CCD 6.67-7.04 -> 6.36-6.59 and impact zones 6.30-6.43 -> 5.79-6.02 ms
    per call, the same outputs bit for bit."""
    code = np.empty(len(movable), dtype=np.uint8)
    _vertex_codes_into(gone, only, movable, code)
    return code


@numba.njit(cache=True)
def _vertex_codes_into(gone: np.ndarray, only: np.ndarray, movable: np.ndarray, code: np.ndarray) -> None:
    """:func:`_vertex_codes` written into ``code`` ((N,) uint8)."""
    use_gone, use_only = len(gone) > 0, len(only) > 0
    for i in range(len(movable)):
        c = _MOVABLE if movable[i] else 0
        if not use_only or only[i]:
            c |= _ONLY
        if use_gone and gone[i]:
            c |= _GONE
        code[i] = c


@numba.njit(cache=True)
def _ccd_range(vf: bool, X0, X1, quads, code, roots, eta: float, max_depth: int, max_intervals: int, start: int,
               stop: int, idx, tois, diag, gap: float) -> int:
    """:func:`ccd_block` of the pairs ``start..stop-1`` (vertex filters in ``code``, :func:`_vertex_codes`): hits
    written to ``idx``/``tois`` from ``start`` on; returns their count."""
    zones = len(roots) > 0
    n = start
    t0, td, x = np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3))
    coef = np.empty(4)
    m = 2 * max_intervals + 2
    lo, hi, nlo, nhi = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    for q in range(start, stop):
        c0, c1, c2, c3 = quads[q, 0], quads[q, 1], quads[q, 2], quads[q, 3]
        # a vertex flagged in ``only``, a movable vertex, and none dropped from the store (searched again after
        # this block was found)
        if ((code[c0] | code[c1] | code[c2] | code[c3]) & (_ONLY | _GONE | _MOVABLE)) != _ONLY | _MOVABLE:
            continue
        if zones and roots[c1] == roots[c0] and roots[c2] == roots[c0] and roots[c3] == roots[c0]:
            continue
        near = True
        for c in range(3):
            # trajectory boxes of the first primitive (vertex c0, or edge c0 c1) and of the second; all three
            # axes without a branch (about half the pairs fail, on an unpredictable axis)
            alo = min(X0[c0, c], X1[c0, c])
            ahi = max(X0[c0, c], X1[c0, c])
            blo = min(X0[c2, c], X1[c2, c], X0[c3, c], X1[c3, c])
            bhi = max(X0[c2, c], X1[c2, c], X0[c3, c], X1[c3, c])
            if vf:
                blo, bhi = min(blo, X0[c1, c], X1[c1, c]), max(bhi, X0[c1, c], X1[c1, c])
            else:
                alo, ahi = min(alo, X0[c1, c], X1[c1, c]), max(ahi, X0[c1, c], X1[c1, c])
            near = near & (alo <= bhi + eta) & (blo <= ahi + eta)
        if not near:
            continue
        if _diagonal_apart(vf, diag, c0, c1, c2, c3, gap):
            continue
        if _separated(vf, X0, X1, c0, c1, c2, c3, eta):
            continue
        toi = _query(vf, X0, X1, c0, c1, c2, c3, eta, max_depth, max_intervals, t0, td, x, coef, lo, hi, nlo, nhi)
        if toi <= 1.0:
            idx[n], tois[n] = q, toi
            n += 1
    return n - start
