"""Bounding-volume hierarchy over triangles with swept boxes and normal cones; vectorised traversal.

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

from modalfem.collision.distance import cross
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

    def _contour_ok(self, na: np.ndarray, nb: np.ndarray, axes: np.ndarray) -> np.ndarray:
        """(k,) bool: the contour of node ``na[k]`` (united with node ``nb[k]`` if >= 0: edges shared by
        both are interior) projected on the plane normal to ``axes[k]`` has no self-intersection at the
        step's start, middle and end positions (the second culling condition of Volino and
        Magnenat-Thalmann). Edges sharing a vertex may touch; collinear overlaps count as crossings."""
        k = len(na)
        ok = np.ones(k, dtype=bool)
        if k == 0 or not self.boundary_check:
            return ok
        st = self._bnd_start
        items, ids = [], []
        for nodes in (na, nb):
            valid = nodes >= 0
            nn = np.where(valid, nodes, 0)
            cnt = np.where(valid, st[nn + 1] - st[nn], 0)
            seg = np.repeat(np.arange(k), cnt)
            rank = np.arange(len(seg)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            items.append(seg)
            ids.append(st[nn][seg] + rank)
        item, pos = np.concatenate(items), np.concatenate(ids)
        key = item * (int(self._bnd_id.max()) + 1) + self._bnd_id[pos]
        _, first, cnt = np.unique(key, return_index=True, return_counts=True)
        item, pos = item[first[cnt == 1]], pos[first[cnt == 1]]  # shared edges are interior
        per = np.bincount(item, minlength=k)
        ok[per > self.contour_limit] = False  # not checked: not culled
        keep = per[item] <= self.contour_limit
        item, E = item[keep], self._bnd_edge[pos[keep]]
        # an orthonormal basis (u, w) of each plane
        helper = np.where(np.abs(axes[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
        u = cross(axes, helper)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        w = cross(axes, u)
        for s in (0.0,) if self._x1 is self._x0 else (0.0, 0.5, 1.0):
            x = self._x0 if s == 0.0 else self._x0 + s * (self._x1 - self._x0)
            ok[self._crossing_items(item, E, x, u[item], w[item])] = False
        return ok

    @staticmethod
    def _crossing_items(item: np.ndarray, E: np.ndarray, x: np.ndarray, u: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Items holding two edges (``E`` (N, 2) vertex pairs of item ``item`` (N,)) that do not share a
        vertex and cross (or touch, or overlap collinearly) when projected on (``u``, ``w``) (N, 3):
        sort and sweep along u over the 2D boxes, orientation tests on the overlapping pairs."""
        a = np.stack([np.einsum("nei,ni->ne", x[E], u), np.einsum("nei,ni->ne", x[E], w)], axis=-1)  # (N, 2, 2)
        lo, hi = a.min(axis=1), a.max(axis=1)
        if len(item) == 0:
            return item
        span = float(hi[:, 0].max() - lo[:, 0].min()) + 1.0
        base = lo[:, 0].min()
        order = np.lexsort((lo[:, 0], item))
        key = item[order] * span + (lo[order, 0] - base)
        tol = 1e-9 * span
        end = np.searchsorted(key, item[order] * span + (hi[order, 0] - base) + tol, side="right")
        cnt = np.maximum(end - np.arange(len(order)) - 1, 0)
        i = np.repeat(np.arange(len(order)), cnt)
        j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        i, j = order[i], order[j]
        near = (item[i] == item[j]) & (lo[i, 1] <= hi[j, 1]) & (lo[j, 1] <= hi[i, 1])
        i, j = i[near], j[near]
        ea, eb = E[i], E[j]
        apart = (ea[:, :1] != eb).all(axis=1) & (ea[:, 1:] != eb).all(axis=1)
        i, j = i[apart], j[apart]
        A0, A1, B0, B1 = a[i, 0], a[i, 1], a[j, 0], a[j, 1]

        def orient(o, d, q):
            return (d[:, 0] - o[:, 0]) * (q[:, 1] - o[:, 1]) - (d[:, 1] - o[:, 1]) * (q[:, 0] - o[:, 0])

        hit = (orient(A0, A1, B0) * orient(A0, A1, B1) <= 0) & (orient(B0, B1, A0) * orient(B0, B1, A1) <= 0)
        return np.unique(item[i[hit]])

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

    def _adjacent(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        key = a * (2 * self.P) + b
        i = np.searchsorted(self._adj, key)
        return (i < len(self._adj)) & (self._adj[np.minimum(i, len(self._adj) - 1)] == key)

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
        tri = self.triangles
        self._x0, self._x1 = x0, (x0 if x1 is None else x1)
        p0 = x0[tri]
        p1 = p0 if x1 is None else x1[tri]
        lo0 = np.minimum(np.minimum(p0[:, 0], p0[:, 1]), p0[:, 2])
        hi0 = np.maximum(np.maximum(p0[:, 0], p0[:, 1]), p0[:, 2])
        lo1 = np.minimum(np.minimum(p1[:, 0], p1[:, 1]), p1[:, 2])
        hi1 = np.maximum(np.maximum(p1[:, 0], p1[:, 1]), p1[:, 2])
        self.tri_lo = np.minimum(lo0, lo1) - margin
        self.tri_hi = np.maximum(hi0, hi1) + margin
        if static_margin is not None:
            self.tri_lo = np.minimum(self.tri_lo, lo0 - static_margin)
            self.tri_hi = np.maximum(self.tri_hi, hi0 + static_margin)
        P, L = self.P, self.leaf_size
        # triangles sit in slots order[0..m-1]; leaf k holds slots k*L..k*L+L-1: reduce per leaf
        m = len(tri)
        order = self.slot_tri.ravel()[:m]
        starts = np.arange(0, m, L)
        full = len(starts)
        self.lo = np.full((2 * P, 3), np.inf)
        self.hi = np.full((2 * P, 3), -np.inf)
        slo = np.full((P * L, 3), np.inf)
        shi = np.full((P * L, 3), -np.inf)
        slo[:m], shi[:m] = self.tri_lo[order], self.tri_hi[order]
        self._slo = slo.T.reshape(3, P, L).copy()
        self._shi = shi.T.reshape(3, P, L).copy()
        self.lo[P:P + full] = np.minimum.reduceat(self.tri_lo[order], starts, axis=0)
        self.hi[P:P + full] = np.maximum.reduceat(self.tri_hi[order], starts, axis=0)
        # normal control vectors (Bernstein form of the swept normal), unit length
        e10, e20 = p0[:, 1] - p0[:, 0], p0[:, 2] - p0[:, 0]
        e11, e21 = p1[:, 1] - p1[:, 0], p1[:, 2] - p1[:, 0]
        ctrl = [cross(e10, e20), 0.5 * (cross(e10, e21) + cross(e11, e20)), cross(e11, e21)]
        nrm = [np.sqrt(np.einsum("ki,ki->k", c, c)) for c in ctrl]
        bad = (nrm[0] == 0) | (nrm[1] == 0) | (nrm[2] == 0)
        unit = [c / np.where(n > 0, n, 1.0)[:, None] for c, n in zip(ctrl, nrm)]
        tsum = (unit[0] + unit[1] + unit[2])[order]
        axis = np.add.reduceat(tsum, starts, axis=0)
        an = np.sqrt(np.einsum("ki,ki->k", axis, axis))
        axis = axis / np.where(an > 0, an, 1.0)[:, None]
        ax_t = axis[np.arange(m) // L]
        ang_t = np.zeros(m)
        for u in unit:
            ang_t = np.maximum(ang_t, np.arccos(np.clip(np.einsum("ki,ki->k", u[order], ax_t), -1.0, 1.0)))
        ang = np.maximum.reduceat(ang_t, starts)
        leafbad = np.logical_or.reduceat(bad[order], starts) | (an == 0)
        ang = np.where(leafbad, np.pi, ang)
        full_axis = np.zeros((P, 3))
        full_ang = np.full(P, np.pi)
        full_axis[:full], full_ang[:full] = axis, ang
        axis, ang = full_axis, full_ang
        self.cone_axis = np.zeros((2 * P, 3))
        self.cone_angle = np.full(2 * P, np.pi)
        self.cone_axis[P:], self.cone_angle[P:] = axis, ang
        for lev in range(self.levels - 1, -1, -1):
            a = np.arange(1 << lev, 2 << lev)
            l, r = 2 * a, 2 * a + 1
            self.lo[a] = np.minimum(self.lo[l], self.lo[r])
            self.hi[a] = np.maximum(self.hi[l], self.hi[r])
            ax = np.where(self.nonempty[l, None], self.cone_axis[l], 0) + np.where(self.nonempty[r, None], self.cone_axis[r], 0)
            n = np.linalg.norm(ax, axis=1, keepdims=True)
            ax = ax / np.where(n > 0, n, 1.0)
            spread_l = np.arccos(np.clip(np.einsum("ki,ki->k", ax, self.cone_axis[l]), -1, 1)) + self.cone_angle[l]
            spread_r = np.arccos(np.clip(np.einsum("ki,ki->k", ax, self.cone_axis[r]), -1, 1)) + self.cone_angle[r]
            ang = np.maximum(np.where(self.nonempty[l], spread_l, 0), np.where(self.nonempty[r], spread_r, 0))
            self.cone_axis[a] = ax
            self.cone_angle[a] = np.where(n[:, 0] > 0, ang, np.pi)

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
        t0, t1, t2 = self.triangles[ids].T
        lo = np.minimum(np.minimum(vlo[t0], vlo[t1]), vlo[t2])
        hi = np.maximum(np.maximum(vhi[t0], vhi[t1]), vhi[t2])
        self.tri_lo[ids], self.tri_hi[ids] = lo, hi
        leaf, col = self.leaf_of_tri[ids] - self.P, self.slot_of_tri[ids]
        self._slo[:, leaf, col], self._shi[:, leaf, col] = lo.T, hi.T
        node = np.unique(leaf)
        self.lo[node + self.P] = self._slo[:, node].min(axis=2).T
        self.hi[node + self.P] = self._shi[:, node].max(axis=2).T
        node = node + self.P
        while node[0] > 1:
            node = np.unique(node >> 1)
            self.lo[node] = np.minimum(self.lo[2 * node], self.lo[2 * node + 1])
            self.hi[node] = np.maximum(self.hi[2 * node], self.hi[2 * node + 1])

    def query(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """All (query, triangle) pairs whose boxes overlap, without culling (call :meth:`refit` first).

        Args:
            lo, hi: (k, 3) query boxes [m].

        Returns:
            ``(qi, tri)``: (p,) query indices and (p,) triangle indices of this tree.
        """
        qlo, qhi = lo.T.copy(), hi.T.copy()
        nlo, nhi = self.lo.T.copy(), self.hi.T.copy()
        qi = np.arange(len(lo))
        node = np.ones(len(qi), dtype=np.int64)
        for _ in range(self.levels + 1):
            keep = self.nonempty[node]
            for ax in range(3):
                keep &= (qlo[ax][qi] <= nhi[ax][node]) & (nlo[ax][node] <= qhi[ax][qi])
            qi, node = qi[keep], node[keep]
            if len(qi) == 0 or node[0] >= self.P:
                break
            qi = np.repeat(qi, 2)
            node = np.repeat(2 * node, 2)
            node[1::2] += 1
        leaf = node - self.P
        ok = self.slot_tri[leaf] >= 0
        for ax in range(3):
            ok &= (qlo[ax][qi][:, None] <= self._shi[ax][leaf]) & (self._slo[ax][leaf] <= qhi[ax][qi][:, None])
        r, c = np.nonzero(ok)
        return qi[r], self.slot_tri[leaf[r], c]

    # ----------------------------------------------------------------------------------- traversal
    def _overlap(self, other: BroadPhaseBVH, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return ((self.lo[a] <= other.hi[b]) & (other.lo[b] <= self.hi[a])).all(axis=1)

    def _leaf_pairs_to_triangles(
        self, other: BroadPhaseBVH, a: np.ndarray, b: np.ndarray, dirty: np.ndarray | None = None
    ) -> tuple[np.ndarray, int]:
        """Triangle pairs of leaf pairs (a, b) whose boxes overlap (only pairs with a ``dirty`` one)."""
        ia, ib = a - self.P, b - other.P
        na, nb = self._leaf_count[ia], other._leaf_count[ib]
        same = a == b if other is self else np.zeros(len(a), dtype=bool)
        tests = int(np.where(same, na * (na - 1) // 2, na * nb).sum())
        ok = None
        for ax in range(3):
            alo, ahi = self._slo[ax][ia], self._shi[ax][ia]
            blo, bhi = other._slo[ax][ib], other._shi[ax][ib]
            o = (alo[:, :, None] <= bhi[:, None, :]) & (blo[:, None, :] <= ahi[:, :, None])
            ok = o if ok is None else ok & o
        if other is self:
            L = self.leaf_size
            ok &= ~same[:, None, None] | (np.arange(L)[:, None] < np.arange(L)[None, :])
        ta, tb = self.slot_tri[ia], other.slot_tri[ib]
        if dirty is not None:
            da = dirty[np.maximum(ta, 0)] & (ta >= 0)
            db = dirty[np.maximum(tb, 0)] & (tb >= 0) if other is self else np.zeros(tb.shape, dtype=bool)
            ok &= da[:, :, None] | db[:, None, :]
        k, r, c = np.nonzero(ok)
        return np.stack([ta[k, r], tb[k, c]], axis=1), tests

    def _dirty_nodes(self, dirty: np.ndarray | None) -> np.ndarray | None:
        """(2P,) bool: subtree holds a triangle flagged in ``dirty`` ((m,) bool), or None."""
        if dirty is None:
            return None
        valid = self.slot_tri >= 0
        node = np.zeros(2 * self.P, dtype=bool)
        node[self.P:] = (valid & dirty[np.where(valid, self.slot_tri, 0)]).any(axis=1)
        for lev in range(self.levels - 1, -1, -1):
            a = np.arange(1 << lev, 2 << lev)
            node[a] = node[2 * a] | node[2 * a + 1]
        return node

    def self_pairs(self, *, culling: bool = True, dirty: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Triangle pairs of this tree whose boxes overlap (call ``refit`` first).

        Args:
            culling: skip the self-test of nodes that cannot self-intersect (normal cones).
            dirty: (m,) bool; if given, only pairs with at least one flagged triangle.

        Returns:
            ``(pairs, tests)``: (k, 2) triangle indices (each unordered pair once) and the number of
            triangle-pair box tests done at the leaves.
        """
        P = self.P
        dn = self._dirty_nodes(dirty)
        singles = np.array([1])
        pa = np.zeros(0, dtype=np.int64)
        pb = np.zeros(0, dtype=np.int64)
        leaf_a, leaf_b = [], []
        while len(singles) or len(pa):
            singles = singles[self.nonempty[singles]]
            if dn is not None:
                singles = singles[dn[singles]]
                keep = dn[pa] | dn[pb]
                pa, pb = pa[keep], pb[keep]
            if culling:
                flat = self.connected[singles] & (self.cone_angle[singles] < 0.5 * np.pi - 1e-9)
                if flat.any():
                    f = singles[flat]
                    flat[flat] = self._contour_ok(f, np.full(len(f), -1), self.cone_axis[f])
                singles = singles[~flat]
            is_leaf = singles >= P
            leaf_a.append(singles[is_leaf])
            leaf_b.append(singles[is_leaf])
            inner = singles[~is_leaf]
            na, nb = self._descend(self, pa, pb, leaf_a, leaf_b, culling=culling)
            pa = np.concatenate([na, 2 * inner])
            pb = np.concatenate([nb, 2 * inner + 1])
            singles = np.concatenate([2 * inner, 2 * inner + 1])
        return self._finish(self, leaf_a, leaf_b, dirty)

    def cross_pairs(self, other: BroadPhaseBVH, *, dirty: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Pairs (triangle of this tree, triangle of ``other``) whose boxes overlap (both refitted).

        Args:
            other: the other tree.
            dirty: (m,) bool over this tree's triangles; if given, only pairs with a flagged one.

        Returns:
            ``(pairs, tests)`` as in :meth:`self_pairs`.
        """
        dn = self._dirty_nodes(dirty)
        pa, pb = np.array([1]), np.array([1])
        leaf_a, leaf_b = [], []
        while len(pa):
            if dn is not None:
                keep = dn[pa]
                pa, pb = pa[keep], pb[keep]
            pa, pb = self._descend(other, pa, pb, leaf_a, leaf_b)
        return self._finish(other, leaf_a, leaf_b, dirty)

    def _descend(self, other, pa, pb, leaf_a, leaf_b, *, culling=False):
        keep = self.nonempty[pa] & other.nonempty[pb]
        pa, pb = pa[keep], pb[keep]
        keep = self._overlap(other, pa, pb)
        pa, pb = pa[keep], pb[keep]
        if culling and len(pa):
            # two adjacent patches whose union is one patch with a narrow normal cone: skip
            c = self.connected[pa] & self.connected[pb]
            c[c] = self._adjacent(pa[c], pb[c])
            if c.any():
                a1, a2 = self.cone_axis[pa[c]], self.cone_axis[pb[c]]
                ax = a1 + a2
                ax /= np.maximum(np.linalg.norm(ax, axis=1), 1e-300)[:, None]
                ang = np.maximum(
                    np.arccos(np.clip(np.einsum("ki,ki->k", ax, a1), -1, 1)) + self.cone_angle[pa[c]],
                    np.arccos(np.clip(np.einsum("ki,ki->k", ax, a2), -1, 1)) + self.cone_angle[pb[c]],
                )
                narrow = ang < 0.5 * np.pi - 1e-9
                if narrow.any():
                    ia, ib = pa[c][narrow], pb[c][narrow]
                    narrow[narrow] = self._contour_ok(ia, ib, ax[narrow])
                c[c] = narrow
                pa, pb = pa[~c], pb[~c]
        la, lb = pa >= self.P, pb >= other.P
        both = la & lb
        leaf_a.append(pa[both])
        leaf_b.append(pb[both])
        pa, pb, la, lb = pa[~both], pb[~both], la[~both], lb[~both]
        size_a = (self.hi[pa] - self.lo[pa]).sum(axis=1)
        size_b = (other.hi[pb] - other.lo[pb]).sum(axis=1)
        split_a = ~la & (lb | (size_a >= size_b))
        sa, sb = pa[split_a], pb[split_a]
        ta, tb = pa[~split_a], pb[~split_a]
        na = np.concatenate([2 * sa, 2 * sa + 1, ta, ta])
        nb = np.concatenate([sb, sb, 2 * tb, 2 * tb + 1])
        return na, nb

    def _finish(self, other, leaf_a, leaf_b, dirty=None) -> tuple[np.ndarray, int]:
        a = np.concatenate(leaf_a) if leaf_a else np.zeros(0, dtype=np.int64)
        b = np.concatenate(leaf_b) if leaf_b else np.zeros(0, dtype=np.int64)
        if len(a) == 0:
            return np.zeros((0, 2), dtype=np.int64), 0
        return self._leaf_pairs_to_triangles(other, a.astype(np.int64), b.astype(np.int64), dirty)

