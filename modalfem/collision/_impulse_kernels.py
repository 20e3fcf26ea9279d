"""Compiled pair impulses (numba ``njit``, cached on disk), the only implementation of
:func:`modalfem.collision.repulsion.apply_pair_impulses` (all pairs against the same velocities, changes
weight-averaged per vertex: the CCD passes) and :func:`modalfem.collision.repulsion.sequential_pair_impulses`
(pair by pair, each against the velocities its predecessors left: stage (a)'s repulsion sweeps).

The sequential sweeps run in parallel over *groups* of pairs (``sweep_groups``): the pairs are cut into slabs
along the widest axis of their positions, the groups' conflict graph (two groups conflict when a vertex an
impulse may move is in pairs of both) is coloured greedily, and a sweep goes colour by colour, the groups of one
colour in parallel, each group's pairs in their given order. Groups of one colour share no movable vertex, so a
sweep is the sequential sweep over the pairs in the order (colour, group, index): the same bits on any number of
threads. Every slab is wider than a pair's reach (the spread of its movable vertices along the axis), so a slab
conflicts with its neighbours only: two colours, about one parallel loop per sweep (a sweep's last colour is the
next one's first: one loop does both, ``sequential_impulses``; 64x64 pile, steps 61-63: 25-29k pairs in 17-18
groups). The order changes the Gauss-Seidel order, not what a sweep does: on that pile the pairs
still approaching after the 10 sweeps are as many as in pair order (1112-1230 against 1138-1277) and the largest
remaining approach as large (0.069 against 0.068 m/s at step 61); over the whole pile 0 intersections either way.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem._threads import chunk_bounds, chunk_count

__all__ = ["GROUP_PAIRS", "MAX_GROUPS", "ROUNDING", "arrange_pairs", "pair_impulses", "pair_keys",
           "sequential_impulses", "sweep_groups"]

#: relative size [-] below which a pair's normal velocity deficit counts as met
ROUNDING = 1e-12
#: pairs per group of the parallel sweeps (at least; their number depends on the pair count only)
GROUP_PAIRS = 1024
#: most groups (a group's conflicts are held in one 64-bit mask)
MAX_GROUPS = 64
#: histogram bins per group when the slabs are cut at equal pair counts
_BINS_PER_GROUP = 32


@numba.njit(cache=True, inline="always")
def _pair_change(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                 target: np.ndarray, friction: float, p: int) -> tuple:
    """The relative velocity change pair ``p`` wants, ``(d0, d1, d2, den)`` with ``den = sum w^2 / m``;
    ``den = 0`` when the pair does not act (its normal velocity is at or above its target, to
    ``ROUNDING`` of the velocities, or all its vertices are kinematic)."""
    vr0 = vr1 = vr2 = 0.0
    den = 0.0
    for j in range(4):
        i = quads[p, j]
        vr0 += w[p, j] * V[i, 0]
        vr1 += w[p, j] * V[i, 1]
        vr2 += w[p, j] * V[i, 2]
        den += w[p, j] * w[p, j] * invm[i]
    vn = vr0 * n[p, 0] + vr1 * n[p, 1] + vr2 * n[p, 2]
    dvn = max(target[p] - vn, 0.0)
    # a deficit at the rounding level of the velocities is none (a pair just brought to its target)
    if not (dvn > ROUNDING * (abs(target[p]) + abs(vn)) and den > 0.0):
        return 0.0, 0.0, 0.0, 0.0
    d0, d1, d2 = dvn * n[p, 0], dvn * n[p, 1], dvn * n[p, 2]
    if friction > 0.0:
        t0, t1, t2 = vr0 - vn * n[p, 0], vr1 - vn * n[p, 1], vr2 - vn * n[p, 2]
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        k = min(friction * dvn / (tn if tn > 0.0 else 1.0), 1.0)
        d0, d1, d2 = d0 - k * t0, d1 - k * t1, d2 - k * t2
    return d0, d1, d2, den


@numba.njit(cache=True, inline="always")
def _scatter(out: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, p: int, d0: float, d1: float,
             d2: float, den: float) -> None:
    """Add pair ``p``'s change ``(d0, d1, d2)`` to ``out`` (N, 3) at its movable vertices, each its share
    ``w_j / m_j / den`` (the impulse that changes the pair's relative velocity by exactly that)."""
    for j in range(4):
        i = quads[p, j]
        if invm[i] > 0.0:
            c = w[p, j] * invm[i] / den
            out[i, 0] += c * d0
            out[i, 1] += c * d1
            out[i, 2] += c * d2


@numba.njit(cache=True)
def pair_impulses(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                  target: np.ndarray, friction: float):
    """Velocity change (N, 3) [m/s] raising each pair's relative normal velocity ``w . V[quads] . n`` to at
    least ``target`` [m/s] (with Coulomb ``friction`` on the tangential part), summed per vertex and
    divided by the vertex's summed weights |w| over the acting pairs when above 1; and the number of
    acting pairs. See :func:`modalfem.collision.repulsion.apply_pair_impulses`."""
    N = len(V)
    dV = np.zeros((N, 3))
    cnt = np.zeros(N)
    active = 0
    for p in range(len(quads)):
        d0, d1, d2, den = _pair_change(V, invm, quads, w, n, target, friction, p)
        if den == 0.0:
            continue
        active += 1
        _scatter(dV, invm, quads, w, p, d0, d1, d2, den)
        for j in range(4):
            if invm[quads[p, j]] > 0.0:
                cnt[quads[p, j]] += abs(w[p, j])
    for i in range(N):
        if cnt[i] > 1.0:
            dV[i, 0] /= cnt[i]
            dV[i, 1] /= cnt[i]
            dV[i, 2] /= cnt[i]
    return dV, active


@numba.njit(cache=True, parallel=True)
def pair_keys(X: np.ndarray, writable: np.ndarray, quads: np.ndarray):
    """The slab keys of ``sweep_groups`` (in parallel chunks): the axis of widest extent of the pairs' first
    vertices, each pair's key (the lowest coordinate of its writable vertices along it; its first vertex's if none)
    and the reach (the largest spread of a pair's writable vertices along it). Returns ``(key, reach)``."""
    k = len(quads)
    chunks = chunk_count(k, 4096)
    lo = np.full((chunks, 3), np.inf)
    hi = np.full((chunks, 3), -np.inf)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        for p in range(start, stop):
            for c in range(3):
                x = X[quads[p, 0], c]
                lo[ch, c] = min(lo[ch, c], x)
                hi[ch, c] = max(hi[ch, c], x)
    span = np.zeros(3)
    for c in range(3):
        a, b = np.inf, -np.inf
        for ch in range(chunks):
            a = min(a, lo[ch, c])
            b = max(b, hi[ch, c])
        span[c] = b - a
    axis = 0
    for c in range(1, 3):
        if span[c] > span[axis]:
            axis = c
    key = np.empty(k)
    part = np.zeros(chunks)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        r = 0.0
        for p in range(start, stop):
            a = np.inf
            b = -np.inf
            for j in range(4):
                v = quads[p, j]
                if writable[v]:
                    a = min(a, X[v, axis])
                    b = max(b, X[v, axis])
            if a == np.inf:
                a = b = X[quads[p, 0], axis]
            key[p] = a
            r = max(r, b - a)
        part[ch] = r
    reach = 0.0
    for ch in range(chunks):
        reach = max(reach, part[ch])
    return key, reach


@numba.njit(cache=True)
def sweep_groups(key: np.ndarray, reach: float, writable: np.ndarray, quads: np.ndarray, groups: int):
    """The order of the parallel sweeps over the pairs ``quads`` (k, 4) from their slab keys ``key`` (k,) [m] and
    ``reach`` [m] (``pair_keys``); ``writable`` (N,) bool marks the vertices an impulse may move (the others are
    only read, they never conflict).

    The pairs are cut into at most ``groups`` slabs along the keys' axis, each of about ``k / groups`` pairs (a
    histogram of ``_BINS_PER_GROUP`` bins per group) and wider than the reach (so that only neighbouring slabs can
    share a vertex), the groups' conflicts (a writable vertex in pairs of both) coloured greedily in slab order: two
    colours unless the reach rule was broken by rounding (the colouring is of the actual conflicts, so it is always
    valid). Returns ``(perm, cptr, tptr)``: (k,) the pairs in sweep order (colour, group, index), (colours + 1,)
    each colour's groups, (groups + 1,) each group's pairs in ``perm``."""
    k = len(quads)
    G = max(1, min(groups, MAX_GROUPS))
    lo_k = np.inf
    hi_k = -np.inf
    for p in range(k):
        lo_k = min(lo_k, key[p])
        hi_k = max(hi_k, key[p])
    B = G * _BINS_PER_GROUP
    width = (hi_k - lo_k) / B if k else 1.0
    width = width if width > 0.0 else 1.0
    binof = np.empty(k, np.int64)
    count = np.zeros(B, np.int64)
    for p in range(k):
        b = min(B - 1, max(0, int((key[p] - lo_k) / width)))
        binof[p] = b
        count[b] += 1
    # slabs of consecutive bins, each closed once it holds ~k / G pairs and is wider than the reach (plus two bins
    # for rounding): two pairs sharing a writable vertex have keys within the reach, so they lie in the same or
    # neighbouring slabs and the slabs' conflicts form a path (two colours)
    gbin = np.empty(B, np.int64)
    g = 0
    start = 0
    inside = 0
    for b in range(B):
        gbin[b] = g
        inside += count[b]
        if g < G - 1 and inside * G >= k and (b + 1 - start) * width > reach + 2.0 * width:
            g += 1
            start = b + 1
            inside = 0
    G = g + 1
    group = np.empty(k, np.int64)
    vmask = np.zeros(len(writable), np.uint64)
    for p in range(k):
        g = gbin[binof[p]]
        group[p] = g
        bit = np.uint64(1) << np.uint64(g)
        for j in range(4):
            v = quads[p, j]
            if writable[v]:
                vmask[v] |= bit
    adj = np.zeros(G, np.uint64)
    for p in range(k):
        g = group[p]
        for j in range(4):
            adj[g] |= vmask[quads[p, j]]
    colour = np.full(G, -1, np.int64)
    for g in range(G):
        used = np.uint64(0)
        for h in range(G):
            if h != g and colour[h] >= 0 and (adj[g] >> np.uint64(h)) & np.uint64(1):
                used |= np.uint64(1) << np.uint64(colour[h])
        c = 0
        while (used >> np.uint64(c)) & np.uint64(1):
            c += 1
        colour[g] = c
    ncol = colour.max() + 1
    # groups by colour, then index; pairs by group (in that order), then index
    gorder = np.argsort(colour * G + np.arange(G))
    cptr = np.zeros(ncol + 1, np.int64)
    for g in range(G):
        cptr[colour[g] + 1] += 1
    for c in range(ncol):
        cptr[c + 1] += cptr[c]
    gsize = np.zeros(G, np.int64)
    for p in range(k):
        gsize[group[p]] += 1
    tptr = np.zeros(G + 1, np.int64)
    slot = np.empty(G, np.int64)  # each group's task position
    for t in range(G):
        slot[gorder[t]] = t
        tptr[t + 1] = tptr[t] + gsize[gorder[t]]
    fill = tptr[:-1].copy()
    perm = np.empty(k, np.int64)
    for p in range(k):
        t = slot[group[p]]
        perm[fill[t]] = p
        fill[t] += 1
    return perm, cptr, tptr


@numba.njit(cache=True, inline="always")
def _group_pass(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                target: np.ndarray, friction: float, first: int, stop: int, back: bool) -> int:
    """One pass over the pairs ``first..stop-1`` (backwards with ``back``), each pair's change applied at once;
    returns the pairs that acted."""
    a = 0
    for r in range(stop - first):
        p = stop - 1 - r if back else first + r
        d0, d1, d2, den = _pair_change(V, invm, quads, w, n, target, friction, p)
        if den == 0.0:
            continue
        a += 1
        _scatter(V, invm, quads, w, p, d0, d1, d2, den)
    return a


@numba.njit(cache=True, parallel=True)
def sequential_impulses(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                        target: np.ndarray, friction: float, sweeps: int, cptr: np.ndarray, tptr: np.ndarray):
    """Velocities (N, 3) [m/s] after up to ``sweeps`` sweeps over the pairs (forwards, then backwards, in turn),
    each pair's whole change applied at once to a copy of ``V``; the sweeps run; and the pairs that acted in the
    last one (0: every pair at or above its target). A sweep goes colour by colour (``cptr``: the groups of each
    colour), the groups of a colour (``tptr``: each group's span of the pairs, which are in sweep order; no two
    groups of a colour share a movable vertex, ``sweep_groups``) in parallel, a backward sweep in exactly the
    reverse order. See :func:`modalfem.collision.repulsion.sequential_pair_impulses`.

    A sweep's last colour is the next sweep's first (the order reverses), so one parallel loop does both: each
    group its pairs of the ending sweep, then the same pairs backwards for the next (the groups of a colour share
    no movable vertex, so this is the order of the two colour loops one after the other): ``sweeps + 1`` parallel
    loops with two colours instead of ``2 sweeps``, the same bits. When the ending sweep turns out to have had no
    acting pair the next one's part changed nothing (the same pairs against the same velocities act again only if
    they acted before), so stopping there is the serial stopping rule."""
    V = V.copy()
    nc = len(cptr) - 1
    if nc == 0 or sweeps < 1:
        return V, min(sweeps, 1), 0
    part = np.zeros((len(tptr) - 1, 2), np.int64)
    counts = np.zeros(sweeps, np.int64)  # the pairs that acted in each sweep
    total = sweeps * nc  # colour loops of all sweeps, the merged ones counted twice
    ph = 0
    while ph < total:
        s = ph // nc
        j = ph - s * nc
        back = s % 2 == 1
        c = nc - 1 - j if back else j
        two = j == nc - 1 and ph + 1 < total  # the next sweep's first colour is this one: in the same loop
        for t in numba.prange(cptr[c], cptr[c + 1]):
            part[t, 0] = _group_pass(V, invm, quads, w, n, target, friction, tptr[t], tptr[t + 1], back)
            if two:
                part[t, 1] = _group_pass(V, invm, quads, w, n, target, friction, tptr[t], tptr[t + 1], not back)
        for t in range(cptr[c], cptr[c + 1]):
            counts[s] += part[t, 0]
            if two:
                counts[s + 1] += part[t, 1]
        ph += 2 if two else 1
        # the sweeps this loop completed (with one colour, the next sweep's too)
        for q in range(s, min((ph - 1) // nc + 1, sweeps)):
            if (q + 1) * nc <= ph and counts[q] == 0:
                return V, q + 1, 0
    return V, sweeps, counts[sweeps - 1]


@numba.njit(cache=True, parallel=True)
def arrange_pairs(perm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray, target: np.ndarray):
    """``(quads[perm], w[perm], n[perm], target[perm])`` (chunks in parallel)."""
    k = len(perm)
    q2, w2, n2, t2 = np.empty((k, 4), np.int64), np.empty((k, 4)), np.empty((k, 3)), np.empty(k)
    chunks = max(1, min(64, k // 4096))
    for ch in numba.prange(chunks):
        for i in range((ch * k) // chunks, ((ch + 1) * k) // chunks):
            p = perm[i]
            for j in range(4):
                q2[i, j] = quads[p, j]
                w2[i, j] = w[p, j]
            for j in range(3):
                n2[i, j] = n[p, j]
            t2[i] = target[p]
    return q2, w2, n2, t2
