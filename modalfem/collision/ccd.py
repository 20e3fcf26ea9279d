"""Conservative continuous collision detection (CCD), vectorised over batches of queries.

A query is a point and a triangle (vertex-face) or two edges (edge-edge) whose four vertices move on
straight lines from ``x0`` (s = 0) to ``x1`` (s = 1). They *collide* when at some s in [0, 1] the
primitives come within ``eta`` [m] of each other (``eta = 0``: they touch).

Method: the coplanarity cubic ``f(s) = det[e1(s), e2(s), e3(s)]`` (zero exactly when the four points are
coplanar, necessary for contact) is isolated on [0, 1] by subdivision of its Bernstein form, with
interval reasoning at every step:

- an interval is discarded when the Bernstein control values of ``f`` (which bound ``f`` on the
  interval) all exceed ``delta * max|e1| * max|e2| + rounding bound`` in magnitude and share a sign
  (``|f| = |e1 x e2| * distance to the plane, or between the lines, <= |e1| |e2| * distance``; the
  lengths' largest values over the step are at its ends, the norm being convex along straight lines);
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
    edge_edge_lower_bound_rows,
    point_triangle_lower_bound_rows,
)
from modalfem.errors import InputError

__all__ = ["MAX_DEPTH", "MAX_INTERVALS", "ccd_rows", "edge_edge_ccd", "vertex_face_ccd"]

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
    return _ccd(x0, x1, float(eta), _vf_lb, _VF_COLUMNS, int(max_depth))


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
    return _ccd(x0, x1, float(eta), _ee_lb, _EE_COLUMNS, int(max_depth))


def _vf_lb(x: np.ndarray) -> np.ndarray:
    """Point-triangle distance lower bounds of (4, 3, k) positions (p, a, b, c)."""
    return point_triangle_lower_bound_rows(x[0], x[1], x[2], x[3])


def _ee_lb(x: np.ndarray) -> np.ndarray:
    """Edge-edge distance lower bounds of (4, 3, k) positions (a0, a1, b0, b1)."""
    return edge_edge_lower_bound_rows(x[0], x[1], x[2], x[3])


#: columns (i, j) = x_i - x_j of det[e1, e2, e3]: vertex-face det[b - a, c - a, p - a], edge-edge
#: det[a1 - a0, b1 - b0, b0 - a0]
_VF_COLUMNS = ((2, 1), (3, 1), (0, 1))
_EE_COLUMNS = ((1, 0), (3, 2), (2, 0))


def _bernstein(columns: tuple, x0: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(4, k) Bernstein coefficients on [0, 1] of ``f(s) = det[e1(s), e2(s), e3(s)]``, ``e(s) = e0 + s de``,
    from the vertex positions ``x0`` and displacements ``d`` in (4, 3, k) layout.

    The cubic's monomial coefficients come from expanding ``(A0 + s dA) x (B0 + s dB) . (C0 + s dC)``
    component by component (each a few products of coordinate differences, rounding within a few ulps
    of ``scale**3``)."""
    (i, j), (k, m), (u, w) = columns
    a0, a1, a2 = x0[i] - x0[j]
    b0, b1, b2 = x0[k] - x0[m]
    g0, g1, g2 = x0[u] - x0[w]
    p0, p1, p2 = d[i] - d[j]
    q0, q1, q2 = d[k] - d[m]
    h0, h1, h2 = d[u] - d[w]
    # cross(A, B) = c0 + s c1 + s^2 c2
    c00, c01, c02 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    c10 = a1 * q2 - a2 * q1 + p1 * b2 - p2 * b1
    c11 = a2 * q0 - a0 * q2 + p2 * b0 - p0 * b2
    c12 = a0 * q1 - a1 * q0 + p0 * b1 - p1 * b0
    c20, c21, c22 = p1 * q2 - p2 * q1, p2 * q0 - p0 * q2, p0 * q1 - p1 * q0
    f0 = c00 * g0 + c01 * g1 + c02 * g2
    f1 = c00 * h0 + c01 * h1 + c02 * h2 + c10 * g0 + c11 * g1 + c12 * g2
    f2 = c10 * h0 + c11 * h1 + c12 * h2 + c20 * g0 + c21 * g1 + c22 * g2
    f3 = c20 * h0 + c21 * h1 + c22 * h2
    return np.stack([f0, f0 + f1 / 3.0, f0 + (2.0 * f1 + f2) / 3.0, f0 + f1 + f2 + f3])


def _subdivide(c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple:
    """Bernstein coefficients on [lo, hi] (four (k,) arrays) of cubics given by their (4, k) coefficients
    on [0, 1]: the blossom values f(lo, lo, lo), f(lo, lo, hi), f(lo, hi, hi), f(hi, hi, hi) (de
    Casteljau steps, convex combinations: rounding stays within a few ulps of max |c|)."""
    ml, mh = 1.0 - lo, 1.0 - hi
    a = ml * c[:3] + lo * c[1:]  # f(lo, ., .)
    aa = ml * a[:2] + lo * a[1:]  # f(lo, lo, .)
    h = mh * c[:3] + hi * c[1:]  # f(hi, ., .)
    hh = mh * h[:2] + hi * h[1:]  # f(hi, hi, .)
    return ml * aa[0] + lo * aa[1], mh * aa[0] + hi * aa[1], ml * hh[0] + lo * hh[1], mh * hh[0] + hi * hh[1]


def ccd_rows(kind: str, t0: np.ndarray, t1: np.ndarray, *, eta: float = 0.0,
             max_depth: int = MAX_DEPTH) -> tuple[np.ndarray, np.ndarray]:
    """:func:`vertex_face_ccd` (``kind`` ``"vf"``) or :func:`edge_edge_ccd` (``"ee"``) of queries given as
    (4, 3, k) start and end positions [m] (vertex, coordinate, query): the layout the arithmetic runs on,
    which callers gathering from many pairs can build without a transposed copy. Both arrays are
    overwritten. Returns ``(hit, toi)`` as those functions."""
    lb, cols = (_vf_lb, _VF_COLUMNS) if kind == "vf" else (_ee_lb, _EE_COLUMNS)
    if t0.ndim != 3 or t0.shape[:2] != (4, 3) or t1.shape != t0.shape:
        raise InputError(f"CCD rows must be (4, 3, k) start and end positions, got {t0.shape}, {t1.shape}")
    return _ccd_rows(t0, t1, float(eta), lb, cols, int(max_depth))


def _ccd(x0: np.ndarray, x1: np.ndarray, eta: float, lower_bound, columns, max_depth: int) -> tuple[np.ndarray, np.ndarray]:
    # (4, 3, k) layout relative to the first vertex: the arithmetic runs on contiguous coordinate rows
    return _ccd_rows(np.ascontiguousarray(x0.transpose(1, 2, 0)), np.ascontiguousarray(x1.transpose(1, 2, 0)), eta,
                     lower_bound, columns, max_depth)


def _ccd_rows(t0: np.ndarray, td: np.ndarray, eta: float, lower_bound, columns, max_depth: int):
    """The CCD of (4, 3, k) start positions ``t0`` and end positions ``td`` (both overwritten: ``td``
    becomes the displacements, ``t0`` the positions relative to the first vertex)."""
    k = t0.shape[2]
    hit = np.zeros(k, dtype=bool)
    toi = np.full(k, np.inf)
    if k == 0:
        return hit, toi
    td -= t0
    t0 -= t0[0].copy()
    scale = np.maximum(np.abs(t0).reshape(12, k).max(axis=0), np.abs(t0 + td).reshape(12, k).max(axis=0)) + 1e-300
    disp = np.sqrt(td[:, 0] ** 2 + td[:, 1] ** 2 + td[:, 2] ** 2)
    lip = (disp[0] + disp[1:].max(axis=0) if lower_bound is _vf_lb else np.maximum(disp[0], disp[1])
           + np.maximum(disp[2], disp[3]))
    lip = lip * (1.0 + 1e-9) + ROUNDING * scale
    delta = eta + ROUNDING * scale
    # |f| = |e1 x e2| * (distance of the point to the plane, or between the lines) <= |e1| |e2| dist where
    # the primitives are within dist; |e(s)| is convex along the straight-line motion, so its largest
    # value on [0, 1] is at an end
    (i, j), (u, w) = columns[0], columns[1]
    e1, e2 = t0[i] - t0[j], t0[u] - t0[w]
    d1, d2 = e1 + td[i] - td[j], e2 + td[u] - td[w]
    len1 = np.sqrt(np.maximum(np.einsum("ik,ik->k", e1, e1), np.einsum("ik,ik->k", d1, d1)))
    len2 = np.sqrt(np.maximum(np.einsum("ik,ik->k", e2, e2), np.einsum("ik,ik->k", d2, d2)))
    eps = delta * (len1 * len2 * (1.0 + 1e-9)) + ROUNDING * 27.0 * scale**3
    coef = _bernstein(columns, t0, td)
    q = np.arange(k)
    lo = np.zeros(k)
    hi = np.ones(k)
    for depth in range(max_depth + 1):
        # the cheap test first: Bernstein control values of f on [lo, hi] of one sign beyond eps (no
        # coplanarity, no contact); an interval whose midpoint is within delta always passes it (there
        # |f| <= eps), so the order of the two tests does not change the answer
        b = coef if depth == 0 else _subdivide(coef[:, q], lo, hi)
        e = eps[q]
        bmin = np.minimum(np.minimum(b[0], b[1]), np.minimum(b[2], b[3]))
        bmax = np.maximum(np.maximum(b[0], b[1]), np.maximum(b[2], b[3]))
        keep = (bmin <= e) & (bmax >= -e)
        q, lo, hi = q[keep], lo[keep], hi[keep]
        if len(q) == 0:
            break
        mid = 0.5 * (lo + hi)
        lb = lower_bound(t0[:, :, q] + mid * td[:, :, q])
        touch = lb <= delta[q]
        if touch.any():
            _record(hit, toi, q[touch], mid[touch])
        keep = ~touch & ~hit[q] & (lb <= delta[q] + lip[q] * (hi - lo) * 0.5)
        q, lo, hi, mid = q[keep], lo[keep], hi[keep], mid[keep]
        if len(q) == 0:
            break
        if depth == max_depth:
            _record(hit, toi, q, lo)
            break
        crowded = np.bincount(q, minlength=k) > MAX_INTERVALS
        if crowded.any():
            c = crowded[q]
            _record(hit, toi, q[c], lo[c])
            q, lo, hi, mid = q[~c], lo[~c], hi[~c], mid[~c]
        q = np.concatenate([q, q])
        lo, hi = np.concatenate([lo, mid]), np.concatenate([mid, hi])
    return hit, toi


def _record(hit: np.ndarray, toi: np.ndarray, q: np.ndarray, s: np.ndarray) -> None:
    hit[q] = True
    np.minimum.at(toi, q, s)
