"""Temporal coherence of the modal bodies' pair search (numba, cached on disk): ``coherent_pairs`` gives the
contacts of ``_solid_kernels.all_pairs`` (the same, in the same order) but walks a pair's rest-surface trees only
when its bodies have moved, relative to each other or in shape, more than a slack since the last walk, and skips
the kept feature pairs that the motion since their last test cannot have brought within reach (the argument is in
``coherent_pairs``' docstring; tests/world/test_modal_contacts.py checks it against the brute-force walk).

numba's disk cache does not notice edits of the other modules a kernel calls: after changing the per-pair tests in
:mod:`modalfem.world._solid_kernels` (``_vf_test``, ``_ee_test``, ``_to_local``, ``_gather``), delete
``modalfem/world/__pycache__``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.collision._distance_kernels import edge_edge_closest, point_triangle_closest
from modalfem.world._solid_kernels import _edge_queries, _ee_test, _gather, _to_local, _vertex_queries, _vf_found, _vf_test


_CUT_EPS = 1e-12
#: the vertex-face walks write box-gap lower bounds, not exact distances (``_walk``'s ``lazy``): most of a fast pair's
#: candidates are never measured by ``_vf_eval`` (a vertex's nearest triangle found, the others skipped on their
#: bounds). The edge-edge walks keep the exact test (lazy there measured no gain: ``_ee_eval`` tests most kept pairs).
LAZY_VF = True
LAZY_EE = False


@numba.njit(cache=True)
def _grow(cv, ct, cd, k):
    """The candidate buffers doubled (their first ``k`` entries kept)."""
    n = 2 * cv.shape[0] + 64
    cv2 = np.empty(n, dtype=np.int64)
    ct2 = np.empty(n, dtype=np.int64)
    cd2 = np.empty(n)
    cv2[:k] = cv[:k]
    ct2[:k] = ct[:k]
    cd2[:k] = cd[:k]
    return cv2, ct2, cd2


@numba.njit(cache=True, inline="always")
def _ball_gap2(x0, x1, x2, y0, y1, y2, l0, l1, l2, h0, h1, h2, radius):
    """The squared gap [m^2] between the query's points and the deformed surface under a rest box (``l``, ``h``),
    from the query box (``x``, ``y``: its points' box grown by ``radius + bound`` on each side; every deformed
    point within ``bound`` of its rest place, each axis so): per axis, the rest boxes' gap less ``bound``
    (``max(l - y, x - h) + radius``), the positive parts squared and summed. A lower bound of the squared
    distance of the query to any entry under the box (the box test bounds each axis alone; this, the sum)."""
    g2 = 0.0
    g = max(l0 - y0, x0 - h0) + radius
    if g > 0.0:
        g2 += g * g
    g = max(l1 - y1, x1 - h1) + radius
    if g > 0.0:
        g2 += g * g
    g = max(l2 - y2, x2 - h2) + radius
    if g > 0.0:
        g2 += g * g
    return g2


@numba.njit(cache=True)
def _walk(edges, lazy, i0, k, ids, y, qlo, qhi, Xb, Fb, radius, P, lo, hi, nonempty, slot_tri, slo, shi, cv, ct, cd):
    """The tree walk of ``_bvh_kernels._query_walk`` (the same boxes, the same order) for queries ``i0...`` with
    the distance test at each leaf entry whose box passes: points ``y`` (m, 3) against triangles ``Fb`` (``edges``
    False), or segments ``y`` (m, 2, 3) against edges ``Fb`` (True); the pairs within ``radius`` are written from
    ``k`` on as (``ids[query]``, entry, distance). ``lazy``: no exact test; every entry whose box gap (below) is
    within the radius (+ rounding) is written with that gap lowered by the rounding band, a lower bound of its
    distance (a superset of the pairs within ``radius``: the evaluations measure the few they need). Stops before a
    query whose pairs do not fit in the buffers: returns (the next query, the count written)."""
    m = qlo.shape[0]
    cap = cv.shape[0]
    x = np.empty((4, 3))
    w = np.empty(3)
    L = slot_tri.shape[1]
    depth = 1
    while (1 << depth) <= P:
        depth += 1
    stack = np.empty(2 * depth + 4, dtype=np.int64)
    for i in range(i0, m):
        k0 = k
        x0, x1, x2 = qlo[i, 0], qlo[i, 1], qlo[i, 2]
        y0, y1, y2 = qhi[i, 0], qhi[i, 1], qhi[i, 2]
        mag = 0.0
        for d in range(3):
            if edges:
                x[0, d] = y[i, 0, d]
                x[1, d] = y[i, 1, d]
                mag = max(mag, max(abs(x[0, d]), abs(x[1, d])))
            else:
                x[0, d] = y[i, 0, d]
                mag = max(mag, abs(x[0, d]))
        band = _CUT_EPS * (mag + radius)
        cut = radius + band
        cut2 = cut * cut
        stack[0] = 1
        top = 1
        while top > 0:
            top -= 1
            a = stack[top]
            if not nonempty[a]:
                continue
            if x0 > hi[a, 0] or lo[a, 0] > y0 or x1 > hi[a, 1] or lo[a, 1] > y1 or x2 > hi[a, 2] or lo[a, 2] > y2:
                continue
            if _ball_gap2(x0, x1, x2, y0, y1, y2, lo[a, 0], lo[a, 1], lo[a, 2], hi[a, 0], hi[a, 1], hi[a, 2],
                          radius) > cut2:
                continue
            if a >= P:
                ia = a - P
                for c in range(L):
                    t = slot_tri[ia, c]
                    if t < 0:
                        continue
                    if (x0 <= shi[0, ia, c] and slo[0, ia, c] <= y0 and x1 <= shi[1, ia, c]
                            and slo[1, ia, c] <= y1 and x2 <= shi[2, ia, c] and slo[2, ia, c] <= y2
                            and _ball_gap2(x0, x1, x2, y0, y1, y2, slo[0, ia, c], slo[1, ia, c], slo[2, ia, c],
                                           shi[0, ia, c], shi[1, ia, c], shi[2, ia, c], radius) <= cut2):
                        # the gap between the boxes of the query and of the entry's deformed corners is a lower
                        # bound of their distance: past the radius (+ rounding), the exact test would reject it too
                        g2 = 0.0
                        if edges:
                            for d in range(3):
                                x[2, d] = Xb[Fb[t, 0], d]
                                x[3, d] = Xb[Fb[t, 1], d]
                                g = max(min(x[2, d], x[3, d]) - max(x[0, d], x[1, d]),
                                        min(x[0, d], x[1, d]) - max(x[2, d], x[3, d]))
                                if g > 0.0:
                                    g2 += g * g
                        else:
                            for d in range(3):
                                x[1, d] = Xb[Fb[t, 0], d]
                                x[2, d] = Xb[Fb[t, 1], d]
                                x[3, d] = Xb[Fb[t, 2], d]
                                g = max(min(x[1, d], min(x[2, d], x[3, d])) - x[0, d],
                                        x[0, d] - max(x[1, d], max(x[2, d], x[3, d])))
                                if g > 0.0:
                                    g2 += g * g
                        if g2 > cut2:
                            continue
                        if lazy:
                            # the computed gap is below the exact test's distance up to rounding (~1e-16 of the
                            # coordinates), far inside the band
                            if k < cap:
                                cv[k], ct[k], cd[k] = ids[i], t, max(math.sqrt(g2) - band, 0.0)
                            k += 1
                            continue
                        if edges:
                            dist = edge_edge_closest(x)[0]
                        else:
                            dist = point_triangle_closest(x, w)
                        if dist <= radius:
                            if k < cap:
                                cv[k], ct[k], cd[k] = ids[i], t, dist
                            k += 1
                continue
            stack[top] = 2 * a
            stack[top + 1] = 2 * a + 1
            top += 2
        if k > cap:
            return i, k0
    return m, k


@numba.njit(cache=True)
def _walk_all(edges, lazy, ids, y, qlo, qhi, Xb, Fb, radius, P, lo, hi, nonempty, slot_tri, slo, shi):
    """``_walk`` over every query, the buffers grown as needed: ``(ids, entries, distances or their lower bounds
    (lazy))``, (k,) each."""
    m = qlo.shape[0]
    cv = np.empty(8 * m + 64, dtype=np.int64)
    ct = np.empty(8 * m + 64, dtype=np.int64)
    cd = np.empty(8 * m + 64)
    i, k = _walk(edges, lazy, 0, 0, ids, y, qlo, qhi, Xb, Fb, radius, P, lo, hi, nonempty, slot_tri, slo, shi, cv,
                 ct, cd)
    while i < m:
        cv, ct, cd = _grow(cv, ct, cd, k)
        i, k = _walk(edges, lazy, i, k, ids, y, qlo, qhi, Xb, Fb, radius, P, lo, hi, nonempty, slot_tri, slo, shi, cv,
                     ct, cd)
    return cv[:k].copy(), ct[:k].copy(), cd[:k].copy()


@numba.njit(cache=True)
def _vf_candidates(xa, Rb, pb, Xb, Tb, bound, radius, blo, bhi, P, lo, hi, nonempty, slot_tri, slo, shi):
    """Every (vertex of a, triangle of b) pair closer than ``radius`` [m] (arguments as ``vertex_face``), grouped
    by vertex in increasing order, each vertex's triangles in the tree's order (the order ``vertex_face`` meets
    them in): ``(vertices, triangles, lower bounds of the distances [m])``, (k,) each (``LAZY_VF``: box gaps, a
    superset of the pairs within ``radius``; else the distances as ``_vf_test`` finds them, exactly those pairs).
    One pass of the walk (``_walk``; was a counting walk, a filling walk, then the tests)."""
    near, y, qlo, qhi = _vertex_queries(xa, Rb, pb, bound, radius, blo, bhi)
    return _walk_all(False, LAZY_VF, near, y.reshape((y.shape[0], 1, 3)), qlo, qhi, Xb, Tb, radius, P, lo, hi,
                     nonempty, slot_tri, slo, shi)


@numba.njit(cache=True)
def _vf_eval(xa, Rb, pb, Xb, Tb, reach, cv, ct, lb, drop):
    """``vertex_face`` over the candidate pairs ``cv``, ``ct`` of ``_vf_candidates`` (a superset of the pairs
    within ``reach``): the same contacts, in the same order. ``lb`` (k,): lower bounds of the pairs' distances [m]
    at the last evaluation, which the bodies' motion since may have lowered by at most ``drop`` [m]: a pair still
    beyond ``reach`` by them, or beyond the distance of its vertex's best triangle so far, is skipped
    (``_vf_test`` would reject it) and its bound lowered; the others are tested and their bound set to their
    distance.

    Before that pass, each vertex's candidate of smallest bound (its likely nearest triangle) is measured (its
    distance ``u``): a candidate whose bound, lowered by ``drop``, exceeds ``u (1 + 1e-9 + 4e-12 c)`` (c: the
    vertex's count of candidates) is farther than that triangle by more than ``_vf_test``'s tie band (1e-12
    relative, which a chain of c ties, each taking a farther triangle by at most that, stretches to at most
    (1 + 1e-12)^c), so even when met first in tree order its taking would be undone at the latest by that
    triangle (then taken strictly, whatever the best was), and skipping it leaves the selection, ties included, as
    the tree-order pass makes it."""
    n = cv.shape[0]
    m = 0
    prev = -1
    for k in range(n):
        if cv[k] != prev:
            m += 1
            prev = cv[k]
    vid = np.empty(m, dtype=np.int64)
    best = np.full(m, -1, dtype=np.int64)
    dbest = np.full(m, np.inf)
    gbest = np.zeros(m)
    bary = np.zeros((m, 3))
    nloc = np.zeros((m, 3))
    yl = np.empty((m, 3))
    cut = np.empty(m)  # the skip threshold from the pre-pass [m]
    x = np.empty((4, 3))
    w = np.empty(3)
    i = -1
    prev = -1
    kmin = k0 = -1
    for k in range(n + 1):
        if k == n or cv[k] != prev:
            if i >= 0 and (k - k0 == 1 or lb[kmin] - drop > reach):
                # a lone candidate (its bound, lowered by drop, is below its distance: the cut would not skip it),
                # or none within reach by their bounds: the measure would not change a skip
                cut[i] = reach
            elif i >= 0:
                t = ct[kmin]
                for d in range(3):
                    x[0, d] = yl[i, d]
                    x[1, d] = Xb[Tb[t, 0], d]
                    x[2, d] = Xb[Tb[t, 1], d]
                    x[3, d] = Xb[Tb[t, 2], d]
                cut[i] = min(reach, point_triangle_closest(x, w) * (1.0 + 1e-9 + 4e-12 * (k - k0)))
            if k == n:
                break
            i += 1
            prev = cv[k]
            vid[i] = prev
            _to_local(xa[prev], Rb, pb, yl[i])
            kmin = k0 = k
        elif lb[k] < lb[kmin]:
            kmin = k
    i = -1
    prev = -1
    for k in range(n):
        if cv[k] != prev:
            i += 1
            prev = cv[k]
        if lb[k] - drop > cut[i] or lb[k] - drop > dbest[i] * (1.0 + 1e-9):
            # beyond reach, or farther than the vertex's pre-measured or best-so-far triangle (``_vf_test`` would
            # not take it, or its taking would be undone: see above): its bound lowered by the motion since
            lb[k] -= drop
            continue
        lb[k] = _vf_test(yl[i], Xb, Tb, ct[k], reach, x, w, i, best, dbest, gbest, bary, nloc)
    return _vf_found(vid, best, gbest, bary, nloc, Rb)


@numba.njit(cache=True)
def _ee_candidates(xa, Ea, Rb, pb, Xb, Eb, bound, radius, blo, bhi, P, lo, hi, nonempty, slot_tri, slo, shi):
    """Every (edge of a, edge of b) pair closer than ``radius`` [m] (arguments as ``edge_edge``), grouped by a's
    edge in increasing order, in the order ``edge_edge`` meets them: ``(mine, other, distances [m])``, (k,) each
    (the distances as ``_ee_test`` finds them). One pass, as ``_vf_candidates``."""
    sel, y, qlo, qhi = _edge_queries(xa, Ea, Rb, pb, bound, radius, blo, bhi)
    return _walk_all(True, LAZY_EE, sel, y, qlo, qhi, Xb, Eb, radius, P, lo, hi, nonempty, slot_tri, slo, shi)


@numba.njit(cache=True, inline="always")
def _ee_interior(y0, y1, Xb, Eb, f):
    """False when ``edge_edge_closest`` of edge ``y0 y1`` and b's edge ``f`` certainly puts a closest point at an
    end of an edge (its lines' closest points outside the segments, or the lines near parallel: the same
    arithmetic as its first lines, without its square roots), which ``_ee_test`` rejects."""
    e0, e1 = Eb[f, 0], Eb[f, 1]
    d10, d11, d12 = y1[0] - y0[0], y1[1] - y0[1], y1[2] - y0[2]
    d20, d21, d22 = Xb[e1, 0] - Xb[e0, 0], Xb[e1, 1] - Xb[e0, 1], Xb[e1, 2] - Xb[e0, 2]
    r0, r1, r2 = y0[0] - Xb[e0, 0], y0[1] - Xb[e0, 1], y0[2] - Xb[e0, 2]
    A = d10 * d10 + d11 * d11 + d12 * d12
    B = d10 * d20 + d11 * d21 + d12 * d22
    E = d20 * d20 + d21 * d21 + d22 * d22
    C = d10 * r0 + d11 * r1 + d12 * r2
    F = d20 * r0 + d21 * r1 + d22 * r2
    den = A * E - B * B
    if not den > 1e-14 * A * E:
        return False
    s = (B * F - C * E) / den
    t = (A * F - B * C) / den
    return 0 <= s <= 1 and 0 <= t <= 1


@numba.njit(cache=True)
def _ee_eval(xa, Ea, Rb, pb, Xb, Eb, adj, Tb, margin, scale, cm, co, lb, drop):
    """``edge_edge`` over the candidate pairs ``cm``, ``co`` of ``_ee_candidates`` (a superset of the pairs within
    ``margin``; ``scale``: max(1, largest |coordinate| of ``Xb``) [m]): the same pairs, in the same order. ``lb``,
    ``drop``: as ``_vf_eval`` (a pair beyond the margin is rejected by ``_ee_test``, and so is a pair whose
    closest points ``_ee_interior`` puts at an end: most of the pairs in a pile; its bound is lowered as a
    skipped pair's)."""
    n = cm.shape[0]
    mine = np.empty(n, dtype=np.int64)
    other = np.empty(n, dtype=np.int64)
    so = np.empty(n)
    to = np.empty(n)
    gap = np.empty(n)
    normal = np.empty((n, 3))
    x = np.empty((4, 3))
    res = np.empty(7)
    y0 = np.empty(3)
    y1 = np.empty(3)
    k = 0
    prev = -1
    for p in range(n):
        e, f = cm[p], co[p]
        if e != prev:
            prev = e
            _to_local(xa[Ea[e, 0]], Rb, pb, y0)
            _to_local(xa[Ea[e, 1]], Rb, pb, y1)
        if lb[p] - drop > margin or not _ee_interior(y0, y1, Xb, Eb, f):
            lb[p] -= drop  # a lower bound of its distance still
            continue
        ok = _ee_test(y0, y1, Xb, Eb, adj, Tb, f, margin, scale, x, res)
        lb[p] = res[6]
        if ok:
            mine[k], other[k], so[k], to[k], gap[k] = e, f, res[0], res[1], res[2]
            for c in range(3):
                normal[k, c] = Rb[c, 0] * res[3] + Rb[c, 1] * res[4] + Rb[c, 2] * res[5]
            k += 1
    return mine[:k], other[:k], so[:k], to[:k], gap[:k], normal[:k]


@numba.njit(cache=True)
def _merge(cv, ct, cd, moved, nv, nt, nd):
    """The kept candidates (``cv``, ``ct``, ``cd`` (k,): grouped by query in increasing order) of the queries not
    ``moved`` and the new walk's (``nv``, ``nt``, ``nd``: the moved queries'), grouped by query in increasing order,
    each query's entries in its walk's order."""
    n = cv.shape[0]
    nn = nv.shape[0]
    keep = 0
    for i in range(n):
        if not moved[cv[i]]:
            keep += 1
    ov = np.empty(keep + nn, dtype=np.int64)
    ot = np.empty(keep + nn, dtype=np.int64)
    od = np.empty(keep + nn)
    i = 0
    j = 0
    k = 0
    while i < n or j < nn:
        if i < n and moved[cv[i]]:
            i += 1
            continue
        if j >= nn or (i < n and cv[i] < nv[j]):
            ov[k], ot[k], od[k] = cv[i], ct[i], cd[i]
            i += 1
        else:
            ov[k], ot[k], od[k] = nv[j], nt[j], nd[j]
            j += 1
        k += 1
    return ov, ot, od


@numba.njit(cache=True)
def _vf_rewalk(xa, Rb, pb, Xb, Tb, bound, radius, blo, bhi, P, lo, hi, nonempty, slot_tri, slo, shi, cv, ct, cd,
               gy, thr):
    """``_vf_candidates`` again for the vertices of a that moved, in b's axes, more than ``thr`` [m] since their
    last walk, the other vertices' candidates ``cv``, ``ct``, ``cd`` kept: ``(vertices, triangles, distances, moved
    count)``, as ``_vf_candidates`` orders them. ``gy`` (g, 4): the vertices that may come within reach (id, then
    its position in b's axes at its last walk; updated); the others are farther (``_guard``). A kept vertex's list
    holds every triangle within ``radius`` of where it was: with ``thr`` = radius - reach - (how much b's surface
    moved since), it holds every triangle within reach now (distances are 1-Lipschitz)."""
    na = xa.shape[0]
    moved = np.zeros(na, dtype=np.bool_)
    ng = gy.shape[0]
    near = np.empty(ng, dtype=np.int64)
    rows = np.empty(ng, dtype=np.int64)
    y = np.empty(3)
    m = 0
    nmoved = 0
    for g in range(ng):
        j = int(gy[g, 0])
        _to_local(xa[j], Rb, pb, y)
        d = (y[0] - gy[g, 1]) ** 2 + (y[1] - gy[g, 2]) ** 2 + (y[2] - gy[g, 3]) ** 2
        if not math.sqrt(d) <= thr:
            moved[j] = True
            nmoved += 1
            gy[g, 1], gy[g, 2], gy[g, 3] = y[0], y[1], y[2]
            if (blo[0] - radius <= xa[j, 0] <= bhi[0] + radius and blo[1] - radius <= xa[j, 1] <= bhi[1] + radius
                    and blo[2] - radius <= xa[j, 2] <= bhi[2] + radius):
                near[m] = j
                rows[m] = g
                m += 1
    if nmoved == 0:
        return cv, ct, cd, 0
    yq = np.empty((m, 1, 3))
    qlo = np.empty((m, 3))
    qhi = np.empty((m, 3))
    grow = radius + bound
    for i in range(m):
        for c in range(3):
            yq[i, 0, c] = gy[rows[i], 1 + c]
            qlo[i, c] = yq[i, 0, c] - grow
            qhi[i, c] = yq[i, 0, c] + grow
    nv, nt, nd = _walk_all(False, LAZY_VF, near[:m], yq, qlo, qhi, Xb, Tb, radius, P, lo, hi, nonempty, slot_tri, slo,
                           shi)
    ov, ot, od = _merge(cv, ct, cd, moved, nv, nt, nd)
    return ov, ot, od, nmoved


@numba.njit(cache=True)
def _ee_rewalk(xa, Ea, Rb, pb, Xb, Eb, bound, radius, blo, bhi, P, lo, hi, nonempty, slot_tri, slo, shi, cm, co, cd,
               gy, thr):
    """``_ee_candidates`` again for a's edges whose ends moved, in b's axes, more than ``thr`` [m] since the edge's
    last walk, the others' candidates kept (as ``_vf_rewalk``; a segment's points move by at most the larger of
    its ends' moves). ``gy`` (g, 7): the edges that may come within reach (id, then its ends at its last walk)."""
    ne = Ea.shape[0]
    moved = np.zeros(ne, dtype=np.bool_)
    ng = gy.shape[0]
    sel = np.empty(ng, dtype=np.int64)
    rows = np.empty(ng, dtype=np.int64)
    y0 = np.empty(3)
    y1 = np.empty(3)
    m = 0
    nmoved = 0
    for g in range(ng):
        e = int(gy[g, 0])
        i, j = Ea[e, 0], Ea[e, 1]
        _to_local(xa[i], Rb, pb, y0)
        _to_local(xa[j], Rb, pb, y1)
        d0 = (y0[0] - gy[g, 1]) ** 2 + (y0[1] - gy[g, 2]) ** 2 + (y0[2] - gy[g, 3]) ** 2
        d1 = (y1[0] - gy[g, 4]) ** 2 + (y1[1] - gy[g, 5]) ** 2 + (y1[2] - gy[g, 6]) ** 2
        if not math.sqrt(max(d0, d1)) <= thr:
            moved[e] = True
            nmoved += 1
            for c in range(3):
                gy[g, 1 + c] = y0[c]
                gy[g, 4 + c] = y1[c]
            ok = True
            for c in range(3):
                if min(xa[i, c], xa[j, c]) > bhi[c] + radius or max(xa[i, c], xa[j, c]) < blo[c] - radius:
                    ok = False
            if ok:
                sel[m] = e
                rows[m] = g
                m += 1
    if nmoved == 0:
        return cm, co, cd, 0
    y = np.empty((m, 2, 3))
    qlo = np.empty((m, 3))
    qhi = np.empty((m, 3))
    grow = radius + bound
    for q in range(m):
        g = rows[q]
        for c in range(3):
            y[q, 0, c] = gy[g, 1 + c]
            y[q, 1, c] = gy[g, 4 + c]
            qlo[q, c] = min(y[q, 0, c], y[q, 1, c]) - grow
            qhi[q, c] = max(y[q, 0, c], y[q, 1, c]) + grow
    nv, nt, nd = _walk_all(True, LAZY_EE, sel[:m], y, qlo, qhi, Xb, Eb, radius, P, lo, hi, nonempty, slot_tri, slo,
                           shi)
    ov, ot, od = _merge(cm, co, cd, moved, nv, nt, nd)
    return ov, ot, od, nmoved


@numba.njit(cache=True)
def _guard(edges, xa, Ea, Rb, pb, llo, lhi, wlo, whi, reach):
    """The vertices of a (``edges`` False) or its edges ``Ea`` (True) whose points, in b's axes (``Rb``,
    ``pb``), lie within ``reach`` [m] of the box of b's vertices in its own axes (``llo``, ``lhi``), and in the
    world within ``reach`` of their world box (``wlo``, ``whi``; a triangle's points are in both boxes): rows (id,
    position(s) in b's axes), (g, 4) for vertices, (g, 7) for edges. The others are farther than ``reach`` from
    every point of b's surface. The world box is tested first, without the change of axes (most of a body's
    vertices are far from the other's box)."""
    n = Ea.shape[0] if edges else xa.shape[0]
    out = np.empty((n, 7 if edges else 4))
    y0 = np.empty(3)
    y1 = np.empty(3)
    g = 0
    for k in range(n):
        i, j = (Ea[k, 0], Ea[k, 1]) if edges else (k, k)
        ok = True
        for c in range(3):
            if min(xa[i, c], xa[j, c]) > whi[c] + reach or max(xa[i, c], xa[j, c]) < wlo[c] - reach:
                ok = False
        if not ok:
            continue
        _to_local(xa[i], Rb, pb, y0)
        if edges:
            _to_local(xa[j], Rb, pb, y1)
        else:
            y1[:] = y0
        for c in range(3):
            if min(y0[c], y1[c]) > lhi[c] + reach or max(y0[c], y1[c]) < llo[c] - reach:
                ok = False
        if not ok:
            continue
        out[g, 0] = k
        for c in range(3):
            out[g, 1 + c] = y0[c]
            if edges:
                out[g, 4 + c] = y1[c]
        g += 1
    return out[:g].copy()


#: layout of a pair's row in the coherence cache's ``meta`` (see ``coherent_pairs``)
_M_AB, _T_AB, _M_BA, _T_BA, _BOUND_A, _BOUND_B, _R_VF, _R_EE, _VALID = 0, 9, 12, 21, 24, 25, 26, 27, 28
_EVAL = 29  # the same frames and bounds (_M_AB ... _BOUND_B) at the pair's last evaluation, from here
_FMAX_A, _FMAX_B = 55, 56  # the most a's and b's surfaces moved in their own axes since the walk (at the steps seen)
_R_G = 57  # the guard radius: primitives farther from the other body at the walk were left out of the re-walk rows
META = 58
#: the guard band, in slacks: primitives within (search radius + GUARD slack) of the other body at a pair's walk are
#: watched for partial re-walks (while the pair's bodies have moved less than that band since the walk)
GUARD = 4.0


@numba.njit(cache=True)
def _relative(Ra, Rb, pa, pb, M, t):
    """a's body axes in b's: ``y = M x + t`` with ``M = Rb^T Ra``, ``t = Rb^T (pa - pb)`` [m]."""
    for i in range(3):
        for j in range(3):
            M[3 * i + j] = Rb[0, i] * Ra[0, j] + Rb[1, i] * Ra[1, j] + Rb[2, i] * Ra[2, j]
        t[i] = Rb[0, i] * (pa[0] - pb[0]) + Rb[1, i] * (pa[1] - pb[1]) + Rb[2, i] * (pa[2] - pb[2])


@numba.njit(cache=True, inline="always")
def _turn_norm(M, M0, A):
    """An upper bound of the spectral norm of ``A = M - M0`` (3x3 row-major; written into ``A`` (9,)), as
    ``_drift`` explains (the smaller of the Laguerre-Samuelson and the Frobenius bound, grown by their rounding)."""
    for i in range(9):
        A[i] = M[i] - M0[i]
    fro2 = 0.0
    for i in range(9):
        fro2 += A[i] * A[i]
    s2 = 0.0  # ||S||_F^2, S_jk = sum_i A_ij A_ik
    for j in range(3):
        for k in range(3):
            v = A[j] * A[k] + A[3 + j] * A[3 + k] + A[6 + j] * A[6 + k]
            s2 += v * v
    mu = fro2 / 3.0
    # rounding: s2 - 3 mu^2 is off by at most ~10 eps s2 <= 10 eps fro2^2, its root by 4e-8 fro2
    lam = min(fro2 * (1.0 + 1e-12), mu + math.sqrt(max(2.0 / 3.0 * (s2 - 3.0 * mu * mu), 0.0)) + 1e-7 * fro2)
    return math.sqrt(lam)


@numba.njit(cache=True)
def _drift(M, t, M0, t0, size):
    """Largest move [m] of a point within ``size`` of a's centre (in a's axes) when a's axes in b's go from
    (M0, t0) to (M, t): ``|(M - M0) x + (t - t0)| <= ||M - M0||_2 |x| + |t - t0|``, with the spectral norm bounded
    through the eigenvalues of ``S = A^T A`` (A = M - M0, 3x3): the largest is at most ``mu + sqrt(2/3 ||S - mu
    I||_F^2)``, mu = tr(S) / 3 (Laguerre-Samuelson: no value of a list of three is farther above their mean than
    sqrt(2) of their standard deviation), and at most tr(S) = ||A||_F^2 (the smaller kept, each grown by a bound
    on its rounding). For a change of rotation by theta, ||A||_F = 2 sqrt(2) sin(theta / 2), the bound 2
    sqrt(4/3) sin(theta / 2) and the true norm 2 sin(theta / 2): the walks' reuse test admits 18 % more turning
    than with the Frobenius norm (was)."""
    A = np.empty(9)
    norm = _turn_norm(M, M0, A)
    d = 0.0
    for i in range(3):
        d += (t[i] - t0[i]) ** 2
    return norm * size + math.sqrt(d)


@numba.njit(cache=True)
def _deformed(q, o, r, amp, snap):
    """Largest move [m] of any surface vertex of a body in its own axes since its modal coordinates were ``snap``:
    ``sum_m amp_m |q_m - snap_m|`` (amp_m = max over vertices of |Phi_v m|), plus the rounding of the products
    (1e-5 of ``sum_m amp_m (|q_m| + |snap_m|)``, above float32's for up to ~80 modes) and 1e-12 m (float64
    rounding of the coordinates; the positions' flush of modes below 1e-20 m is within it)."""
    s = 0.0
    u = 0.0
    for m in range(r):
        s += amp[o + m] * abs(q[o + m] - snap[m])
        u += amp[o + m] * (abs(q[o + m]) + abs(snap[m]))
    return s + 1e-5 * u + 1e-12


@numba.njit(cache=True)
def _drift_at(M, t, M0, t0, c, size):
    """Largest move [m] of a point within ``size`` of ``c`` (a's axes) when a's axes in b's go from (M0, t0) to
    (M, t): ``|A c + t - t0| + ||A||_2 size`` (A = M - M0, the spectral norm bounded as in ``_drift``), plus 1e-12
    m for rounding. ``_drift`` is the case c = 0; with c at the region where contacts can be, the turn's lever is
    that region's radius, not the body's."""
    A = np.empty(9)
    norm = _turn_norm(M, M0, A)
    d = 0.0
    for i in range(3):
        u = A[3 * i] * c[0] + A[3 * i + 1] * c[1] + A[3 * i + 2] * c[2] + t[i] - t0[i]
        d += u * u
    return norm * size + math.sqrt(d) + 1e-12


@numba.njit(cache=True)
def _near_ball(Ra, pa, blo, bhi, a, b, grow, c):
    """Centre ``c`` (written, in a's axes: ``Ra`` its rotation, ``pa`` its centre [m]) and radius [m] of a ball
    holding every point of the world box where a's and b's boxes (``blo``, ``bhi`` rows a, b), each grown by
    ``grow`` [m], overlap (a point when they do not: then no pair is within reach)."""
    h2 = 0.0
    w = np.empty(3)
    for d in range(3):
        lo = max(blo[a, d], blo[b, d]) - grow
        hi = min(bhi[a, d], bhi[b, d]) + grow
        if hi < lo:
            lo = hi = 0.5 * (lo + hi)
        w[d] = 0.5 * (lo + hi) - pa[d]
        h2 += (0.5 * (hi - lo)) ** 2
    for i in range(3):
        c[i] = Ra[0, i] * w[0] + Ra[1, i] * w[1] + Ra[2, i] * w[2]
    return math.sqrt(h2) * (1.0 + 1e-12) + 1e-12


@numba.njit(cache=True)
def coherent_pairs(pa, pb, rr, mm, slack, X, Xl, voff, R, pos, bound, radius, q, qoff, nm, amp, blo, bhi, tris, toff,
                   edges, eoff, adj, meta, qsnap, cva, cta, cvb, ctb, cem, ceo, cla, clb, cle, cya, cyb, cye,
                   tP, tlo, thi, tne, tslot, tslo, tshi, eP, elo, ehi, ene, eslot, eslo, eshi):
    """``all_pairs`` with temporal coherence: the same contacts in the same order, the trees walked only when a
    pair's bodies have moved, relative to each other or in shape, more than a slack since its last walk.

    Why nothing is missed: the walk of pair (a, b) at time t0 keeps every (vertex, triangle) pair within
    ``R = reach + slack`` [m] and every (edge, edge) pair within ``Re = margin + slack`` (``_vf_candidates``,
    ``_ee_candidates``), and records a's axes in b's (M0, t0), both bodies' modal coordinates and deformation
    bounds. Later a vertex of a, at ``x`` in a's axes (``|x| <= radius_a + bound_a(t0)`` then), sits in b's axes
    at ``M x + t``; since t0 it has moved by at most ``da = ||M - M0||_F (radius_a + bound_a(t0)) + |t - t0| +
    deform_a`` (``_drift``; deform_a: ``_deformed``, the most any vertex moved in a's own axes), and every point
    of b's triangles by at most ``deform_b`` in b's axes. Point-triangle and segment-segment distances move by
    at most the sum of their ends' moves (1-Lipschitz; a triangle's points are convex combinations of its
    corners), so a pair farther than R at t0 is farther than ``R - da - deform_b`` now. The kept pairs are
    therefore a superset of the pairs within this step's ``reach`` (``margin``) while ``reach + da + deform_b
    <= R`` (``margin + da + deform_b <= Re``), and the same both ways with a and b swapped; else the pair is
    walked again with this step's radii. ``_vf_eval`` / ``_ee_eval`` then test the kept pairs in the order the
    walk met them: the same selection, ties included, as ``vertex_face`` / ``edge_edge``. The same bound from the
    pair's last evaluation (its frames and modal coordinates then) lets them skip a kept pair whose distance then,
    lowered by the motion since, is still beyond reach (margin).

    Two refinements of that bound: (1) the distance of a pair is the same in either body's axes, so the drop may be
    measured in b's axes (a's point moved by da, b's by deform_b) or in a's (b's point by db, a's by deform_a):
    ``min(da + deform_b, db + deform_a)`` serves all three tests and the evaluations' skips; (2) a pair within
    reach now has its closest points (a convex combination of its corners, so deformed by at most deform) in the
    overlap of the two bodies' current world boxes grown by ``reach``; their move since the walk is bounded by
    ``_drift_at`` about the centre of a ball holding that overlap (``_near_ball``), grown by the deformation since,
    instead of by ``_drift`` over the whole body (the smaller kept; tried only when the whole-body test fails).

    Partial re-walks: when that test fails but the pair has moved less than a guard band ``GUARD * slack`` beyond
    it (``reach + dm <= R + guard``), only a primitive that was within ``R + guard`` of the other body's box at the
    walk can be within reach now (``_guard`` lists them, with their positions in the other body's axes); of those,
    the ones that moved, in the other body's axes, more than ``R - reach - (the other surface's deformation since
    their walk: at most its deformation now plus the most seen since the pair's walk)`` are walked again
    (``_vf_rewalk``, ``_ee_rewalk``; exact moves, a segment's by its ends'), the others keep their candidates. The
    row is then marked 2: its lists no longer match one walk's frames, so the whole-pair test is skipped until the
    next full walk (once the guard band or half the slack is used up).

    Args:
        pa ... bhi, tris ... adj, tP ... eshi: as ``all_pairs``; slack: (p,) [m]; radius: (n,) the bodies' rest
            radii about their centres of mass [m]; q: every body's modal coordinates, body i's ``nm[i]`` from
            ``qoff[i]``; amp: the same layout, max over vertices of |Phi_v m| [m / q unit].
        meta, qsnap, cva ... cle: the cache, one row per ordered pair ``a * n + b`` (a < b): ``meta`` (n*n,
            ``META``) floats, ``qsnap`` (n*n, 4, max modes) (a's and b's at the walk, then at the last
            evaluation), typed lists of int64 arrays (a's vertices on b's triangles, b's vertices on a's, a's edges on
            b's) and of the float lower bounds of their distances [m], then (``cya``, ``cyb``, ``cye``) the guard
            rows of a's vertices, b's vertices and a's edges (``_guard``). Updated in place.

    Returns:
        ``(vf, ee, walks)``: as ``all_pairs``, and the number of pairs whose trees were walked (wholly or in part).
    """
    nb = voff.shape[0] - 1
    scale = np.ones(nb)
    llo = np.full((nb, 3), np.inf)  # the boxes of the bodies' deformed surfaces in their own axes [m]
    lhi = np.full((nb, 3), -np.inf)
    for i in range(nb):
        for v in range(voff[i], voff[i + 1]):
            for c in range(3):
                scale[i] = max(scale[i], abs(Xl[v, c]))
                llo[i, c] = min(llo[i, c], Xl[v, c])
                lhi[i, c] = max(lhi[i, c], Xl[v, c])
    M = np.empty(9)
    t = np.empty(3)
    M2 = np.empty(9)
    t2 = np.empty(3)
    vl_a = numba.typed.List()
    vl_b = numba.typed.List()
    vl = numba.typed.List()
    el_a = numba.typed.List()
    el_b = numba.typed.List()
    el = numba.typed.List()
    nvf = 0
    nee = 0
    walks = 0
    cA = np.empty(3)
    cB = np.empty(3)
    for i in range(pa.shape[0]):
        a, b = pa[i], pb[i]
        s = a * nb + b
        row = meta[s]
        _relative(R[a], R[b], pos[a], pos[b], M, t)
        _relative(R[b], R[a], pos[b], pos[a], M2, t2)
        ok = False
        fa = fb = 0.0
        dm = np.inf
        if row[_VALID] > 0.0:
            fa = _deformed(q, qoff[a], nm[a], amp, qsnap[s, 0])
            fb = _deformed(q, qoff[b], nm[b], amp, qsnap[s, 1])
            da = _drift(M, t, row[_M_AB:_M_AB + 9], row[_T_AB:_T_AB + 3], radius[a] + row[_BOUND_A]) + fa
            db = _drift(M2, t2, row[_M_BA:_M_BA + 9], row[_T_BA:_T_BA + 3], radius[b] + row[_BOUND_B]) + fb
            dm = min(da + fb, db + fa)
            # (_VALID 2.0: part of the pair re-walked since, so the whole-pair test no longer holds)
            ok = row[_VALID] == 1.0 and rr[i] + dm <= row[_R_VF] and mm[i] + dm <= row[_R_EE]
            if not ok:
                ha = _near_ball(R[a], pos[a], blo, bhi, a, b, rr[i], cA) + fa
                hb = _near_ball(R[b], pos[b], blo, bhi, a, b, rr[i], cB) + fb
                da = min(da, _drift_at(M, t, row[_M_AB:_M_AB + 9], row[_T_AB:_T_AB + 3], cA, ha) + fa)
                db = min(db, _drift_at(M2, t2, row[_M_BA:_M_BA + 9], row[_T_BA:_T_BA + 3], cB, hb) + fb)
                dm = min(da + fb, db + fa)
                ok = row[_VALID] == 1.0 and rr[i] + dm <= row[_R_VF] and mm[i] + dm <= row[_R_EE]
        if not ok and row[_VALID] > 0.0 and rr[i] + dm <= row[_R_VF] + row[_R_G] and mm[i] + dm <= row[_R_EE] + row[_R_G]:
            # every primitive that can be within reach now was in the guard band at the walk (its distance then was
            # at most reach + dm): re-walk only those that moved more than the slack left since their own walk
            fma = max(row[_FMAX_A], fa)
            fmb = max(row[_FMAX_B], fb)
            thr_a = row[_R_VF] - rr[i] - fb - fmb - 1e-12  # a's vertices against b's triangles
            thr_b = row[_R_VF] - rr[i] - fa - fma - 1e-12
            thr_e = row[_R_EE] - mm[i] - fb - fmb - 1e-12
            if min(thr_a, min(thr_b, thr_e)) >= 0.5 * slack[i]:
                ok = True
                row[_VALID] = 2.0
                row[_FMAX_A], row[_FMAX_B] = fma, fmb
                cva[s], cta[s], cla[s], n1 = _vf_rewalk(X[voff[a]:voff[a + 1]], R[b], pos[b], Xl[voff[b]:voff[b + 1]],
                                                        tris[toff[b]:toff[b + 1]], bound[b], row[_R_VF], blo[b], bhi[b],
                                                        tP[b], tlo[b], thi[b], tne[b], tslot[b], tslo[b], tshi[b],
                                                        cva[s], cta[s], cla[s], cya[s], thr_a)
                cvb[s], ctb[s], clb[s], n2 = _vf_rewalk(X[voff[b]:voff[b + 1]], R[a], pos[a], Xl[voff[a]:voff[a + 1]],
                                                        tris[toff[a]:toff[a + 1]], bound[a], row[_R_VF], blo[a], bhi[a],
                                                        tP[a], tlo[a], thi[a], tne[a], tslot[a], tslo[a], tshi[a],
                                                        cvb[s], ctb[s], clb[s], cyb[s], thr_b)
                cem[s], ceo[s], cle[s], n3 = _ee_rewalk(X[voff[a]:voff[a + 1]], edges[eoff[a]:eoff[a + 1]], R[b],
                                                        pos[b], Xl[voff[b]:voff[b + 1]], edges[eoff[b]:eoff[b + 1]],
                                                        bound[b], row[_R_EE], blo[b], bhi[b], eP[b], elo[b], ehi[b],
                                                        ene[b], eslot[b], eslo[b], eshi[b], cem[s], ceo[s], cle[s],
                                                        cye[s], thr_e)
                if n1 + n2 + n3 > 0:
                    walks += 1
        if not ok:
            walks += 1
            row[_R_VF] = rr[i] + slack[i]
            row[_R_EE] = mm[i] + slack[i]
            row[_M_AB:_M_AB + 9] = M
            row[_T_AB:_T_AB + 3] = t
            row[_M_BA:_M_BA + 9] = M2
            row[_T_BA:_T_BA + 3] = t2
            row[_BOUND_A], row[_BOUND_B] = bound[a], bound[b]
            row[_VALID] = 1.0
            row[_FMAX_A], row[_FMAX_B] = 0.0, 0.0
            qsnap[s, 0, :nm[a]] = q[qoff[a]:qoff[a] + nm[a]]
            qsnap[s, 1, :nm[b]] = q[qoff[b]:qoff[b] + nm[b]]
            for side in range(2):
                p, o = (a, b) if side == 0 else (b, a)
                cv, ct, cd = _vf_candidates(X[voff[p]:voff[p + 1]], R[o], pos[o], Xl[voff[o]:voff[o + 1]],
                                        tris[toff[o]:toff[o + 1]], bound[o], row[_R_VF], blo[o], bhi[o], tP[o],
                                        tlo[o], thi[o], tne[o], tslot[o], tslo[o], tshi[o])
                if side == 0:
                    cva[s], cta[s], cla[s] = cv, ct, cd
                else:
                    cvb[s], ctb[s], clb[s] = cv, ct, cd
            cm, co, cd = _ee_candidates(X[voff[a]:voff[a + 1]], edges[eoff[a]:eoff[a + 1]], R[b], pos[b],
                                    Xl[voff[b]:voff[b + 1]], edges[eoff[b]:eoff[b + 1]], bound[b], row[_R_EE], blo[b],
                                    bhi[b], eP[b], elo[b], ehi[b], ene[b], eslot[b], eslo[b], eshi[b])
            cem[s], ceo[s], cle[s] = cm, co, cd
            row[_R_G] = GUARD * slack[i]
            none = edges[eoff[a]:eoff[a]]
            cya[s] = _guard(False, X[voff[a]:voff[a + 1]], none, R[b], pos[b], llo[b], lhi[b], blo[b], bhi[b],
                            row[_R_VF] + row[_R_G])
            cyb[s] = _guard(False, X[voff[b]:voff[b + 1]], none, R[a], pos[a], llo[a], lhi[a], blo[a], bhi[a],
                            row[_R_VF] + row[_R_G])
            cye[s] = _guard(True, X[voff[a]:voff[a + 1]], edges[eoff[a]:eoff[a + 1]], R[b], pos[b], llo[b], lhi[b],
                            blo[b], bhi[b], row[_R_EE] + row[_R_G])
            # evaluated now: no motion since, and the distances (or gaps) the walk found are the pairs' bounds (the
            # kept pairs beyond this step's reach or margin, in the slack, are not tested again)
            row[_EVAL:_EVAL + 26] = row[0:26]
            qsnap[s, 2], qsnap[s, 3] = qsnap[s, 0], qsnap[s, 1]
        # how far the pair's distances may have dropped since its last evaluation (as the walk's test above)
        fa = _deformed(q, qoff[a], nm[a], amp, qsnap[s, 2])
        fb = _deformed(q, qoff[b], nm[b], amp, qsnap[s, 3])
        e = _EVAL
        drop_a = _drift(M, t, row[e + _M_AB:e + _M_AB + 9], row[e + _T_AB:e + _T_AB + 3],
                        radius[a] + row[e + _BOUND_A]) + fa + fb
        drop_b = _drift(M2, t2, row[e + _M_BA:e + _M_BA + 9], row[e + _T_BA:e + _T_BA + 3],
                        radius[b] + row[e + _BOUND_B]) + fb + fa
        drop = min(drop_a, drop_b)  # (the same in either body's axes: the smaller serves both sides)
        for side in range(2):
            p, o = (a, b) if side == 0 else (b, a)
            out = _vf_eval(X[voff[p]:voff[p + 1]], R[o], pos[o], Xl[voff[o]:voff[o + 1]], tris[toff[o]:toff[o + 1]],
                           rr[i], cva[s] if side == 0 else cvb[s], cta[s] if side == 0 else ctb[s],
                           cla[s] if side == 0 else clb[s], drop)
            if out[0].shape[0]:
                vl_a.append(p)
                vl_b.append(o)
                vl.append(out)
                nvf += out[0].shape[0]
        out2 = _ee_eval(X[voff[a]:voff[a + 1]], edges[eoff[a]:eoff[a + 1]], R[b], pos[b], Xl[voff[b]:voff[b + 1]],
                        edges[eoff[b]:eoff[b + 1]], adj[eoff[b]:eoff[b + 1]], tris[toff[b]:toff[b + 1]], mm[i],
                        scale[b], cem[s], ceo[s], cle[s], drop)
        if out2[0].shape[0]:
            el_a.append(a)
            el_b.append(b)
            el.append(out2)
            nee += out2[0].shape[0]
        row[e + _M_AB:e + _M_AB + 9] = M
        row[e + _T_AB:e + _T_AB + 3] = t
        row[e + _M_BA:e + _M_BA + 9] = M2
        row[e + _T_BA:e + _T_BA + 3] = t2
        row[e + _BOUND_A], row[e + _BOUND_B] = bound[a], bound[b]
        qsnap[s, 2, :nm[a]] = q[qoff[a]:qoff[a] + nm[a]]
        qsnap[s, 3, :nm[b]] = q[qoff[b]:qoff[b] + nm[b]]
    vf, ee = _gather(vl_a, vl_b, vl, nvf, el_a, el_b, el, nee)
    return vf, ee, walks


@numba.njit(cache=True)
def box_pairs(lo, hi, marg, reach):
    """The body pairs a < b whose world boxes (``lo``, ``hi`` (n, 3) [m]) meet within ``rr = max(marg_a, marg_b) +
    reach_a + reach_b`` [m], in increasing (a, b) order: ``(a, b, rr, mm)`` (k,) each, ``mm`` the larger margin."""
    n = lo.shape[0]
    k = 0
    ia = np.empty(n * (n - 1) // 2, dtype=np.int64)
    ib = np.empty_like(ia)
    rr = np.empty(ia.shape[0])
    mm = np.empty(ia.shape[0])
    for a in range(n):
        for b in range(a + 1, n):
            m = max(marg[a], marg[b])
            r = m + reach[a] + reach[b]
            ok = True
            for c in range(3):
                if not (lo[a, c] - r <= hi[b, c] and lo[b, c] - r <= hi[a, c]):
                    ok = False
            if ok:
                ia[k], ib[k], rr[k], mm[k] = a, b, r, m
                k += 1
    return ia[:k], ib[:k], rr[:k], mm[:k]
