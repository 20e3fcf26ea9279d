"""Compiled candidate-pair kernels: the expansion of triangle pairs into point-triangle and edge-edge pairs,
and the updates and selections of the pipeline's pair store.

The expansion's box-diagonal test (:func:`box_diagonals`, :func:`triangle_diagonals`,
:func:`modalfem.collision._system.diagonal_test`), whole 64x64 pile (80 steps, one thread, every timer on CPU
time, the code before and after in alternating processes, 3 runs each, Intel Xeon, load 3-3.8): 115.3-116.4 ->
108.7-110.8 CPU ms per step; per stage (fastest runs) broad phase 31.6 -> 33.3 (the test's own cost), repulsion
9.2 -> 6.3 (half the proximity pairs no longer reach the distance kernel), CCD 7.9 -> 6.5, impact zones 7.7 -> 6.5
(a 40 % smaller pair store to scan), smoothing with its re-check 34.4 -> 32.1, implicit 24.0 -> 23.5 (noise);
0 intersections, the same smoothing iterations and zones (the answers are the same bits).

Tried for the pile and dropped (one thread, CPU time, Intel Xeon, shared machine): (1) per-slot packed records
(a leaf's triangles' boxes, owned vertices' and edges' boxes and indices in one contiguous row each) read by a
leaf-pair expansion fused into the traversal: the same pairs, 10.3 -> 11.4 ms for a late step's proximity search
(the expansion is bound by its branches and tests, not by gathers); (2) leaf sizes 4 and 16 instead of 8: no gain
(replayed pipeline calls 41.4 ms per call at 8, 43.9 at 4, 41.3 at 16); (3) the point-triangle diagonal test
reading the triangle's row of :func:`triangle_diagonals` instead of its three vertices' rows: the same pairs, no
measurable change (7.3-7.6 ms either way for a 144k triangle-pair expansion); (4) a vertex searched again within a
step keeping the union of its old box and its new trajectory grown by twice the margin (fewer repeated dirty
searches: 43 % of a step's dirty vertices were dirty before in the same step): about -1 ms per pipeline call, but
a different candidate order (answers equal only to ~1e-9 m/s per call), so not taken then; taken since the CCD
hands its hits on in a canonical order (``_stages.ccd_hits``, ``_stages.DIRTY_GROW``); (5) the pipeline's numpy
glue compiled (``(dV != 0).any(axis=1)``-style masks, the CCD's end positions and diagonal intervals in one
pass, the dirty triangles): no measurable change (the glue is ~9 of the pipeline's ~82 CPU ms per step, spread
over many small calls).
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem._threads import apply as _apply_threads
from modalfem._threads import chunk_bounds, chunk_count

__all__ = ["box_diagonals", "dirty_self_pairs", "dirty_triangles", "flagged_triangles", "outgrown", "primitive_boxes", "primitive_pairs",
           "primitive_pairs_serial", "select_indexed",
           "rows_nonzero", "select_pairs", "triangle_diagonals", "update_box_diagonals", "vertex_index",
           "vertex_triangles"]

_apply_threads()


@numba.njit(cache=True)
def _boxes_overlap(alo, ahi, blo, bhi, i: int, j: int) -> bool:
    # bitwise: no branch per comparison (most tests fail on an unpredictable axis)
    return ((alo[i, 0] <= bhi[j, 0]) & (blo[j, 0] <= ahi[i, 0]) & (alo[i, 1] <= bhi[j, 1]) & (blo[j, 1] <= ahi[i, 1])
            & (alo[i, 2] <= bhi[j, 2]) & (blo[j, 2] <= ahi[i, 2]))


#: triangle pairs per chunk of :func:`primitive_pairs`
PAIR_CHUNK = 256


@numba.njit(cache=True, parallel=True)
def primitive_pairs(tp: np.ndarray, tris: np.ndarray, edges: np.ndarray, own_v: np.ndarray, own_e: np.ndarray,
                    vlo: np.ndarray, vhi: np.ndarray, dirty: np.ndarray, diag: np.ndarray, gap: float):
    """Point-triangle and edge-edge pairs of the triangle pairs ``tp`` (k, 2) whose boxes overlap.

    Each vertex and edge is owned by one triangle (``own_v``/``own_e`` (F, 3), -1 padded): a primitive
    pair comes from the triangle pair of its owners only. Boxes are the vertex boxes ``vlo``/``vhi``
    (N, 3) [m] (already grown by the margin), a triangle's or edge's the union of its vertices'. Pairs
    sharing a vertex are left out; with ``dirty`` ((N,) bool, empty: no filter) only pairs holding a
    flagged vertex are kept. With ``diag`` ((N, 8) per-vertex intervals on the four box diagonals, as
    :func:`modalfem.collision._ccd_kernels.diagonal_intervals`; empty: no such test), a pair is also left out
    when its two primitives' intervals on one diagonal are more than ``gap`` [m] apart (:func:`_diagonal_apart`).
    Chunks of ``tp`` run in parallel (:mod:`modalfem._threads`), their pairs
    concatenated in order: the same pairs in the same order on any number of threads.

    Returns:
        ``(vf, ee)``: (p, 4) vertex quadruples ``(p, a, b, c)`` and (q, 4) ``(a0, a1, b0, b1)``.
    """
    F, E = len(tris), len(edges)
    k = len(tp)
    use_diag = len(diag) > 0
    # boxes (and diagonal intervals) of the triangles in tp and of the edges they own only (a dirty search holds a
    # few of them)
    fdiag = np.empty((F if use_diag else 0, 8))
    flo, fhi = np.empty((F, 3)), np.empty((F, 3))
    elo, ehi = np.empty((E, 3)), np.empty((E, 3))
    fdone = np.zeros(F, dtype=np.bool_)
    chunks = chunk_count(k, PAIR_CHUNK)
    for ch in numba.prange(chunks):  # the triangles in tp (every writer stores the same True)
        start, stop = chunk_bounds(k, chunks, ch)
        for p in range(start, stop):
            fdone[tp[p, 0]] = True
            fdone[tp[p, 1]] = True
    used = np.flatnonzero(fdone)
    nu = len(used)
    bchunks = chunk_count(nu, PAIR_CHUNK)
    for ch in numba.prange(bchunks):
        start, stop = chunk_bounds(nu, bchunks, ch)
        for u in range(start, stop):
            _triangle_boxes(used[u], tris, edges, own_e, vlo, vhi, diag, flo, fhi, elo, ehi, fdiag)
    vbufs = [np.empty((0, 4), dtype=np.int64) for _ in range(chunks)]
    ebufs = [np.empty((0, 4), dtype=np.int64) for _ in range(chunks)]
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        vbufs[ch], ebufs[ch] = _primitive_range(tp, start, stop, tris, edges, own_v, own_e, vlo, vhi, flo, fhi, elo,
                                                ehi, dirty, diag, fdiag, gap)
    return _concat4(vbufs), _concat4(ebufs)


@numba.njit(cache=True, inline="always")
def _triangle_boxes(f: int, tris, edges, own_e, vlo, vhi, diag, flo, fhi, elo, ehi, fdiag) -> None:
    """Triangle ``f``'s box (and with a non-empty ``diag`` its diagonal intervals) and the boxes of the edges it
    owns, written into their rows of ``flo``/``fhi``, ``fdiag``, ``elo``/``ehi`` (for :func:`_primitive_range`)."""
    for c in range(3):
        flo[f, c] = min(vlo[tris[f, 0], c], vlo[tris[f, 1], c], vlo[tris[f, 2], c])
        fhi[f, c] = max(vhi[tris[f, 0], c], vhi[tris[f, 1], c], vhi[tris[f, 2], c])
    if len(diag) > 0:
        _triangle_diagonals(tris, diag, f, fdiag)
    for r in range(3):
        e = own_e[f, r]
        if e >= 0:
            for c in range(3):
                elo[e, c] = min(vlo[edges[e, 0], c], vlo[edges[e, 1], c])
                ehi[e, c] = max(vhi[edges[e, 0], c], vhi[edges[e, 1], c])


@numba.njit(cache=True)
def primitive_pairs_serial(tp: np.ndarray, tris: np.ndarray, edges: np.ndarray, own_v: np.ndarray, own_e: np.ndarray,
                           vlo: np.ndarray, vhi: np.ndarray, dirty: np.ndarray, diag: np.ndarray, gap: float,
                           flo: np.ndarray, fhi: np.ndarray, elo: np.ndarray, ehi: np.ndarray, fdiag: np.ndarray,
                           fdone: np.ndarray):
    """:func:`primitive_pairs` (the same pairs in the same order) in one serial pass for a few triangle pairs (a
    dirty search's): no parallel region to launch, and the triangle and edge boxes written into the caller's work
    arrays ``flo``/``fhi`` (F, 3), ``elo``/``ehi`` (E, 3), ``fdiag`` (F, 8) (only the rows of the triangles in
    ``tp``) instead of new ones; ``fdone`` ((F,) bool, all False) is left all False. Its cost follows ``tp``."""
    k = len(tp)
    used = np.empty(2 * k, dtype=np.int64)
    nu = 0
    for p in range(k):
        for side in range(2):
            f = tp[p, side]
            if not fdone[f]:
                fdone[f] = True
                used[nu] = f
                nu += 1
    for u in range(nu):
        _triangle_boxes(used[u], tris, edges, own_e, vlo, vhi, diag, flo, fhi, elo, ehi, fdiag)
        fdone[used[u]] = False
    return _primitive_range(tp, 0, k, tris, edges, own_v, own_e, vlo, vhi, flo, fhi, elo, ehi, dirty, diag, fdiag,
                            gap)


@numba.njit(cache=True, parallel=True)
def primitive_boxes(tris: np.ndarray, edges: np.ndarray, vlo: np.ndarray, vhi: np.ndarray):
    """Boxes of every triangle (F, 3) and edge (E, 3) [m]: the union of their vertices' boxes ``vlo``/``vhi``
    (N, 3) [m] (for :func:`_primitive_range` called by a fused traversal); chunks in parallel."""
    F, E = len(tris), len(edges)
    flo, fhi = np.empty((F, 3)), np.empty((F, 3))
    elo, ehi = np.empty((E, 3)), np.empty((E, 3))
    chunks = chunk_count(F, PAIR_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(F, chunks, ch)
        for f in range(start, stop):
            for c in range(3):
                flo[f, c] = min(vlo[tris[f, 0], c], vlo[tris[f, 1], c], vlo[tris[f, 2], c])
                fhi[f, c] = max(vhi[tris[f, 0], c], vhi[tris[f, 1], c], vhi[tris[f, 2], c])
    echunks = chunk_count(E, PAIR_CHUNK)
    for ch in numba.prange(echunks):
        start, stop = chunk_bounds(E, echunks, ch)
        for e in range(start, stop):
            for c in range(3):
                elo[e, c] = min(vlo[edges[e, 0], c], vlo[edges[e, 1], c])
                ehi[e, c] = max(vhi[edges[e, 0], c], vhi[edges[e, 1], c])
    return flo, fhi, elo, ehi


@numba.njit(cache=True, parallel=True)
def _concat4(bufs):
    """The (k_i, 4) arrays of ``bufs`` one after the other (copied in parallel, each to its offset)."""
    nb = len(bufs)
    offsets = np.zeros(nb + 1, dtype=np.int64)
    for i in range(nb):
        offsets[i + 1] = offsets[i] + len(bufs[i])
    out = np.empty((offsets[nb], 4), dtype=np.int64)
    for i in numba.prange(nb):
        b = bufs[i]
        o = offsets[i]
        for r in range(len(b)):
            for c in range(4):
                out[o + r, c] = b[r, c]
    return out


@numba.njit(cache=True, inline="always")
def _diagonal_apart(diag: np.ndarray, a0: int, a1: int, b0: int, b1: int, b2: int, gap: float) -> bool:
    """The primitive of vertices ``a0, a1`` and that of ``b0, b1, b2`` (repeat an index for fewer) have intervals
    on one of the four diagonals of ``diag`` ((N, 8): ``lo_0..lo_3, hi_0..hi_3`` per vertex) more than ``gap``
    apart."""
    apart = False
    for d in range(4):
        alo, ahi = min(diag[a0, d], diag[a1, d]), max(diag[a0, 4 + d], diag[a1, 4 + d])
        blo = min(diag[b0, d], diag[b1, d], diag[b2, d])
        bhi = max(diag[b0, 4 + d], diag[b1, 4 + d], diag[b2, 4 + d])
        apart = apart | (alo > bhi + gap) | (blo > ahi + gap)
    return apart


@numba.njit(cache=True, inline="always")
def _triangle_diagonals(tris: np.ndarray, diag: np.ndarray, f: int, fdiag: np.ndarray) -> None:
    """Row ``f`` of ``fdiag``: the union of triangle ``f``'s vertices' intervals on the four diagonals of ``diag``
    ((N, 8) ``lo_0..lo_3, hi_0..hi_3``)."""
    i, j, k = tris[f, 0], tris[f, 1], tris[f, 2]
    for d in range(4):
        fdiag[f, d] = min(diag[i, d], diag[j, d], diag[k, d])
        fdiag[f, 4 + d] = max(diag[i, 4 + d], diag[j, 4 + d], diag[k, 4 + d])


@numba.njit(cache=True, parallel=True)
def triangle_diagonals(tris: np.ndarray, diag: np.ndarray) -> np.ndarray:
    """(F, 8): each triangle's interval on the four diagonals of ``diag`` ((N, 8), the union of its vertices'
    intervals; empty if ``diag`` is); chunks in parallel."""
    F = len(tris) if len(diag) else 0
    fdiag = np.empty((F, 8))
    chunks = chunk_count(F, PAIR_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(F, chunks, ch)
        for f in range(start, stop):
            _triangle_diagonals(tris, diag, f, fdiag)
    return fdiag


@numba.njit(cache=True, parallel=True)
def box_diagonals(vlo: np.ndarray, vhi: np.ndarray) -> np.ndarray:
    """Per vertex, its box ``vlo``/``vhi`` ((N, 3) [m]) projected on the four box diagonals ``(1, 1, 1)``,
    ``(1, 1, -1)``, ``(1, -1, 1)``, ``(-1, 1, 1)`` (not normalised; the rows of
    :func:`modalfem.collision._ccd_kernels.diagonal_intervals`): (N, 8) ``lo_0..lo_3, hi_0..hi_3`` [m], each the
    box corner's sum of three coordinates (rounded to within a few ulps of three times the coordinate scale)."""
    N = len(vlo)
    out = np.empty((N, 8))
    chunks = chunk_count(N, 1024)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(N, chunks, ch)
        for i in range(start, stop):
            _box_diagonal_row(vlo, vhi, i, out)
    return out


@numba.njit(cache=True, inline="always")
def _box_diagonal_row(vlo: np.ndarray, vhi: np.ndarray, i: int, out: np.ndarray) -> None:
    """Row ``i`` of :func:`box_diagonals` written into ``out``."""
    l0, l1, l2 = vlo[i, 0], vlo[i, 1], vlo[i, 2]
    h0, h1, h2 = vhi[i, 0], vhi[i, 1], vhi[i, 2]
    out[i, 0], out[i, 4] = l0 + l1 + l2, h0 + h1 + h2
    out[i, 1], out[i, 5] = l0 + l1 - h2, h0 + h1 - l2
    out[i, 2], out[i, 6] = l0 - h1 + l2, h0 - l1 + h2
    out[i, 3], out[i, 7] = l1 + l2 - h0, h1 + h2 - l0


@numba.njit(cache=True)
def update_box_diagonals(diag: np.ndarray, ids: np.ndarray, vlo: np.ndarray, vhi: np.ndarray) -> float:
    """In place: the rows ``ids`` ((k,) int) of ``diag`` ((N, 8), :func:`box_diagonals` of earlier boxes) recomputed
    from the boxes ``vlo``/``vhi`` ((N, 3) [m]); returns the largest absolute coordinate [m] of those rows' boxes (the
    coordinate scale of :func:`modalfem.collision._ccd_kernels.diagonal_gap`). Serial: O(k), for a few rows."""
    scale = 0.0
    for i in ids:
        _box_diagonal_row(vlo, vhi, i, diag)
        for c in range(3):
            scale = max(scale, abs(vlo[i, c]), abs(vhi[i, c]))
    return scale


@numba.njit(cache=True)
def vertex_triangles(tris: np.ndarray, n: int):
    """The triangles ``tris`` (m, 3) holding each vertex ``0..n-1`` as a compressed list: ``(ptr, tri)``, vertex
    ``v``'s triangles ``tri[ptr[v]:ptr[v + 1]]`` in increasing order. Any row width: the rows of ``tris`` (m, w)
    holding each vertex (``vertex_index`` for the pairs' four vertices)."""
    m, w = tris.shape
    ptr = np.zeros(n + 1, dtype=np.int64)
    for f in range(m):
        for r in range(w):
            ptr[tris[f, r] + 1] += 1
    for v in range(n):
        ptr[v + 1] += ptr[v]
    fill = ptr[:-1].copy()
    tri = np.empty(ptr[n], dtype=np.int64)
    for f in range(m):
        for r in range(w):
            v = tris[f, r]
            tri[fill[v]] = f
            fill[v] += 1
    return ptr, tri


@numba.njit(cache=True)
def dirty_triangles(flags: np.ndarray, ptr: np.ndarray, vtri: np.ndarray, m: int):
    """The triangles holding a vertex flagged in ``flags`` ((N,) bool), from the vertex -> triangles list
    ``ptr``/``vtri`` (:func:`vertex_triangles` of the m triangles over the first ``len(ptr) - 1`` vertices; the
    other vertices' flags are not read): ``(mask, ids)``, (m,) bool as :func:`flagged_triangles` and the (k,)
    flagged triangles in increasing order. Serial; reads the flagged vertices' lists only (no pass over the
    triangles)."""
    n = len(ptr) - 1
    mask = np.zeros(m, dtype=np.bool_)
    found = np.empty(len(vtri), dtype=np.int64)  # (at most every listed triangle; only the found rows are written)
    count = 0
    for v in range(n):
        if flags[v]:
            for j in range(ptr[v], ptr[v + 1]):
                f = vtri[j]
                if not mask[f]:
                    mask[f] = True
                    found[count] = f
                    count += 1
    ids = found[:count].copy()
    ids.sort()
    return mask, ids


@numba.njit(cache=True)
def _primitive_range(tp, start: int, stop: int, tris, edges, own_v, own_e, vlo, vhi, flo, fhi, elo, ehi, dirty, diag,
                     fdiag, gap: float):
    """:func:`primitive_pairs` of the triangle pairs ``tp[start:stop]``, given the triangle and edge boxes.

    Each candidate is written at the next free row and kept by adding its box test to the count, without a
    branch on the test (about half of the tests fail, unpredictably): 30 % less time than branching on it
    (64x64 pile, full searches of 120k-165k triangle pairs: 10.1 -> 7.0 ms on one thread, Intel Xeon)."""
    filt = len(dirty) > 0
    use_diag = len(diag) > 0
    k = stop - start
    vf_ids = np.empty((6 * k, 2), dtype=np.int64)
    ee_ids = np.empty((9 * k, 2), dtype=np.int64)
    nv = ne = 0
    for p in range(start, stop):
        if use_diag:
            # two triangles apart on a diagonal (``fdiag``: the union of their vertices' intervals): so is every
            # primitive pair they own, which the test below would leave out
            A, B = tp[p, 0], tp[p, 1]
            apart = False
            for d in range(4):
                apart = apart | (fdiag[A, d] > fdiag[B, 4 + d] + gap) | (fdiag[B, d] > fdiag[A, 4 + d] + gap)
            if apart:
                continue
        for side in range(2):
            A, B = tp[p, side], tp[p, 1 - side]
            b0, b1, b2 = tris[B, 0], tris[B, 1], tris[B, 2]
            for r in range(3):
                v = own_v[A, r]
                if v < 0 or v == b0 or v == b1 or v == b2:
                    continue
                if filt and not (dirty[v] or dirty[b0] or dirty[b1] or dirty[b2]):
                    continue
                # written always, kept by the count (no branch on the box test, which fails unpredictably)
                vf_ids[nv, 0], vf_ids[nv, 1] = v, B
                nv += _boxes_overlap(vlo, vhi, flo, fhi, v, B)
        A, B = tp[p, 0], tp[p, 1]
        for r in range(3):
            ea = own_e[A, r]
            if ea < 0:
                continue
            a0, a1 = edges[ea, 0], edges[ea, 1]
            for c in range(3):
                eb = own_e[B, c]
                if eb < 0:
                    continue
                c0, c1 = edges[eb, 0], edges[eb, 1]
                if a0 == c0 or a0 == c1 or a1 == c0 or a1 == c1:
                    continue
                if filt and not (dirty[a0] or dirty[a1] or dirty[c0] or dirty[c1]):
                    continue
                ee_ids[ne, 0], ee_ids[ne, 1] = ea, eb
                ne += _boxes_overlap(elo, ehi, elo, ehi, ea, eb)
    # the box-passing pairs (a few percent of the tests) as vertex quadruples, without those apart on a diagonal
    vf = np.empty((nv, 4), dtype=np.int64)
    o = 0
    for i in range(nv):
        v, B = vf_ids[i, 0], vf_ids[i, 1]
        b0, b1, b2 = tris[B, 0], tris[B, 1], tris[B, 2]
        vf[o, 0], vf[o, 1], vf[o, 2], vf[o, 3] = v, b0, b1, b2
        o += not (use_diag and _diagonal_apart(diag, v, v, b0, b1, b2, gap))
    vf = vf[:o]
    ee = np.empty((ne, 4), dtype=np.int64)
    o = 0
    for i in range(ne):
        a0, a1 = edges[ee_ids[i, 0], 0], edges[ee_ids[i, 0], 1]
        c0, c1 = edges[ee_ids[i, 1], 0], edges[ee_ids[i, 1], 1]
        ee[o, 0], ee[o, 1], ee[o, 2], ee[o, 3] = a0, a1, c0, c1
        o += not (use_diag and _diagonal_apart(diag, a0, a1, c0, c1, c1, gap))
    return vf, ee[:o]


@numba.njit(cache=True, inline="always")
def _alive(q: np.ndarray, i: int, stamp: np.ndarray, epoch: int) -> bool:
    """Pair ``i`` of a store block found at ``epoch`` is still in the store: no vertex of it searched again
    since (its ``stamp`` above ``epoch``); every pair is when ``stamp`` is empty."""
    if len(stamp) == 0:
        return True
    return (stamp[q[i, 0]] <= epoch) & (stamp[q[i, 1]] <= epoch) & (stamp[q[i, 2]] <= epoch) & (stamp[q[i, 3]] <= epoch)


#: pairs per chunk of the parallel scans of the pair store (selections)
SCAN_CHUNK = 4096


@numba.njit(cache=True, parallel=True)
def _compact(q: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The rows of ``q`` (k, 4) where ``keep`` is True, in order: counted per chunk, then copied per chunk
    at the offsets of the chunks before it (chunks fixed by k: the same rows on any thread count)."""
    k = len(q)
    chunks = chunk_count(k, SCAN_CHUNK)
    counts = np.zeros(chunks + 1, dtype=np.int64)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        c = 0
        for i in range(start, stop):
            if keep[i]:
                c += 1
        counts[ch + 1] = c
    for ch in range(chunks):
        counts[ch + 1] += counts[ch]
    out = np.empty((counts[chunks], 4), dtype=q.dtype)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        o = counts[ch]
        for i in range(start, stop):
            if keep[i]:
                for c in range(4):
                    out[o, c] = q[i, c]
                o += 1
    return out


#: pairs per chunk of :func:`select_pairs` (below two chunks it runs serially: on one thread the two parallel
#: regions' launches cost 5-30 us, the serial scan of 5000 pairs 7 us; Intel Xeon, load 3.5)
SELECT_CHUNK = 16384


@numba.njit(cache=True, parallel=True)
def select_pairs(q: np.ndarray, stamp: np.ndarray, epoch: int, only: np.ndarray) -> np.ndarray:
    """The pairs of ``q`` (k, 4) still in the store (:func:`_alive`), only those holding a vertex flagged in
    ``only`` ((N,) bool) unless it is empty, in their order. From two chunks on, in parallel: a pass marking
    the pairs, then :func:`_compact` (the same pairs in the same order for any thread count)."""
    use = len(only) > 0
    k = len(q)
    chunks = chunk_count(k, SELECT_CHUNK)
    if chunks == 1:  # one serial pass: a parallel region's launch costs more than a small scan
        mark = np.empty(k, dtype=np.int64)
        n = 0
        for i in range(k):
            if _alive(q, i, stamp, epoch) and (not use or only[q[i, 0]] or only[q[i, 1]] or only[q[i, 2]]
                                               or only[q[i, 3]]):
                mark[n] = i
                n += 1
        res = np.empty((n, 4), dtype=q.dtype)
        for j in range(n):
            for c in range(4):
                res[j, c] = q[mark[j], c]
        return res
    keep = np.empty(k, dtype=np.bool_)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        for i in range(start, stop):
            keep[i] = _alive(q, i, stamp, epoch) and (not use or only[q[i, 0]] or only[q[i, 1]] or only[q[i, 2]]
                                                      or only[q[i, 3]])
    return _compact(q, keep)


@numba.njit(cache=True)
def vertex_index(q: np.ndarray, N: int):
    """The pairs of ``q`` (k, 4) holding each vertex 0..N-1: ``(ptr (N + 1,), pid (4k,))``, vertex v's
    pairs ``pid[ptr[v]:ptr[v + 1]]`` (ascending; a pair twice under a vertex it holds twice never
    happens: a pair's four vertices are distinct). :func:`vertex_triangles` over the pairs' rows."""
    return vertex_triangles(q, N)


@numba.njit(cache=True)
def _mark(k: int, ptr: np.ndarray, pid: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """(k,) bool: the pairs of a block listed under one of ``verts`` in its :func:`vertex_index`."""
    mark = np.zeros(k, dtype=np.bool_)
    for v in verts:
        for s in range(ptr[v], ptr[v + 1]):
            mark[pid[s]] = True
    return mark


@numba.njit(cache=True)
def select_indexed(q: np.ndarray, stamp: np.ndarray, epoch: int, ptr: np.ndarray, pid: np.ndarray,
                   verts: np.ndarray):
    """:func:`select_pairs` with a filter through a :func:`vertex_index`: the pairs of ``q`` still in the
    store holding one of ``verts``, in the block's order (the marks set through the index, the block compacted
    by :func:`_compact` in parallel chunks)."""
    mark = _mark(len(q), ptr, pid, verts)
    for i in range(len(q)):
        if mark[i] and not _alive(q, i, stamp, epoch):
            mark[i] = False
    return _compact(q, mark)


#: vertices below which :func:`outgrown` runs its chunks serially: ~9 ns per vertex on one thread (Intel Xeon,
#: fastest of 7 x 300 calls, 4,096 and 16,384 vertices), 8192 vertices ~75 us, :data:`modalfem._threads.SERIAL_WORK_US`
OUTGROWN_SERIAL = 8192


@numba.njit(cache=True, inline="always")
def _outgrown_range(X0, V, dt, grow, lo, hi, Vc, vtol, vel, n, X1, out, start, stop):
    """:func:`outgrown` of the vertices ``start..stop-1``: returns their dirty counts (below ``n``, in all)."""
    h = 0
    k = 0
    for i in range(start, stop):
        d = False
        for c in range(3):
            a = X0[i, c]
            b = a + dt * V[i, c]
            X1[i, c] = b
            d |= (min(a, b) - grow < lo[i, c]) | (max(a, b) + grow > hi[i, c])
            if vel:  # (without it, the default configuration's pass reads Vc for nothing: 35 -> 48 us)
                d |= dt * abs(V[i, c] - Vc[i, c]) > vtol
        out[i] = d
        if d:
            k += 1
            if i < n:
                h += 1
    return h, k


@numba.njit(cache=True, parallel=True)
def outgrown(X0: np.ndarray, V: np.ndarray, dt: float, grow: float, lo: np.ndarray, hi: np.ndarray,
             Vc: np.ndarray, vtol: float, n: int):
    """End positions ``X1 = X0 + dt V`` ((N, 3) [m]), the (N,) bool dirty vertices and their counts.

    A vertex is dirty when its trajectory ``X0 -> X1`` grown by ``grow`` [m] leaves its box ``lo``/``hi``
    ((N, 3) [m]) or when ``dt |V - Vc|`` exceeds ``vtol`` [m] in a component (``Vc`` (N, 3) [m/s]: the
    velocities the vertex's pairs were found with; ``vtol = inf`` turns that test off). One pass instead of
    numpy's temporaries, the same floating-point operations per entry (so the same answer), chunks in
    parallel. Returns ``(X1, dirty, dirty among the first n, dirty in all)``."""
    N = len(X0)
    X1 = np.empty((N, 3))
    # every entry written in the loop: np.zeros (and head.sum()) would each be a parallel region of their own
    out = np.empty(N, dtype=np.bool_)
    chunks = chunk_count(N, 1024)
    head = np.empty(chunks, dtype=np.int64)
    total = np.empty(chunks, dtype=np.int64)
    vel = vtol < np.inf
    if N < OUTGROWN_SERIAL:  # the same chunks, serially: the region would not pay for the pool's wake-up
        for ch in range(chunks):
            start, stop = chunk_bounds(N, chunks, ch)
            head[ch], total[ch] = _outgrown_range(X0, V, dt, grow, lo, hi, Vc, vtol, vel, n, X1, out, start, stop)
    else:
        for ch in numba.prange(chunks):
            start, stop = chunk_bounds(N, chunks, ch)
            head[ch], total[ch] = _outgrown_range(X0, V, dt, grow, lo, hi, Vc, vtol, vel, n, X1, out, start, stop)
    nh, nt = 0, 0
    for ch in range(chunks):
        nh += head[ch]
        nt += total[ch]
    return X1, out, nh, nt


@numba.njit(cache=True, parallel=True)
def flagged_triangles(flags: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(m,) bool: the triangles ``tris`` (m, 3) holding a vertex flagged in ``flags`` ((N,) bool), chunks in
    parallel."""
    m = len(tris)
    out = np.empty(m, dtype=np.bool_)
    chunks = chunk_count(m, 2048)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        for i in range(start, stop):
            out[i] = flags[tris[i, 0]] or flags[tris[i, 1]] or flags[tris[i, 2]]
    return out


@numba.njit(cache=True, parallel=True)
def rows_nonzero(a: np.ndarray) -> np.ndarray:
    """(k,) bool: the rows of ``a`` (k, 3) with a nonzero entry (``(a != 0).any(axis=1)``), chunks in parallel."""
    k = len(a)
    out = np.empty(k, dtype=np.bool_)
    if k < ROWS_SERIAL:  # one serial pass: the region would not pay for the pool's wake-up
        for i in range(k):
            out[i] = (a[i, 0] != 0.0) or (a[i, 1] != 0.0) or (a[i, 2] != 0.0)
        return out
    chunks = chunk_count(k, 1024)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        for i in range(start, stop):
            out[i] = (a[i, 0] != 0.0) or (a[i, 1] != 0.0) or (a[i, 2] != 0.0)
    return out


#: rows below which :func:`rows_nonzero` runs serially: ~2.5 ns per row on one thread (Intel Xeon, fastest of
#: 7 x 300 calls, 4,096 and 16,384 rows), 32768 rows ~80 us, :data:`modalfem._threads.SERIAL_WORK_US`
ROWS_SERIAL = 32768


@numba.njit(cache=True)
def dirty_self_pairs(ids: np.ndarray, qi: np.ndarray, tri: np.ndarray, dirty_tri: np.ndarray) -> np.ndarray:
    """Triangle pairs ``(ids[qi[r]], tri[r])`` of the box queries of the dirty triangles ``ids`` (query ``qi[r]``
    found triangle ``tri[r]``), without a triangle paired with itself and each pair of two dirty triangles once
    (from the smaller one's query), in query order."""
    p = len(qi)
    out = np.empty((p, 2), dtype=np.int64)
    n = 0
    for r in range(p):
        a, t = ids[qi[r]], tri[r]
        if a != t and (not dirty_tri[t] or a < t):
            out[n, 0], out[n, 1] = a, t
            n += 1
    return out[:n].copy()

