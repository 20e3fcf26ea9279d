"""Compiled conservative CCD (numba ``njit``, cached on disk): one query at a time, breadth-first
subdivision of [0, 1] with at most ``max_intervals`` live intervals. :mod:`modalfem.collision.ccd`
documents the method and its bounds; this module is its only implementation.

numba's disk cache does not notice edits of the other modules a kernel calls: after changing
:mod:`modalfem.collision._distance_kernels`, delete ``modalfem/collision/__pycache__``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.collision._distance_kernels import edge_edge_lb, point_triangle_lb

__all__ = ["ccd_batch", "ccd_candidates"]

#: relative rounding bound (times the coordinate scale) added to the tolerance [-]
ROUNDING = 1e-12


@numba.njit(cache=True)
def _bernstein(vf: bool, t0: np.ndarray, td: np.ndarray, coef: np.ndarray) -> None:
    """Bernstein coefficients ``coef`` (4,) on [0, 1] of ``f(s) = det[e1(s), e2(s), e3(s)]`` (vertex-face
    det[b - a, c - a, p - a], edge-edge det[a1 - a0, b1 - b0, b0 - a0]) from the positions ``t0`` and
    displacements ``td`` (4, 3) [m], by expanding ``(A0 + s dA) x (B0 + s dB) . (C0 + s dC)``."""
    if vf:
        i, j, k, m, u, w = 2, 1, 3, 1, 0, 1
    else:
        i, j, k, m, u, w = 1, 0, 3, 2, 2, 0
    a0, a1, a2 = t0[i, 0] - t0[j, 0], t0[i, 1] - t0[j, 1], t0[i, 2] - t0[j, 2]
    b0, b1, b2 = t0[k, 0] - t0[m, 0], t0[k, 1] - t0[m, 1], t0[k, 2] - t0[m, 2]
    g0, g1, g2 = t0[u, 0] - t0[w, 0], t0[u, 1] - t0[w, 1], t0[u, 2] - t0[w, 2]
    p0, p1, p2 = td[i, 0] - td[j, 0], td[i, 1] - td[j, 1], td[i, 2] - td[j, 2]
    q0, q1, q2 = td[k, 0] - td[m, 0], td[k, 1] - td[m, 1], td[k, 2] - td[m, 2]
    h0, h1, h2 = td[u, 0] - td[w, 0], td[u, 1] - td[w, 1], td[u, 2] - td[w, 2]
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
    coef[0] = f0
    coef[1] = f0 + f1 / 3.0
    coef[2] = f0 + (2.0 * f1 + f2) / 3.0
    coef[3] = f0 + f1 + f2 + f3


@numba.njit(cache=True)
def _query(vf: bool, x0: np.ndarray, x1: np.ndarray, eta: float, max_depth: int, max_intervals: int,
           t0: np.ndarray, td: np.ndarray, x: np.ndarray, coef: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           nlo: np.ndarray, nhi: np.ndarray) -> float:
    """Time of impact in [0, 1] of one query (start ``x0``, end ``x1`` (4, 3) [m]), inf if none; the
    remaining arrays are scratch space (``lo``..``nhi`` of length >= 2 ``max_intervals``)."""
    scale = 0.0
    for v in range(4):
        for c in range(3):
            td[v, c] = x1[v, c] - x0[v, c]
    for v in range(4):
        for c in range(3):
            t0[v, c] = x0[v, c] - x0[0, c]
    for v in range(4):
        for c in range(3):
            scale = max(scale, abs(t0[v, c]), abs(t0[v, c] + td[v, c]))
    scale += 1e-300
    d0 = math.sqrt(td[0, 0] ** 2 + td[0, 1] ** 2 + td[0, 2] ** 2)
    d1 = math.sqrt(td[1, 0] ** 2 + td[1, 1] ** 2 + td[1, 2] ** 2)
    d2 = math.sqrt(td[2, 0] ** 2 + td[2, 1] ** 2 + td[2, 2] ** 2)
    d3 = math.sqrt(td[3, 0] ** 2 + td[3, 1] ** 2 + td[3, 2] ** 2)
    lip = d0 + max(d1, d2, d3) if vf else max(d0, d1) + max(d2, d3)
    lip = lip * (1.0 + 1e-9) + ROUNDING * scale
    delta = eta + ROUNDING * scale
    # |f| = |e1 x e2| * (distance of the point to the plane, or between the lines) <= |e1| |e2| dist; |e(s)|
    # is convex along the straight-line motion, so its largest value on [0, 1] is at an end
    i, j, u, w = (2, 1, 3, 1) if vf else (1, 0, 3, 2)
    s10 = s11 = s20 = s21 = 0.0
    for c in range(3):
        e1 = t0[i, c] - t0[j, c]
        e2 = t0[u, c] - t0[w, c]
        d1 = e1 + td[i, c] - td[j, c]
        d2 = e2 + td[u, c] - td[w, c]
        s10 += e1 * e1
        s11 += d1 * d1
        s20 += e2 * e2
        s21 += d2 * d2
    len1, len2 = math.sqrt(max(s10, s11)), math.sqrt(max(s20, s21))
    eps = delta * (len1 * len2 * (1.0 + 1e-9)) + ROUNDING * 27.0 * scale ** 3
    _bernstein(vf, t0, td, coef)
    lo[0], hi[0] = 0.0, 1.0
    count = 1
    toi = math.inf
    for depth in range(max_depth + 1):
        kept = 0
        hit = False
        for k in range(count):
            a, b = lo[k], hi[k]
            if depth == 0:
                b0, b1, b2, b3 = coef[0], coef[1], coef[2], coef[3]
            else:
                # de Casteljau blossoms f(a, a, a), f(a, a, b), f(a, b, b), f(b, b, b)
                ma, mb = 1.0 - a, 1.0 - b
                l0, l1, l2 = ma * coef[0] + a * coef[1], ma * coef[1] + a * coef[2], ma * coef[2] + a * coef[3]
                ll0, ll1 = ma * l0 + a * l1, ma * l1 + a * l2
                r0, r1, r2 = mb * coef[0] + b * coef[1], mb * coef[1] + b * coef[2], mb * coef[2] + b * coef[3]
                rr0, rr1 = mb * r0 + b * r1, mb * r1 + b * r2
                b0, b1, b2, b3 = ma * ll0 + a * ll1, mb * ll0 + b * ll1, ma * rr0 + a * rr1, mb * rr0 + b * rr1
            # the cheap test first: control values of one sign beyond eps (no coplanarity, no contact)
            if min(min(b0, b1), min(b2, b3)) > eps or max(max(b0, b1), max(b2, b3)) < -eps:
                continue
            mid = 0.5 * (a + b)
            for v in range(4):
                for c in range(3):
                    x[v, c] = t0[v, c] + mid * td[v, c]
            lb = point_triangle_lb(x) if vf else edge_edge_lb(x)
            if lb <= delta:
                hit = True
                toi = min(toi, mid)
            elif not hit and lb <= delta + lip * (b - a) * 0.5:
                nlo[kept], nhi[kept] = a, b
                kept += 1
        if hit:
            return toi
        if kept == 0:
            return math.inf
        if depth == max_depth or kept > max_intervals:
            for k in range(kept):
                toi = min(toi, nlo[k])
            return toi
        for k in range(kept):
            a, b = nlo[k], nhi[k]
            m = 0.5 * (a + b)
            lo[2 * k], hi[2 * k] = a, m
            lo[2 * k + 1], hi[2 * k + 1] = m, b
        count = 2 * kept
    return toi


@numba.njit(cache=True)
def ccd_batch(vf: bool, x0: np.ndarray, x1: np.ndarray, eta: float, max_depth: int,
              max_intervals: int) -> np.ndarray:
    """Times of impact (k,) in [0, 1] (inf: no collision) of queries given by their start and end
    positions ``x0``/``x1`` (k, 4, 3) [m]: ``vf`` point-triangle (p, a, b, c), else edge-edge."""
    k = len(x0)
    toi = np.empty(k)
    t0, td, x = np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3))
    coef = np.empty(4)
    n = 2 * max_intervals + 2
    lo, hi, nlo, nhi = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for q in range(k):
        toi[q] = _query(vf, x0[q], x1[q], eta, max_depth, max_intervals, t0, td, x, coef, lo, hi, nlo, nhi)
    return toi


@numba.njit(cache=True)
def ccd_candidates(vf: bool, X0: np.ndarray, X1: np.ndarray, quads: np.ndarray, movable: np.ndarray,
                   roots: np.ndarray, eta: float, max_depth: int, max_intervals: int):
    """The pipeline's CCD of candidate pairs ``quads`` (k, 4) on trajectories ``X0 -> X1`` ((N, 3) [m]):
    pairs without a ``movable`` ((N,) bool) vertex, pairs inside one zone (all four ``roots`` ((N,) int,
    empty: no zones) equal) and pairs whose primitives' trajectory boxes are farther apart than ``eta``
    [m] are skipped; the others get :func:`ccd_batch`'s test.

    Returns:
        ``(idx, toi)``: (h,) indices into ``quads`` of the colliding pairs and their (h,) times in [0, 1].
    """
    k = len(quads)
    zones = len(roots) > 0
    idx = np.empty(k, dtype=np.int64)
    tois = np.empty(k)
    n = 0
    a0, a1 = np.empty((4, 3)), np.empty((4, 3))
    t0, td, x = np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 3))
    coef = np.empty(4)
    m = 2 * max_intervals + 2
    lo, hi, nlo, nhi = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    first = 1 if vf else 2  # the first primitive: vertex 0 (vf) or vertices 0, 1 (ee)
    for q in range(k):
        c0, c1, c2, c3 = quads[q, 0], quads[q, 1], quads[q, 2], quads[q, 3]
        if not (movable[c0] or movable[c1] or movable[c2] or movable[c3]):
            continue
        if zones and roots[c1] == roots[c0] and roots[c2] == roots[c0] and roots[c3] == roots[c0]:
            continue
        for v in range(4):
            for c in range(3):
                a0[v, c] = X0[quads[q, v], c]
                a1[v, c] = X1[quads[q, v], c]
        near = True
        for c in range(3):
            alo, ahi = math.inf, -math.inf
            blo, bhi = math.inf, -math.inf
            for v in range(4):
                vlo, vhi = min(a0[v, c], a1[v, c]), max(a0[v, c], a1[v, c])
                if v < first:
                    alo, ahi = min(alo, vlo), max(ahi, vhi)
                else:
                    blo, bhi = min(blo, vlo), max(bhi, vhi)
            near = near and alo <= bhi + eta and blo <= ahi + eta
        if not near:
            continue
        toi = _query(vf, a0, a1, eta, max_depth, max_intervals, t0, td, x, coef, lo, hi, nlo, nhi)
        if toi <= 1.0:
            idx[n], tois[n] = q, toi
            n += 1
    return idx[:n].copy(), tois[:n].copy()
