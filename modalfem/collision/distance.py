"""Point-triangle and edge-edge distances, vectorised over batches.

Two kinds of function:

- closest points (``point_segment``, ``point_triangle``, ``edge_edge``): the distance [m] and the
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
    "point_segment",
    "point_triangle",
    "point_triangle_lower_bound",
]

#: parameters within this slack of [0, 1] count as "maybe inside" for the lower bounds [-]
_SLACK = 1e-6
#: sine of the angle below which two edges count as parallel [-]
_PARALLEL = 1e-3


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of (..., 3) arrays (``np.cross`` without its axis handling overhead)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(_dot(a, a))


def point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points to segments.

    Args:
        p: (k, 3) points [m].
        a, b: (k, 3) segment ends [m] (zero-length segments allowed).

    Returns:
        ``(d, t)``: (k,) distances [m] and (k,) parameters in [0, 1] of the closest point ``a + t (b - a)``.
    """
    ap = p - a
    d = b - a
    dd = _dot(d, d)
    pos = dd > 0
    # np.minimum/np.maximum: np.clip's argument checks cost more than the arithmetic on small batches
    t = np.where(pos, np.minimum(np.maximum(_dot(ap, d) / np.where(pos, dd, 1.0), 0.0), 1.0), 0.0)
    return _norm(ap - t[..., None] * d), t


def point_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points to triangles and the barycentric coordinates of the closest point.

    Args:
        p: (k, 3) points [m].
        a, b, c: (k, 3) triangle corners [m] (degenerate triangles allowed).

    Returns:
        ``(d, w)``: (k,) distances [m] and (k, 3) barycentric weights of the closest point
        ``w0 a + w1 b + w2 c``.
    """
    p, a, b, c = np.broadcast_arrays(p, a, b, c)
    e1, e2, ap = b - a, c - a, p - a
    d00, d01, d11 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    d20, d21 = _dot(ap, e1), _dot(ap, e2)
    den = d00 * d11 - d01 * d01
    good = den > 1e-14 * d00 * d11
    sden = np.where(good, den, 1.0)
    v = (d11 * d20 - d01 * d21) / sden
    w = (d00 * d21 - d01 * d20) / sden
    u = 1.0 - v - w
    inside = good & (u >= 0) & (v >= 0) & (w >= 0)
    q = a + v[..., None] * e1 + w[..., None] * e2
    best = np.where(inside, _norm(p - q), np.inf)
    bary = np.stack([u, v, w], axis=-1)
    for i, (x, y) in enumerate(((a, b), (b, c), (c, a))):
        d, t = point_segment(p, x, y)
        better = d < best
        best = np.where(better, d, best)
        wz = np.zeros(bary.shape)
        wz[..., i] = 1.0 - t
        wz[..., (i + 1) % 3] = t
        bary = np.where(better[..., None], wz, bary)
    return best, bary


def edge_edge(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance between segments ``a0 a1`` and ``b0 b1`` and the parameters of a closest pair.

    Args:
        a0, a1, b0, b1: (k, 3) segment ends [m] (parallel and zero-length segments allowed).

    Returns:
        ``(d, s, t)``: (k,) distances [m]; closest points ``a0 + s (a1 - a0)`` and ``b0 + t (b1 - b0)``.
    """
    a0, a1, b0, b1 = np.broadcast_arrays(a0, a1, b0, b1)
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    A, B, E = _dot(d1, d1), _dot(d1, d2), _dot(d2, d2)
    C, F = _dot(d1, r), _dot(d2, r)
    den = A * E - B * B
    good = den > 1e-14 * A * E
    sden = np.where(good, den, 1.0)
    s = (B * F - C * E) / sden
    t = (A * F - B * C) / sden
    inside = good & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    best = np.where(inside, _norm(r + s[..., None] * d1 - t[..., None] * d2), np.inf)
    s = np.where(inside, s, 0.0)
    t = np.where(inside, t, 0.0)
    for which, (pt, x, y) in enumerate(((a0, b0, b1), (a1, b0, b1), (b0, a0, a1), (b1, a0, a1))):
        d, u = point_segment(pt, x, y)
        better = d < best
        best = np.where(better, d, best)
        if which < 2:
            s = np.where(better, float(which), s)
            t = np.where(better, u, t)
        else:
            s = np.where(better, u, s)
            t = np.where(better, float(which - 2), t)
    return best, s, t


def point_triangle_lower_bound(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """A lower bound [m] of the point-triangle distance, safe under rounding and for slivers.

    Where the projection may fall inside (barycentrics within a slack of [0, 1]) the distance to the
    plane is used (never above the true distance); for slivers the edge distances minus the
    triangle's height; elsewhere the distance to the edges (exact).

    Args:
        p, a, b, c: (k, 3) point and triangle corners [m].

    Returns:
        (k,) lower bounds [m] (>= 0).
    """
    p, a, b, c = np.broadcast_arrays(p, a, b, c)
    return point_triangle_lower_bound_rows(p.T, a.T, b.T, c.T)


def edge_edge_lower_bound(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """A lower bound [m] of the segment-segment distance, safe under rounding and for parallel edges.

    Where the closest pair may be interior the distance between the lines is used; for nearly parallel
    edges (angle sine below 1e-3) the endpoint distances minus ``max length * sin(angle)``, a proven
    bound; elsewhere the endpoint-to-segment distances (exact).

    Args:
        a0, a1, b0, b1: (k, 3) segment ends [m].

    Returns:
        (k,) lower bounds [m] (>= 0).
    """
    a0, a1, b0, b1 = np.broadcast_arrays(a0, a1, b0, b1)
    return edge_edge_lower_bound_rows(a0.T, a1.T, b0.T, b1.T)


# ------------------------------------------------------------------------------------------------
# The lower bounds on coordinate rows: each point is a sequence of three (k,) arrays (x, y, z), the
# arithmetic written per coordinate, so that the CCD's many small batches pay a dozen fewer array calls
# per bound (no einsum, stack or clip per product). The (k, 3) functions above call these.


def _rcross(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _rdot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _rsub(a, b):
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def _rpoint_segment(p, a, b):
    ap, d = _rsub(p, a), _rsub(b, a)
    dd = _rdot(d, d)
    pos = dd > 0
    t = np.where(pos, np.minimum(np.maximum(_rdot(ap, d) / np.where(pos, dd, 1.0), 0.0), 1.0), 0.0)
    e = (ap[0] - t * d[0], ap[1] - t * d[1], ap[2] - t * d[2])
    return np.sqrt(_rdot(e, e))


def point_triangle_lower_bound_rows(p, a, b, c) -> np.ndarray:
    """:func:`point_triangle_lower_bound` for points given as coordinate rows (each a (3, k) array or a
    sequence of three (k,) arrays) [m]; returns (k,) lower bounds [m]."""
    e1, e2, ap = _rsub(b, a), _rsub(c, a), _rsub(p, a)
    n = _rcross(e1, e2)
    nn = np.sqrt(_rdot(n, n))
    cb = _rsub(c, b)
    lmax = np.maximum(np.maximum(np.sqrt(_rdot(e1, e1)), np.sqrt(_rdot(e2, e2))), np.sqrt(_rdot(cb, cb)))
    sliver = nn <= _PARALLEL * lmax * lmax
    edge = np.minimum(np.minimum(_rpoint_segment(p, a, b), _rpoint_segment(p, b, c)), _rpoint_segment(p, c, a))
    snn = np.where(nn > 0, nn, 1.0)
    s2 = snn * snn
    # barycentrics from signed sub-areas along n (exact-ish; only their sign with a slack matters)
    wa = _rdot(_rcross(_rsub(b, p), _rsub(c, p)), n) / s2
    wb = _rdot(_rcross(_rsub(c, p), _rsub(a, p)), n) / s2
    wc = 1.0 - wa - wb
    maybe_in = (wa >= -_SLACK) & (wb >= -_SLACK) & (wc >= -_SLACK)
    plane = np.abs(_rdot(ap, n)) / snn
    height = nn / np.where(lmax > 0, lmax, 1.0)
    lb = np.where(maybe_in, np.minimum(plane, edge), edge)
    lb = np.where(sliver, np.minimum(lb, edge - height), lb)
    return np.maximum(lb, 0.0)


def edge_edge_lower_bound_rows(a0, a1, b0, b1) -> np.ndarray:
    """:func:`edge_edge_lower_bound` for points given as coordinate rows (each a (3, k) array or a
    sequence of three (k,) arrays) [m]; returns (k,) lower bounds [m]."""
    d1, d2, r = _rsub(a1, a0), _rsub(b1, b0), _rsub(b0, a0)
    n = _rcross(d1, d2)
    nn = np.sqrt(_rdot(n, n))
    l1, l2 = np.sqrt(_rdot(d1, d1)), np.sqrt(_rdot(d2, d2))
    ends = np.minimum(
        np.minimum(_rpoint_segment(a0, b0, b1), _rpoint_segment(a1, b0, b1)),
        np.minimum(_rpoint_segment(b0, a0, a1), _rpoint_segment(b1, a0, a1)),
    )
    prod = l1 * l2
    sin = nn / np.where(prod > 0, prod, 1.0) + 1e-12
    parallel = sin <= _PARALLEL
    snn2 = np.where(nn > 0, nn * nn, 1.0)
    s = _rdot(_rcross(r, d2), n) / snn2
    t = _rdot(_rcross(r, d1), n) / snn2
    maybe_in = (s >= -_SLACK) & (s <= 1 + _SLACK) & (t >= -_SLACK) & (t <= 1 + _SLACK)
    line = np.abs(_rdot(r, n)) / np.where(nn > 0, nn, 1.0)
    lb = np.where(maybe_in & ~parallel, np.minimum(line, ends), ends)
    lb = np.where(parallel, ends - np.maximum(l1, l2) * sin, lb)
    return np.maximum(lb, 0.0)
