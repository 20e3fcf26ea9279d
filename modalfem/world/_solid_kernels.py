"""Compiled contact search for modal bodies in the World's solid solve (numba, cached on disk).

Every modal body keeps a BVH of its rest surface (triangles, and edges as degenerate triangles) built once and
never refitted: its deformed surface in body axes is the rest surface plus ``Phi q``, which moves no vertex by
more than ``bound = max_v |Phi_v q|``. A query point of another body is taken into this body's axes (distances
do not change under a rigid motion) and its box, grown by ``bound``, is walked against the rest tree: every
triangle whose deformed box is within the search radius is found (a superset), and the exact point-triangle
(edge-edge) distances to the deformed triangles select the contacts. No tree is refitted per step.

``modalfem.world._contact_rows.assemble`` turns the contacts found into the solve's entries.

``vertex_face``, ``edge_edge`` and ``all_pairs`` walk the trees afresh (the reference); the World uses
``modalfem.world._coherent_kernels.coherent_pairs``, which reuses a walk over steps with the same per-pair tests
(``_vf_test``, ``_ee_test``: after changing them, delete ``modalfem/world/__pycache__``, numba's cache of the
other module does not notice). ``frames`` and ``velocity_blocks`` give every body's frame, surface and velocity
block at once.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.collision._bvh_kernels import _query_range
from modalfem.collision._distance_kernels import edge_edge_closest, point_triangle_closest


@numba.njit(cache=True)
def _to_local(x, R, p, out):
    d0, d1, d2 = x[0] - p[0], x[1] - p[1], x[2] - p[2]
    for c in range(3):
        out[c] = R[0, c] * d0 + R[1, c] * d1 + R[2, c] * d2


@numba.njit(cache=True, inline="always")
def _vf_test(y, Xb, Tb, t, reach, x, w, i, best, dbest, gbest, bary, nloc):
    """Point ``y`` (b's axes) against b's triangle ``t``: when within ``reach`` [m] and closer than query ``i``'s
    best so far (ties: the one ``y`` is most in front of), it becomes the best (its distance, plane gap [m],
    barycentric weights and unit normal in b's axes). Returns the distance [m]."""
    a, b, c = Tb[t, 0], Tb[t, 1], Tb[t, 2]
    for d in range(3):
        x[0, d] = y[d]
        x[1, d] = Xb[a, d]
        x[2, d] = Xb[b, d]
        x[3, d] = Xb[c, d]
    dist = point_triangle_closest(x, w)
    if not dist <= reach:
        return dist
    e10, e11, e12 = x[2, 0] - x[1, 0], x[2, 1] - x[1, 1], x[2, 2] - x[1, 2]
    e20, e21, e22 = x[3, 0] - x[1, 0], x[3, 1] - x[1, 1], x[3, 2] - x[1, 2]
    f0, f1, f2 = e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20
    ln = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if not ln > 0.0:
        return dist
    f0, f1, f2 = f0 / ln, f1 / ln, f2 / ln
    g = 0.0
    for d in range(3):
        q = w[0] * x[1, d] + w[1] * x[2, d] + w[2] * x[3, d]
        g += (x[0, d] - q) * (f0 if d == 0 else (f1 if d == 1 else f2))
    if dist < dbest[i] * (1.0 - 1e-12) or (dist <= dbest[i] * (1.0 + 1e-12) and g > gbest[i]):
        best[i], dbest[i], gbest[i] = t, dist, g
        bary[i, 0], bary[i, 1], bary[i, 2] = w[0], w[1], w[2]
        nloc[i, 0], nloc[i, 1], nloc[i, 2] = f0, f1, f2
    return dist


@numba.njit(cache=True)
def _vertex_queries(xa, Rb, pb, bound, radius, blo, bhi):
    """a's vertices inside b's world box grown by ``radius`` [m] (``near`` (m,)), in b's body axes (``y`` (m, 3)),
    and their query boxes in b's rest tree (grown by ``radius + bound``): ``(near, y, qlo, qhi)``."""
    na = xa.shape[0]
    near = np.empty(na, dtype=np.int64)
    m = 0
    for j in range(na):
        if (blo[0] - radius <= xa[j, 0] <= bhi[0] + radius and blo[1] - radius <= xa[j, 1] <= bhi[1] + radius
                and blo[2] - radius <= xa[j, 2] <= bhi[2] + radius):
            near[m] = j
            m += 1
    y = np.empty((m, 3))
    qlo = np.empty((m, 3))
    qhi = np.empty((m, 3))
    grow = radius + bound
    for i in range(m):
        _to_local(xa[near[i]], Rb, pb, y[i])
        for c in range(3):
            qlo[i, c] = y[i, c] - grow
            qhi[i, c] = y[i, c] + grow
    return near[:m], y, qlo, qhi


@numba.njit(cache=True)
def _vf_found(vid, best, gbest, bary, nloc, Rb):
    """``vertex_face``'s outputs from the per-vertex bests (vertex ``vid[i]``, triangle ``best[i]``, -1: none)."""
    m = best.shape[0]
    k = 0
    for i in range(m):
        if best[i] >= 0:
            k += 1
    vertex = np.empty(k, dtype=np.int64)
    tri = np.empty(k, dtype=np.int64)
    wb = np.empty((k, 3))
    gap = np.empty(k)
    normal = np.empty((k, 3))
    k = 0
    for i in range(m):
        if best[i] < 0:
            continue
        vertex[k], tri[k], gap[k] = vid[i], best[i], gbest[i]
        for c in range(3):
            wb[k, c] = bary[i, c]
            normal[k, c] = Rb[c, 0] * nloc[i, 0] + Rb[c, 1] * nloc[i, 1] + Rb[c, 2] * nloc[i, 2]
        k += 1
    return vertex, tri, wb, gap, normal


@numba.njit(cache=True)
def _edge_queries(xa, Ea, Rb, pb, bound, radius, blo, bhi):
    """a's edges whose box meets b's world box grown by ``radius`` [m] (``sel`` (m,)), their ends in b's body axes
    (``y`` (m, 2, 3)) and their query boxes in b's rest edge tree (grown by ``radius + bound``)."""
    ne = Ea.shape[0]
    sel = np.empty(ne, dtype=np.int64)
    m = 0
    for e in range(ne):
        i, j = Ea[e, 0], Ea[e, 1]
        ok = True
        for c in range(3):
            if min(xa[i, c], xa[j, c]) > bhi[c] + radius or max(xa[i, c], xa[j, c]) < blo[c] - radius:
                ok = False
        if ok:
            sel[m] = e
            m += 1
    y = np.empty((m, 2, 3))
    qlo = np.empty((m, 3))
    qhi = np.empty((m, 3))
    grow = radius + bound
    for q in range(m):
        _to_local(xa[Ea[sel[q], 0]], Rb, pb, y[q, 0])
        _to_local(xa[Ea[sel[q], 1]], Rb, pb, y[q, 1])
        for c in range(3):
            qlo[q, c] = min(y[q, 0, c], y[q, 1, c]) - grow
            qhi[q, c] = max(y[q, 0, c], y[q, 1, c]) + grow
    return sel[:m], y, qlo, qhi


@numba.njit(cache=True)
def vertex_face(xa, Rb, pb, Xb, Tb, bound, reach, blo, bhi, P, lo, hi, nonempty, slot_tri, slo, shi):
    """Vertices of body a within ``reach`` [m] of body b's deformed surface, each with its closest triangle.

    Args:
        xa: (na, 3) world vertices of a [m]. Rb, pb: b's rotation (3, 3) and centre of mass (3,) [m].
        Xb: (nb, 3) b's deformed vertices in body axes [m]; Tb: (mb, 3) its outward triangles.
        bound: max |Phi q| of b [m]. reach: search radius [m]. blo, bhi: (3,) b's world box [m].
        P ... shi: b's rest-surface tree (``BroadPhaseBVH`` arrays at the rest positions).

    Returns:
        ``(vertex, triangle, bary, gap, normal)``: (k,) vertices of a, (k,) triangles of b, (k, 3) barycentric
        weights of the closest point, (k,) signed distance [m] to the triangle's plane along its unit normal
        (negative behind it), (k, 3) the world unit normal of the triangle. The closest triangle is the one at
        the least distance (ties: the one the point is most in front of), as ``proximity.SurfaceProximity``.
    """
    near, y, qlo, qhi = _vertex_queries(xa, Rb, pb, bound, reach, blo, bhi)
    m = near.shape[0]
    pairs = _query_range(qlo, qhi, 0, m, P, lo, hi, nonempty, slot_tri, slo, shi)
    best = np.full(m, -1, dtype=np.int64)
    dbest = np.full(m, np.inf)
    gbest = np.zeros(m)
    bary = np.zeros((m, 3))
    nloc = np.zeros((m, 3))
    x = np.empty((4, 3))
    w = np.empty(3)
    for k in range(pairs.shape[0]):
        i = pairs[k, 0]
        _vf_test(y[i], Xb, Tb, pairs[k, 1], reach, x, w, i, best, dbest, gbest, bary, nloc)
    return _vf_found(near, best, gbest, bary, nloc, Rb)


@numba.njit(cache=True, inline="always")
def _ee_test(y0, y1, Xb, Eb, adj, Tb, f, margin, scale, x, res):
    """Edge ``y0 y1`` (b's axes) against b's edge ``f``: True when within ``margin`` [m] with closest points inside
    both edges, at least ~12 degrees from parallel; then ``res`` = (s, t, gap, normal in b's axes (3)); ``res[6]``:
    the edges' distance [m], always."""
    for d in range(3):
        x[0, d] = y0[d]
        x[1, d] = y1[d]
        x[2, d] = Xb[Eb[f, 0], d]
        x[3, d] = Xb[Eb[f, 1], d]
    dist, s, t = edge_edge_closest(x)
    res[6] = dist
    if not (dist <= margin and 1e-6 < s < 1 - 1e-6 and 1e-6 < t < 1 - 1e-6):
        return False
    u0, u1, u2 = x[1, 0] - x[0, 0], x[1, 1] - x[0, 1], x[1, 2] - x[0, 2]
    v0, v1, v2 = x[3, 0] - x[2, 0], x[3, 1] - x[2, 1], x[3, 2] - x[2, 2]
    c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    if not (math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            > 0.2 * math.sqrt(u0 * u0 + u1 * u1 + u2 * u2) * math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)):
        return False
    s0 = s1 = s2 = 0.0
    for j in range(2):
        fc = adj[f, j]
        if fc < 0:
            continue
        a, b, c = Tb[fc, 0], Tb[fc, 1], Tb[fc, 2]
        e10, e11, e12 = Xb[b, 0] - Xb[a, 0], Xb[b, 1] - Xb[a, 1], Xb[b, 2] - Xb[a, 2]
        e20, e21, e22 = Xb[c, 0] - Xb[a, 0], Xb[c, 1] - Xb[a, 1], Xb[c, 2] - Xb[a, 2]
        f0, f1, f2 = e11 * e22 - e12 * e21, e12 * e20 - e10 * e22, e10 * e21 - e11 * e20
        ln = max(math.sqrt(f0 * f0 + f1 * f1 + f2 * f2), 1e-300)
        s0, s1, s2 = s0 + f0 / ln, s1 + f1 / ln, s2 + f2 / ln
    dd = max(dist, 1e-300)
    n0 = (x[0, 0] + s * u0 - x[2, 0] - t * v0) / dd
    n1 = (x[0, 1] + s * u1 - x[2, 1] - t * v1) / dd
    n2 = (x[0, 2] + s * u2 - x[2, 2] - t * v2) / dd
    g = dist
    if n0 * s0 + n1 * s1 + n2 * s2 < 0:
        n0, n1, n2, g = -n0, -n1, -n2, -dist
    if dist <= 1e-12 * scale:
        ls = max(math.sqrt(s0 * s0 + s1 * s1 + s2 * s2), 1e-300)
        n0, n1, n2 = s0 / ls, s1 / ls, s2 / ls
    if not math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) > 0.5:
        return False
    res[0], res[1], res[2], res[3], res[4], res[5] = s, t, g, n0, n1, n2
    return True


@numba.njit(cache=True)
def edge_edge(xa, Ea, Rb, pb, Xb, Eb, adj, Tb, bound, margin, blo, bhi, P, lo, hi, nonempty, slot_tri, slo, shi):
    """Pairs of a's edges with b's edges closer than ``margin`` [m], as ``proximity.EdgeProximity.query``: closest
    points inside both edges, the edges at least ~12 degrees from parallel; the normal points from b to a's edge
    on b's outward side (the sum of the normals of b's faces at its edge).

    Args:
        xa: (na, 3) world vertices of a; Ea: (ea, 2) its edges. Rb, pb, Xb, bound, blo, bhi: as ``vertex_face``.
        Eb: (eb, 2) b's edges; adj: (eb, 2) their faces (-1: none); Tb: b's triangles. P ... shi: the rest tree of
        b's edges (degenerate triangles ``e0 e1 e1``).

    Returns:
        ``(mine, other, s, t, gap, normal)``: (k,) edges of a and of b, (k,) closest-point parameters on each,
        (k,) gap [m] (negative: a's edge behind b's surface), (k, 3) world normals.
    """
    sel, y, qlo, qhi = _edge_queries(xa, Ea, Rb, pb, bound, margin, blo, bhi)
    pairs = _query_range(qlo, qhi, 0, sel.shape[0], P, lo, hi, nonempty, slot_tri, slo, shi)
    scale = 1.0
    for v in range(Xb.shape[0]):
        for c in range(3):
            scale = max(scale, abs(Xb[v, c]))
    n = pairs.shape[0]
    mine = np.empty(n, dtype=np.int64)
    other = np.empty(n, dtype=np.int64)
    so = np.empty(n)
    to = np.empty(n)
    gap = np.empty(n)
    normal = np.empty((n, 3))
    x = np.empty((4, 3))
    res = np.empty(7)
    k = 0
    for p in range(n):
        q, f = pairs[p, 0], pairs[p, 1]
        if _ee_test(y[q, 0], y[q, 1], Xb, Eb, adj, Tb, f, margin, scale, x, res):
            mine[k], other[k], so[k], to[k], gap[k] = sel[q], f, res[0], res[1], res[2]
            for c in range(3):
                normal[k, c] = Rb[c, 0] * res[3] + Rb[c, 1] * res[4] + Rb[c, 2] * res[5]
            k += 1
    return mine[:k], other[:k], so[:k], to[:k], gap[:k], normal[:k]


@numba.njit(cache=True)
def plane_contacts(X, voff, center, radius, reach, normals, offsets):
    """Vertices within ``reach[b]`` [m] of static planes ``n . x = d`` (outward unit normals (p, 3), offsets (p,)
    [m]), over every body's world vertices ``X`` (concatenated; body b's are ``voff[b]:voff[b + 1]``); bodies
    whose bounding sphere (``center`` (nb, 3), ``radius`` (nb,) [m]) is farther are skipped.

    Returns: ``(body, vertex, plane, gap)``, (k,) each (vertex local to its body).
    """
    nb = voff.shape[0] - 1
    npl = normals.shape[0]
    near = np.zeros((nb, npl), dtype=np.bool_)  # the body's bounding sphere within reach of the plane
    cap = 0
    for b in range(nb):
        for p in range(npl):
            sd = (normals[p, 0] * center[b, 0] + normals[p, 1] * center[b, 1] + normals[p, 2] * center[b, 2]
                  - offsets[p])
            if sd - radius[b] < reach[b]:
                near[b, p] = True
                cap += voff[b + 1] - voff[b]
    body = np.empty(cap, dtype=np.int64)
    vertex = np.empty(cap, dtype=np.int64)
    plane = np.empty(cap, dtype=np.int64)
    gap = np.empty(cap)
    k = 0
    for b in range(nb):
        for p in range(npl):
            if not near[b, p]:
                continue
            for v in range(voff[b], voff[b + 1]):
                g = normals[p, 0] * X[v, 0] + normals[p, 1] * X[v, 1] + normals[p, 2] * X[v, 2] - offsets[p]
                if g < reach[b]:
                    body[k], vertex[k], plane[k], gap[k] = b, v - voff[b], p, g
                    k += 1
    return body[:k], vertex[:k], plane[:k], gap[:k]


@numba.njit(cache=True)
def _gather(vl_a, vl_b, vl, nvf, el_a, el_b, el, nee):
    """The per-pair outputs of ``vertex_face`` (bodies ``vl_a`` on ``vl_b``) and ``edge_edge`` in one array each,
    as ``all_pairs`` returns them."""
    va = np.empty(nvf, dtype=np.int64)
    vb = np.empty(nvf, dtype=np.int64)
    vv = np.empty(nvf, dtype=np.int64)
    vt = np.empty(nvf, dtype=np.int64)
    vw = np.empty((nvf, 3))
    vg = np.empty(nvf)
    vn = np.empty((nvf, 3))
    k = 0
    for j in range(len(vl)):
        o = vl[j]
        for r in range(o[0].shape[0]):
            va[k], vb[k], vv[k], vt[k], vg[k] = vl_a[j], vl_b[j], o[0][r], o[1][r], o[3][r]
            for c in range(3):
                vw[k, c] = o[2][r, c]
                vn[k, c] = o[4][r, c]
            k += 1
    ea = np.empty(nee, dtype=np.int64)
    eb = np.empty(nee, dtype=np.int64)
    em = np.empty(nee, dtype=np.int64)
    eo = np.empty(nee, dtype=np.int64)
    es = np.empty(nee)
    et = np.empty(nee)
    eg = np.empty(nee)
    en = np.empty((nee, 3))
    k = 0
    for j in range(len(el)):
        o = el[j]
        for r in range(o[0].shape[0]):
            ea[k], eb[k], em[k], eo[k], es[k], et[k], eg[k] = el_a[j], el_b[j], o[0][r], o[1][r], o[2][r], o[3][r], o[4][r]
            for c in range(3):
                en[k, c] = o[5][r, c]
            k += 1
    return (va, vb, vv, vt, vw, vg, vn), (ea, eb, em, eo, es, et, eg, en)


@numba.njit(cache=True)
def all_pairs(pa, pb, rr, mm, X, Xl, voff, R, pos, bound, blo, bhi, tris, toff, edges, eoff, adj,
              tP, tlo, thi, tne, tslot, tslo, tshi, eP, elo, ehi, ene, eslot, eslo, eshi):
    """``vertex_face`` both ways and ``edge_edge`` for every candidate pair of bodies in one call.

    Args:
        pa, pb: (p,) body pairs (a < b); rr, mm: (p,) their search radius and margin [m]. X, Xl: (n, 3) every
            body's world and body-axes deformed vertices, body i's at ``voff[i]:voff[i + 1]``; R, pos, bound,
            blo, bhi: per body as in ``vertex_face``. tris/toff, edges/eoff, adj: every body's triangles, edges and
            edge faces (local indices) with offsets. tP ... tshi, eP ... eshi: typed lists of the bodies' rest
            triangle and edge trees.

    Returns:
        ``(vf, ee)``: vertex-face contacts ``(a, b, vertex, triangle, bary (k, 3), gap, normal (k, 3))`` and edge
        pairs ``(a, b, mine, other, s, t, gap, normal)`` (a the body whose vertex or edge it is).
    """
    vl_a = numba.typed.List()
    vl_b = numba.typed.List()
    vl = numba.typed.List()
    el_a = numba.typed.List()
    el_b = numba.typed.List()
    el = numba.typed.List()
    nvf = 0
    nee = 0
    for i in range(pa.shape[0]):
        a, b = pa[i], pb[i]
        for side in range(2):
            p, q = (a, b) if side == 0 else (b, a)
            out = vertex_face(X[voff[p]:voff[p + 1]], R[q], pos[q], Xl[voff[q]:voff[q + 1]],
                              tris[toff[q]:toff[q + 1]], bound[q], rr[i], blo[q], bhi[q], tP[q], tlo[q], thi[q],
                              tne[q], tslot[q], tslo[q], tshi[q])
            if out[0].shape[0]:
                vl_a.append(p)
                vl_b.append(q)
                vl.append(out)
                nvf += out[0].shape[0]
        out2 = edge_edge(X[voff[a]:voff[a + 1]], edges[eoff[a]:eoff[a + 1]], R[b], pos[b], Xl[voff[b]:voff[b + 1]],
                         edges[eoff[b]:eoff[b + 1]], adj[eoff[b]:eoff[b + 1]], tris[toff[b]:toff[b + 1]], bound[b],
                         mm[i], blo[b], bhi[b], eP[b], elo[b], ehi[b], ene[b], eslot[b], eslo[b], eshi[b])
        if out2[0].shape[0]:
            el_a.append(a)
            el_b.append(b)
            el.append(out2)
            nee += out2[0].shape[0]
    return _gather(vl_a, vl_b, vl, nvf, el_a, el_b, el, nee)


@numba.njit(cache=True)
def frames(quat, position, q, qoff, nm, phi, phi_off, rest, voff, inertia_inv):
    """Every body's frame and deformed surface at once.

    Args:
        quat: (nb, 4) unit orientations (w, x, y, z); position: (nb, 3) centres of mass [m]. q: the bodies' modal
            coordinates, body i's ``nm[i]`` from ``qoff[i]``; phi: their mode shapes as in
            ``_contact_rows.assemble``; rest: (n, 3) every body's rest surface about its centre of mass [m], body
            i's ``voff[i]:voff[i + 1]``;
            inertia_inv: (nb, 3, 3) inverse inertias in body axes [1/(kg m^2)].

    Returns:
        ``(R, Iw_inv, Xl, X, bound, lo, hi)``: rotations (nb, 3, 3) (``runtime.rotation.quat_to_matrix``), world
        inverse inertias ``R I^-1 R^T``, deformed vertices ``rest + Phi q`` in body axes and in the world (n, 3)
        [m], the largest |Phi_v q| (nb,) [m] (0 without modes), world boxes (nb, 3) [m].
    """
    nb = quat.shape[0]
    n = rest.shape[0]
    R = np.empty((nb, 3, 3))
    Iw = np.empty((nb, 3, 3))
    Xl = np.empty((n, 3))
    X = np.empty((n, 3))
    bound = np.zeros(nb)
    lo = np.empty((nb, 3))
    hi = np.empty((nb, 3))
    for b in range(nb):
        w, x, y, z = quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3]
        R[b, 0, 0], R[b, 0, 1], R[b, 0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
        R[b, 1, 0], R[b, 1, 1], R[b, 1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
        R[b, 2, 0], R[b, 2, 1], R[b, 2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
        for i in range(3):
            for j in range(3):
                s = 0.0
                for k in range(3):
                    t = 0.0
                    for m in range(3):
                        t += inertia_inv[b, k, m] * R[b, j, m]
                    s += R[b, i, k] * t
                Iw[b, i, j] = s
        r = nm[b]
        base = phi_off[b]
        o = qoff[b]
        act = np.empty(r, dtype=np.int64)  # the modes with q != 0 (a body at rest, or whose modes the contact
        na = 0                             # never excites, has none)
        for m in range(r):
            if q[o + m] != 0.0:
                act[na] = m
                na += 1
        d2 = 0.0
        for c in range(3):
            lo[b, c] = np.inf
            hi[b, c] = -np.inf
        for v in range(voff[b], voff[b + 1]):
            u = v - voff[b]
            dd = 0.0
            for c in range(3):
                s = 0.0
                p = base + (u * 3 + c) * r
                for j in range(na):
                    m = act[j]
                    s += phi[p + m] * q[o + m]
                Xl[v, c] = rest[v, c] + s
                dd += s * s
            d2 = max(d2, dd)
            for c in range(3):
                X[v, c] = R[b, c, 0] * Xl[v, 0] + R[b, c, 1] * Xl[v, 1] + R[b, c, 2] * Xl[v, 2] + position[b, c]
                lo[b, c] = min(lo[b, c], X[v, c])
                hi[b, c] = max(hi[b, c], X[v, c])
        bound[b] = math.sqrt(d2) if r > 0 else 0.0
    return R, Iw, Xl, X, bound, lo, hi


@numba.njit(cache=True)
def velocity_blocks(quat, vel, L, qdot, qoff, nm, inertia_inv, g, radius, phi, phi_off, voff, dt):
    """Every body's block of the solve's velocities and the bound of its surface points' speed.

    Args:
        quat, vel, L: (nb, 4) orientations, (nb, 3) velocities [m/s] and world angular momenta [kg m^2/s];
            qdot: modal velocities (body i's ``nm[i]`` from ``qoff[i]``); inertia_inv: (nb, 3, 3) body axes
            [1/(kg m^2)]; g: (nb, 3) gravity [m/s^2]; radius: (nb,) rest radii [m]; phi, phi_off, voff: as
            ``frames``. dt: step [s].

    Returns:
        ``(V, speed)``: every body's ``(v + g dt, w, qdot)`` (6 + r) one after another (w = R I^-1 R^T L
        [rad/s]), and (nb,) ``|v| + |w| radius + |g| dt + max_i |(Phi qdot)_i|`` [m/s] (the largest vertex speed of
        the deformation, a 3-vector norm per vertex: a bound on every surface point's speed).
    """
    nb = quat.shape[0]
    V = np.empty(6 * nb + qdot.shape[0])
    speed = np.empty(nb)
    o = 0
    for b in range(nb):
        w, x, y, z = quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3]
        R00, R01, R02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
        R10, R11, R12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
        R20, R21, R22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
        t0 = R00 * L[b, 0] + R10 * L[b, 1] + R20 * L[b, 2]
        t1 = R01 * L[b, 0] + R11 * L[b, 1] + R21 * L[b, 2]
        t2 = R02 * L[b, 0] + R12 * L[b, 1] + R22 * L[b, 2]
        u0 = inertia_inv[b, 0, 0] * t0 + inertia_inv[b, 0, 1] * t1 + inertia_inv[b, 0, 2] * t2
        u1 = inertia_inv[b, 1, 0] * t0 + inertia_inv[b, 1, 1] * t1 + inertia_inv[b, 1, 2] * t2
        u2 = inertia_inv[b, 2, 0] * t0 + inertia_inv[b, 2, 1] * t1 + inertia_inv[b, 2, 2] * t2
        w0 = R00 * u0 + R01 * u1 + R02 * u2
        w1 = R10 * u0 + R11 * u1 + R12 * u2
        w2 = R20 * u0 + R21 * u1 + R22 * u2
        for c in range(3):
            V[o + c] = vel[b, c] + g[b, c] * dt
        V[o + 3], V[o + 4], V[o + 5] = w0, w1, w2
        r = nm[b]
        for m in range(r):
            V[o + 6 + m] = qdot[qoff[b] + m]
        sp = (math.sqrt(vel[b, 0] ** 2 + vel[b, 1] ** 2 + vel[b, 2] ** 2)
              + math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) * radius[b]
              + math.sqrt(g[b, 0] ** 2 + g[b, 1] ** 2 + g[b, 2] ** 2) * dt)
        act = np.empty(r, dtype=np.int64)
        na = 0
        for m in range(r):
            if qdot[qoff[b] + m] != 0.0:
                act[na] = m
                na += 1
        if r:
            top = 0.0
            if na:
                base = phi_off[b]
                for u in range(voff[b + 1] - voff[b]):
                    s2 = 0.0
                    for c in range(3):
                        p = base + (u * 3 + c) * r
                        s = 0.0
                        for j in range(na):
                            m = act[j]
                            s += phi[p + m] * qdot[qoff[b] + m]
                        s2 += s * s
                    top = max(top, s2)
            sp += math.sqrt(top)
        speed[b] = sp
        o += 6 + r
    return V, speed


@numba.njit(cache=True)
def island_labels(body, other, m):
    """The islands of a solve's contacts (``body``, ``other`` (k,) body indices, ``other`` -1 for an obstacle) among
    ``m`` bodies: per body the smallest body index of its island (the connected component of the graph whose edges
    are the body-body contacts; an obstacle links nothing), -1 for a body with no contact."""
    parent = np.arange(m)
    for c in range(body.shape[0]):
        a, b = body[c], other[c]
        if b < 0:
            continue
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        while parent[b] != b:
            parent[b] = parent[parent[b]]
            b = parent[b]
        if a != b:
            parent[max(a, b)] = min(a, b)
    touched = np.zeros(m, dtype=np.bool_)
    for c in range(body.shape[0]):
        touched[body[c]] = True
        if other[c] >= 0:
            touched[other[c]] = True
    label = np.full(m, -1, dtype=np.int64)
    for i in range(m):  # a root is the smallest index of its tree (links point to the smaller root)
        if touched[i]:
            r = i
            while parent[r] != r:
                r = parent[r]
            label[i] = r
    return label


@numba.njit(cache=True, inline="always")
def _gain(s, work, quad, coef, a, gn, ids, n):
    """An island's energy change [J] for its impulses scaled by ``s`` (``no_gain_scales``)."""
    lift = 0.0
    for j in range(n):
        i = ids[j]
        lift += coef[i] * min(max(s * a[i], 0.0), gn[i])
    return s * work + 0.5 * s * s * quad - lift


@numba.njit(cache=True)
def no_gain_scales(dV, V0, body, other, off, size, mass, R, inertia, shift, lifted, exempt):
    """The no-gain factor of every body's impulses (see ``_solid_stage._solve``): per island (``island_labels`` of
    the contacts ``body``, ``other``) the largest s in [0, 1] with ``f(s) <= 0``, ``f(s) = s work + s^2 quad / 2 -
    sum_b m_b |g_b dt| / 2 min(max(s a_b, 0), |g_b dt|)`` (``work``, ``quad`` as ``_kernels.modal_energy_change``
    over the island's bodies, summed in the same order; ``a_b`` body b's dv against gravity; the lift term only for
    ``lifted`` bodies); 1 when ``f(1) <= 1e-12 quad``, and for islands holding an ``exempt`` body (a moving obstacle
    touches it) or bodies without contact.

    f is convex and piecewise quadratic with a break where a body's lift reaches its cap (``s a_b = |g_b dt|``):
    the breaks in (0, 1) are sorted, f is evaluated at each to find the piece where it turns positive, and that
    piece's quadratic is solved (the root taken back, if rounding left f > 0 there, to where f <= 0 as evaluated).

    Args: dV, V0: the solve's velocity change and start velocities; off, size, mass, R, inertia, shift: per body as
    ``_SolidStage._inverse_mass_blocks``; lifted, exempt: (m,) bool. Returns (m,) factors."""
    m = off.shape[0]
    label = island_labels(body, other, m)
    work = np.zeros(m)
    quad = np.zeros(m)
    Iw = np.empty((3, 3))
    for i in range(m):  # as modal_energy_change, accumulated per island in body order
        r = label[i]
        if r < 0:
            continue
        o = off[i]
        mi = mass[i]
        for x in range(3):
            for y in range(3):
                s = 0.0
                for c in range(3):
                    for d in range(3):
                        s += R[i, x, c] * inertia[i, c, d] * R[i, y, d]
                Iw[x, y] = s
        for x in range(3):
            work[r] += mi * dV[o + x] * (V0[o + x] - shift[i, x])
            quad[r] += mi * dV[o + x] * dV[o + x]
        for x in range(3):
            s0 = 0.0
            s1 = 0.0
            for y in range(3):
                s0 += Iw[x, y] * V0[o + 3 + y]
                s1 += Iw[x, y] * dV[o + 3 + y]
            work[r] += dV[o + 3 + x] * s0
            quad[r] += dV[o + 3 + x] * s1
        for j in range(o + 6, o + size[i]):
            work[r] += dV[j] * V0[j]
            quad[r] += dV[j] * dV[j]
    gn = np.empty(m)
    a = np.zeros(m)
    coef = np.zeros(m)
    for i in range(m):
        gn[i] = math.sqrt(shift[i, 0] ** 2 + shift[i, 1] ** 2 + shift[i, 2] ** 2)
        if gn[i] > 0.0:
            a[i] = -(dV[off[i]] * shift[i, 0] + dV[off[i] + 1] * shift[i, 1] + dV[off[i] + 2] * shift[i, 2]) / gn[i]
            if lifted[i]:
                coef[i] = mass[i] * gn[i] * 0.5
    skip = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        if label[i] >= 0 and exempt[i]:
            skip[label[i]] = True
    scale = np.ones(m)
    ids = np.empty(m, dtype=np.int64)
    brk = np.empty(m + 1)
    for r in range(m):
        if label[r] != r or skip[r]:
            continue
        n = 0
        for i in range(r, m):
            if label[i] == r:
                ids[n] = i
                n += 1
        w, qd = work[r], quad[r]
        if _gain(1.0, w, qd, coef, a, gn, ids, n) <= 1e-12 * qd:
            continue
        nb = 0
        for j in range(n):  # the breaks in (0, 1)
            i = ids[j]
            if coef[i] > 0.0 and a[i] > gn[i]:  # s a_b = |g_b dt| at s = gn / a in (0, 1)
                brk[nb] = gn[i] / a[i]
                nb += 1
        brk[nb] = 1.0
        b = np.sort(brk[:nb + 1])
        lo = 0.0  # f(lo) <= 0 (f(0) = 0); find the first break where f > 0 (f(1) > 0)
        hi = 1.0
        for k in range(nb + 1):
            if _gain(b[k], w, qd, coef, a, gn, ids, n) > 0.0:
                hi = b[k]
                break
            lo = b[k]
        # on (lo, hi) no cap switches: f(s) = A s^2 + B s + C, with the bodies capped at the middle
        mid = 0.5 * (lo + hi)
        B = w
        C = 0.0
        for j in range(n):
            i = ids[j]
            if coef[i] > 0.0 and mid * a[i] > 0.0:
                if mid * a[i] >= gn[i]:
                    C -= coef[i] * gn[i]
                else:
                    B -= coef[i] * a[i]
        A = 0.5 * qd
        if A > 0.0:
            disc = B * B - 4.0 * A * C
            sq = math.sqrt(max(disc, 0.0))
            # the larger root (f turns positive there), without cancellation
            s = (-B + sq) / (2.0 * A) if B <= 0.0 else (2.0 * C) / (-B - sq)
        elif B != 0.0:
            s = -C / B
        else:
            s = lo
        s = min(max(s, lo), hi)
        step = 4e-16 * max(s, 1e-300)
        for _ in range(64):  # rounding: step back until f(s) <= 0 as evaluated (f(lo) <= 0)
            if s <= lo or _gain(s, w, qd, coef, a, gn, ids, n) <= 0.0:
                break
            s = max(lo, s - step)
            step *= 2.0
        for j in range(n):
            scale[ids[j]] = s
    return scale
