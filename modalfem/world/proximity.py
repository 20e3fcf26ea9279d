"""Points near a triangle surface: the closest triangle of each point within a margin (the collision module's
BVH for candidates, its point-triangle kernel for the distances).

The gap is the signed distance to the closest triangle's plane along its normal (negative behind it: inside a
closed outward surface; never more than the distance to the triangle), and the contact normal is that
triangle's unit normal, so a point is pushed along the face it touches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.collision.bvh import BroadPhaseBVH
from modalfem.collision.distance import point_triangle

__all__ = ["Hits", "SurfaceProximity"]


@dataclass
class Hits:
    """Closest-triangle contacts of query points.

    Attributes:
        point: (k,) query point indices (each at most once).
        triangle: (k,) triangle indices of the surface.
        bary: (k, 3) barycentric weights of the closest point on the triangle.
        gap: (k,) signed distances [m] (negative behind the triangle).
        normal: (k, 3) unit normals of the triangles [-].
    """

    point: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    gap: np.ndarray
    normal: np.ndarray


class SurfaceProximity:
    """A BVH over one surface's triangles (built once, refitted per query).

    Args:
        triangles: (f, 3) vertex indices of the surface.
        x_ref: (n, 3) reference positions [m] fixing the tree's grouping.
    """

    def __init__(self, triangles: np.ndarray, x_ref: np.ndarray) -> None:
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self.bvh = BroadPhaseBVH(self.triangles, np.asarray(x_ref, dtype=np.float64))

    def query(self, points: np.ndarray, V: np.ndarray, margin: float, *, every: bool = False) -> Hits:
        """The closest triangle within ``margin`` [m] (either side) of each of ``points`` (k, 3) [m], for the
        surface at vertex positions ``V`` (n, 3) [m]; ``every``: each triangle within ``margin`` of a point (a point
        over an edge or corner of the surface meets each face there), a point then possibly more than once."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        V = np.ascontiguousarray(V, dtype=np.float64)
        self.bvh.refit(V, margin=0.0)
        qi, tri = self.bvh.query(points - margin, points + margin)
        if len(qi) == 0:
            z = np.zeros(0, dtype=np.int64)
            return Hits(z, z, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
        T = self.triangles[tri]
        a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
        d, w = point_triangle(points[qi], a, b, c)
        nrm = np.cross(b - a, c - a)
        ln = np.sqrt(np.einsum("ij,ij->i", nrm, nrm))
        nrm = nrm / np.where(ln > 0, ln, 1.0)[:, None]
        closest = w[:, 0:1] * a + w[:, 1:2] * b + w[:, 2:3] * c
        # the distance along the triangle's normal (to its plane: the closest point lies in it), at most the
        # distance d: a contact that may close ``gap`` along the normal never reaches the triangle's plane
        gap = np.einsum("ij,ij->i", points[qi] - closest, nrm)
        keep = (d <= margin) & (ln > 0)
        qi, tri, w, gap, nrm, d = qi[keep], tri[keep], w[keep], gap[keep], nrm[keep], d[keep]
        # the closest triangle of each point (ties: the one the point is most in front of)
        order = np.lexsort((-gap, d, qi))
        qi, tri, w, gap, nrm = qi[order], tri[order], w[order], gap[order], nrm[order]
        if every:
            return Hits(qi, tri, w, gap, nrm)
        first = np.ones(len(qi), dtype=bool)
        first[1:] = qi[1:] != qi[:-1]
        return Hits(qi[first], tri[first], w[first], gap[first], nrm[first])


def surface_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique edges (e, 2) of a triangle surface and, per edge, up to two adjacent triangles (e, 2) (-1: none)."""
    t = np.asarray(triangles, dtype=np.int64)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    owner = np.tile(np.arange(len(t)), 3)
    key = np.sort(e, axis=1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    adj = np.full((len(uniq), 2), -1, dtype=np.int64)
    order = np.argsort(inv, kind="stable")
    first = np.ones(len(order), dtype=bool)
    first[1:] = inv[order][1:] != inv[order][:-1]
    adj[inv[order][first], 0] = owner[order][first]
    second = ~first
    adj[inv[order][second], 1] = owner[order][second]
    return uniq, adj


@dataclass
class EdgeHits:
    """Close edge pairs: ``mine`` (k,) and ``other`` (k,) edge indices, closest-point parameters ``s`` on mine and
    ``t`` on the other's (k,) [-], ``gap`` (k,) [m] (negative: my edge is behind the other surface) and
    ``normal`` (k, 3) pointing from the other surface to my edge."""

    mine: np.ndarray
    other: np.ndarray
    s: np.ndarray
    t: np.ndarray
    gap: np.ndarray
    normal: np.ndarray


class EdgeProximity:
    """Edge-edge proximity against one surface (a BVH over its edges, built once, refitted per query).

    Args:
        triangles: (f, 3) triangles of the surface (outward).
        x_ref: (n, 3) reference positions [m].
    """

    def __init__(self, triangles: np.ndarray, x_ref: np.ndarray) -> None:
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self.edges, self.adjacent = surface_edges(self.triangles)
        e = self.edges
        self.bvh = BroadPhaseBVH(np.column_stack([e[:, 0], e[:, 1], e[:, 1]]), np.asarray(x_ref, dtype=np.float64))

    def sides(self, V: np.ndarray, ei: np.ndarray) -> np.ndarray:
        """The surface's outward side (k, 3) [-] at its edges ``ei`` (k,) for vertex positions ``V`` (n, 3) [m]: the
        sum of the adjacent faces' unit normals (length 2 on a flat edge, less on a bent one)."""
        T = self.triangles
        side = np.zeros((len(ei), 3))
        for j in range(2):
            f = self.adjacent[ei, j]
            ok = f >= 0
            tri = T[np.where(ok, f, 0)]
            nf = np.cross(V[tri[:, 1]] - V[tri[:, 0]], V[tri[:, 2]] - V[tri[:, 0]])
            side += np.where(ok[:, None], nf / np.maximum(np.linalg.norm(nf, axis=1), 1e-300)[:, None], 0.0)
        return side

    def query(self, a0: np.ndarray, a1: np.ndarray, V: np.ndarray, margin: float) -> EdgeHits:
        """Pairs of my edges ``a0 a1`` (k, 3) [m] with the surface's edges (at vertex positions ``V``) closer than
        ``margin`` [m], their closest points inside both edges and the edges at least ~12 degrees from parallel: the
        closest point pair and its separation along the other surface's outward side."""
        from modalfem.collision.distance import edge_edge

        V = np.ascontiguousarray(V, dtype=np.float64)
        self.bvh.refit(V, margin=0.0)
        lo = np.minimum(a0, a1) - margin
        hi = np.maximum(a0, a1) + margin
        qi, ei = self.bvh.query(lo, hi)
        if len(qi) == 0:
            z = np.zeros(0, dtype=np.int64)
            return EdgeHits(z, z, np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 3)))
        b0, b1 = V[self.edges[ei, 0]], V[self.edges[ei, 1]]
        d, s, t = edge_edge(a0[qi], a1[qi], b0, b1)
        # only pairs whose closest points are inside both edges and whose edges are far from parallel: the others
        # are vertex-face contacts already (and parallel pairs have no well-defined normal)
        ua, ub = a1[qi] - a0[qi], b1 - b0
        cr = np.linalg.norm(np.cross(ua, ub), axis=1)
        keep = (d <= margin) & (s > 1e-6) & (s < 1 - 1e-6) & (t > 1e-6) & (t < 1 - 1e-6) & \
            (cr > 0.2 * np.linalg.norm(ua, axis=1) * np.linalg.norm(ub, axis=1))
        qi, ei, d, s, t, b0, b1 = qi[keep], ei[keep], d[keep], s[keep], t[keep], b0[keep], b1[keep]
        pa = a0[qi] + s[:, None] * (a1[qi] - a0[qi])
        pb = b0 + t[:, None] * (b1 - b0)
        side = self.sides(V, ei)
        diff = pa - pb
        n = diff / np.maximum(d, 1e-300)[:, None]
        flip = np.einsum("ij,ij->i", n, side) < 0
        n = np.where(flip[:, None], -n, n)
        gap = np.where(flip, -d, d)
        tiny = d <= 1e-12 * max(1.0, float(np.abs(V).max()))
        ln = np.linalg.norm(side, axis=1)
        n[tiny] = side[tiny] / np.maximum(ln[tiny], 1e-300)[:, None]
        good = np.linalg.norm(n, axis=1) > 0.5
        return EdgeHits(qi[good], ei[good], s[good], t[good], gap[good], n[good])
