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

    def query(self, points: np.ndarray, V: np.ndarray, margin: float) -> Hits:
        """The closest triangle within ``margin`` [m] (either side) of each of ``points`` (k, 3) [m], for the
        surface at vertex positions ``V`` (n, 3) [m]."""
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
        first = np.ones(len(qi), dtype=bool)
        first[1:] = qi[1:] != qi[:-1]
        return Hits(qi[first], tri[first], w[first], gap[first], nrm[first])
