"""The cloth and its mesh obstacles as one system of vertices, edges and triangles; candidate pairs.

Vertices ``0..n-1`` are the cloth's, then the obstacle meshes' (kinematic: infinite mass). Triangles
and edges are numbered likewise. Candidates are point-triangle (``vf``: p, a, b, c) and edge-edge
(``ee``: a0, a1, b0, b1) vertex quadruples from BVH triangle pairs, without pairs sharing a vertex.

Tried and dropped: the step's two full searches (the proximity search of stage (a), the first swept search of
stage (b)) as one walk of the tree. The swept search needs the velocities after stage (a), which needs the
proximity pairs, so the walk used union boxes (the trajectories before stage (a) grown by the margin, joined with
the start positions grown by h / 2), carried per node pair whether the proximity search (its own boxes, its
culling, split by its box sizes) was alive there, and gave the proximity pairs exactly (same pairs, same order,
same test counts: 23 recorded 64x64 pile states) plus the union boxes' triangle pairs; after stage (a) the swept
pairs were expanded from that list with the new boxes (a vertex leaving its union box took the union box and was
searched again). Answers the same bits on all 154 replayed pile calls, but slower (one thread, CPU time, Intel
Xeon, load 3.6-5): a late call's leaf tests and expansions dominate a search (walk 3.3 ms of a 19.4 ms proximity
search), and both searches still need their own: shared walk 29.0 ms + expansion from the list 13.0 against 19.4 +
20.5 for the two searches; and 12 % of the vertices (up to 27 %) leave their union box in stage (a) (4.3 % at once
dirty: dirty searches 6.6 -> 9.6-10.8 ms per call). Replay 47-51 against 40-42 ms per call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.collision import _ccd_kernels, _pair_kernels
from modalfem.collision.bvh import BroadPhaseBVH
from modalfem.collision.obstacles import Plane, Sphere, TriangleMeshObstacle
from modalfem.collision.tritri import intersecting_pairs
from modalfem.errors import InputError

__all__ = ["Candidates", "PairStore", "System", "check_triangles", "count_intersections", "diagonal_test", "edges_of",
           "update_diagonal_test"]


def check_triangles(triangles) -> np.ndarray:
    tri = np.asarray(triangles)
    if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0 or not np.issubdtype(tri.dtype, np.integer):
        raise InputError(f"cloth triangles must be a non-empty (m, 3) integer array, got shape {tri.shape}")
    if tri.min() < 0:
        raise InputError("cloth triangles contain negative vertex indices")
    if (tri[:, 0] == tri[:, 1]).any() or (tri[:, 1] == tri[:, 2]).any() or (tri[:, 0] == tri[:, 2]).any():
        raise InputError("cloth triangles must have three distinct vertices")
    return tri.astype(np.int64)


def edges_of(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges (e, 2) sorted, and the (m, 3) edge index of each triangle side (v0v1, v1v2, v2v0)."""
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e.sort(axis=1)
    edges, inv = np.unique(e, axis=0, return_inverse=True)
    return edges, inv.reshape(3, -1).T


@dataclass
class Candidates:
    """Candidate primitive pairs: vertex quadruples and the triangle-pair test counts."""

    vf: np.ndarray
    ee: np.ndarray
    tests: int
    tests_unculled: int


class PairStore:
    """The candidate pairs of one step as blocks of (k, 4) vertex indices, each found at an ``epoch``: a
    :meth:`drop` only stamps its dirty vertices with a new epoch (a pair is in the store while none of its
    vertices carries a stamp above its block's epoch), and the replacements found for them are added as a
    new block, so an update copies no pairs and scans no block. The CCD takes a block of at least
    ``INDEXED`` pairs as it is (:meth:`segments`), testing the stamps and the flagged vertices in its own
    parallel pass; :meth:`pairs` selects through an index of the pairs each vertex holds (built at its first
    use). Replayed 64x64 pile (80 steps, both pipeline calls per step, one thread, CPU time, Intel Xeon): the
    drops took 7.0 ms/step as parallel scans of every block clearing alive masks, 0.1 ms/step as stamps. The
    CCD's pairs of a few flagged vertices read through that index instead of a scan were tried and dropped:
    building it costs ~1 ms for a 91k-pair block, scanning one 0.24 ms (int32 pairs, none flagged)."""

    #: pairs per block from which the CCD filters the block in its own pass (:meth:`segments`), and from
    #: which :meth:`pairs` selects through a vertex -> pairs index
    INDEXED = 4096

    def __init__(self, cand: Candidates) -> None:
        self.blocks: list = []  # (kind, (k, 4) int32 pairs, epoch)
        self.epoch = 0
        self.stamp = np.zeros(0, dtype=np.int64)  # (N,) epoch of each vertex's last drop; empty: none yet
        self._index: dict = {}
        self.add(cand)

    def add(self, cand: Candidates) -> None:
        """Append the pairs of ``cand`` (found now: the current epoch), stored as int32 (half the bytes of
        the CCD's scans, which stream whole blocks: 2.6M stored pairs of replayed 64x64 pile steps, none
        flagged, 19-21 -> 12 ms on one thread, Intel Xeon, fastest of 9)."""
        for kind, q in (("vf", cand.vf), ("ee", cand.ee)):
            if len(q):
                self.blocks.append((kind, np.ascontiguousarray(q, dtype=np.int32), self.epoch))
        if len(self.blocks) > 24:
            merged = []
            for kind in ("vf", "ee"):
                parts = [_pair_kernels.select_pairs(q, self.stamp, e, _NO_FLAGS)
                         for k, q, e in self.blocks if k == kind]
                if parts:
                    merged.append((kind, np.concatenate(parts), self.epoch))
            self.blocks = merged
            self._index = {}

    def _vertex_index(self, b: int, N: int):
        """Block ``b``'s :func:`_pair_kernels.vertex_index`, built at its first use (a block never changes
        its pairs; blocks keep their numbers until a merge, which clears the indices)."""
        if b not in self._index:
            self._index[b] = _pair_kernels.vertex_index(self.blocks[b][1], N)
        return self._index[b]

    def drop(self, dirty: np.ndarray) -> None:
        """Drop the pairs holding a vertex flagged in ``dirty`` ((N,) bool)."""
        if len(self.stamp) == 0:
            self.stamp = np.zeros(len(dirty), dtype=np.int64)
        self.epoch += 1
        self.stamp[dirty] = self.epoch

    def segments(self, kind: str, only: np.ndarray | None = None):
        """The pairs of ``kind`` for a compiled pass that filters them itself (e.g.
        :func:`modalfem.collision._ccd_kernels.ccd_block`), in block order, as ``(q, gone, flags)``: the pass
        takes the pairs of ``q`` that hold no vertex flagged in ``gone`` ((N,) bool, the vertices stamped after
        the block was found; empty: none) and hold a vertex flagged in ``flags`` (empty: no flag test). A block
        of at least ``INDEXED`` pairs comes as stored (its ``gone`` a byte per vertex, cheaper to read in the
        pass than the stamps), consecutive smaller blocks as their selected pairs
        (:func:`_pair_kernels.select_pairs`)."""
        flags = _NO_FLAGS if only is None else only
        small = []
        gone = {}
        for k, q, e in self.blocks:
            if k != kind:
                continue
            stamp = self.stamp if e < self.epoch else _NO_STAMP  # no drop since the block was found: all in
            if len(q) >= self.INDEXED:
                if small:
                    yield (small[0] if len(small) == 1 else np.concatenate(small)), _NO_FLAGS, _NO_FLAGS
                    small = []
                if len(stamp) and e not in gone:
                    gone[e] = stamp > e
                yield q, (gone[e] if len(stamp) else _NO_FLAGS), flags
            else:
                small.append(_pair_kernels.select_pairs(q, stamp, e, flags))
        if small:
            yield (small[0] if len(small) == 1 else np.concatenate(small)), _NO_FLAGS, _NO_FLAGS

    def pairs(self, kind: str, only: np.ndarray | None = None) -> np.ndarray:
        """(k, 4) pairs of ``kind`` (``"vf"``/``"ee"``) in the store, only those holding a vertex flagged in
        ``only`` ((N,) bool) if given."""
        flags = _NO_FLAGS if only is None else only
        verts = None if only is None else np.flatnonzero(only)
        parts = []
        for b, (k, q, e) in enumerate(self.blocks):
            if k != kind:
                continue
            if verts is not None and len(q) >= self.INDEXED:
                index = self._vertex_index(b, len(only))
                parts.append(_pair_kernels.select_indexed(q, self.stamp, e, *index, verts))
            else:
                parts.append(_pair_kernels.select_pairs(q, self.stamp, e, flags))
        if not parts:
            return np.zeros((0, 4), dtype=np.int64)
        return np.concatenate(parts).astype(np.int64)


_NO_FLAGS = np.zeros(0, dtype=bool)
_NO_STAMP = np.zeros(0, dtype=np.int64)


class System:
    """Cloth triangles plus obstacle meshes, their edges and BVHs."""

    def __init__(self, triangles: np.ndarray, obstacles, n_cloth: int | None = None) -> None:
        self.n_cloth = int(triangles.max()) + 1 if n_cloth is None else int(n_cloth)
        if self.n_cloth <= int(triangles.max()):
            raise InputError(f"cloth triangles index vertex {int(triangles.max())} but n_vertices is {self.n_cloth}")
        self.m_cloth = len(triangles)
        self.meshes = [o for o in obstacles if isinstance(o, TriangleMeshObstacle)]
        self.analytic = [o for o in obstacles if isinstance(o, (Plane, Sphere))]
        bad = [type(o).__name__ for o in obstacles if not isinstance(o, (Plane, Sphere, TriangleMeshObstacle))]
        if bad:
            raise InputError(f"unknown obstacle type(s): {', '.join(bad)}")
        tris = [triangles]
        offset = self.n_cloth
        for mo in self.meshes:
            tris.append(mo.triangles + offset)
            offset += len(mo.vertices)
        self.n_total = offset
        self.tris = np.concatenate(tris)
        self.edges, self.tri_edges = edges_of(self.tris)
        # each vertex and edge is owned by one of its triangles: a primitive pair is generated only by
        # the triangle pair of its owners, so it comes out once (no deduplication) and its boxes
        # (inside the owners' boxes) cannot be missed
        self.owned_verts = self._owned(self.tris, self.n_total)
        self.owned_edges = self._owned(self.tri_edges, len(self.edges))
        self._work = None  # work arrays of the serial primitive pair expansion (_primitive_pairs)
        # each cloth vertex's cloth triangles: a dirty search's triangles from its dirty vertices alone
        self.vertex_tris = _pair_kernels.vertex_triangles(np.ascontiguousarray(self.tris[: self.m_cloth]), self.n_cloth)
        self.cloth_bvh: BroadPhaseBVH | None = None
        self.obstacle_bvh: BroadPhaseBVH | None = None
        if self.meshes:
            ref = np.concatenate([np.zeros((self.n_cloth, 3))] + [mo.positions(mo.t_start) for mo in self.meshes])
            self.obstacle_bvh = BroadPhaseBVH(self.tris[self.m_cloth:], ref)

    @staticmethod
    def _owned(items: np.ndarray, count: int) -> np.ndarray:
        """(F, 3) items owned by each triangle (first triangle listing them), -1 padded."""
        F = len(items)
        owner = np.full(count, F)
        np.minimum.at(owner, items.ravel(), np.repeat(np.arange(F), 3))
        mine = owner[items] == np.arange(F)[:, None]
        return np.ascontiguousarray(np.where(mine, items, -1))

    def build_cloth_bvh(self, x_ref: np.ndarray) -> None:
        """Build the cloth's BVH grouping triangles by ``x_ref`` (n_cloth, 3) [m]."""
        self.cloth_bvh = BroadPhaseBVH(self.tris[: self.m_cloth], x_ref)

    def obstacle_positions(self, t: float) -> np.ndarray:
        """(n_total - n_cloth, 3) obstacle mesh vertex positions [m] at time ``t`` [s]."""
        if not self.meshes:
            return np.zeros((0, 3))
        return np.concatenate([mo.positions(t) for mo in self.meshes])

    def candidates(
        self, X0: np.ndarray, X1: np.ndarray, *, margin: float, self_collision: bool, culling: bool,
        count_unculled: bool = False, dirty: np.ndarray | None = None, static_margin: float | None = None,
        diagonals: bool = False, within: float | None = None,
    ) -> Candidates:
        """Candidate pairs for trajectories ``X0 -> X1`` ((n_total, 3) [m]), boxes grown by ``margin`` [m]
        (and covering the primitives at ``X0`` grown by ``static_margin`` [m] if given).

        ``diagonals``: also leave out the pairs whose boxes' projections on one of the four box diagonals do
        not overlap (:func:`diagonal_test`; a pair whose trajectories come within ``eta`` while inside boxes
        that hold them grown by ``eta / 2`` always overlaps there). ``within`` [m] (static boxes only, ``X1``
        is ``X0``): leave out the pairs proven farther apart than ``within`` at ``X0`` by their vertices'
        projections on those diagonals instead (what stage (a) keeps are the pairs closer than the thickness).
        Both only remove pairs whose answer downstream is known: the same pairs otherwise, in the same order.

        With ``dirty`` ((n_total,) bool), only the pairs holding at least one flagged vertex. Without it, the
        self pairs are expanded inside the traversal, chunk by chunk (:meth:`BroadPhaseBVH.self_primitive_pairs`):
        a full search of the 64x64 pile (120k triangle pairs) 15.9 -> 15.1 ms on one thread, same pairs."""
        dtri = None if dirty is None else _flagged_triangles(dirty, self.tris)
        n = self.n_cloth
        if self.cloth_bvh is None:
            self.build_cloth_bvh(X0[:n])
        self.cloth_bvh.refit(X0, X1, margin=margin, static_margin=static_margin)
        vlo, vhi = self.vertex_boxes(X0, X1, margin, static_margin)
        vlo, vhi = np.ascontiguousarray(vlo), np.ascontiguousarray(vhi)
        if within is not None:
            if X1 is not X0 or static_margin is not None:
                raise InputError("candidates within a distance need static boxes (X1 is X0, no static_margin)")
            X0c = np.ascontiguousarray(X0, dtype=float)
            diag = _ccd_kernels.diagonal_intervals(X0c, X0c), _ccd_kernels.diagonal_gap(X0c, X0c, float(within))
        else:
            diag = diagonal_test(vlo, vhi) if diagonals else (_NO_DIAG, 0.0)
        parts, tests, unculled = [], 0, 0
        fused = None
        if self_collision and dirty is None:
            # the self pairs expanded chunk by chunk inside the traversal (the triangle pairs never gathered):
            # the same pairs in the same order as the expansion of the gathered list
            boxes = _pair_kernels.primitive_boxes(self.tris, self.edges, vlo, vhi)
            fdiag = _pair_kernels.triangle_diagonals(self.tris, diag[0])
            expand = (self.tris, self.edges, self.owned_verts, self.owned_edges, vlo, vhi, *boxes, diag[0], fdiag,
                      diag[1])
            fused = self.cloth_bvh.self_primitive_pairs(expand, culling=culling)
            tests = unculled = fused[2]
            if count_unculled and culling:
                # the same traversal without culling (it prunes node pairs apart on a box diagonal too): what culling
                # saved, and nothing else
                unculled = self.cloth_bvh.self_primitive_pairs(expand, culling=False)[2]
        elif self_collision:
            pairs, tests = self.cloth_bvh.self_pairs(culling=culling, dirty=dtri[: self.m_cloth])
            parts.append(pairs)
            unculled = tests
            if count_unculled and culling:
                unculled = self.cloth_bvh.self_pairs(culling=False)[1]
        if self.obstacle_bvh is not None:
            self.obstacle_bvh.refit(X0, X1, margin=margin, static_margin=static_margin)
            pairs, t2 = self.cloth_bvh.cross_pairs(self.obstacle_bvh, dirty=None if dtri is None else dtri[: self.m_cloth])
            parts.append(pairs + np.array([0, self.m_cloth]))
            tests += t2
            unculled += t2
        if fused is not None and not parts:
            return Candidates(fused[0], fused[1], tests, unculled)
        tp = np.concatenate(parts) if parts else np.zeros((0, 2), dtype=np.int64)
        vf, ee = self._primitive_pairs(tp, vlo, vhi, dirty, diag)
        if fused is not None:
            vf, ee = np.concatenate([fused[0], vf]), np.concatenate([fused[1], ee])
        return Candidates(vf, ee, tests, unculled)

    def dirty_candidates(self, vlo: np.ndarray, vhi: np.ndarray, dirty: np.ndarray, *,
                         self_collision: bool, diagonals: bool = False, diag: tuple | None = None) -> Candidates:
        """The candidate pairs holding a ``dirty`` vertex ((n_total,) bool), searched again with the vertex
        boxes ``vlo``/``vhi`` ((n_total, 3) [m]; a clean vertex keeps the box of the last search). Only
        the dirty triangles' boxes are refitted and searched (no culling: a superset of what a full
        traversal would give for them), by one walk of the dirty triangles' own boxes against the tree
        (:meth:`BroadPhaseBVH.dirty_pairs`); the cost follows the dirty set. The dirty triangles come from the
        dirty vertices' own triangle lists. ``diag``: :func:`diagonal_test` of ``vlo``/``vhi`` if known (kept up
        to date by :func:`update_diagonal_test`), else computed here when ``diagonals``.

        Replayed 64x64 pile (80 steps, 680 dirty searches, one thread, CPU time, fastest of 2 per search, Intel
        Xeon, load ~5): the triangle-pair search 9.3-10.5 -> 4.9-5.6 ms per step against the earlier one box query
        per dirty triangle (a traversal of the tree against itself pruned to subtrees holding a dirty triangle
        above 300 of them, whose node boxes were the whole nodes'); the same pairs in every search."""
        n, m = self.n_cloth, self.m_cloth
        dtri, ids = _pair_kernels.dirty_triangles(np.ascontiguousarray(dirty, dtype=bool), *self.vertex_tris, m)
        bvh = self.cloth_bvh
        bvh.refit_triangles(ids, vlo[:n], vhi[:n])
        parts = []
        if self_collision:
            parts.append(bvh.dirty_pairs(dtri, ids))
        if self.obstacle_bvh is not None:
            qi, other = self.obstacle_bvh.query(bvh.tri_lo[ids], bvh.tri_hi[ids])
            parts.append(np.stack([ids[qi], other + m], axis=1))
        tp = np.concatenate(parts) if parts else np.zeros((0, 2), dtype=np.int64)
        if diag is None:
            diag = diagonal_test(vlo, vhi) if diagonals else (_NO_DIAG, 0.0)
        vf, ee = self._primitive_pairs(tp, vlo, vhi, dirty, diag)
        return Candidates(vf, ee, 0, 0)

    @staticmethod
    def vertex_boxes(X0, X1, margin, static_margin=None):
        """Vertex boxes (N, 3), (N, 3) [m]: the trajectory ``X0 -> X1`` grown by ``margin`` [m] and, if
        given, the point at ``X0`` grown by ``static_margin`` [m]."""
        vlo = np.minimum(X0, X1) - margin
        vhi = np.maximum(X0, X1) + margin
        if static_margin is not None:
            vlo = np.minimum(vlo, X0 - static_margin)
            vhi = np.maximum(vhi, X0 + static_margin)
        return vlo, vhi

    def _primitive_pairs(self, tp: np.ndarray, vlo: np.ndarray, vhi: np.ndarray, dirty=None, diag=None) -> tuple:
        """Point-triangle and edge-edge pairs of triangle pairs ``tp`` whose boxes overlap (vertex boxes
        ``vlo``/``vhi`` (N, 3) [m] already grown by the margin), without pairs sharing a vertex; with
        ``dirty`` ((N,) bool) only pairs holding a flagged vertex; with ``diag`` (``(intervals, gap)``, see
        :func:`diagonal_test`) not the pairs apart on a diagonal."""
        flags = np.zeros(0, dtype=bool) if dirty is None else np.asarray(dirty, dtype=bool)
        d, gap = (_NO_DIAG, 0.0) if diag is None else diag
        if _pair_kernels.chunk_count(len(tp), _pair_kernels.PAIR_CHUNK) == 1:
            # one chunk (a few triangle pairs, e.g. a dirty search's): serially, into kept work arrays
            if self._work is None:
                F, E = len(self.tris), len(self.edges)
                self._work = (np.empty((F, 3)), np.empty((F, 3)), np.empty((E, 3)), np.empty((E, 3)),
                              np.empty((F, 8)), np.zeros(F, dtype=bool))
            return _pair_kernels.primitive_pairs_serial(
                np.ascontiguousarray(tp, dtype=np.int64), self.tris, self.edges, self.owned_verts, self.owned_edges,
                np.ascontiguousarray(vlo), np.ascontiguousarray(vhi), flags, d, float(gap), *self._work)
        return _pair_kernels.primitive_pairs(np.ascontiguousarray(tp, dtype=np.int64), self.tris, self.edges,
                                            self.owned_verts, self.owned_edges, np.ascontiguousarray(vlo),
                                            np.ascontiguousarray(vhi), flags, d, float(gap))


_NO_DIAG = np.zeros((0, 8))


def _flagged_triangles(flags: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(m,) bool: triangles ``tris`` (m, 3) holding a vertex flagged in ``flags`` ((N,) bool); ``flags[tris].any(axis=1)``
    without numpy's slow reduction along a length-3 axis (8192 triangles: 122 -> 25 us with numpy 1.24, 608 -> 66
    with numpy 2.4, Intel Xeon); one compiled parallel pass (:func:`_pair_kernels.flagged_triangles`)."""
    return _pair_kernels.flagged_triangles(np.ascontiguousarray(flags, dtype=bool),
                                           np.ascontiguousarray(tris, dtype=np.int64))


def diagonal_test(vlo: np.ndarray, vhi: np.ndarray) -> tuple[np.ndarray, float]:
    """The vertex boxes' ``vlo``/``vhi`` ((N, 3) [m]) intervals on the four box diagonals
    (:func:`modalfem.collision._pair_kernels.box_diagonals`) and the gap [m] beyond which two primitives' intervals
    prove their boxes disjoint: the rounding of the projections (a sum of three coordinates, a few ulps of three
    times the coordinate scale), bounded as in :func:`modalfem.collision._ccd_kernels.diagonal_gap` with
    ``eta = 0``.

    Two points within ``eta`` of each other project on a diagonal (length sqrt(3)) within ``sqrt(3) eta``; a box
    holding a point grown by ``eta / 2`` on every axis projects over at least ``1.5 eta`` on each side of it. So
    primitives that come within ``eta`` while inside boxes holding them grown by ``eta / 2`` (the pipeline's
    candidate boxes: a vertex whose trajectory grown by ``eta / 2`` leaves its box is searched again) have
    overlapping box intervals on every diagonal: a pair apart on one can be left out of the candidates.

    Measured on the 64x64 pile (a late step): the swept search's 68k pairs that pass the boxes, 40 % apart on a
    diagonal; the proximity search's 120k (with ``within``: the vertices' own projections), 50 %.
    """
    return _pair_kernels.box_diagonals(vlo, vhi), float(_ccd_kernels.diagonal_gap(vlo, vhi, 0.0))


def update_diagonal_test(diag: tuple[np.ndarray, float], vlo: np.ndarray, vhi: np.ndarray,
                         ids: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`diagonal_test` of the boxes ``vlo``/``vhi`` ((N, 3) [m]) from ``diag``, that of earlier boxes which
    differ only in the rows ``ids`` ((k,) int), each of them grown (holding its earlier box): those rows of the
    intervals recomputed in place, the gap the larger of the old one and that of the rows ``ids``. The same numbers
    as a new :func:`diagonal_test` in O(k): the rows are computed alike, and the gap is increasing in the largest
    absolute coordinate of the boxes, which over a growing row never decreases (the largest ``|x|`` over an
    interval), so the old rows' share in the old gap is bounded by their new one."""
    from modalfem.collision._ccd_kernels import _gap_of

    ids = np.ascontiguousarray(ids, dtype=np.int64)
    scale = _pair_kernels.update_box_diagonals(diag[0], ids, vlo, vhi)
    return diag[0], max(diag[1], float(_gap_of(np.array([scale]), 0.0)))


def count_intersections(system: System, x: np.ndarray, t: float, self_collision: bool) -> int:
    """Intersecting pairs at ``x`` (n_cloth, 3) [m]: triangle pairs (independent test) + vertices inside
    planes/spheres."""
    tri = system.tris[: system.m_cloth]
    count = len(intersecting_pairs(x, tri)) if self_collision else 0
    for mo in system.meshes:
        count += len(intersecting_pairs(x, tri, other_points=mo.positions(t), other_triangles=mo.triangles))
    for ob in system.analytic:
        count += int((ob.signed_distance(x, t) < 0).sum())
    return count
