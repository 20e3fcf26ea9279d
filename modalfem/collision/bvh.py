"""Bounding-volume hierarchy over triangles with swept boxes and normal cones; compiled traversal.

The tree's topology is fixed when it is built (triangles sorted by the Morton code of their centroids
at a reference configuration, then grouped ``leaf_size`` to a leaf in a complete binary tree), and
``refit`` recomputes the boxes and normal cones for a step: a box bounds a triangle's straight-line
trajectory from ``x0`` to ``x1`` (a swept box) grown by a margin, and a cone bounds all its normals
along the trajectory (the normal is quadratic in time; its three Bernstein control vectors bound it).

Self-collision culling (Volino and Magnenat-Thalmann): a node whose triangles form one edge-connected
patch, whose normal cone is narrower than a half-space and whose contour projected on the plane normal
to the cone axis does not cross itself cannot intersect itself during the step, so its self-test is
skipped; likewise the test between two such patches that share an edge when their union passes both
tests. The contour test runs on the positions at the step's start, middle and end (the cone bounds the
normals at all times). Build the tree from the rest shape (``x_ref``) so that nodes are compact patches.
"""

from __future__ import annotations

import numpy as np

from modalfem.collision import _bvh_kernels
from modalfem.errors import InputError

__all__ = ["BroadPhaseBVH"]

#: longest projected contour [edges] checked for self-crossings; a longer one leaves its patch unculled
#: (its sub-patches are still culled)
CONTOUR_LIMIT = 4096


def _morton(points: np.ndarray) -> np.ndarray:
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023).astype(np.int64)
    code = np.zeros(len(points), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return code


class BroadPhaseBVH:
    """A BVH over triangles for candidate pairs (self and against another BVH).

    Args:
        triangles: (m, 3) int vertex indices.
        x_ref: (n, 3) reference positions [m] fixing the tree's grouping.
        leaf_size: triangles per leaf.
    """

    def __init__(self, triangles: np.ndarray, x_ref: np.ndarray, *, leaf_size: int = 8) -> None:
        tri = np.asarray(triangles, dtype=np.int64)
        if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0:
            raise InputError(f"BVH triangles must be a non-empty (m, 3) array, got shape {tri.shape}")
        self.triangles = tri
        m = len(tri)
        self.leaf_size = L = int(leaf_size)
        order = np.argsort(_morton(np.asarray(x_ref, dtype=float)[tri].mean(axis=1)), kind="stable")
        leaves = -(-m // L)
        self.P = P = 1 << int(np.ceil(np.log2(max(leaves, 1))))
        self.levels = int(np.log2(P))
        slots = np.full(P * L, -1, dtype=np.int64)
        slots[:m] = order
        self.slot_tri = slots.reshape(P, L)
        self.leaf_of_tri = np.empty(m, dtype=np.int64)
        self.leaf_of_tri[order] = P + np.arange(m) // L
        self.slot_of_tri = np.empty(m, dtype=np.int64)
        self.slot_of_tri[order] = np.arange(m) % L
        self.nonempty = np.zeros(2 * P, dtype=bool)
        self.nonempty[P:] = (self.slot_tri >= 0).any(axis=1)
        for lev in range(self.levels - 1, -1, -1):
            a = np.arange(1 << lev, 2 << lev)
            self.nonempty[a] = self.nonempty[2 * a] | self.nonempty[2 * a + 1]
        self.connected = self._connectivity()
        self._boundary_lists()
        #: check the contour condition when culling (off: the normal cone alone, as a comparison)
        self.boundary_check = True
        #: contours longer than this (edges) are not checked, and their patches not culled
        self.contour_limit = CONTOUR_LIMIT
        self._leaf_count = (self.slot_tri >= 0).sum(axis=1)
        self.lo = self.hi = self.tri_lo = self.tri_hi = None
        self.cone_axis = self.cone_angle = None
        self._x0 = self._x1 = None

    def _connectivity(self) -> np.ndarray:
        """(2P,) bool: the node's triangles form one edge-connected patch."""
        tri, m = self.triangles, len(self.triangles)
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        e.sort(axis=1)
        owner = np.tile(np.arange(m), 3)
        key = e[:, 0] * (tri.max() + 1) + e[:, 1]
        o = np.argsort(key, kind="stable")
        same = key[o][1:] == key[o][:-1]
        t1, t2 = owner[o][:-1][same], owner[o][1:][same]
        connected = np.zeros(2 * self.P, dtype=bool)
        self._adjacency_keys(t1, t2)
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        node = self.leaf_of_tri.copy()
        for _ in range(self.levels + 1):
            sel = node[t1] == node[t2]
            graph = coo_matrix((np.ones(int(sel.sum())), (t1[sel], t2[sel])), shape=(m, m))
            lab = connected_components(graph, directed=False)[1]
            comps = np.bincount(np.unique(node * m + lab) // m, minlength=2 * self.P)
            u = np.unique(node)
            connected[u] = comps[u] == 1
            node = node >> 1
        return connected

    def _boundary_lists(self) -> None:
        """Per node, its boundary edges (edges with exactly one triangle in the node) as CSR
        ``_bnd_start`` (2P + 1,) into ``_bnd_edge`` (vertex pairs (E, 2))."""
        tri = self.triangles
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        e.sort(axis=1)
        owner = np.tile(np.arange(len(tri)), 3)
        edges, inv = np.unique(e, axis=0, return_inverse=True)
        inv = inv.ravel()
        # two triangles per interior edge (a non-manifold edge's extra triangles count as boundary)
        o = np.argsort(inv, kind="stable")
        starts = np.searchsorted(inv[o], np.arange(len(edges)))
        cnt = np.bincount(inv, minlength=len(edges))
        has2 = cnt >= 2
        first, second = owner[o][starts], owner[o][np.minimum(starts + 1, len(o) - 1)]
        node_a, node_b, eid = [], [], np.arange(len(edges))
        la = self.leaf_of_tri[first]
        lb = np.where(has2, self.leaf_of_tri[second], -1)
        for shift in range(self.levels + 1):
            a = la >> shift
            b = np.where(has2, lb >> shift, -1)
            bnd = (a != b) | (cnt > 2)
            node_a.append(np.stack([a[bnd], eid[bnd]], 1))
            two = bnd & has2
            node_b.append(np.stack([b[two], eid[two]], 1))
        ne = np.concatenate(node_a + node_b)
        ne = ne[np.lexsort((ne[:, 1], ne[:, 0]))]
        self._bnd_start = np.searchsorted(ne[:, 0], np.arange(2 * self.P + 1))
        self._bnd_edge = edges[ne[:, 1]]
        self._bnd_id = ne[:, 1]

    def _adjacency_keys(self, t1: np.ndarray, t2: np.ndarray) -> None:
        """Sorted keys ``A * 2P + B`` of node pairs (any levels) holding two edge-adjacent triangles."""
        l1, l2 = self.leaf_of_tri[t1], self.leaf_of_tri[t2]
        diff = l1 != l2
        l1, l2 = l1[diff], l2[diff]
        keys = []
        for da in range(self.levels + 1):
            for db in range(self.levels + 1):
                a, b = l1 >> da, l2 >> db
                ok = (a != b) & (a > 0) & (b > 0)
                keys.append(a[ok] * (2 * self.P) + b[ok])
                keys.append(b[ok] * (2 * self.P) + a[ok])
        self._adj = np.unique(np.concatenate(keys)) if keys else np.zeros(0, dtype=np.int64)


    def refit(
        self, x0: np.ndarray, x1: np.ndarray | None = None, *, margin: float = 0.0, static_margin: float | None = None
    ) -> None:
        """Recompute boxes (swept from ``x0`` to ``x1``, grown by ``margin``) and normal cones.

        Args:
            x0: (n, 3) positions [m] at the step start.
            x1: (n, 3) positions [m] at the step end (None: static boxes).
            margin: box growth [m] on every side.
            static_margin: if given, each box also covers the triangle at ``x0`` grown by this [m].
        """
        same = x1 is None or x1 is x0  # static boxes: the contour test needs the start positions only
        x0 = np.ascontiguousarray(x0, dtype=float)
        x1 = x0 if same else np.ascontiguousarray(x1, dtype=float)
        self._x0, self._x1 = x0, x1
        sm = np.nan if static_margin is None else float(static_margin)
        (self.tri_lo, self.tri_hi, self.lo, self.hi, self._slo, self._shi, self.cone_axis,
         self.cone_angle) = _bvh_kernels.refit(self.triangles, x0, x1, float(margin), sm, self.P, self.slot_tri,
                                               self.nonempty)

    def refit_boxes(self, x: np.ndarray, *, margin: float = 0.0) -> None:
        """Static boxes at positions x (n, 3) [m] grown by ``margin`` [m], without normal cones: enough for
        :meth:`query` (which does not cull), several times cheaper than :meth:`refit` on small trees. The cones
        are set to "no bound", so a traversal after it culls nothing (and misses nothing).
        """
        x = np.ascontiguousarray(x, dtype=float)
        self._x0 = self._x1 = x
        (self.tri_lo, self.tri_hi, self.lo, self.hi, self._slo, self._shi) = _bvh_kernels.refit_boxes(
            self.triangles, x, float(margin), self.P, self.slot_tri)
        self.cone_axis = np.zeros((2 * self.P, 3))
        self.cone_angle = np.full(2 * self.P, np.pi)

    def refit_triangles(self, ids: np.ndarray, vlo: np.ndarray, vhi: np.ndarray) -> None:
        """Set the boxes of triangles ``ids`` to the union of their vertices' boxes and refit their
        ancestors only (normal cones are left as they are: :meth:`query` does not cull). Call
        :meth:`refit` first.

        Args:
            ids: (k,) triangle indices.
            vlo, vhi: (n, 3) vertex boxes [m] (e.g. a vertex's trajectory grown by the margin).
        """
        ids = np.asarray(ids, dtype=np.int64)
        if len(ids) == 0:
            return
        _bvh_kernels.refit_triangles(ids, self.triangles, np.ascontiguousarray(vlo, dtype=float),
                                     np.ascontiguousarray(vhi, dtype=float), self.tri_lo, self.tri_hi, self._slo,
                                     self._shi, self.lo, self.hi, self.leaf_of_tri, self.slot_of_tri, self.P)

    def query(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All (query, triangle) pairs whose boxes overlap, without culling (call :meth:`refit` first).

        Args:
            lo, hi: (k, 3) query boxes [m].

        Returns:
            ``(qi, tri)``: (p,) query indices and (p,) triangle indices of this tree.
        """
        out = _bvh_kernels.query(np.ascontiguousarray(lo, dtype=float), np.ascontiguousarray(hi, dtype=float), self.P,
                                 self.lo, self.hi, self.nonempty, self.slot_tri, self._slo, self._shi)
        return out[:, 0], out[:, 1]

    # ----------------------------------------------------------------------------------- traversal
    def _dirty_nodes(self, dirty: np.ndarray | None) -> np.ndarray:
        """(2P,) bool: subtree holds a triangle flagged in ``dirty`` ((m,) bool); empty if None."""
        if dirty is None:
            return np.zeros(0, dtype=bool)
        valid = self.slot_tri >= 0
        node = np.zeros(2 * self.P, dtype=bool)
        node[self.P:] = (valid & dirty[np.where(valid, self.slot_tri, 0)]).any(axis=1)
        for lev in range(self.levels - 1, -1, -1):
            a = np.arange(1 << lev, 2 << lev)
            node[a] = node[2 * a] | node[2 * a + 1]
        return node

    def _traverse(self, other: BroadPhaseBVH, culling: bool, dirty: np.ndarray | None) -> tuple[np.ndarray, int]:
        same = other is self
        dt = np.zeros(0, dtype=bool) if dirty is None else np.asarray(dirty, dtype=bool)
        pairs, tests = _bvh_kernels.traverse(
            same, bool(culling and same), self.P, self.lo, self.hi, self.nonempty, self.slot_tri, self._slo, self._shi,
            other.P, other.lo, other.hi, other.nonempty, other.slot_tri, other._slo, other._shi,
            self.connected, self.cone_axis, self.cone_angle, self._adj, self._bnd_start, self._bnd_edge, self._bnd_id,
            int(self.contour_limit), self._x0, self._x1, self._x1 is self._x0, bool(self.boundary_check),
            self._dirty_nodes(dirty), dt,
        )
        return pairs, int(tests)

    def self_pairs(self, *, culling: bool = True, dirty: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Triangle pairs of this tree whose boxes overlap (call ``refit`` first).

        Args:
            culling: skip the self-test of nodes that cannot self-intersect (normal cones and contours).
            dirty: (m,) bool; if given, only pairs with at least one flagged triangle.

        Returns:
            ``(pairs, tests)``: (k, 2) triangle indices (each unordered pair once) and the number of
            triangle-pair box tests done at the leaves.
        """
        return self._traverse(self, culling, dirty)

    def dirty_pairs(self, dirty: np.ndarray, ids: np.ndarray | None = None) -> np.ndarray:
        """Triangle pairs of this tree whose boxes overlap and that hold a triangle flagged in ``dirty`` ((m,)
        bool), without culling (call :meth:`refit`, and :meth:`refit_triangles` for changed boxes, first): the
        pairs of :meth:`self_pairs` ``(culling=False, dirty=dirty)``, found by a walk of the flagged triangles' own
        boxes against the tree (:func:`modalfem.collision._bvh_kernels.traverse_dirty`), in another order.

        ``ids``: the flagged triangles ((k,) int) if known (else found from ``dirty``).

        Returns:
            (k, 2) triangle indices, each unordered pair once, a flagged triangle first.
        """
        dirty = np.ascontiguousarray(dirty, dtype=bool)
        ids = np.flatnonzero(dirty) if ids is None else np.ascontiguousarray(ids, dtype=np.int64)
        return _bvh_kernels.traverse_dirty(self.P, self.lo, self.hi, self.slot_tri, self._slo, self._shi, dirty, ids,
                                           self.leaf_of_tri, self.slot_of_tri)

    def self_primitive_pairs(self, expand: tuple, *, culling: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
        """:meth:`self_pairs` (no dirty filter) with each parallel chunk's triangle pairs expanded at once into
        primitive pairs (:func:`modalfem.collision._bvh_kernels.traverse_primitives`).

        Args:
            expand: ``(tris, edges, own_v, own_e, vlo, vhi, flo, fhi, elo, ehi, diag, fdiag, gap)``, the
                arguments of :func:`modalfem.collision._pair_kernels.primitive_pairs` after the triangle pairs,
                plus the triangle and edge boxes (:func:`modalfem.collision._pair_kernels.primitive_boxes`), the
                vertices' and triangles' diagonal intervals and their gap (empty ``diag``: no diagonal test;
                :func:`modalfem.collision._system.diagonal_test`).
            culling: as in :meth:`self_pairs`.

        Returns:
            ``(vf, ee, tests)``: (p, 4) point-triangle and (q, 4) edge-edge vertex quadruples, leaf tests.
        """
        vf, ee, tests = _bvh_kernels.traverse_primitives(
            bool(culling), self.P, self.lo, self.hi, self.nonempty, self.slot_tri, self._slo, self._shi, self.connected,
            self.cone_axis, self.cone_angle, self._adj, self._bnd_start, self._bnd_edge, self._bnd_id,
            int(self.contour_limit), self._x0, self._x1, self._x1 is self._x0, bool(self.boundary_check), *expand)
        return vf, ee, int(tests)

    def cross_pairs(self, other: BroadPhaseBVH, *, dirty: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Pairs (triangle of this tree, triangle of ``other``) whose boxes overlap (both refitted).

        Args:
            other: the other tree.
            dirty: (m,) bool over this tree's triangles; if given, only pairs with a flagged one.

        Returns:
            ``(pairs, tests)`` as in :meth:`self_pairs`.
        """
        return self._traverse(other, False, dirty)
