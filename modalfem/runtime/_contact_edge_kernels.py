"""Compiled search of box-edge contacts of one modal body (numba ``njit(cache=True)``; ``contact.find_contacts``).

Vertex contacts cannot hold a body face lying across a box's edge: the box's edge passes under the face between
its vertices, and the vertices beyond the edge are outside the box. Here each of a box's 12 edges is clipped
against the body's surface triangles near it: where the edge passes under a triangle (its projection along the
triangle's normal inside the triangle) within the contact margin, the clipped segment's two ends are contacts.
Each is a point of the body's surface, the barycentric combination ``sum_a w_a X_a`` of the triangle's three
vertices (its velocity and Jacobian rows the same combination of theirs), against the plane through the edge
point with the normal the triangle's outward normal reversed (pushing the body away from the box), so the
contact's normal is the body face's, not the direction to the box's nearest feature.

Only triangles whose rigid bounding box (grown by the deformation bound and the margin) meets the box and an edge's
line are tested against that edge, so a body far from a box's edges (or resting inside one of its faces) costs one
pass over its vertices and triangles per box; a body with no box among its obstacles costs nothing (the caller
skips the search).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.runtime._contact_body_kernels import _active, _world
from modalfem.runtime.obstacles import BOX

__all__ = ["FACING", "edge_contacts"]

#: a triangle takes part at a box edge when its reversed normal is within 60 degrees of one of the edge's two box
#: face normals and not more than 120 degrees from the other (the edge lies in the triangle's support region)
FACING = 0.5


@numba.njit(cache=True)
def _bary(p0, p1, p2, a, e0, e1, d00, d01, d11, den):
    """Barycentric coordinates (wA, wB, wC) of the projection of point p onto the plane of the triangle A, A + e0,
    A + e1 (d.. the dot products of e0, e1; den = d00 d11 - d01^2)."""
    f0, f1, f2 = p0 - a[0], p1 - a[1], p2 - a[2]
    d20 = f0 * e0[0] + f1 * e0[1] + f2 * e0[2]
    d21 = f0 * e1[0] + f1 * e1[1] + f2 * e1[2]
    wb = (d11 * d20 - d01 * d21) / den
    wc = (d00 * d21 - d01 * d20) / den
    return 1.0 - wb - wc, wb, wc


@numba.njit(cache=True)
def edge_contacts(kinds, params, margins, depths, rest, vm, q, skip, R, c, bound, tri):
    """Box-edge contacts of the body at the pose (R (3, 3) body -> world, c (3,) [m]) and modal coordinates q.

    Args:
        kinds, params, margins, depths: the obstacles (``_contact_kernels``; only boxes are used), their search
            margins [m] (an edge point at most this far outside a face is a contact) and the depth [m] beyond which
            an edge point behind a face is not (it is another part of the body's, e.g. the far side's).
        rest, vm, q, skip, bound: rest positions (nv, 3) [m], vertex-major modes, modal coordinates, skipped
            modes (r,) bool, and a bound [m] of every vertex's deformation.
        tri: (nt, 3) the surface triangles (outward by the right-hand rule).

    Returns:
        (obstacle (p,), vertices (p, 3) int64, weights (p, 3), normal (p, 3), gap (p,), offset (p,)): per contact
        the box, the triangle's vertices and the barycentric weights of the body point, the contact normal n (world,
        out of the box: the triangle's outward normal reversed), the gap [m] of the body point from the edge point
        along it, and the offset ``n . edge point`` [m] of the contact's plane.
    """
    nv = rest.shape[0]
    nt = tri.shape[0]
    act = _active(skip)
    cap = 64
    o_out = np.empty(cap, dtype=np.int64)
    v_out = np.empty((cap, 3), dtype=np.int64)
    w_out = np.empty((cap, 3))
    n_out = np.empty((cap, 3))
    g_out = np.empty(cap)
    d_out = np.empty(cap)
    k = 0
    loc = np.empty((nv, 3))  # rigid box-local positions
    blo = np.empty(3)
    bhi = np.empty(3)
    X = np.empty((3, 3))
    for o in range(kinds.shape[0]):
        if kinds[o] != BOX:
            continue
        p = params[o]
        h0, h1, h2 = p[3], p[4], p[5]
        lim = margins[o] + bound
        # rigid positions in box axes: l = B^T (c + R X - centre)
        b0, b1, b2 = c[0] - p[0], c[1] - p[1], c[2] - p[2]
        for j in range(nv):
            x0 = b0 + R[0, 0] * rest[j, 0] + R[0, 1] * rest[j, 1] + R[0, 2] * rest[j, 2]
            x1 = b1 + R[1, 0] * rest[j, 0] + R[1, 1] * rest[j, 1] + R[1, 2] * rest[j, 2]
            x2 = b2 + R[2, 0] * rest[j, 0] + R[2, 1] * rest[j, 1] + R[2, 2] * rest[j, 2]
            l0 = p[6] * x0 + p[9] * x1 + p[12] * x2
            l1 = p[7] * x0 + p[10] * x1 + p[13] * x2
            l2 = p[8] * x0 + p[11] * x1 + p[14] * x2
            loc[j, 0], loc[j, 1], loc[j, 2] = l0, l1, l2
        for t in range(nt):
            ia, ib, ic = tri[t, 0], tri[t, 1], tri[t, 2]
            # the triangle's box-local bounding box (rigid, grown by lim) must meet the box and, for an edge to be
            # tested, that edge's line (below): a body resting inside a box's face tests no edge
            for d in range(3):
                blo[d] = min(loc[ia, d], loc[ib, d], loc[ic, d]) - lim
                bhi[d] = max(loc[ia, d], loc[ib, d], loc[ic, d]) + lim
            if (blo[0] > h0 or bhi[0] < -h0 or blo[1] > h1 or bhi[1] < -h1 or blo[2] > h2 or bhi[2] < -h2):
                continue
            ok = False
            for ax in range(3):
                u = (ax + 1) % 3
                v = (ax + 2) % 3
                for su in (-1.0, 1.0):
                    for sv in (-1.0, 1.0):
                        if blo[u] <= su * p[3 + u] <= bhi[u] and blo[v] <= sv * p[3 + v] <= bhi[v]:
                            ok = True
            if not ok:
                continue
            # deformed world positions of the three vertices
            for s in range(3):
                X[s, 0], X[s, 1], X[s, 2] = _world(tri[t, s], rest, vm, q, act, R, c)
            a = X[0]
            e0 = np.empty(3)
            e1 = np.empty(3)
            for d in range(3):
                e0[d] = X[1, d] - a[d]
                e1[d] = X[2, d] - a[d]
            f0 = e0[1] * e1[2] - e0[2] * e1[1]
            f1 = e0[2] * e1[0] - e0[0] * e1[2]
            f2 = e0[0] * e1[1] - e0[1] * e1[0]
            fl = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
            if fl == 0.0:
                continue
            f0, f1, f2 = f0 / fl, f1 / fl, f2 / fl  # outward normal of the triangle (world)
            m0, m1, m2 = -f0, -f1, -f2  # the contact normal: out of the box, into the body
            d00 = e0[0] * e0[0] + e0[1] * e0[1] + e0[2] * e0[2]
            d01 = e0[0] * e1[0] + e0[1] * e1[1] + e0[2] * e1[2]
            d11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]
            den = d00 * d11 - d01 * d01
            if den <= 0.0:
                continue
            for ax in range(3):  # the edges along box axis ax
                u = (ax + 1) % 3
                v = (ax + 2) % 3
                for su in (-1.0, 1.0):
                    for sv in (-1.0, 1.0):
                        if not (blo[u] <= su * p[3 + u] <= bhi[u] and blo[v] <= sv * p[3 + v] <= bhi[v]):
                            continue  # the triangle is not near this edge's line
                        # the edge's two box face normals (world): su e_u, sv e_v
                        nu0, nu1, nu2 = su * p[6 + u], su * p[9 + u], su * p[12 + u]
                        nv0, nv1, nv2 = sv * p[6 + v], sv * p[9 + v], sv * p[12 + v]
                        cu = m0 * nu0 + m1 * nu1 + m2 * nu2
                        cv = m0 * nv0 + m1 * nv1 + m2 * nv2
                        if not ((cu > FACING or cv > FACING) and cu > -FACING and cv > -FACING):
                            continue
                        # the edge's end points (world): centre + B l, l_ax = -/+ h_ax, l_u = su h_u, l_v = sv h_v
                        lu = su * p[3 + u]
                        lv = sv * p[3 + v]
                        P = np.empty((2, 3))
                        for e in range(2):
                            la = (2.0 * e - 1.0) * p[3 + ax]
                            for d in range(3):
                                P[e, d] = p[d] + p[6 + 3 * d + ax] * la + p[6 + 3 * d + u] * lu + p[6 + 3 * d + v] * lv
                        wa0, wb0, wc0 = _bary(P[0, 0], P[0, 1], P[0, 2], a, e0, e1, d00, d01, d11, den)
                        wa1, wb1, wc1 = _bary(P[1, 0], P[1, 1], P[1, 2], a, e0, e1, d00, d01, d11, den)
                        t0, t1 = 0.0, 1.0
                        for w0, w1 in ((wa0, wa1), (wb0, wb1), (wc0, wc1)):
                            dw = w1 - w0
                            if dw > 0.0:
                                t0 = max(t0, -w0 / dw)
                            elif dw < 0.0:
                                t1 = min(t1, -w0 / dw)
                            elif w0 < 0.0:
                                t1 = -1.0
                        if t0 > t1:
                            continue
                        ends = 1 if t1 - t0 <= 1e-9 else 2
                        for e in range(ends):
                            tt = t0 if e == 0 else t1
                            x0 = P[0, 0] + tt * (P[1, 0] - P[0, 0])
                            x1 = P[0, 1] + tt * (P[1, 1] - P[0, 1])
                            x2 = P[0, 2] + tt * (P[1, 2] - P[0, 2])
                            gap = (x0 - a[0]) * f0 + (x1 - a[1]) * f1 + (x2 - a[2]) * f2
                            if gap > margins[o] or gap < -depths[o]:
                                continue
                            wa = max(wa0 + tt * (wa1 - wa0), 0.0)
                            wb = max(wb0 + tt * (wb1 - wb0), 0.0)
                            wc = max(wc0 + tt * (wc1 - wc0), 0.0)
                            ws = wa + wb + wc
                            if k == cap:
                                cap *= 2
                                o_out = _grow_i(o_out, cap)
                                v_out = _grow_i2(v_out, cap)
                                w_out = _grow_f2(w_out, cap)
                                n_out = _grow_f2(n_out, cap)
                                g_out = _grow_f(g_out, cap)
                                d_out = _grow_f(d_out, cap)
                            o_out[k] = o
                            v_out[k, 0], v_out[k, 1], v_out[k, 2] = ia, ib, ic
                            w_out[k, 0], w_out[k, 1], w_out[k, 2] = wa / ws, wb / ws, wc / ws
                            n_out[k, 0], n_out[k, 1], n_out[k, 2] = m0, m1, m2
                            g_out[k] = gap
                            d_out[k] = m0 * x0 + m1 * x1 + m2 * x2
                            k += 1
    return o_out[:k].copy(), v_out[:k].copy(), w_out[:k].copy(), n_out[:k].copy(), g_out[:k].copy(), d_out[:k].copy()


@numba.njit(cache=True)
def _grow_i(a, cap):
    b = np.empty(cap, dtype=np.int64)
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True)
def _grow_f(a, cap):
    b = np.empty(cap)
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True)
def _grow_i2(a, cap):
    b = np.empty((cap, 3), dtype=np.int64)
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True)
def _grow_f2(a, cap):
    b = np.empty((cap, 3))
    b[:a.shape[0]] = a
    return b
