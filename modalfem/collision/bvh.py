"""Bounding-volume hierarchy over triangles with swept boxes and normal cones; vectorised traversal.

The tree's topology is fixed when it is built (triangles sorted by the Morton code of their centroids
at a reference configuration, then grouped ``leaf_size`` to a leaf in a complete binary tree), and
``refit`` recomputes the boxes and normal cones for a step: a box bounds a triangle's straight-line
trajectory from ``x0`` to ``x1`` (a swept box) grown by a margin, and a cone bounds all its normals
along the trajectory (the normal is quadratic in time; its three Bernstein control vectors bound it).

Self-collision culling (Volino and Magnenat-Thalmann): a node whose triangles form one edge-connected
patch and whose normal cone is narrower than a half-space cannot intersect itself during the step, so
its self-test is skipped; likewise the test between two such patches that share an edge when the cone
of their union is narrower than a half-space. (The paper's second condition, a contour that does not
fold back in projection, is not checked: with connected patches from compact Morton groups it fails
only for a helicoid-like patch winding around a point.) Build the tree from the rest shape
(``x_ref``) so that nodes are compact patches.
"""

from __future__ import annotations

import numpy as np

from modalfem.collision.distance import cross
from modalfem.errors import InputError

__all__ = ["BroadPhaseBVH"]


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
        self.nonempty = np.zeros(2 * P, dtype=bool)
        self.nonempty[P:] = (self.slot_tri >= 0).any(axis=1)
        for lev in range(self.levels - 1, -1, -1):
            a = np.arange(1 << lev, 2 << lev)
            self.nonempty[a] = self.nonempty[2 * a] | self.nonempty[2 * a + 1]
        self.connected = self._connectivity()
        self._leaf_count = (self.slot_tri >= 0).sum(axis=1)
        self.lo = self.hi = self.tri_lo = self.tri_hi = None
        self.cone_axis = self.cone_angle = None

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
        node = self.leaf_of_tri.copy()
        for _ in range(self.levels + 1):
            sel = node[t1] == node[t2]
            a, b = t1[sel], t2[sel]
            lab = np.arange(m)
            while True:
                low = np.minimum(lab[a], lab[b])
                new = lab.copy()
                np.minimum.at(new, a, low)
                np.minimum.at(new, b, low)
                new = new[new]
                if np.array_equal(new, lab):
                    break
                lab = new
            roots = np.unique(np.stack([node, lab], axis=1), axis=0)
            comps = np.bincount(roots[:, 0], minlength=2 * self.P)
            u = np.unique(node)
            connected[u] = comps[u] == 1
            node = node >> 1
        return connected

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
        self._tlo, self._thi = self.tri_lo.T.copy(), self.tri_hi.T.copy()
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
                c[c] = ang < 0.5 * np.pi - 1e-9
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

