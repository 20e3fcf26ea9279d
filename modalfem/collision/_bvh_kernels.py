"""Compiled kernels of the broad phase: BVH refits, traversal with normal-cone and contour culling
(:mod:`modalfem.collision._contour_kernels`), box queries.

Plain loops over nodes and pairs with explicit stacks (numba ``njit``, compiled on first call and cached
on disk). The data layout is :class:`modalfem.collision.bvh.BroadPhaseBVH`'s: nodes ``1..2P-1`` of a
complete binary tree (leaves ``P..2P-1``), per-node boxes ``lo``/``hi`` (2P, 3) [m], per-leaf triangle
slots ``slot_tri`` (P, L) (-1: empty) and their boxes ``slo``/``shi`` (3, P, L) [m].

numba's disk cache does not notice edits of the other modules a kernel calls: after changing
:mod:`modalfem.collision._contour_kernels` or :mod:`modalfem.collision._pair_kernels`, delete
``modalfem/collision/__pycache__``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem._threads import apply as _apply_threads
from modalfem.collision._contour_kernels import contour_ok
from modalfem.collision._pair_kernels import _concat4, _primitive_range
from modalfem._threads import MAX_CHUNKS, chunk_bounds, chunk_count

__all__ = ["query", "refit", "refit_boxes", "refit_triangles", "traverse", "traverse_dirty", "traverse_primitives"]

_HALF_PI = 0.5 * math.pi - 1e-9

_apply_threads()


@numba.njit(cache=True)
def _grow(buf: np.ndarray, count: int) -> np.ndarray:
    """``buf`` (k, 2) with room for at least one more row past ``count``."""
    if count < len(buf):
        return buf
    out = np.empty((2 * len(buf) + 16, buf.shape[1]), dtype=buf.dtype)
    out[:count] = buf[:count]
    return out


@numba.njit(cache=True)
def _adjacent(adj: np.ndarray, key: int) -> bool:
    """``key`` is in the sorted ``adj`` (binary search)."""
    lo, hi = 0, len(adj)
    while lo < hi:
        mid = (lo + hi) // 2
        if adj[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo < len(adj) and adj[lo] == key


@numba.njit(cache=True)
def _angle(ax: np.ndarray, b: np.ndarray) -> float:
    c = ax[0] * b[0] + ax[1] * b[1] + ax[2] * b[2]
    return math.acos(min(max(c, -1.0), 1.0))


@numba.njit(cache=True, inline="always")
def _slots_meeting(slot, slo, shi, leaf: int, lo, hi, node: int, every: bool, out):
    """The slots of ``leaf`` whose triangle box overlaps node ``node``'s box (``lo``/``hi``; all its triangles'
    slots when ``every``), written to ``out`` in slot order: ``(how many, how many triangles the leaf holds)``."""
    n = held = 0
    for r in range(slot.shape[1]):
        if slot[leaf, r] < 0:
            continue
        held += 1
        out[n] = r
        n += every | ((slo[0, leaf, r] <= hi[node, 0]) & (lo[node, 0] <= shi[0, leaf, r])
                      & (slo[1, leaf, r] <= hi[node, 1]) & (lo[node, 1] <= shi[1, leaf, r])
                      & (slo[2, leaf, r] <= hi[node, 2]) & (lo[node, 2] <= shi[2, leaf, r]))
    return n, held


@numba.njit(cache=True)
def _leaf_triangle_pairs(leaves: np.ndarray, count: int, same: bool, Pa: int, lo_a, hi_a, slot_a, slo_a, shi_a, Pb: int,
                         lo_b, hi_b, slot_b, slo_b, shi_b, filt: bool, dirty_tris):
    """Triangle pairs of the leaf pairs ``leaves[:count]`` (leaf indices) whose boxes overlap, and the number
    of tests (a leaf paired with itself: each unordered pair of its triangles once).

    Of two different leaves, only the triangles of a whose box overlaps b's leaf box (``lo_b``/``hi_b`` of node
    ``Pb + leaf``) are tested against those of b overlapping a's leaf box (a triangle outside the other leaf's box
    overlaps none of its triangles): the same pairs in the same order as all L x L tests, about half the tests on
    the 64x64 pile. The count of tests stays that of all pairs of the two leaves' triangles. The box tests of a
    row run branch-free (they fail unpredictably)."""
    L, Lb = slot_a.shape[1], slot_b.shape[1]
    out = np.empty((count * L * Lb, 2), dtype=np.int64)
    rows = np.empty(L, dtype=np.int64)
    cols = np.empty(Lb, dtype=np.int64)
    n = 0
    tests = 0
    for p in range(count):
        ia, ib = leaves[p, 0], leaves[p, 1]
        na, nb = Pa + ia, Pb + ib
        self_leaf = same and ia == ib
        nr, cnt_a = _slots_meeting(slot_a, slo_a, shi_a, ia, lo_b, hi_b, nb, self_leaf, rows)
        ncol, cnt_b = _slots_meeting(slot_b, slo_b, shi_b, ib, lo_a, hi_a, na, self_leaf, cols)
        tests += cnt_a * (cnt_a - 1) // 2 if self_leaf else cnt_a * cnt_b
        for i in range(nr):
            r = rows[i]
            ta = slot_a[ia, r]
            alo0, alo1, alo2 = slo_a[0, ia, r], slo_a[1, ia, r], slo_a[2, ia, r]
            ahi0, ahi1, ahi2 = shi_a[0, ia, r], shi_a[1, ia, r], shi_a[2, ia, r]
            da = filt and dirty_tris[ta]
            for j in range(i + 1 if self_leaf else 0, ncol):
                c = cols[j]
                tb = slot_b[ib, c]
                ok = ((alo0 <= shi_b[0, ib, c]) & (slo_b[0, ib, c] <= ahi0) & (alo1 <= shi_b[1, ib, c])
                      & (slo_b[1, ib, c] <= ahi1) & (alo2 <= shi_b[2, ib, c]) & (slo_b[2, ib, c] <= ahi2))
                # written always, kept by the count: no branch on the box tests
                out[n, 0], out[n, 1] = ta, tb
                if filt:
                    n += ok & (da | (same & dirty_tris[tb]))
                else:
                    n += ok
    return out[:n].copy(), tests


@numba.njit(cache=True, inline="always")
def _box_size(lo, hi, a: int) -> float:
    """Sum of the side lengths of node ``a``'s box [m] (which side of a node pair a walk descends)."""
    return (hi[a, 0] - lo[a, 0]) + (hi[a, 1] - lo[a, 1]) + (hi[a, 2] - lo[a, 2])


@numba.njit(cache=True, inline="always")
def _push_children(stack, top: int, a: int, b: int, depth: int, descend_a: bool):
    """Push the children of node pair ``(a, b)`` onto a walk's ``(node a, node b, depth)`` stack: a's two
    children paired with b when ``descend_a``, else a with b's two; returns the stack (grown if needed) and its
    new top."""
    if top + 2 > len(stack):
        stack = _grow(stack, top + 2)
    if descend_a:
        stack[top, 0], stack[top, 1], stack[top, 2] = 2 * a, b, depth + 1
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = 2 * a + 1, b, depth + 1
    else:
        stack[top, 0], stack[top, 1], stack[top, 2] = a, 2 * b, depth + 1
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = a, 2 * b + 1, depth + 1
    return stack, top + 2


@numba.njit(cache=True)
def _walk(a0: int, b0: int, split: int, same: bool, culling: bool, Pa: int, lo_a, hi_a, ne_a, Pb: int, lo_b, hi_b,
          ne_b, connected, cone_axis, cone_angle, adj, bnd_start, bnd_edge, bnd_id, limit: int, x0, x1, static: bool,
          check_contour: bool, dirty_nodes, nd, gap: float):
    """Depth-first walk from the node pair ``(a0, b0)`` (see :func:`traverse`).

    ``nd`` (2P, 8) (empty: no such test; a tree against itself only): per node the union of its triangles'
    intervals on the four box diagonals (:func:`node_diagonals`); a node pair whose intervals on one diagonal are
    more than ``gap`` apart is not walked (every triangle pair under it is that far apart, which the expansion
    drops: :func:`modalfem.collision._pair_kernels._primitive_range`).

    ``split`` < 0: returns the leaf pairs reached (leaf indices), in depth-first order. ``split`` >= 0:
    returns node pairs instead, for :func:`traverse` to walk from in parallel: every pair popped at depth
    ``split`` (not tested) and every pair that would give a leaf pair above it, in depth-first order, so
    that the walks from them, concatenated, give the leaf pairs of one whole walk in its order.
    """
    filt = len(dirty_nodes) > 0
    use_nd = len(nd) > 0
    stack = np.empty((256, 3), dtype=np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2] = a0, b0, 0
    top = 1
    leaves = np.empty((1024, 2), dtype=np.int64)
    count = 0
    ax = np.empty(3)
    while top:
        top -= 1
        a, b, depth = stack[top, 0], stack[top, 1], stack[top, 2]
        if split >= 0 and depth >= split:
            if count == len(leaves):
                leaves = _grow(leaves, count)
            leaves[count, 0], leaves[count, 1] = a, b
            count += 1
            continue
        if same and a == b:  # the node's self-test
            if not ne_a[a] or (filt and not dirty_nodes[a]):
                continue
            if culling and connected[a] and cone_angle[a] < _HALF_PI and (
                    not check_contour
                    or contour_ok(a, -1, cone_axis[a], bnd_start, bnd_edge, bnd_id, limit, x0, x1, static)):
                continue
            if a >= Pa:
                if count == len(leaves):
                    leaves = _grow(leaves, count)
                leaves[count, 0], leaves[count, 1] = (a, a) if split >= 0 else (a - Pa, a - Pa)
                count += 1
                continue
            if top + 3 > len(stack):
                stack = _grow(stack, top + 3)
            stack[top, 0], stack[top, 1], stack[top, 2] = 2 * a, 2 * a, depth + 1
            stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = 2 * a + 1, 2 * a + 1, depth + 1
            stack[top + 2, 0], stack[top + 2, 1], stack[top + 2, 2] = 2 * a, 2 * a + 1, depth + 1
            top += 3
            continue
        if filt and not (dirty_nodes[a] or (same and dirty_nodes[b])):
            continue
        if not (ne_a[a] and ne_b[b]):
            continue
        if (lo_a[a, 0] > hi_b[b, 0] or lo_b[b, 0] > hi_a[a, 0] or lo_a[a, 1] > hi_b[b, 1] or lo_b[b, 1] > hi_a[a, 1]
                or lo_a[a, 2] > hi_b[b, 2] or lo_b[b, 2] > hi_a[a, 2]):
            continue
        if use_nd:
            apart = False
            for d in range(4):
                apart = apart | (nd[a, d] > nd[b, 4 + d] + gap) | (nd[b, d] > nd[a, 4 + d] + gap)
            if apart:
                continue
        if same and culling and connected[a] and connected[b] and _adjacent(adj, a * (2 * Pa) + b):
            # two adjacent patches whose union is one patch with a narrow normal cone: skip
            for i in range(3):
                ax[i] = cone_axis[a, i] + cone_axis[b, i]
            nrm = max(math.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]), 1e-300)
            for i in range(3):
                ax[i] /= nrm
            ang = max(_angle(ax, cone_axis[a]) + cone_angle[a], _angle(ax, cone_axis[b]) + cone_angle[b])
            if ang < _HALF_PI and (not check_contour or contour_ok(a, b, ax, bnd_start, bnd_edge, bnd_id, limit,
                                                                   x0, x1, static)):
                continue
        leaf_a, leaf_b = a >= Pa, b >= Pb
        if leaf_a and leaf_b:
            if count == len(leaves):
                leaves = _grow(leaves, count)
            leaves[count, 0], leaves[count, 1] = (a, b) if split >= 0 else (a - Pa, b - Pb)
            count += 1
            continue
        stack, top = _push_children(stack, top, a, b, depth, not leaf_a and (
            leaf_b or _box_size(lo_a, hi_a, a) >= _box_size(lo_b, hi_b, b)))
    return leaves[:count]


@numba.njit(cache=True)
def node_diagonals(P: int, slot_tri, fdiag):
    """(2P, 8): per node the union of its triangles' intervals on the four box diagonals (``fdiag`` (m, 8),
    ``lo_0..lo_3, hi_0..hi_3`` per triangle; empty nodes +inf / -inf): a node pair whose intervals on one diagonal
    are more than the expansion's gap apart holds only triangle pairs that far apart."""
    L = slot_tri.shape[1]
    nd = np.empty((2 * P, 8))
    nd[:, :4] = np.inf
    nd[:, 4:] = -np.inf
    for leaf in range(P):
        node = P + leaf
        for r in range(L):
            f = slot_tri[leaf, r]
            if f < 0:
                continue
            for d in range(4):
                nd[node, d] = min(nd[node, d], fdiag[f, d])
                nd[node, 4 + d] = max(nd[node, 4 + d], fdiag[f, 4 + d])
    for a in range(P - 1, 0, -1):
        for d in range(4):
            nd[a, d] = min(nd[2 * a, d], nd[2 * a + 1, d])
            nd[a, 4 + d] = max(nd[2 * a, 4 + d], nd[2 * a + 1, 4 + d])
    return nd


#: depth of the serial walk that hands node pairs to the parallel walks (a self-test splits in 3: up to
#: 3^6 = 729 tasks, fewer where pruned)
SPLIT_DEPTH = 6
#: node pairs per chunk of the parallel walks
TASK_CHUNK = 4


@numba.njit(cache=True)
def _walk_tasks(tasks, start: int, stop: int, same: bool, culling: bool, Pa: int, lo_a, hi_a, ne_a, slot_a, slo_a,
                shi_a, Pb: int, lo_b, hi_b, ne_b, slot_b, slo_b, shi_b, connected, cone_axis, cone_angle, adj,
                bnd_start, bnd_edge, bnd_id, limit: int, x0, x1, static: bool, check_contour: bool, dirty_nodes,
                dirty_tris, nd, gap: float):
    """Triangle pairs and leaf tests of the walks from ``tasks[start:stop]``, concatenated in task order."""
    filt = len(dirty_nodes) > 0
    leaves = np.empty((0, 2), dtype=np.int64)
    for t in range(start, stop):
        got = _walk(tasks[t, 0], tasks[t, 1], -1, same, culling, Pa, lo_a, hi_a, ne_a, Pb, lo_b, hi_b, ne_b,
                    connected, cone_axis, cone_angle, adj, bnd_start, bnd_edge, bnd_id, limit, x0, x1, static,
                    check_contour, dirty_nodes, nd, gap)
        if len(leaves) == 0:
            leaves = got
        elif len(got):
            both = np.empty((len(leaves) + len(got), 2), dtype=np.int64)
            both[:len(leaves)] = leaves
            both[len(leaves):] = got
            leaves = both
    return _leaf_triangle_pairs(leaves, len(leaves), same, Pa, lo_a, hi_a, slot_a, slo_a, shi_a, Pb, lo_b, hi_b,
                                slot_b, slo_b, shi_b, filt, dirty_tris)


@numba.njit(cache=True, parallel=True)
def traverse(same: bool, culling: bool, Pa: int, lo_a, hi_a, ne_a, slot_a, slo_a, shi_a,
             Pb: int, lo_b, hi_b, ne_b, slot_b, slo_b, shi_b,
             connected, cone_axis, cone_angle, adj, bnd_start, bnd_edge, bnd_id, limit: int,
             x0, x1, static: bool, check_contour: bool, dirty_nodes, dirty_tris):
    """Triangle pairs (tree a, tree b) whose boxes overlap, and the number of triangle-pair (leaf) tests.

    ``same``: b is a itself (each unordered pair once, no pair of a triangle with itself), with normal
    cone and contour culling when ``culling`` (a node that is one connected patch, with a cone narrower
    than a half-space and a non-crossing contour, is not tested against itself; two adjacent such
    patches are not tested against each other when their union passes both tests). ``dirty_nodes``
    (2Pa,) / ``dirty_tris`` (m_a,) (empty: no filter): only pairs holding a flagged triangle of tree a.

    A serial walk to depth ``SPLIT_DEPTH`` lists node pairs in depth-first order; chunks of them are
    walked, and their leaves tested, in parallel (:mod:`modalfem._threads`), and the chunks' pairs
    concatenated in order: the pairs, and their order, are those of one depth-first walk on any number
    of threads.
    """
    nd = np.zeros((0, 8))
    tasks = _walk(1, 1, SPLIT_DEPTH, same, culling, Pa, lo_a, hi_a, ne_a, Pb, lo_b, hi_b, ne_b, connected,
                  cone_axis, cone_angle, adj, bnd_start, bnd_edge, bnd_id, limit, x0, x1, static, check_contour,
                  dirty_nodes, nd, 0.0)
    T = len(tasks)
    chunks = max(1, min(MAX_CHUNKS, -(-T // TASK_CHUNK)))
    bufs = [np.empty((0, 2), dtype=np.int64) for _ in range(chunks)]
    tests = np.zeros(chunks, dtype=np.int64)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(T, chunks, ch)
        bufs[ch], tests[ch] = _walk_tasks(tasks, start, stop, same, culling, Pa, lo_a, hi_a, ne_a, slot_a, slo_a,
                                          shi_a, Pb, lo_b, hi_b, ne_b, slot_b, slo_b, shi_b, connected, cone_axis,
                                          cone_angle, adj, bnd_start, bnd_edge, bnd_id, limit, x0, x1, static,
                                          check_contour, dirty_nodes, dirty_tris, nd, 0.0)
    return _concat(bufs), tests.sum()


@numba.njit(cache=True, parallel=True)
def traverse_primitives(culling: bool, P: int, lo, hi, ne, slot, slo, shi, connected, cone_axis, cone_angle, adj,
                        bnd_start, bnd_edge, bnd_id, limit: int, x0, x1, static: bool, check_contour: bool,
                        tris, edges, own_v, own_e, vlo, vhi, flo, fhi, elo, ehi, diag, fdiag, gap):
    """:func:`traverse` of a tree against itself (no dirty filter) fused with the expansion of each chunk's
    triangle pairs into point-triangle and edge-edge pairs (:func:`modalfem.collision._pair_kernels
    ._primitive_range`, with the triangle and edge boxes ``flo``..``ehi`` of
    :func:`modalfem.collision._pair_kernels.primitive_boxes` and its diagonal test ``diag``, ``fdiag``, ``gap``)
    while they are in cache: the triangle pairs are never gathered into one list. The same pairs in the same
    order as :func:`traverse` followed by :func:`modalfem.collision._pair_kernels.primitive_pairs`, on any number
    of threads. With the diagonal test, node pairs apart on a diagonal (:func:`node_diagonals`) are not walked.

    Returns:
        ``(vf, ee, tests)``: (p, 4) and (q, 4) vertex quadruples and the leaf tests.
    """
    none = np.zeros(0, dtype=np.bool_)
    nd = node_diagonals(P, slot, fdiag) if len(diag) > 0 else np.zeros((0, 8))
    tasks = _walk(1, 1, SPLIT_DEPTH, True, culling, P, lo, hi, ne, P, lo, hi, ne, connected, cone_axis, cone_angle,
                  adj, bnd_start, bnd_edge, bnd_id, limit, x0, x1, static, check_contour, none, nd, gap)
    T = len(tasks)
    chunks = max(1, min(MAX_CHUNKS, -(-T // TASK_CHUNK)))
    vbufs = [np.empty((0, 4), dtype=np.int64) for _ in range(chunks)]
    ebufs = [np.empty((0, 4), dtype=np.int64) for _ in range(chunks)]
    tests = np.zeros(chunks, dtype=np.int64)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(T, chunks, ch)
        tp, tests[ch] = _walk_tasks(tasks, start, stop, True, culling, P, lo, hi, ne, slot, slo, shi, P, lo, hi, ne,
                                    slot, slo, shi, connected, cone_axis, cone_angle, adj, bnd_start, bnd_edge, bnd_id,
                                    limit, x0, x1, static, check_contour, none, none, nd, gap)
        vbufs[ch], ebufs[ch] = _primitive_range(tp, 0, len(tp), tris, edges, own_v, own_e, vlo, vhi, flo, fhi, elo,
                                                ehi, none, diag, fdiag, gap)
    return _concat4(vbufs), _concat4(ebufs), tests.sum()


@numba.njit(cache=True)
def _dirty_boxes_of(P: int, ids, leaf_of_tri, slot_of_tri, slo, shi):
    """Node boxes (2P, 3) [m] of the flagged triangles ``ids`` ((k,) int) only: per node the union of the slot boxes
    of its flagged triangles (empty, +inf / -inf, where it holds none), each one's slot box joined into its leaf and
    every ancestor (a minimum or maximum is exact in any order), O(k log P) after the fill. (Before: a pass over
    every slot testing its triangle's flag, then the internal nodes bottom-up; the same boxes.)"""
    dlo, dhi = np.full((2 * P, 3), np.inf), np.full((2 * P, 3), -np.inf)
    for f in ids:
        node, col = leaf_of_tri[f], slot_of_tri[f]
        leaf = node - P
        while node >= 1:
            for c in range(3):
                dlo[node, c] = min(dlo[node, c], slo[c, leaf, col])
                dhi[node, c] = max(dhi[node, c], shi[c, leaf, col])
            node >>= 1
    return dlo, dhi


@numba.njit(cache=True)
def _dirty_walk(a0: int, b0: int, split: int, P: int, dlo, dhi, lo, hi):
    """Depth-first walk of the node pairs (a, b) whose boxes overlap, a's box that of its flagged triangles only
    (``dlo``/``dhi``), b's its whole box (``lo``/``hi``), from ``(a0, b0)``: the leaf pairs reached (node
    indices), or with ``split`` >= 0 the pairs reached at that depth and the leaf pairs above it (as
    :func:`_walk`)."""
    stack = np.empty((256, 3), dtype=np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2] = a0, b0, 0
    top = 1
    out = np.empty((1024, 2), dtype=np.int64)
    count = 0
    while top:
        top -= 1
        a, b, depth = stack[top, 0], stack[top, 1], stack[top, 2]
        # (an a without flagged triangles has an empty box and never overlaps)
        if (dlo[a, 0] > hi[b, 0] or lo[b, 0] > dhi[a, 0] or dlo[a, 1] > hi[b, 1] or lo[b, 1] > dhi[a, 1]
                or dlo[a, 2] > hi[b, 2] or lo[b, 2] > dhi[a, 2]):
            continue
        leaf_a, leaf_b = a >= P, b >= P
        if (split >= 0 and depth >= split) or (leaf_a and leaf_b):
            if count == len(out):
                out = _grow(out, count)
            out[count, 0], out[count, 1] = a, b
            count += 1
            continue
        stack, top = _push_children(stack, top, a, b, depth, not leaf_a and (
            leaf_b or _box_size(dlo, dhi, a) >= _box_size(lo, hi, b)))
    return out[:count]


@numba.njit(cache=True)
def _dirty_leaf_pairs(leaves, P: int, dlo, dhi, slot_tri, slo, shi, dirty_tris):
    """Triangle pairs (flagged ta of leaf a, tb of leaf b) of the leaf pairs ``leaves`` (node indices) whose boxes
    overlap, without ta == tb, and a pair of two flagged triangles only as (smaller, larger); only b's triangles
    overlapping the box of a's flagged ones (``dlo``/``dhi``) are tested."""
    L = slot_tri.shape[1]
    out = np.empty((len(leaves) * L * L, 2), dtype=np.int64)
    cols = np.empty(L, dtype=np.int64)
    n = 0
    for p in range(len(leaves)):
        na = leaves[p, 0]
        ia, ib = na - P, leaves[p, 1] - P
        ncol = 0
        for c in range(L):
            tb = slot_tri[ib, c]
            cols[ncol] = c
            ncol += (tb >= 0) & ((slo[0, ib, c] <= dhi[na, 0]) & (dlo[na, 0] <= shi[0, ib, c])
                                 & (slo[1, ib, c] <= dhi[na, 1]) & (dlo[na, 1] <= shi[1, ib, c])
                                 & (slo[2, ib, c] <= dhi[na, 2]) & (dlo[na, 2] <= shi[2, ib, c]))
        for r in range(L):
            ta = slot_tri[ia, r]
            if ta < 0 or not dirty_tris[ta]:
                continue
            alo0, alo1, alo2 = slo[0, ia, r], slo[1, ia, r], slo[2, ia, r]
            ahi0, ahi1, ahi2 = shi[0, ia, r], shi[1, ia, r], shi[2, ia, r]
            # written always, kept by the count: no branch on the box tests
            for j in range(ncol):
                c = cols[j]
                tb = slot_tri[ib, c]
                ok = ((alo0 <= shi[0, ib, c]) & (slo[0, ib, c] <= ahi0) & (alo1 <= shi[1, ib, c])
                      & (slo[1, ib, c] <= ahi1) & (alo2 <= shi[2, ib, c]) & (slo[2, ib, c] <= ahi2))
                out[n, 0], out[n, 1] = ta, tb
                n += ok & (tb != ta) & ((not dirty_tris[tb]) | (ta < tb))
    return out[:n].copy()


@numba.njit(cache=True)
def _dirty_tasks(tasks, start: int, stop: int, P: int, dlo, dhi, lo, hi, slot_tri, slo, shi, dirty_tris):
    """Triangle pairs of the walks from ``tasks[start:stop]`` (:func:`_dirty_walk`), in task order."""
    leaves = np.empty((0, 2), dtype=np.int64)
    for t in range(start, stop):
        got = _dirty_walk(tasks[t, 0], tasks[t, 1], -1, P, dlo, dhi, lo, hi)
        if len(leaves) == 0:
            leaves = got
        elif len(got):
            both = np.empty((len(leaves) + len(got), 2), dtype=np.int64)
            both[:len(leaves)] = leaves
            both[len(leaves):] = got
            leaves = both
    return _dirty_leaf_pairs(leaves, P, dlo, dhi, slot_tri, slo, shi, dirty_tris)


@numba.njit(cache=True, parallel=True)
def traverse_dirty(P: int, lo, hi, slot_tri, slo, shi, dirty_tris, ids, leaf_of_tri, slot_of_tri):
    """Triangle pairs of a tree whose boxes overlap and that hold a triangle flagged in ``dirty_tris`` (m,): each
    unordered pair once (a flagged triangle first; two flagged ones as (smaller, larger)), no triangle paired with
    itself, no culling. The same pairs as :func:`traverse` of the tree against itself with that dirty filter, but
    a walk of the flagged triangles' own boxes (a node's box the union of its flagged triangles' boxes only,
    :func:`_dirty_boxes_of`) against the whole tree: a node holding one flagged triangle among clean ones is not
    tested with its whole box, and only the flagged triangles' rows are tested at the leaves.

    Parallel as :func:`traverse`: a serial walk to depth ``SPLIT_DEPTH`` lists node pairs, chunks of them are
    walked in parallel and their pairs concatenated in order (the same pairs in the same order on any number of
    threads).

    ``ids``: the flagged triangles ((k,) int), with the tree's ``leaf_of_tri``/``slot_of_tri`` for their node
    boxes. One chunk of tasks is walked serially (no parallel region to launch: the same pairs), so that a search
    for a few triangles costs about what they pair with."""
    dlo, dhi = _dirty_boxes_of(P, ids, leaf_of_tri, slot_of_tri, slo, shi)
    tasks = _dirty_walk(1, 1, SPLIT_DEPTH, P, dlo, dhi, lo, hi)
    T = len(tasks)
    chunks = max(1, min(MAX_CHUNKS, -(-T // TASK_CHUNK)))
    if chunks == 1:
        return _dirty_tasks(tasks, 0, T, P, dlo, dhi, lo, hi, slot_tri, slo, shi, dirty_tris)
    bufs = [np.empty((0, 2), dtype=np.int64) for _ in range(chunks)]
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(T, chunks, ch)
        bufs[ch] = _dirty_tasks(tasks, start, stop, P, dlo, dhi, lo, hi, slot_tri, slo, shi, dirty_tris)
    return _concat(bufs)


@numba.njit(cache=True)
def _concat(bufs):
    """The (k_i, 2) arrays of ``bufs`` one after the other."""
    total = 0
    for b in bufs:
        total += len(b)
    out = np.empty((total, 2), dtype=np.int64)
    o = 0
    for b in bufs:
        out[o:o + len(b)] = b
        o += len(b)
    return out


@numba.njit(cache=True)
def _query_walk(qlo, qhi, start: int, stop: int, P: int, lo, hi, nonempty, slot_tri, slo, shi, out, fill: bool) -> int:
    """Count (and with ``fill`` write into ``out``) the (query, triangle) pairs of queries ``start..stop-1``.

    The query box is held in locals and the stack has a fixed size (a complete tree of 2P nodes is at most
    log2(P) + 1 deep, and a depth-first walk holds at most one sibling per level): no array is reassigned in
    the loop. (The earlier loop, which read the box from its array at every node and grew its output and stack
    arrays inside the walk, took ~60 ns per node visited instead of ~8.)
    """
    L = slot_tri.shape[1]
    depth = 1
    while (1 << depth) <= P:
        depth += 1
    stack = np.empty(2 * depth + 4, dtype=np.int64)
    count = 0
    for q in range(start, stop):
        x0, x1, x2 = qlo[q, 0], qlo[q, 1], qlo[q, 2]
        y0, y1, y2 = qhi[q, 0], qhi[q, 1], qhi[q, 2]
        stack[0] = 1
        top = 1
        while top > 0:
            top -= 1
            a = stack[top]
            if not nonempty[a]:
                continue
            if x0 > hi[a, 0] or lo[a, 0] > y0 or x1 > hi[a, 1] or lo[a, 1] > y1 or x2 > hi[a, 2] or lo[a, 2] > y2:
                continue
            if a >= P:
                ia = a - P
                for c in range(L):
                    t = slot_tri[ia, c]
                    if t < 0:
                        continue
                    if (x0 <= shi[0, ia, c] and slo[0, ia, c] <= y0 and x1 <= shi[1, ia, c]
                            and slo[1, ia, c] <= y1 and x2 <= shi[2, ia, c] and slo[2, ia, c] <= y2):
                        if fill:
                            out[count, 0] = q
                            out[count, 1] = t
                        count += 1
                continue
            stack[top] = 2 * a
            stack[top + 1] = 2 * a + 1
            top += 2
    return count


@numba.njit(cache=True)
def _query_range(qlo, qhi, start: int, stop: int, P: int, lo, hi, nonempty, slot_tri, slo, shi):
    """The (query, triangle) pairs of queries ``start..stop-1`` (see :func:`query`): counted in one walk,
    written in a second into an array of that size."""
    out = np.empty((0, 2), dtype=np.int64)
    n = _query_walk(qlo, qhi, start, stop, P, lo, hi, nonempty, slot_tri, slo, shi, out, False)
    out = np.empty((n, 2), dtype=np.int64)
    _query_walk(qlo, qhi, start, stop, P, lo, hi, nonempty, slot_tri, slo, shi, out, True)
    return out


#: queries per chunk of :func:`query`
QUERY_CHUNK = 64


@numba.njit(cache=True, parallel=True)
def query(qlo: np.ndarray, qhi: np.ndarray, P: int, lo: np.ndarray, hi: np.ndarray, nonempty: np.ndarray,
          slot_tri: np.ndarray, slo: np.ndarray, shi: np.ndarray):
    """All (query, triangle) pairs whose boxes overlap: query boxes ``qlo``/``qhi`` (k, 3) [m] against
    the tree; returns (p, 2) indices, by query (chunks of queries in parallel, concatenated in order)."""
    k = len(qlo)
    chunks = chunk_count(k, QUERY_CHUNK)
    bufs = [np.empty((0, 2), dtype=np.int64) for _ in range(chunks)]
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        bufs[ch] = _query_range(qlo, qhi, start, stop, P, lo, hi, nonempty, slot_tri, slo, shi)
    return _concat(bufs)


@numba.njit(cache=True)
def _unit_cross(a0, a1, a2, b0, b1, b2, f: float) -> tuple:
    """``f (a x b)`` normalised, and whether it was zero (then returned as is)."""
    c0, c1, c2 = f * (a1 * b2 - a2 * b1), f * (a2 * b0 - a0 * b2), f * (a0 * b1 - a1 * b0)
    n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    if n > 0:
        return c0 / n, c1 / n, c2 / n, False
    return c0, c1, c2, True


@numba.njit(cache=True, parallel=True)
def refit(tri: np.ndarray, x0: np.ndarray, x1: np.ndarray, margin: float, static_margin: float, P: int,
          slot_tri: np.ndarray, nonempty: np.ndarray):
    """Boxes and normal cones of a tree (see ``BroadPhaseBVH.refit``); ``static_margin`` NaN: none.

    Returns:
        ``(tri_lo, tri_hi, lo, hi, slo, shi, cone_axis, cone_angle)``: triangle boxes (m, 3), node boxes
        (2P, 3), slot boxes (3, P, L) [m] (empty: +inf / -inf), node cone axes (2P, 3) and half angles
        (2P,) [rad] (pi: no bound).
    """
    m, L = len(tri), slot_tri.shape[1]
    tri_lo, tri_hi = np.empty((m, 3)), np.empty((m, 3))
    use_static = not math.isnan(static_margin)
    tchunks = chunk_count(m, 256)
    for ch in numba.prange(tchunks):  # triangles, then leaves in parallel (each writes only its own entries)
        start, stop = chunk_bounds(m, tchunks, ch)
        for f in range(start, stop):
            i, j, k = tri[f, 0], tri[f, 1], tri[f, 2]
            for c in range(3):
                l0, h0 = min(x0[i, c], x0[j, c], x0[k, c]), max(x0[i, c], x0[j, c], x0[k, c])
                l1, h1 = min(x1[i, c], x1[j, c], x1[k, c]), max(x1[i, c], x1[j, c], x1[k, c])
                lo_, hi_ = min(l0, l1) - margin, max(h0, h1) + margin
                if use_static:
                    lo_, hi_ = min(lo_, l0 - static_margin), max(hi_, h0 + static_margin)
                tri_lo[f, c], tri_hi[f, c] = lo_, hi_
    lo, hi = np.full((2 * P, 3), np.inf), np.full((2 * P, 3), -np.inf)
    slo, shi = np.full((3, P, L), np.inf), np.full((3, P, L), -np.inf)
    cone_axis, cone_angle = np.zeros((2 * P, 3)), np.full(2 * P, math.pi)
    chunks = chunk_count(P, 64)
    for ch in numba.prange(chunks):
        units = np.empty((L, 3, 3))
        start, stop = chunk_bounds(P, chunks, ch)
        for leaf in range(start, stop):
            _refit_leaf(leaf, P, L, tri, x0, x1, slot_tri, tri_lo, tri_hi, lo, hi, slo, shi, cone_axis, cone_angle,
                        units)
    for a in range(P - 1, 0, -1):
        l, r = 2 * a, 2 * a + 1
        for c in range(3):
            lo[a, c] = min(lo[l, c], lo[r, c])
            hi[a, c] = max(hi[l, c], hi[r, c])
        s0 = s1 = s2 = 0.0
        if nonempty[l]:
            s0, s1, s2 = s0 + cone_axis[l, 0], s1 + cone_axis[l, 1], s2 + cone_axis[l, 2]
        if nonempty[r]:
            s0, s1, s2 = s0 + cone_axis[r, 0], s1 + cone_axis[r, 1], s2 + cone_axis[r, 2]
        n = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        if not n > 0:
            continue  # angle pi
        s0, s1, s2 = s0 / n, s1 / n, s2 / n
        cone_axis[a, 0], cone_axis[a, 1], cone_axis[a, 2] = s0, s1, s2
        ang = 0.0
        for child in (l, r):
            if nonempty[child]:
                d = s0 * cone_axis[child, 0] + s1 * cone_axis[child, 1] + s2 * cone_axis[child, 2]
                ang = max(ang, math.acos(min(max(d, -1.0), 1.0)) + cone_angle[child])
        cone_angle[a] = ang
    return tri_lo, tri_hi, lo, hi, slo, shi, cone_axis, cone_angle


@numba.njit(cache=True)
def _refit_leaf(leaf, P, L, tri, x0, x1, slot_tri, tri_lo, tri_hi, lo, hi, slo, shi, cone_axis, cone_angle, units):
    """Slot boxes, box and normal cone of one leaf (see :func:`refit`); ``units`` (L, 3, 3) scratch."""
    node = P + leaf
    s0 = s1 = s2 = 0.0
    bad = False
    count = 0
    for r in range(L):
        f = slot_tri[leaf, r]
        if f < 0:
            continue
        for c in range(3):
            slo[c, leaf, r], shi[c, leaf, r] = tri_lo[f, c], tri_hi[f, c]
            lo[node, c] = min(lo[node, c], tri_lo[f, c])
            hi[node, c] = max(hi[node, c], tri_hi[f, c])
        # normal control vectors (Bernstein form of the swept normal), unit length
        i, j, k = tri[f, 0], tri[f, 1], tri[f, 2]
        a0, a1, a2 = x0[j, 0] - x0[i, 0], x0[j, 1] - x0[i, 1], x0[j, 2] - x0[i, 2]
        b0, b1, b2 = x0[k, 0] - x0[i, 0], x0[k, 1] - x0[i, 1], x0[k, 2] - x0[i, 2]
        p0, p1, p2 = x1[j, 0] - x1[i, 0], x1[j, 1] - x1[i, 1], x1[j, 2] - x1[i, 2]
        q0, q1, q2 = x1[k, 0] - x1[i, 0], x1[k, 1] - x1[i, 1], x1[k, 2] - x1[i, 2]
        u0, u1, u2, z0 = _unit_cross(a0, a1, a2, b0, b1, b2, 1.0)
        # the middle control vector 0.5 (a x q + p x b)
        m0 = 0.5 * ((a1 * q2 - a2 * q1) + (p1 * b2 - p2 * b1))
        m1 = 0.5 * ((a2 * q0 - a0 * q2) + (p2 * b0 - p0 * b2))
        m2 = 0.5 * ((a0 * q1 - a1 * q0) + (p0 * b1 - p1 * b0))
        mn = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        z1 = not mn > 0
        if mn > 0:
            m0, m1, m2 = m0 / mn, m1 / mn, m2 / mn
        w0, w1, w2, z2 = _unit_cross(p0, p1, p2, q0, q1, q2, 1.0)
        bad = bad or z0 or z1 or z2
        units[count, 0, 0], units[count, 0, 1], units[count, 0, 2] = u0, u1, u2
        units[count, 1, 0], units[count, 1, 1], units[count, 1, 2] = m0, m1, m2
        units[count, 2, 0], units[count, 2, 1], units[count, 2, 2] = w0, w1, w2
        s0 += u0 + m0 + w0
        s1 += u1 + m1 + w1
        s2 += u2 + m2 + w2
        count += 1
    if count == 0:
        return
    an = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    if bad or not an > 0:
        return  # axis 0, angle pi
    s0, s1, s2 = s0 / an, s1 / an, s2 / an
    ang = 0.0
    for t in range(count):
        for v in range(3):
            d = units[t, v, 0] * s0 + units[t, v, 1] * s1 + units[t, v, 2] * s2
            ang = max(ang, math.acos(min(max(d, -1.0), 1.0)))
    cone_axis[node, 0], cone_axis[node, 1], cone_axis[node, 2] = s0, s1, s2
    cone_angle[node] = ang


@numba.njit(cache=True)
def refit_triangles(ids: np.ndarray, tri: np.ndarray, vlo: np.ndarray, vhi: np.ndarray, tri_lo: np.ndarray,
                    tri_hi: np.ndarray, slo: np.ndarray, shi: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    leaf_of_tri: np.ndarray, slot_of_tri: np.ndarray, P: int) -> None:
    """In place: the boxes of triangles ``ids`` become the union of their vertices' boxes ``vlo``/``vhi``
    (n, 3) [m]; their leaves' and ancestors' boxes are recomputed (see ``BroadPhaseBVH.refit_triangles``)."""
    L = slo.shape[2]
    for f in ids:
        leaf, col = leaf_of_tri[f] - P, slot_of_tri[f]
        for c in range(3):
            a = min(vlo[tri[f, 0], c], vlo[tri[f, 1], c], vlo[tri[f, 2], c])
            b = max(vhi[tri[f, 0], c], vhi[tri[f, 1], c], vhi[tri[f, 2], c])
            tri_lo[f, c], tri_hi[f, c] = a, b
            slo[c, leaf, col], shi[c, leaf, col] = a, b
    # each path from a changed leaf to the root, bottom-up: a node is last recomputed after every
    # changed leaf below it
    for f in ids:
        leaf = leaf_of_tri[f] - P
        node = leaf + P
        for c in range(3):
            a, b = math.inf, -math.inf
            for r in range(L):
                a, b = min(a, slo[c, leaf, r]), max(b, shi[c, leaf, r])
            lo[node, c], hi[node, c] = a, b
        while node > 1:
            node >>= 1
            for c in range(3):
                lo[node, c] = min(lo[2 * node, c], lo[2 * node + 1, c])
                hi[node, c] = max(hi[2 * node, c], hi[2 * node + 1, c])


@numba.njit(cache=True)
def refit_boxes(tri: np.ndarray, x: np.ndarray, margin: float, P: int, slot_tri: np.ndarray):
    """Static boxes of a tree at positions ``x`` (n, 3) [m] grown by ``margin``, without normal cones (for
    :func:`query`, which does not cull): one serial pass over the triangles and the nodes.

    Returns:
        ``(tri_lo, tri_hi, lo, hi, slo, shi)`` as :func:`refit`.
    """
    m, L = len(tri), slot_tri.shape[1]
    tri_lo, tri_hi = np.empty((m, 3)), np.empty((m, 3))
    for f in range(m):
        i, j, k = tri[f, 0], tri[f, 1], tri[f, 2]
        for c in range(3):
            tri_lo[f, c] = min(x[i, c], x[j, c], x[k, c]) - margin
            tri_hi[f, c] = max(x[i, c], x[j, c], x[k, c]) + margin
    lo, hi = np.full((2 * P, 3), np.inf), np.full((2 * P, 3), -np.inf)
    slo, shi = np.full((3, P, L), np.inf), np.full((3, P, L), -np.inf)
    for leaf in range(P):
        node = P + leaf
        for r in range(L):
            f = slot_tri[leaf, r]
            if f < 0:
                continue
            for c in range(3):
                slo[c, leaf, r], shi[c, leaf, r] = tri_lo[f, c], tri_hi[f, c]
                lo[node, c] = min(lo[node, c], tri_lo[f, c])
                hi[node, c] = max(hi[node, c], tri_hi[f, c])
    for a in range(P - 1, 0, -1):
        for c in range(3):
            lo[a, c] = min(lo[2 * a, c], lo[2 * a + 1, c])
            hi[a, c] = max(hi[2 * a, c], hi[2 * a + 1, c])
    return tri_lo, tri_hi, lo, hi, slo, shi
