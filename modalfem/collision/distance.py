"""Point-triangle and edge-edge distances over batches (compiled kernels in
:mod:`modalfem.collision._distance_kernels`, one query at a time).

Two kinds of function:

- closest points (``point_triangle``, ``edge_edge``): the distance [m] and the
  parameters of a closest pair, robust for degenerate triangles and parallel edges;
- lower bounds (``point_triangle_lower_bound``, ``edge_edge_lower_bound``), used by the conservative
  CCD: never above the true distance by more than rounding (a few ulps of the coordinates), also for
  slivers and nearly parallel edges, where the closest pair itself is ill-conditioned.

Arrays are (k, 3) [m] (any leading shape broadcasts); distances are (k,) [m].
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "cross",
    "edge_edge",
    "edge_edge_lower_bound",
    "point_triangle",
    "point_triangle_lower_bound",
]


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of (..., 3) arrays (``np.cross`` without its axis handling overhead)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _quads(*points: np.ndarray) -> tuple[np.ndarray, tuple]:
    """(k, 4, 3) contiguous quadruples of the broadcast (..., 3) points, and their leading shape."""
    pts = np.broadcast_arrays(*(np.asarray(p, dtype=float) for p in points))
    return np.ascontiguousarray(np.stack(pts, axis=-2).reshape(-1, 4, 3)), pts[0].shape[:-1]


def point_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points to triangles and the barycentric coordinates of the closest point.

    Args:
        p: (k, 3) points [m].
        a, b, c: (k, 3) triangle corners [m] (degenerate triangles allowed).

    Returns:
        ``(d, w)``: (k,) distances [m] and (k, 3) barycentric weights of the closest point
        ``w0 a + w1 b + w2 c``.
    """
    from modalfem.collision._distance_kernels import point_triangle_batch

    x, shape = _quads(p, a, b, c)
    d, w = point_triangle_batch(x)
    return d.reshape(shape), w.reshape(shape + (3,))


def edge_edge(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance between segments ``a0 a1`` and ``b0 b1`` and the parameters of a closest pair.

    Args:
        a0, a1, b0, b1: (k, 3) segment ends [m] (parallel and zero-length segments allowed).

    Returns:
        ``(d, s, t)``: (k,) distances [m]; closest points ``a0 + s (a1 - a0)`` and ``b0 + t (b1 - b0)``.
    """
    from modalfem.collision._distance_kernels import edge_edge_batch

    x, shape = _quads(a0, a1, b0, b1)
    d, s, t = edge_edge_batch(x)
    return d.reshape(shape), s.reshape(shape), t.reshape(shape)


def point_triangle_lower_bound(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """A lower bound [m] of the point-triangle distance, safe under rounding and for slivers.

    Where the projection may fall inside (barycentrics within a slack of [0, 1]) the distance to the
    plane is used (never above the true distance); for slivers the edge distances minus the
    triangle's height; elsewhere the distance to the edges (exact). Compiled
    (``modalfem.collision._distance_kernels``, shared with the CCD).

    Args:
        p, a, b, c: (k, 3) point and triangle corners [m].

    Returns:
        (k,) lower bounds [m] (>= 0).
    """
    from modalfem.collision._distance_kernels import point_triangle_lb_batch

    x, shape = _quads(p, a, b, c)
    return point_triangle_lb_batch(x).reshape(shape)


def edge_edge_lower_bound(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """A lower bound [m] of the segment-segment distance, safe under rounding and for parallel edges.

    Where the closest pair may be interior the distance between the lines is used; for nearly parallel
    edges (angle sine below 1e-3) the endpoint distances minus ``max length * sin(angle)``, a proven
    bound; elsewhere the endpoint-to-segment distances (exact). Compiled
    (``modalfem.collision._distance_kernels``, shared with the CCD).

    Args:
        a0, a1, b0, b1: (k, 3) segment ends [m].

    Returns:
        (k,) lower bounds [m] (>= 0).
    """
    from modalfem.collision._distance_kernels import edge_edge_lb_batch

    x, shape = _quads(a0, a1, b0, b1)
    return edge_edge_lb_batch(x).reshape(shape)
