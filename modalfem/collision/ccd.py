"""Conservative continuous collision detection (CCD), vectorised over batches of queries.

A query is a point and a triangle (vertex-face) or two edges (edge-edge) whose four vertices move on
straight lines from ``x0`` (s = 0) to ``x1`` (s = 1). They *collide* when at some s in [0, 1] the
primitives come within ``eta`` [m] of each other (``eta = 0``: they touch).

Method: the coplanarity cubic ``f(s) = det[e1(s), e2(s), e3(s)]`` (zero exactly when the four points are
coplanar, necessary for contact) is isolated on [0, 1] by subdivision of its Bernstein form, with
interval reasoning at every step:

- an interval is discarded when the Bernstein control values of ``f`` (which bound ``f`` on the
  interval) all exceed ``eta * |normal| + rounding bound`` in magnitude and share a sign (no root);
- or when a distance lower bound at the interval's midpoint exceeds ``delta + L * width / 2``, where
  ``L`` bounds how fast the distance can change (the sum of the largest vertex displacements) so no
  time in the interval can come within ``delta = eta + rounding bound`` (Lipschitz bound);
- an interval whose midpoint is within ``delta`` reports a collision (the inside test with a
  tolerance); intervals still alive at the maximum depth, or queries with too many live intervals,
  report a collision too.

Degenerate cases need no special code: a cubic that degenerates to a quadratic, a line or zero
(coplanar throughout, e.g. a flat sheet sliding in its plane) leaves only the distance test, and
degenerate triangles and parallel edges are covered by the distance lower bounds of
:mod:`modalfem.collision.distance`. Every discard is a proof of separation up to the stated rounding
bounds, so there are no false negatives; false positives are near misses closer than ``delta`` plus
the subdivision resolution.
"""

from __future__ import annotations

import numpy as np

from modalfem.collision.distance import (
    cross,
    edge_edge_lower_bound,
    point_triangle_lower_bound,
)
from modalfem.errors import InputError

__all__ = ["MAX_DEPTH", "MAX_INTERVALS", "edge_edge_ccd", "vertex_face_ccd"]

#: maximum bisection depth of [0, 1] (interval width 2**-MAX_DEPTH)
MAX_DEPTH = 40
#: live intervals per query above which the query reports a (conservative) collision
MAX_INTERVALS = 32
#: relative rounding bound (times the coordinate scale) added to the tolerance [-]
ROUNDING = 1e-12


def _check(x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x0 = np.asarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    if x0.ndim != 3 or x0.shape[1:] != (4, 3) or x1.shape != x0.shape:
        raise InputError(f"CCD queries must be (k, 4, 3) start and end positions, got {x0.shape}, {x1.shape}")
    return x0, x1


def vertex_face_ccd(
    x0: np.ndarray, x1: np.ndarray, *, eta: float = 0.0, max_depth: int = MAX_DEPTH
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex-face CCD of ``k`` queries.

    Args:
        x0: (k, 4, 3) positions [m] of ``p, a, b, c`` (point, triangle corners) at s = 0.
        x1: (k, 4, 3) positions [m] at s = 1.
        eta: minimum separation [m]: coming closer than this counts as a collision.
        max_depth: bisection depth after which a live interval reports a collision (conservative;
            fewer levels are faster and give more false positives).

    Returns:
        ``(hit, toi)``: (k,) bool, and (k,) a time in [0, 1] at which the primitives are within the
        tolerance (or the start of the first unresolved interval); inf if no hit.
    """
    x0, x1 = _check(x0, x1)
    return _ccd(x0, x1, float(eta), _vf_lb, _vf_det, int(max_depth))


def edge_edge_ccd(
    x0: np.ndarray, x1: np.ndarray, *, eta: float = 0.0, max_depth: int = MAX_DEPTH
) -> tuple[np.ndarray, np.ndarray]:
    """Edge-edge CCD of ``k`` queries.

    Args:
        x0: (k, 4, 3) positions [m] of ``a0, a1, b0, b1`` (edge a, edge b) at s = 0.
        x1: (k, 4, 3) positions [m] at s = 1.
        eta: minimum separation [m]: coming closer than this counts as a collision.
        max_depth: bisection depth after which a live interval reports a collision (conservative;
            fewer levels are faster and give more false positives).

    Returns:
        ``(hit, toi)``: (k,) bool, and (k,) a time in [0, 1] at which the primitives are within the
        tolerance (or the start of the first unresolved interval); inf if no hit.
    """
    x0, x1 = _check(x0, x1)
    return _ccd(x0, x1, float(eta), _ee_lb, _ee_det, int(max_depth))


def _vf_lb(x: np.ndarray) -> np.ndarray:
    return point_triangle_lower_bound(x[:, 0], x[:, 1], x[:, 2], x[:, 3])


def _ee_lb(x: np.ndarray) -> np.ndarray:
    return edge_edge_lower_bound(x[:, 0], x[:, 1], x[:, 2], x[:, 3])


def _vf_det(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    # polar form of det[b - a, c - a, p - a]: each column is taken at its own time (u, v, w), so the
    # determinant is affine in each of them; f(s) = _vf_det(x(s), x(s), x(s))
    return np.einsum(
        "ki,ki->k", cross(u[:, 2] - u[:, 1], v[:, 3] - v[:, 1]), w[:, 0] - w[:, 1]
    )


def _ee_det(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> np.ndarray:
    # polar form of det[a1 - a0, b1 - b0, b0 - a0]
    return np.einsum(
        "ki,ki->k", cross(u[:, 1] - u[:, 0], v[:, 3] - v[:, 2]), w[:, 2] - w[:, 0]
    )


def _bernstein(det, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(k, 4) Bernstein coefficients of f on [sa, sb] from positions at sa (xa) and sb (xb)."""
    b0 = det(xa, xa, xa)
    b3 = det(xb, xb, xb)
    b1 = (det(xb, xa, xa) + det(xa, xb, xa) + det(xa, xa, xb)) / 3.0
    b2 = (det(xb, xb, xa) + det(xb, xa, xb) + det(xa, xb, xb)) / 3.0
    return np.stack([b0, b1, b2, b3], axis=1)


def _ccd(x0: np.ndarray, x1: np.ndarray, eta: float, lower_bound, det, max_depth: int) -> tuple[np.ndarray, np.ndarray]:
    k = len(x0)
    hit = np.zeros(k, dtype=bool)
    toi = np.full(k, np.inf)
    if k == 0:
        return hit, toi
    origin = x0[:, :1].copy()
    x0 = x0 - origin
    x1 = x1 - origin
    d = x1 - x0
    scale = np.maximum(np.abs(x0).max(axis=(1, 2)), np.abs(x1).max(axis=(1, 2))) + 1e-300
    disp = np.linalg.norm(d, axis=2)
    lip = (disp[:, 0] + disp[:, 1:].max(axis=1) if lower_bound is _vf_lb else disp[:, :2].max(axis=1) + disp[:, 2:].max(axis=1))
    lip = lip * (1.0 + 1e-9) + ROUNDING * scale
    delta = eta + ROUNDING * scale
    # |f| <= dist * |e1 x e2| <= dist * (2 * scale)**2 where the primitives are within dist
    eps = delta * 4.0 * scale**2 + ROUNDING * 27.0 * scale**3
    q = np.arange(k)
    lo = np.zeros(k)
    hi = np.ones(k)
    for depth in range(max_depth + 1):
        if len(q) == 0:
            break
        mid = 0.5 * (lo + hi)
        xm = x0[q] + mid[:, None, None] * d[q]
        lb = lower_bound(xm)
        touch = lb <= delta[q]
        if touch.any():
            _record(hit, toi, q[touch], mid[touch])
        keep = ~touch & ~hit[q] & (lb <= delta[q] + lip[q] * (hi - lo) * 0.5)
        q, lo, hi = q[keep], lo[keep], hi[keep]
        if len(q) == 0:
            break
        xa = x0[q] + lo[:, None, None] * d[q]
        xb = x0[q] + hi[:, None, None] * d[q]
        b = _bernstein(det, xa, xb)
        e = eps[q][:, None]
        keep = ~((b > e).all(axis=1) | (b < -e).all(axis=1))
        q, lo, hi = q[keep], lo[keep], hi[keep]
        if len(q) == 0:
            break
        if depth == max_depth:
            _record(hit, toi, q, lo)
            break
        crowded = np.bincount(q, minlength=k) > MAX_INTERVALS
        if crowded.any():
            c = crowded[q]
            _record(hit, toi, q[c], lo[c])
            q, lo, hi = q[~c], lo[~c], hi[~c]
        mid = 0.5 * (lo + hi)
        q = np.concatenate([q, q])
        lo, hi = np.concatenate([lo, mid]), np.concatenate([mid, hi])
    return hit, toi


def _record(hit: np.ndarray, toi: np.ndarray, q: np.ndarray, s: np.ndarray) -> None:
    hit[q] = True
    np.minimum.at(toi, q, s)
