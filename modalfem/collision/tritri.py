"""An independent triangle-triangle intersection check (shares no code with the CCD or the BVH).

Two non-coplanar triangles intersect exactly when an edge of one crosses the other. A segment
``q0 q1`` crosses triangle ``a b c`` when its ends are not strictly on the same side of the plane
and the line ``q0 q1`` passes through the triangle (three signed volumes of one sign); both tests are
sign tests of 3x3 determinants, inclusive (touching counts). Triangles sharing one vertex are tested
by the edges opposite the shared vertex; triangles sharing an edge are not tested (only a coplanar
fold could make them overlap). Coplanar overlaps are not detected. Candidates come from a sort and
sweep of the triangles' boxes along the axis of largest spread.
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import InputError

__all__ = ["intersecting_pairs", "segment_crosses_triangle"]

_CHUNK = 2_000_000


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Six times the signed volume of tetrahedron (a, b, c, d)."""
    u, v, w = b - a, c - a, d - a
    return (
        u[..., 0] * (v[..., 1] * w[..., 2] - v[..., 2] * w[..., 1])
        - u[..., 1] * (v[..., 0] * w[..., 2] - v[..., 2] * w[..., 0])
        + u[..., 2] * (v[..., 0] * w[..., 1] - v[..., 1] * w[..., 0])
    )


def segment_crosses_triangle(q0, q1, a, b, c) -> np.ndarray:
    """Whether segments cross triangles (touching included, coplanar segments excluded).

    Volumes below ``1e-12 * L**3`` (L: the pair's largest coordinate extent) count as zero, so a
    segment lying in the triangle's plane (up to rounding) is not a crossing.

    Args:
        q0, q1: (k, 3) segment ends [m].
        a, b, c: (k, 3) triangle corners [m].

    Returns:
        (k,) bool.
    """
    pts = np.stack([q0, q1, a, b, c], axis=1)
    ext = (pts.max(axis=1) - pts.min(axis=1)).max(axis=1)
    tol = 1e-12 * ext**3
    s0, s1 = _orient(a, b, c, q0), _orient(a, b, c, q1)
    z0, z1 = np.abs(s0) <= tol, np.abs(s1) <= tol
    straddle = ((s0 <= tol) & (s1 >= -tol) | (s0 >= -tol) & (s1 <= tol)) & ~(z0 & z1)
    v1, v2, v3 = _orient(q0, q1, a, b), _orient(q0, q1, b, c), _orient(q0, q1, c, a)
    inside = ((v1 >= -tol) & (v2 >= -tol) & (v3 >= -tol)) | ((v1 <= tol) & (v2 <= tol) & (v3 <= tol))
    return straddle & inside


def _sweep(lo: np.ndarray, hi: np.ndarray, group: np.ndarray | None):
    """Yield chunks of candidate pairs (i, j) whose boxes overlap (different groups if given)."""
    axis = int(np.argmax(hi.max(axis=0) - lo.min(axis=0)))
    order = np.argsort(lo[:, axis], kind="stable")
    slo = lo[order, axis]
    end = np.searchsorted(slo, hi[order, axis], side="right")
    count = np.maximum(end - np.arange(len(order)) - 1, 0)
    start = 0
    while start < len(order):
        stop = start + 1
        total = count[start]
        while stop < len(order) and total + count[stop] <= _CHUNK:
            total += count[stop]
            stop += 1
        rows = np.arange(start, stop)
        i = np.repeat(rows, count[rows])
        offs = np.arange(len(i)) - np.repeat(np.cumsum(count[rows]) - count[rows], count[rows])
        j = i + 1 + offs
        i, j = order[i], order[j]
        ok = ((lo[i] <= hi[j]) & (lo[j] <= hi[i])).all(axis=1)
        if group is not None:
            ok &= group[i] != group[j]
        yield i[ok], j[ok]
        start = stop


def _pair_test(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Intersection of triangles A[k] and B[k] (corner index arrays into P), sharing no vertex."""
    hit = np.zeros(len(A), dtype=bool)
    for S, T in ((A, B), (B, A)):
        for e in range(3):
            q0, q1 = P[S[:, e]], P[S[:, (e + 1) % 3]]
            hit |= segment_crosses_triangle(q0, q1, P[T[:, 0]], P[T[:, 1]], P[T[:, 2]])
    return hit


def _shared_vertex_test(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Triangles sharing exactly one vertex: the edges opposite it against the other triangle."""
    hit = np.zeros(len(A), dtype=bool)
    for S, T in ((A, B), (B, A)):
        shared = (S[:, :, None] == T[:, None, :]).any(axis=2)
        k = np.argmax(shared, axis=1)
        q0 = P[S[np.arange(len(S)), (k + 1) % 3]]
        q1 = P[S[np.arange(len(S)), (k + 2) % 3]]
        hit |= segment_crosses_triangle(q0, q1, P[T[:, 0]], P[T[:, 1]], P[T[:, 2]])
    return hit


def intersecting_pairs(
    x: np.ndarray,
    triangles: np.ndarray,
    *,
    other_points: np.ndarray | None = None,
    other_triangles: np.ndarray | None = None,
) -> np.ndarray:
    """Intersecting triangle pairs of one mesh (self) or between two meshes.

    Args:
        x: (n, 3) vertex positions [m].
        triangles: (m, 3) int vertex indices.
        other_points: (n2, 3) positions [m] of a second mesh (then only pairs between the meshes).
        other_triangles: (m2, 3) int triangles of the second mesh.

    Returns:
        (k, 2) int array of triangle index pairs: ``i < j`` in the mesh (self), or
        (triangle of the mesh, triangle of the other mesh).

    Raises:
        InputError: malformed arrays, or only one of the ``other_*`` given.
    """
    x = np.asarray(x, dtype=float)
    tri = np.asarray(triangles, dtype=np.int64)
    if x.ndim != 2 or x.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3:
        raise InputError(f"intersecting_pairs needs points (n, 3) and triangles (m, 3), got {x.shape}, {tri.shape}")
    if (other_points is None) != (other_triangles is None):
        raise InputError("give both other_points and other_triangles, or neither")
    m = len(tri)
    group = None
    if other_points is not None:
        op = np.asarray(other_points, dtype=float)
        ot = np.asarray(other_triangles, dtype=np.int64)
        tri = np.concatenate([tri, ot + len(x)])
        x = np.concatenate([x, op])
        group = np.arange(len(tri)) >= m
    if len(tri) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    corners = x[tri]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    found = []
    for i, j in _sweep(lo, hi, group):
        A, B = tri[i], tri[j]
        nshared = (A[:, :, None] == B[:, None, :]).sum(axis=(1, 2))
        hit = np.zeros(len(i), dtype=bool)
        s0, s1 = nshared == 0, nshared == 1
        hit[s0] = _pair_test(x, A[s0], B[s0])
        hit[s1] = _shared_vertex_test(x, A[s1], B[s1])
        found.append(np.stack([i[hit], j[hit]], axis=1))
    pairs = np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
    if group is not None:
        pairs = np.sort(pairs, axis=1)
        pairs[:, 1] -= m
    else:
        pairs = np.sort(pairs, axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if len(pairs) else pairs.reshape(0, 2)
