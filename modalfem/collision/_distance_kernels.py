"""Compiled point-triangle and edge-edge distance lower bounds (numba ``njit``, cached on disk).

Scalar kernels on four points given as a (4, 3) array [m] (``p, a, b, c`` or ``a0, a1, b0, b1``), and
batch loops over (k, 4, 3) arrays. :mod:`modalfem.collision.distance` documents the bounds and exposes
the batch versions; the CCD kernels call the scalar ones.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem._threads import chunk_bounds, chunk_count

__all__ = [
    "ccd_frames",
    "close_frames",
    "contact_frames",
    "edge_edge_batch",
    "edge_edge_closest",
    "edge_edge_lb",
    "edge_edge_lb_batch",
    "obstacle_impulses",
    "obstacle_repulsion",
    "obstacle_vertex_hits",
    "point_triangle_batch",
    "point_triangle_closest",
    "point_triangle_lb",
    "point_triangle_lb_batch",
]

#: parameters within this slack of [0, 1] count as "maybe inside" for the lower bounds [-]
SLACK = 1e-6
#: sine of the angle below which two edges (and relative height below which a triangle) count as
#: degenerate [-]
PARALLEL = 1e-3


@numba.njit(cache=True)
def _segment_param(x: np.ndarray, i: int, j: int, m: int) -> tuple:
    """(distance [m], parameter t in [0, 1]) of the point of segment ``x[j] x[m]`` closest to ``x[i]``."""
    ap0, ap1, ap2 = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
    d0, d1, d2 = x[m, 0] - x[j, 0], x[m, 1] - x[j, 1], x[m, 2] - x[j, 2]
    dd = d0 * d0 + d1 * d1 + d2 * d2
    t = 0.0
    if dd > 0:
        t = min(max((ap0 * d0 + ap1 * d1 + ap2 * d2) / dd, 0.0), 1.0)
    e0, e1, e2 = ap0 - t * d0, ap1 - t * d1, ap2 - t * d2
    return math.sqrt(e0 * e0 + e1 * e1 + e2 * e2), t


@numba.njit(cache=True)
def _point_segment(x: np.ndarray, i: int, j: int, m: int) -> float:
    """Distance [m] from point ``x[i]`` to the segment ``x[j] x[m]`` (zero length allowed)."""
    return _segment_param(x, i, j, m)[0]


@numba.njit(cache=True)
def point_triangle_lb(x: np.ndarray) -> float:
    """Lower bound [m] of the distance from point ``x[0]`` to triangle ``x[1] x[2] x[3]``: the distance to
    the plane where the projection may fall inside (barycentrics within ``SLACK`` of [0, 1]), for slivers
    the edge distances minus the triangle's height, elsewhere the distance to the edges (exact)."""
    e10, e11, e12 = x[2, 0] - x[1, 0], x[2, 1] - x[1, 1], x[2, 2] - x[1, 2]
    e20, e21, e22 = x[3, 0] - x[1, 0], x[3, 1] - x[1, 1], x[3, 2] - x[1, 2]
    n0, n1, n2 = e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    c0, c1, c2 = x[3, 0] - x[2, 0], x[3, 1] - x[2, 1], x[3, 2] - x[2, 2]
    lmax = max(math.sqrt(e10 * e10 + e11 * e11 + e12 * e12), math.sqrt(e20 * e20 + e21 * e21 + e22 * e22),
               math.sqrt(c0 * c0 + c1 * c1 + c2 * c2))
    edge = min(_point_segment(x, 0, 1, 2), _point_segment(x, 0, 2, 3), _point_segment(x, 0, 3, 1))
    snn = nn if nn > 0 else 1.0
    s2 = snn * snn
    # barycentrics from signed sub-areas along n (only their sign with a slack matters)
    pa0, pa1, pa2 = x[1, 0] - x[0, 0], x[1, 1] - x[0, 1], x[1, 2] - x[0, 2]
    pb0, pb1, pb2 = x[2, 0] - x[0, 0], x[2, 1] - x[0, 1], x[2, 2] - x[0, 2]
    pc0, pc1, pc2 = x[3, 0] - x[0, 0], x[3, 1] - x[0, 1], x[3, 2] - x[0, 2]
    wa = ((pb1 * pc2 - pb2 * pc1) * n0 + (pb2 * pc0 - pb0 * pc2) * n1 + (pb0 * pc1 - pb1 * pc0) * n2) / s2
    wb = ((pc1 * pa2 - pc2 * pa1) * n0 + (pc2 * pa0 - pc0 * pa2) * n1 + (pc0 * pa1 - pc1 * pa0) * n2) / s2
    wc = 1.0 - wa - wb
    lb = edge
    if wa >= -SLACK and wb >= -SLACK and wc >= -SLACK:
        plane = abs(pa0 * n0 + pa1 * n1 + pa2 * n2) / snn
        lb = min(plane, edge)
    if nn <= PARALLEL * lmax * lmax:  # sliver
        lb = min(lb, edge - nn / (lmax if lmax > 0 else 1.0))
    return max(lb, 0.0)


@numba.njit(cache=True)
def edge_edge_lb(x: np.ndarray) -> float:
    """Lower bound [m] of the distance between segments ``x[0] x[1]`` and ``x[2] x[3]``: the distance
    between the lines where the closest pair may be interior, for nearly parallel edges (angle sine
    below ``PARALLEL``) the endpoint distances minus ``max length * sin(angle)``, elsewhere the
    endpoint-to-segment distances (exact)."""
    d10, d11, d12 = x[1, 0] - x[0, 0], x[1, 1] - x[0, 1], x[1, 2] - x[0, 2]
    d20, d21, d22 = x[3, 0] - x[2, 0], x[3, 1] - x[2, 1], x[3, 2] - x[2, 2]
    r0, r1, r2 = x[2, 0] - x[0, 0], x[2, 1] - x[0, 1], x[2, 2] - x[0, 2]
    n0, n1, n2 = d11 * d22 - d12 * d21, d12 * d20 - d10 * d22, d10 * d21 - d11 * d20
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    l1 = math.sqrt(d10 * d10 + d11 * d11 + d12 * d12)
    l2 = math.sqrt(d20 * d20 + d21 * d21 + d22 * d22)
    ends = min(min(_point_segment(x, 0, 2, 3), _point_segment(x, 1, 2, 3)),
               min(_point_segment(x, 2, 0, 1), _point_segment(x, 3, 0, 1)))
    prod = l1 * l2
    sin = nn / (prod if prod > 0 else 1.0) + 1e-12
    if sin <= PARALLEL:
        return max(ends - max(l1, l2) * sin, 0.0)
    snn2 = nn * nn if nn > 0 else 1.0
    s = ((r1 * d22 - r2 * d21) * n0 + (r2 * d20 - r0 * d22) * n1 + (r0 * d21 - r1 * d20) * n2) / snn2
    t = ((r1 * d12 - r2 * d11) * n0 + (r2 * d10 - r0 * d12) * n1 + (r0 * d11 - r1 * d10) * n2) / snn2
    lb = ends
    if -SLACK <= s <= 1 + SLACK and -SLACK <= t <= 1 + SLACK:
        line = abs(r0 * n0 + r1 * n1 + r2 * n2) / (nn if nn > 0 else 1.0)
        lb = min(line, ends)
    return max(lb, 0.0)


@numba.njit(cache=True)
def point_triangle_lb_batch(x: np.ndarray) -> np.ndarray:
    """:func:`point_triangle_lb` of (k, 4, 3) point-triangle quadruples [m]; (k,) bounds [m]."""
    out = np.empty(len(x))
    for i in range(len(x)):
        out[i] = point_triangle_lb(x[i])
    return out


@numba.njit(cache=True)
def edge_edge_lb_batch(x: np.ndarray) -> np.ndarray:
    """:func:`edge_edge_lb` of (k, 4, 3) edge-edge quadruples [m]; (k,) bounds [m]."""
    out = np.empty(len(x))
    for i in range(len(x)):
        out[i] = edge_edge_lb(x[i])
    return out


@numba.njit(cache=True)
def point_triangle_closest(x: np.ndarray, bary: np.ndarray) -> float:
    """Distance [m] from point ``x[0]`` to triangle ``x[1] x[2] x[3]`` (degenerate allowed); writes the
    barycentric weights (3,) of the closest point into ``bary``."""
    e10, e11, e12 = x[2, 0] - x[1, 0], x[2, 1] - x[1, 1], x[2, 2] - x[1, 2]
    e20, e21, e22 = x[3, 0] - x[1, 0], x[3, 1] - x[1, 1], x[3, 2] - x[1, 2]
    ap0, ap1, ap2 = x[0, 0] - x[1, 0], x[0, 1] - x[1, 1], x[0, 2] - x[1, 2]
    d00 = e10 * e10 + e11 * e11 + e12 * e12
    d01 = e10 * e20 + e11 * e21 + e12 * e22
    d11 = e20 * e20 + e21 * e21 + e22 * e22
    d20 = ap0 * e10 + ap1 * e11 + ap2 * e12
    d21 = ap0 * e20 + ap1 * e21 + ap2 * e22
    den = d00 * d11 - d01 * d01
    good = den > 1e-14 * d00 * d11
    sden = den if good else 1.0
    v = (d11 * d20 - d01 * d21) / sden
    w = (d00 * d21 - d01 * d20) / sden
    u = 1.0 - v - w
    best = math.inf
    bary[0], bary[1], bary[2] = u, v, w
    if good and u >= 0 and v >= 0 and w >= 0:
        q0, q1, q2 = ap0 - v * e10 - w * e20, ap1 - v * e11 - w * e21, ap2 - v * e12 - w * e22
        best = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    for i in range(3):
        d, t = _segment_param(x, 0, 1 + i, 1 + (i + 1) % 3)
        if d < best:
            best = d
            bary[0] = bary[1] = bary[2] = 0.0
            bary[i] = 1.0 - t
            bary[(i + 1) % 3] = t
    return best


@numba.njit(cache=True)
def edge_edge_closest(x: np.ndarray) -> tuple:
    """(distance [m], s, t) between segments ``x[0] x[1]`` and ``x[2] x[3]`` (parallel and zero-length
    allowed) with closest points ``x[0] + s (x[1] - x[0])`` and ``x[2] + t (x[3] - x[2])``."""
    d10, d11, d12 = x[1, 0] - x[0, 0], x[1, 1] - x[0, 1], x[1, 2] - x[0, 2]
    d20, d21, d22 = x[3, 0] - x[2, 0], x[3, 1] - x[2, 1], x[3, 2] - x[2, 2]
    r0, r1, r2 = x[0, 0] - x[2, 0], x[0, 1] - x[2, 1], x[0, 2] - x[2, 2]
    A = d10 * d10 + d11 * d11 + d12 * d12
    B = d10 * d20 + d11 * d21 + d12 * d22
    E = d20 * d20 + d21 * d21 + d22 * d22
    C = d10 * r0 + d11 * r1 + d12 * r2
    F = d20 * r0 + d21 * r1 + d22 * r2
    den = A * E - B * B
    good = den > 1e-14 * A * E
    sden = den if good else 1.0
    s = (B * F - C * E) / sden
    t = (A * F - B * C) / sden
    best = math.inf
    if good and 0 <= s <= 1 and 0 <= t <= 1:
        q0, q1, q2 = r0 + s * d10 - t * d20, r1 + s * d11 - t * d21, r2 + s * d12 - t * d22
        best = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    else:
        s = t = 0.0
    for which in range(4):
        if which < 2:
            d, u = _segment_param(x, which, 2, 3)
        else:
            d, u = _segment_param(x, which, 0, 1)
        if d < best:
            best = d
            if which < 2:
                s, t = float(which), u
            else:
                s, t = u, float(which - 2)
    return best, s, t


@numba.njit(cache=True)
def point_triangle_batch(x: np.ndarray) -> tuple:
    """:func:`point_triangle_closest` of (k, 4, 3) quadruples [m]: (k,) distances [m], (k, 3) weights."""
    d = np.empty(len(x))
    bary = np.empty((len(x), 3))
    for i in range(len(x)):
        d[i] = point_triangle_closest(x[i], bary[i])
    return d, bary


@numba.njit(cache=True)
def edge_edge_batch(x: np.ndarray) -> tuple:
    """:func:`edge_edge_closest` of (k, 4, 3) quadruples [m]: (k,) distances [m], (k,) s, (k,) t."""
    d, s, t = np.empty(len(x)), np.empty(len(x)), np.empty(len(x))
    for i in range(len(x)):
        d[i], s[i], t[i] = edge_edge_closest(x[i])
    return d, s, t


#: pairs per chunk of :func:`contact_frames`
FRAME_CHUNK = 256


@numba.njit(cache=True, parallel=True)
def contact_frames(vf: bool, X: np.ndarray, quads: np.ndarray, Xref: np.ndarray) -> tuple:
    """Weights (k, 4), unit normals (k, 3) and distances (k,) [m] of the primitive pairs ``quads`` (k, 4)
    at positions ``X`` (N, 3) [m]; ``Xref`` (N, 3) [m] orients the normal of touching pairs (see
    :func:`modalfem.collision.repulsion.contact_frames`). Chunks of pairs in parallel (each pair alone)."""
    k = len(quads)
    W, N, D = np.empty((k, 4)), np.empty((k, 3)), np.empty(k)
    chunks = chunk_count(k, FRAME_CHUNK)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        _frames_range(vf, X, quads, Xref, start, stop, W, N, D)
    return W, N, D


@numba.njit(cache=True)
def _frames_range(vf: bool, X, quads, Xref, start: int, stop: int, W, N, D) -> None:
    """:func:`contact_frames` of the pairs ``start..stop-1``, into ``W``, ``N``, ``D``."""
    bary = np.empty(3)
    x = np.empty((4, 3))
    for q in range(start, stop):
        for v in range(4):
            for c in range(3):
                x[v, c] = X[quads[q, v], c]
        if vf:
            d = point_triangle_closest(x, bary)
            W[q, 0], W[q, 1], W[q, 2], W[q, 3] = 1.0, -bary[0], -bary[1], -bary[2]
            i, j, u, w = 2, 1, 3, 1
        else:
            d, s, t = edge_edge_closest(x)
            W[q, 0], W[q, 1], W[q, 2], W[q, 3] = 1.0 - s, s, -(1.0 - t), -t
            i, j, u, w = 1, 0, 3, 2
        a0, a1, a2 = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
        b0, b1, b2 = x[u, 0] - x[w, 0], x[u, 1] - x[w, 1], x[u, 2] - x[w, 2]
        g0, g1, g2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        sep0 = sep1 = sep2 = 0.0
        ref0 = ref1 = ref2 = 0.0
        scale = 0.0
        for v in range(4):
            sep0 += W[q, v] * x[v, 0]
            sep1 += W[q, v] * x[v, 1]
            sep2 += W[q, v] * x[v, 2]
            ref0 += W[q, v] * Xref[quads[q, v], 0]
            ref1 += W[q, v] * Xref[quads[q, v], 1]
            ref2 += W[q, v] * Xref[quads[q, v], 2]
            scale = max(scale, abs(x[v, 0]), abs(x[v, 1]), abs(x[v, 2]))
        D[q] = d
        if d <= 1e-9 * (scale + 1e-300):
            # touching: the geometric normal, oriented by the side the first primitive started on
            sgn = -1.0 if g0 * ref0 + g1 * ref1 + g2 * ref2 < 0 else 1.0
            gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
            gn = gn if gn > 0 else 1.0
            N[q, 0], N[q, 1], N[q, 2] = sgn * g0 / gn, sgn * g1 / gn, sgn * g2 / gn
        else:
            dd = d if d > 0 else 1.0
            N[q, 0], N[q, 1], N[q, 2] = sep0 / dd, sep1 / dd, sep2 / dd


@numba.njit(cache=True, parallel=True)
def close_frames(vf: bool, X: np.ndarray, quads: np.ndarray, Xref: np.ndarray, thickness: float) -> tuple:
    """:func:`contact_frames` of the pairs ``quads`` (k, 4) closer than ``thickness`` [m] only, in their
    order: ``(q, W, N, D)`` with (p, 4) quads, (p, 4) weights, (p, 3) unit normals and (p,) distances [m].
    The frames and the per-chunk counts in parallel chunks, then the close rows copied, each chunk to the
    offset of the chunks before it (the same rows on any thread count; stage (a)'s pairs without numpy
    masks over all candidates)."""
    k = len(quads)
    W, N, D = np.empty((k, 4)), np.empty((k, 3)), np.empty(k)
    chunks = chunk_count(k, FRAME_CHUNK)
    offsets = np.zeros(chunks + 1, dtype=np.int64)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        _frames_range(vf, X, quads, Xref, start, stop, W, N, D)
        c = 0
        for q in range(start, stop):
            c += D[q] < thickness
        offsets[ch + 1] = c
    for ch in range(chunks):
        offsets[ch + 1] += offsets[ch]
    p = offsets[chunks]
    qo, Wo, No, Do = np.empty((p, 4), dtype=np.int64), np.empty((p, 4)), np.empty((p, 3)), np.empty(p)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        o = offsets[ch]
        for q in range(start, stop):
            if D[q] < thickness:
                for c in range(4):
                    qo[o, c] = quads[q, c]
                    Wo[o, c] = W[q, c]
                for c in range(3):
                    No[o, c] = N[q, c]
                Do[o] = D[q]
                o += 1
    return qo, Wo, No, Do


#: vertices per chunk of the passes of all cloth vertices against a plane or sphere (``obstacle_vertex_hits``,
#: ``obstacle_repulsion``): below two chunks' worth they run serially. Such a pass costs ~5 ns a vertex, a parallel
#: launch ~10 us on two threads (TBB): on the 64x64 pile's 4,096 vertices in 4 chunks of 1024 the hits pass took
#: longer on two threads than on one (replayed calls of steps 61-62, fastest of interleaved runs while two cores
#: were free, Intel Xeon: 0.35 -> 0.43 ms per step over 15.5 calls)
OBSTACLE_CHUNK = 8192


@numba.njit(cache=True, inline="always")
def _vertex_hits_range(sphere, X0, V, dt, a, b, c, eta, start, stop, hit, out):
    """``obstacle_vertex_hits`` of the vertices ``start..stop-1``."""
    for i in range(start, stop):
        if not sphere:
            d0 = X0[i, 0] * a[0] + X0[i, 1] * a[1] + X0[i, 2] * a[2] - b[0]
            d1 = ((X0[i, 0] + dt * V[i, 0]) * a[0] + (X0[i, 1] + dt * V[i, 1]) * a[1]
                  + (X0[i, 2] + dt * V[i, 2]) * a[2] - b[1])
            hit[i] = d1 < eta
            s = (d0 - eta) / (d0 - d1) if d0 > d1 else 0.0
            out[i] = min(max(s, 0.0), 1.0)
        else:
            r0, r1, r2 = X0[i, 0] - a[0], X0[i, 1] - a[1], X0[i, 2] - a[2]
            e0, e1, e2 = dt * (V[i, 0] - b[0]), dt * (V[i, 1] - b[1]), dt * (V[i, 2] - b[2])
            dd = e0 * e0 + e1 * e1 + e2 * e2
            s = -(r0 * e0 + r1 * e1 + r2 * e2) / (dd if dd > 0 else 1.0)
            s = min(max(s, 0.0), 1.0)
            m0, m1, m2 = r0 + s * e0, r1 + s * e1, r2 + s * e2
            f0, f1, f2 = r0 + e0, r1 + e1, r2 + e2
            near = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2) < c + eta
            end = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2) < c + eta
            hit[i] = (near and s > 0) or end
            out[i] = s if hit[i] else np.inf


@numba.njit(cache=True, parallel=True)
def obstacle_vertex_hits(sphere: bool, X0: np.ndarray, V: np.ndarray, dt: float, a: np.ndarray, b: np.ndarray,
                         c: float, eta: float) -> tuple:
    """Vertex trajectories ``X0 + s dt V`` (s in [0, 1]; (n, 3) [m], [m/s]) against a plane or a sphere (in
    parallel chunks): ``(hit, s)``, (n,) bool and (n,) times of impact in [0, 1].

    Plane (``sphere`` False): ``a`` its unit normal, ``b[0]``, ``b[1]`` its offsets ``p . n`` [m] at the step's
    start and end; signed distances ``d0``, ``d1`` at the trajectory's ends; a hit ends closer than ``eta``, at
    ``s = (d0 - eta) / (d0 - d1)`` when approaching (else 0), clipped to [0, 1].
    Sphere: centre ``a`` [m] at the step start, velocity ``b`` [m/s], radius ``c`` [m]; ``s`` the closest approach
    of the relative trajectory (clipped to [0, 1]); a hit comes within ``c + eta`` there (s > 0) or at the end,
    ``s = inf`` elsewhere."""
    n = len(X0)
    hit = np.empty(n, np.bool_)  # every entry written (np.zeros: a parallel region even on the serial branch)
    out = np.empty(n)
    chunks = chunk_count(n, OBSTACLE_CHUNK)
    if chunks == 1:  # a parallel launch would cost more than the pass
        _vertex_hits_range(sphere, X0, V, dt, a, b, c, eta, 0, n, hit, out)
        return hit, out
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        _vertex_hits_range(sphere, X0, V, dt, a, b, c, eta, start, stop, hit, out)
    return hit, out


@numba.njit(cache=True, inline="always")
def _ccd_frames_range(vf, X0, V, quads, toi, dt, thickness, eta, start, stop, W, N, T):
    """``ccd_frames`` of the pairs ``start..stop-1``."""
    m = stop - start
    Xl, Xr = np.empty((4 * m, 3)), np.empty((4 * m, 3))
    ql = np.empty((m, 4), np.int64)
    for j in range(m):
        f = min(max(toi[start + j], 0.0), 1.0) * dt
        for v in range(4):
            i = quads[start + j, v]
            ql[j, v] = 4 * j + v
            for c in range(3):
                Xr[4 * j + v, c] = X0[i, c]
                Xl[4 * j + v, c] = X0[i, c] + f * V[i, c]
    Wl, Nl, Dl = np.empty((m, 4)), np.empty((m, 3)), np.empty(m)
    _frames_range(vf, Xl, ql, Xr, 0, m, Wl, Nl, Dl)
    for j in range(m):
        d0 = 0.0
        for c in range(3):
            s = 0.0
            for v in range(4):
                s += Wl[j, v] * Xr[4 * j + v, c]
            d0 += s * Nl[j, c]
        for v in range(4):
            W[start + j, v] = Wl[j, v]
        for c in range(3):
            N[start + j, c] = Nl[j, c]
        T[start + j] = (min(max(0.5 * d0, 2.0 * eta), thickness) - d0) / dt


@numba.njit(cache=True, parallel=True)
def ccd_frames(vf: bool, X0: np.ndarray, V: np.ndarray, quads: np.ndarray, toi: np.ndarray, dt: float,
               thickness: float, eta: float) -> tuple:
    """The CCD impulses' frames and targets of colliding pairs ``quads`` (k, 4) with times of impact ``toi`` (k,)
    (fractions of the step ``dt`` [s]): the weights (k, 4) and unit normals (k, 3) at the positions
    ``X0 + clip(toi, 0, 1) dt V`` ((N, 3) [m], [m/s]; oriented by the start positions, :func:`contact_frames`),
    and the relative normal velocities (k,) [m/s] that end the step at ``clip(d0 / 2, 2 eta, thickness)``
    (``d0`` the start separation along that normal, ``eta`` and ``thickness`` [m]). Parallel chunks of pairs."""
    k = len(quads)
    W, N, T = np.empty((k, 4)), np.empty((k, 3)), np.empty(k)
    chunks = chunk_count(k, FRAME_CHUNK)
    if chunks == 1:  # a few hits (most passes): a parallel launch would cost more than the pass
        _ccd_frames_range(vf, X0, V, quads, toi, dt, thickness, eta, 0, k, W, N, T)
        return W, N, T
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        _ccd_frames_range(vf, X0, V, quads, toi, dt, thickness, eta, start, stop, W, N, T)
    return W, N, T


@numba.njit(cache=True, inline="always")
def _obstacle_frame(sphere: bool, x0, x1, x2, a):
    """Unit normal of a plane (unit normal ``a``) or sphere (centre ``a``) at the point ``x`` (the sphere's normal
    at its centre: +z, as ``Sphere.normal_at``)."""
    if not sphere:
        return a[0], a[1], a[2]
    r0, r1, r2 = x0 - a[0], x1 - a[1], x2 - a[2]
    rn = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if rn > 0:
        return r0 / rn, r1 / rn, r2 / rn
    return 0.0, 0.0, 1.0


@numba.njit(cache=True, inline="always")
def _repulsion_range(sphere, X0, V, invm, a, off, radius, lin, ang, thickness, friction, dt, dV, start, stop):
    """``obstacle_repulsion`` of the vertices ``start..stop-1``; returns their count of close vertices."""
    cnt = 0
    for i in range(start, stop):
        x0, x1, x2 = X0[i, 0], X0[i, 1], X0[i, 2]
        if not sphere:
            d = x0 * a[0] + x1 * a[1] + x2 * a[2] - off
        else:
            d = math.sqrt((x0 - a[0]) ** 2 + (x1 - a[1]) ** 2 + (x2 - a[2]) ** 2) - radius
        if not (d < thickness and invm[i] > 0):
            continue
        cnt += 1
        n0, n1, n2 = _obstacle_frame(sphere, x0, x1, x2, a)
        u0, u1, u2 = lin[0], lin[1], lin[2]
        if sphere:
            r0, r1, r2 = x0 - a[0], x1 - a[1], x2 - a[2]
            u0 += ang[1] * r2 - ang[2] * r1
            u1 += ang[2] * r0 - ang[0] * r2
            u2 += ang[0] * r1 - ang[1] * r0
        v0, v1, v2 = V[i, 0] - u0, V[i, 1] - u1, V[i, 2] - u2
        vn = v0 * n0 + v1 * n1 + v2 * n2
        dvn = max(0.1 * (thickness - d) / dt - vn, 0.0)
        t0, t1, t2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        kf = min(friction * dvn / (tn if tn > 0 else 1.0), 1.0)
        dV[i, 0] += dvn * n0 - kf * t0
        dV[i, 1] += dvn * n1 - kf * t1
        dV[i, 2] += dvn * n2 - kf * t2
    return cnt


@numba.njit(cache=True, parallel=True)
def obstacle_repulsion(sphere: bool, X0: np.ndarray, V: np.ndarray, invm: np.ndarray, a: np.ndarray, off: float,
                       radius: float, lin: np.ndarray, ang: np.ndarray, thickness: float, friction: float, dt: float,
                       dV: np.ndarray) -> int:
    """Stage (a) against a plane or sphere (in parallel chunks): every movable vertex of ``X0`` (n, 3) [m] closer
    than ``thickness`` [m] gets (added to ``dV`` (n, 3) [m/s]) the normal velocity change raising its normal
    velocity relative to the obstacle's material to ``0.1 (thickness - d) / dt`` [m/s], with Coulomb ``friction``
    on the tangential part. Plane: unit normal ``a``, offset ``off = p . n`` [m]; sphere: centre ``a`` [m], radius
    ``radius`` [m]; the obstacle moves with velocity ``lin`` [m/s] and angular velocity ``ang`` [rad/s] about
    ``a`` (sphere). Returns the number of such vertices."""
    n = len(X0)
    chunks = chunk_count(n, OBSTACLE_CHUNK)
    if chunks == 1:  # a parallel launch would cost more than the pass
        return _repulsion_range(sphere, X0, V, invm, a, off, radius, lin, ang, thickness, friction, dt, dV, 0, n)
    part = np.zeros(chunks, np.int64)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        part[ch] = _repulsion_range(sphere, X0, V, invm, a, off, radius, lin, ang, thickness, friction, dt, dV, start,
                                    stop)
    total = 0
    for ch in range(chunks):
        total += part[ch]
    return total


@numba.njit(cache=True, inline="always")
def _obstacle_impulses_range(sphere, X0, V, invm, ids, toi, dt, a, off, radius, lin, ang, thickness, eta, dV, start,
                             stop):
    """``obstacle_impulses`` of the vertices ``ids[start:stop]``."""
    for j in range(start, stop):
        i = ids[j]
        s = min(max(toi[j], 0.0), 1.0)
        x0, x1, x2 = X0[i, 0] + dt * s * V[i, 0], X0[i, 1] + dt * s * V[i, 1], X0[i, 2] + dt * s * V[i, 2]
        n0, n1, n2 = a[0], a[1], a[2]
        if sphere:  # from the centre at the time of impact (a vertex at the centre: no normal)
            f = dt * s
            r0, r1, r2 = x0 - (a[0] + f * lin[0]), x1 - (a[1] + f * lin[1]), x2 - (a[2] + f * lin[2])
            rn = max(math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-300)
            n0, n1, n2 = r0 / rn, r1 / rn, r2 / rn
        if not sphere:
            d0 = X0[i, 0] * a[0] + X0[i, 1] * a[1] + X0[i, 2] * a[2] - off
        else:
            d0 = math.sqrt((X0[i, 0] - a[0]) ** 2 + (X0[i, 1] - a[1]) ** 2 + (X0[i, 2] - a[2]) ** 2) - radius
        u0, u1, u2 = lin[0], lin[1], lin[2]
        if sphere:  # the material's velocity at the point of impact, about the centre at the step start
            r0, r1, r2 = x0 - a[0], x1 - a[1], x2 - a[2]
            u0 += ang[1] * r2 - ang[2] * r1
            u1 += ang[2] * r0 - ang[0] * r2
            u2 += ang[0] * r1 - ang[1] * r0
        vn = (V[i, 0] - u0) * n0 + (V[i, 1] - u1) * n1 + (V[i, 2] - u2) * n2
        want = (min(max(0.5 * d0, 2.0 * eta), thickness) - d0) / dt
        dvn = max(want - vn, 0.0) if invm[i] > 0 else 0.0
        dV[i, 0] += dvn * n0
        dV[i, 1] += dvn * n1
        dV[i, 2] += dvn * n2


@numba.njit(cache=True, parallel=True)
def obstacle_impulses(sphere: bool, X0: np.ndarray, V: np.ndarray, invm: np.ndarray, ids: np.ndarray, toi: np.ndarray,
                      dt: float, a: np.ndarray, off: float, radius: float, lin: np.ndarray, ang: np.ndarray,
                      thickness: float, eta: float, dV: np.ndarray) -> None:
    """The CCD impulses of vertices ``ids`` (distinct) hitting a plane or sphere at times ``toi`` (fractions of the
    step ``dt`` [s], clipped to [0, 1]), added to ``dV`` (N, 3) [m/s] (in parallel chunks): the normal at the
    point of impact (the sphere's centre moved on by ``toi dt lin``), the normal velocity relative to the obstacle's
    material that ends the step at ``clip(d0 / 2, 2 eta, thickness)`` from the start distance ``d0``, applied only
    where the vertex is slower and movable. Obstacle arguments as :func:`obstacle_repulsion` (at the step start)."""
    k = len(ids)
    chunks = chunk_count(k, 256)
    if chunks == 1:  # a few hits (most passes): a parallel launch would cost more than the pass
        _obstacle_impulses_range(sphere, X0, V, invm, ids, toi, dt, a, off, radius, lin, ang, thickness, eta, dV, 0, k)
        return
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(k, chunks, ch)
        _obstacle_impulses_range(sphere, X0, V, invm, ids, toi, dt, a, off, radius, lin, ang, thickness, eta, dV,
                                 start, stop)
