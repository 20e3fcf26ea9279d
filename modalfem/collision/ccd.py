"""Conservative continuous collision detection (CCD) over batches of queries (compiled, one query at a
time: :mod:`modalfem.collision._ccd_kernels`).

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

from modalfem.errors import InputError

__all__ = ["MAX_DEPTH", "MAX_INTERVALS", "ccd_pairs", "edge_edge_ccd", "vertex_face_ccd"]

#: maximum bisection depth of [0, 1] (interval width 2**-MAX_DEPTH)
MAX_DEPTH = 40
#: live intervals per query above which the query reports a (conservative) collision
MAX_INTERVALS = 32


def _check(x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x0 = np.ascontiguousarray(x0, dtype=float)
    x1 = np.ascontiguousarray(x1, dtype=float)
    if x0.ndim != 3 or x0.shape[1:] != (4, 3) or x1.shape != x0.shape:
        raise InputError(f"CCD queries must be (k, 4, 3) start and end positions, got {x0.shape}, {x1.shape}")
    return x0, x1


def _answer(toi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.isfinite(toi), toi


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
    from modalfem.collision import _ccd_kernels

    x0, x1 = _check(x0, x1)
    return _answer(_ccd_kernels.ccd_batch(True, x0, x1, float(eta), int(max_depth), MAX_INTERVALS))


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
    from modalfem.collision import _ccd_kernels

    x0, x1 = _check(x0, x1)
    return _answer(_ccd_kernels.ccd_batch(False, x0, x1, float(eta), int(max_depth), MAX_INTERVALS))


def ccd_pairs(kind: str, X0: np.ndarray, X1: np.ndarray, quads: np.ndarray, *, eta: float = 0.0,
              max_depth: int = MAX_DEPTH) -> tuple[np.ndarray, np.ndarray]:
    """:func:`vertex_face_ccd` (``kind`` ``"vf"``) or :func:`edge_edge_ccd` (``"ee"``) of the vertex
    quadruples ``quads`` (k, 4) of the trajectories ``X0 -> X1`` ((N, 3) [m] each), without gathering
    the (k, 4, 3) arrays (the pipeline's entry, which also skips pairs by mass, zone and trajectory box).
    Returns ``(hit, toi)`` as those functions."""
    from modalfem.collision import _ccd_kernels

    if kind not in ("vf", "ee"):
        raise InputError(f"CCD kind must be 'vf' or 'ee', got {kind!r}")
    X0, X1 = np.ascontiguousarray(X0, dtype=float), np.ascontiguousarray(X1, dtype=float)
    quads = np.ascontiguousarray(quads, dtype=np.int64)
    if X0.ndim != 2 or X0.shape[1] != 3 or X1.shape != X0.shape or quads.ndim != 2 or quads.shape[1] != 4:
        raise InputError(f"CCD pairs need (N, 3) positions and (k, 4) quadruples, got {X0.shape}, {X1.shape}, "
                         f"{quads.shape}")
    if len(quads) and (quads.min() < 0 or quads.max() >= len(X0)):
        raise InputError("CCD quadruples index vertices outside the positions")
    idx, t = _ccd_kernels.ccd_candidates(kind == "vf", X0, X1, quads, np.ones(len(X0), dtype=bool),
                                         np.zeros(0, dtype=np.int64), float(eta), int(max_depth), MAX_INTERVALS)
    toi = np.full(len(quads), np.inf)
    toi[idx] = t
    return _answer(toi)
