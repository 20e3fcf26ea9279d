"""Compiled assembly of a step's modal contacts into the entries of the solid solve (numba, cached on disk).

``assemble`` takes what the searches found (vertices on static planes: ``_solid_kernels.plane_contacts``; vertices
on triangles and edges on edges between bodies: ``_coherent_kernels.coherent_pairs``) and writes, in one call and
without a numpy pass per array, every contact's touching features, world points, normal, gap, friction,
restitution and margin, its warm-start key and last impulse, and its entries in the layout of
``modalfem.world._kernels`` (a body's block of ``6 + r`` velocities ``(v, w, qdot)`` per side, J and W J^T) with
its 3 x 3 effective inverse mass. Each side's rigid lever arm sits at one world point for both sides when the
contact is within its margin, so its impulse conserves linear and angular momentum to rounding.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.world._kernels import effective_masses


#: contact kinds in the warm-start keys
VF, EE, PLANE = 0, 1, 2
#: feature indices (a vertex; an edge pair, mine * (other body's edge count) + other) sit below this in a key
FEATURES = 1 << 40


@numba.njit(cache=True)
def _side_modes(c, body, verts, wts, sign, R, nm, nuse, phi_off, phi, mask_off, mask, J, WJt, jbase, n):
    """The modal columns of contact c's entry for ``body`` (``_rows``; n = 6 + nuse[body] velocities from ``jbase``):
    ``sign R Phi`` at the point ``sum_j wts[c, j] verts[c, j]``, the fast modes (``mask`` 0) zero. Called only when
    a mode takes part (rarely at millisecond steps, where the stiff bodies' modes are all faster than the step)."""
    r = nm[body]
    base = phi_off[body]
    for mo in range(nuse[body]):
        p0 = p1 = p2 = 0.0
        if mask[mask_off[body] + mo]:
            for q in range(verts.shape[1]):
                wq = wts[c, q]
                if wq == 0.0:
                    continue
                o = base + (verts[c, q] * 3) * r + mo
                p0 += wq * phi[o]
                p1 += wq * phi[o + r]
                p2 += wq * phi[o + 2 * r]
        for a in range(3):
            v = sign * (R[body, a, 0] * p0 + R[body, a, 1] * p1 + R[body, a, 2] * p2)
            J[jbase + a * n + 6 + mo] = v
            WJt[jbase + (6 + mo) * 3 + a] = v


@numba.njit(cache=True)
def _rows(body_a, verts_a, w_a, body_b, verts_b, w_b, point, point_b, R, Iw_inv, pos, mass, nm, phi_off, phi,
          mask_off, mask, vel_off):
    """Entries ``(ptr, off, nd, jptr, J, WJt)`` of k contacts between modal bodies (``body_b`` -1: a static
    obstacle, one entry) and their effective inverse masses K (k, 3, 3) [1/kg] (``_kernels.effective_masses``'s
    sums); a body's entries span its ``6 + m`` first velocities, m the last mode taking part (``mask``) plus one."""
    k = body_a.shape[0]
    # a body's entries cover its modes up to the last one taking part: the modes after it (the fast ones, when the
    # modes rise in frequency) would only add zero columns to J, and every sweep of the solve reads them
    nuse = np.zeros(nm.shape[0], dtype=np.int64)
    for b in range(nm.shape[0]):
        for mo in range(nm[b]):
            if mask[mask_off[b] + mo]:
                nuse[b] = mo + 1
    ne = 0
    jl = 0
    for c in range(k):
        ne += 1
        jl += 3 * (6 + nuse[body_a[c]])
        if body_b[c] >= 0:
            ne += 1
            jl += 3 * (6 + nuse[body_b[c]])
    ptr = np.empty(k + 1, dtype=np.int64)
    off = np.empty(ne, dtype=np.int64)
    nd = np.empty(ne, dtype=np.int64)
    jptr = np.empty(ne, dtype=np.int64)
    J = np.empty(jl)
    WJt = np.empty(jl)
    e = 0
    jb = 0
    ptr[0] = 0
    # each side's entries written here, and K by one call after the loop, not by helpers taking ~20 and 7 arrays per
    # side and contact (called or inlined by numba, they were most of the assembly's time: pile of 20, 2,522
    # contacts, Intel Xeon, one process, alternating calls: 1.40-1.91 -> 0.59-0.76 ms, the same arrays bit for bit)
    for c in range(k):
        for side in range(2):
            body = body_a[c] if side == 0 else body_b[c]
            if body < 0:
                break
            sign = 1.0 if side == 0 else -1.0
            # entry e: body's block (6 + nuse) at the world point point[c] (a) / point_b[c] (b), the modal part at
            # sum_j w[c, j] verts[c, j]; S = [r]x; J rows: (I, -S, R Phi); W J^T rows: (I / m, Iw^-1 S, (R Phi)^T)
            n = 6 + nuse[body]
            off[e] = vel_off[body]
            nd[e] = n
            jptr[e] = jb
            if side == 0:
                r0, r1, r2 = point[c, 0] - pos[body, 0], point[c, 1] - pos[body, 1], point[c, 2] - pos[body, 2]
            else:
                r0, r1, r2 = point_b[c, 0] - pos[body, 0], point_b[c, 1] - pos[body, 1], point_b[c, 2] - pos[body, 2]
            im = 1.0 / mass[body]
            for a in range(3):
                # column a of S
                if a == 0:
                    c0, c1, c2 = 0.0, r2, -r1
                elif a == 1:
                    c0, c1, c2 = -r2, 0.0, r0
                else:
                    c0, c1, c2 = r1, -r0, 0.0
                for j in range(3):
                    J[jb + a * n + j] = sign if a == j else 0.0
                    WJt[jb + j * 3 + a] = sign * im if a == j else 0.0
                    WJt[jb + (3 + j) * 3 + a] = sign * (Iw_inv[body, j, 0] * c0 + Iw_inv[body, j, 1] * c1
                                                        + Iw_inv[body, j, 2] * c2)
                # row a of S is minus column a (S is skew): J's rotational entries -sign S[a, j] = sign c_j
                J[jb + a * n + 3] = sign * c0
                J[jb + a * n + 4] = sign * c1
                J[jb + a * n + 5] = sign * c2
            if nuse[body] > 0:
                if side == 0:
                    _side_modes(c, body, verts_a, w_a, sign, R, nm, nuse, phi_off, phi, mask_off, mask, J, WJt, jb, n)
                else:
                    _side_modes(c, body, verts_b, w_b, sign, R, nm, nuse, phi_off, phi, mask_off, mask, J, WJt, jb, n)
            jb += 3 * n
            e += 1
        ptr[c + 1] = e
    return ptr, off, nd, jptr, J, WJt, effective_masses(ptr, off, nd, jptr, J, WJt)


@numba.njit(cache=True)
def assemble(plane_body, plane_vertex, plane_index, plane_gap, vf_a, vf_b, vf_vertex, vf_tri, vf_w, vf_gap,
             vf_normal, ee_a, ee_b, ee_mine, ee_other, ee_s, ee_t, ee_gap, ee_normal, X, voff, tris, toff, edges, eoff,
             plane_n, margin, friction, restitution, R, Iw_inv, pos, mass, nm, phi_off, phi, mask_off, mask, vel_off,
             solve_index, warm_keys, warm_lam):
    """Every contact of the step, in the order planes, vertex-face, edge-edge, with its solve entries.

    Args:
        plane_body ... plane_gap: (kp,) vertices on static planes (body, vertex, plane, gap [m]).
        vf_a ... vf_normal: (kv,) vertices of body a on triangles of body b: bodies, vertex, triangle, the
            triangle's barycentric weights (kv, 3), gap [m], unit normal (kv, 3) from b towards a.
        ee_a ... ee_normal: (ke,) edges of a on edges of b: bodies, edge indices, parameters s and t along them,
            gap [m], unit normal (ke, 3).
        X: (n, 3) every body's world surface [m], body i's from ``voff[i]``; tris, toff, edges, eoff: the bodies'
            triangles and edges (local vertex ids) and their offsets. plane_n: (P, 3) the planes' normals.
        margin, friction, restitution: (nb,) the bodies' Contact values [m, -, -].
        R, Iw_inv, pos, mass, nm, phi_off, phi, mask_off, mask, vel_off: as ``_rows``. solve_index: (nb,) each
            body's index in the solve. warm_keys, warm_lam: the last step's keys (sorted) and impulses (., 3) [N s].

    Returns:
        ``(ptr, off, nd, jptr, J, WJt, K, normal, gap, mu, e, margin, body, other, point, keys, lam0, body_a,
        verts_a, w_a, body_b, verts_b, w_b)``: the solve's arrays (``body`` / ``other`` as solve indices,
        ``other`` -1 for a plane), the warm-start keys and start impulses, and each side's body (``body_b`` -1
        for a plane), touching vertices (k, 3) and weights (k, 3) (unused slots weight 0).
    """
    kp = plane_body.shape[0]
    kv = vf_a.shape[0]
    ke = ee_a.shape[0]
    k = kp + kv + ke
    nb = voff.shape[0] - 1
    npl = plane_n.shape[0]
    body_a = np.empty(k, dtype=np.int64)
    body_b = np.full(k, -1, dtype=np.int64)
    verts_a = np.zeros((k, 3), dtype=np.int64)
    verts_b = np.zeros((k, 3), dtype=np.int64)
    w_a = np.zeros((k, 3))
    w_b = np.zeros((k, 3))
    point = np.empty((k, 3))
    point_b = np.empty((k, 3))
    normal = np.empty((k, 3))
    gap = np.empty(k)
    keys = np.empty(k, dtype=np.int64)
    for i in range(kp):
        b = plane_body[i]
        v = plane_vertex[i]
        body_a[i] = b
        verts_a[i, 0] = v
        w_a[i, 0] = 1.0
        for d in range(3):
            point[i, d] = X[voff[b] + v, d]
            normal[i, d] = plane_n[plane_index[i], d]
        gap[i] = plane_gap[i]
        keys[i] = ((b * (nb + npl) + nb + plane_index[i]) * 3 + PLANE) * FEATURES + v
    for i in range(kv):
        c = kp + i
        a, b, v = vf_a[i], vf_b[i], vf_vertex[i]
        body_a[c], body_b[c] = a, b
        verts_a[c, 0] = v
        w_a[c, 0] = 1.0
        for j in range(3):
            verts_b[c, j] = tris[toff[b] + vf_tri[i], j]
            w_b[c, j] = vf_w[i, j]
        for d in range(3):
            point[c, d] = X[voff[a] + v, d]
            normal[c, d] = vf_normal[i, d]
        gap[c] = vf_gap[i]
        keys[c] = ((a * (nb + npl) + b) * 3 + VF) * FEATURES + v
    for i in range(ke):
        c = kp + kv + i
        a, b = ee_a[i], ee_b[i]
        body_a[c], body_b[c] = a, b
        s, t = ee_s[i], ee_t[i]
        ea0, ea1 = edges[eoff[a] + ee_mine[i], 0], edges[eoff[a] + ee_mine[i], 1]
        eb0, eb1 = edges[eoff[b] + ee_other[i], 0], edges[eoff[b] + ee_other[i], 1]
        verts_a[c, 0], verts_a[c, 1] = ea0, ea1
        verts_b[c, 0], verts_b[c, 1] = eb0, eb1
        w_a[c, 0], w_a[c, 1] = 1.0 - s, s
        w_b[c, 0], w_b[c, 1] = 1.0 - t, t
        for d in range(3):
            pa = X[voff[a] + ea0, d] * (1.0 - s) + X[voff[a] + ea1, d] * s
            pb = X[voff[b] + eb0, d] * (1.0 - t) + X[voff[b] + eb1, d] * t
            point[c, d] = 0.5 * (pa + pb)
            normal[c, d] = ee_normal[i, d]
        gap[c] = ee_gap[i]
        # the edge pair in the key (an edge may touch several of the other body's edges: one key each)
        keys[c] = ((a * (nb + npl) + b) * 3 + EE) * FEATURES + ee_mine[i] * (eoff[b + 1] - eoff[b]) + ee_other[i]
    mu = np.empty(k)
    e = np.empty(k)
    marg = np.empty(k)
    body = np.empty(k, dtype=np.int64)
    other = np.empty(k, dtype=np.int64)
    for c in range(k):
        a, b = body_a[c], body_b[c]
        body[c] = solve_index[a]
        for d in range(3):
            point_b[c, d] = point[c, d]
        if b < 0:
            other[c] = -1
            mu[c] = friction[a]
            e[c] = restitution[a]
            marg[c] = margin[a]
            continue
        other[c] = solve_index[b]
        mu[c] = math.sqrt(friction[a] * friction[b])
        e[c] = min(restitution[a], restitution[b])
        marg[c] = max(margin[a], margin[b])
        if gap[c] > marg[c]:
            # a speculative contact farther apart than the margin has no friction (it is not touching yet) and acts
            # on b at the foot of a's point on b's tangent plane when that is within the margin of b's closest
            # point (a's point minus a multiple of the normal: the normal impulse's moment is the same at both, so
            # momentum stays exact), else at b's closest point itself (at a's point the far body would be turned
            # about a point off its surface: at dt = 0.1 s bars then tunnelled; the angular momentum then changes
            # by (x_a - x_b) x impulse)
            mu[c] = 0.0
            p0 = p1 = p2 = 0.0
            for j in range(3):
                o = voff[b] + verts_b[c, j]
                p0 += w_b[c, j] * X[o, 0]
                p1 += w_b[c, j] * X[o, 1]
                p2 += w_b[c, j] * X[o, 2]
            h = ((point[c, 0] - p0) * normal[c, 0] + (point[c, 1] - p1) * normal[c, 1]
                 + (point[c, 2] - p2) * normal[c, 2])
            f0 = point[c, 0] - normal[c, 0] * h
            f1 = point[c, 1] - normal[c, 1] * h
            f2 = point[c, 2] - normal[c, 2] * h
            if math.sqrt((f0 - p0) ** 2 + (f1 - p1) ** 2 + (f2 - p2) ** 2) <= margin[a]:
                point_b[c, 0], point_b[c, 1], point_b[c, 2] = f0, f1, f2
            else:
                point_b[c, 0], point_b[c, 1], point_b[c, 2] = p0, p1, p2
    ptr, off, nd, jptr, J, WJt, K = _rows(body_a, verts_a, w_a, body_b, verts_b, w_b, point, point_b, R, Iw_inv, pos,
                                          mass, nm, phi_off, phi, mask_off, mask, vel_off)
    lam0 = np.zeros((k, 3))
    nw = warm_keys.shape[0]
    if nw:
        for c in range(k):
            j = min(np.searchsorted(warm_keys, keys[c]), nw - 1)
            if warm_keys[j] == keys[c]:
                lam0[c, 0], lam0[c, 1], lam0[c, 2] = warm_lam[j, 0], warm_lam[j, 1], warm_lam[j, 2]
    return (ptr, off, nd, jptr, J, WJt, K, normal, gap, mu, e, marg, body, other, point, keys, lam0, body_a, verts_a,
            w_a, body_b, verts_b, w_b)
