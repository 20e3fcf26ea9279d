"""Compiled kernels of modal-body contact (numba ``njit(cache=True)``): obstacle distances, contact
candidates, per-contact Jacobian rows and the matrix-free sequential-impulse solve.

Generalised velocities. Body b has ``m_b = 6 + r_b`` generalised velocities V_b = (v, w, qdot)
[m/s, rad/s, sqrt(kg) m/s] with kinetic energy ``0.5 V^T W^-1 V``, ``W = diag(I/m, Iw^-1, I_r)``
(mass-normalised modes). All bodies' V are stacked in one vector with offsets ``off[b]``. The world
velocity of a surface vertex j of body b is ``J_j V_b`` with the (3, m_b) row block
``J_j = [I, -[r_j]x, R Phi_j]`` (r_j from the centre of mass to the deformed vertex, world; the modal
columns zero when the contact does not excite the modes). A contact i couples side a (body ``ba[i]``)
and side b (body ``bb[i]``, or -1 for a static obstacle): relative velocity ``u_i = J_a V_a - J_b V_b``
and an impulse ``lambda`` (3,) [N s] acting on a (+) and b (-) changes ``V_a += W_a J_a^T lambda``,
``V_b -= W_b J_b^T lambda``. Rows ``J`` and ``WJ = W J^T`` are formed once per solve (O(m) each);
an iteration costs O(m) per contact; no contacts x contacts matrix is ever formed.

Obstacles are encoded as ``(kind, params)``: kind 0 a plane (normal 0:3, offset 3), 1 a sphere
(center 0:3, radius 3), 2 a box (center 0:3, half extents 3:6, rotation box -> world 6:15, row-major).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.collision._distance_kernels import point_triangle_closest
from modalfem.runtime.obstacles import BOX, PARAMS, PLANE, SPHERE  # noqa: F401 (PARAMS re-exported)


@numba.njit(cache=True, inline="always")
def _signed(kind, p, x0, x1, x2):
    """Gap [m] (negative inside) and outward normal of one obstacle at the point (x0, x1, x2)."""
    if kind == PLANE:
        return x0 * p[0] + x1 * p[1] + x2 * p[2] - p[3], p[0], p[1], p[2]
    if kind == SPHERE:
        d0, d1, d2 = x0 - p[0], x1 - p[1], x2 - p[2]
        r = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if r > 0.0:
            return r - p[3], d0 / r, d1 / r, d2 / r
        return -p[3], 0.0, 0.0, 1.0
    # box: local coordinates l = R^T (x - c)
    d0, d1, d2 = x0 - p[0], x1 - p[1], x2 - p[2]
    l0 = p[6] * d0 + p[9] * d1 + p[12] * d2
    l1 = p[7] * d0 + p[10] * d1 + p[13] * d2
    l2 = p[8] * d0 + p[11] * d1 + p[14] * d2
    q0, q1, q2 = abs(l0) - p[3], abs(l1) - p[4], abs(l2) - p[5]
    s0 = -1.0 if l0 < 0 else 1.0
    s1 = -1.0 if l1 < 0 else 1.0
    s2 = -1.0 if l2 < 0 else 1.0
    o0, o1, o2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
    dout = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
    if dout > 0.0:
        n0, n1, n2 = s0 * o0 / dout, s1 * o1 / dout, s2 * o2 / dout
        gap = dout
    else:
        n0 = n1 = n2 = 0.0
        if q0 >= q1 and q0 >= q2:
            n0, gap = s0, q0
        elif q1 >= q2:
            n1, gap = s1, q1
        else:
            n2, gap = s2, q2
    w0 = p[6] * n0 + p[7] * n1 + p[8] * n2
    w1 = p[9] * n0 + p[10] * n1 + p[11] * n2
    w2 = p[12] * n0 + p[13] * n1 + p[14] * n2
    return gap, w0, w1, w2


@numba.njit(cache=True)
def signed_distances(kind, params, x):
    """Gaps (k,) [m] and normals (k, 3) of points x (k, 3) [m] against one obstacle."""
    k = x.shape[0]
    gap = np.empty(k)
    nrm = np.empty((k, 3))
    for i in range(k):
        g, a, b, c = _signed(kind, params, x[i, 0], x[i, 1], x[i, 2])
        gap[i] = g
        nrm[i, 0], nrm[i, 1], nrm[i, 2] = a, b, c
    return gap, nrm


@numba.njit(cache=True)
def _rigid_gaps(kind, p, rest, R, c, out):
    """Gaps (nv,) [m] of the rigid positions ``c + R X_j`` against one obstacle (written into ``out``)."""
    nv = rest.shape[0]
    if kind == PLANE:
        # gap = n . (c + R X) - d = (R^T n) . X + (n . c - d): one dot per vertex
        a0 = R[0, 0] * p[0] + R[1, 0] * p[1] + R[2, 0] * p[2]
        a1 = R[0, 1] * p[0] + R[1, 1] * p[1] + R[2, 1] * p[2]
        a2 = R[0, 2] * p[0] + R[1, 2] * p[1] + R[2, 2] * p[2]
        base = c[0] * p[0] + c[1] * p[1] + c[2] * p[2] - p[3]
        for j in range(nv):
            out[j] = base + a0 * rest[j, 0] + a1 * rest[j, 1] + a2 * rest[j, 2]
        return
    for j in range(nv):
        x0 = c[0] + R[0, 0] * rest[j, 0] + R[0, 1] * rest[j, 1] + R[0, 2] * rest[j, 2]
        x1 = c[1] + R[1, 0] * rest[j, 0] + R[1, 1] * rest[j, 1] + R[1, 2] * rest[j, 2]
        x2 = c[2] + R[2, 0] * rest[j, 0] + R[2, 1] * rest[j, 1] + R[2, 2] * rest[j, 2]
        g, _, _, _ = _signed(kind, p, x0, x1, x2)
        out[j] = g


@numba.njit(cache=True)
def candidates(kinds, params, rest, R, c, bound, margins):
    """Vertices that may be within ``margins[o]`` [m] of obstacle o.

    The rigid position ``c + R X_j`` of every vertex is tested against each obstacle with the margin
    grown by ``bound`` [m], an upper bound of the deformation ``|Phi_j q|`` of any vertex, so no vertex
    closer than the margin is missed. Returns ``(vertex, obstacle)`` (p,) int64 arrays, obstacle-major.
    """
    nv = rest.shape[0]
    no = kinds.shape[0]
    g = np.empty((no, nv))
    n = 0
    for o in range(no):
        _rigid_gaps(kinds[o], params[o], rest, R, c, g[o])
        lim = margins[o] + bound
        for j in range(nv):
            if g[o, j] < lim:
                n += 1
    vs = np.empty(n, dtype=np.int64)
    os_ = np.empty(n, dtype=np.int64)
    n = 0
    for o in range(no):
        lim = margins[o] + bound
        for j in range(nv):
            if g[o, j] < lim:
                vs[n] = j
                os_[n] = o
                n += 1
    return vs, os_


@numba.njit(cache=True)
def local_positions(vertex, rest, vm, q, skip):
    """Deformed positions ``X_j + Phi_j q`` (k, 3) [m] of vertices in body axes from the vertex-major shapes
    ``vm`` (nv, r, 3), float64 sums (modes
    with ``skip[i]`` True left out: their contribution is below any physical size)."""
    k = vertex.shape[0]
    r = q.shape[0]
    out = np.empty((k, 3))
    for i in range(k):
        j = vertex[i]
        a0, a1, a2 = 0.0, 0.0, 0.0
        for m in range(r):
            if skip[m]:
                continue
            qm = q[m]
            a0 += float(vm[j, m, 0]) * qm
            a1 += float(vm[j, m, 1]) * qm
            a2 += float(vm[j, m, 2]) * qm
        out[i, 0] = a0 + rest[j, 0]
        out[i, 1] = a1 + rest[j, 1]
        out[i, 2] = a2 + rest[j, 2]
    return out


@numba.njit(cache=True)
def world_positions(local, R, c):
    """``c + R x`` (k, 3) for body-axes points x (k, 3)."""
    k = local.shape[0]
    out = np.empty((k, 3))
    for i in range(k):
        x0, x1, x2 = local[i, 0], local[i, 1], local[i, 2]
        for a in range(3):
            out[i, a] = c[a] + R[a, 0] * x0 + R[a, 1] * x1 + R[a, 2] * x2
    return out


@numba.njit(cache=True)
def gaps_of(vertex_world, obstacle, kinds, params):
    """Gaps (k,) [m] and normals (k, 3) of points (k, 3) [m], each against its own obstacle."""
    k = vertex_world.shape[0]
    gap = np.empty(k)
    nrm = np.empty((k, 3))
    for i in range(k):
        o = obstacle[i]
        g, a, b, cc = _signed(kinds[o], params[o], vertex_world[i, 0], vertex_world[i, 1], vertex_world[i, 2])
        gap[i] = g
        nrm[i, 0], nrm[i, 1], nrm[i, 2] = a, b, cc
    return gap, nrm


@numba.njit(cache=True)
def rows(vertex, local, modal, vm, R, mass, Iw_inv, m, J, WJ, col):
    """Fill the Jacobian rows of one body's contact side (see the module docstring).

    Args:
        vertex: (k,) surface vertex indices.
        local: (k, 3) deformed positions relative to the centre of mass [m], body axes.
        modal: (k,) bool, include the modal columns.
        vm: (nv, r, 3) mode shapes [m/sqrt(kg)], body axes, vertex-major (``contact.vertex_modes``).
        R: (3, 3) body -> world; mass [kg]; Iw_inv (3, 3) world inverse inertia [1/(kg m^2)].
        m: 6 + r (columns used).
        J, WJ: (K, 3, M) outputs, rows ``col[i]`` written (M >= m; the rest of the row zeroed).
        col: (k,) row indices into J / WJ.
    """
    k = vertex.shape[0]
    r = m - 6
    for i in range(k):
        ci = col[i]
        j = vertex[i]
        x0, x1, x2 = local[i, 0], local[i, 1], local[i, 2]
        r0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2
        r1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2
        r2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2
        Jr = J[ci]
        Wr = WJ[ci]
        Jr[:, :] = 0.0
        Wr[:, :] = 0.0
        # linear part
        Jr[0, 0] = 1.0
        Jr[1, 1] = 1.0
        Jr[2, 2] = 1.0
        # w x r = -[r]x w: rows of -[r]x
        Jr[0, 4], Jr[0, 5] = r2, -r1
        Jr[1, 3], Jr[1, 5] = -r2, r0
        Jr[2, 3], Jr[2, 4] = r1, -r0
        if modal[i]:
            for mm in range(r):
                p0 = float(vm[j, mm, 0])
                p1 = float(vm[j, mm, 1])
                p2 = float(vm[j, mm, 2])
                Jr[0, 6 + mm] = R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2
                Jr[1, 6 + mm] = R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2
                Jr[2, 6 + mm] = R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2
        # W J^T (stored as rows like J): linear / mass, angular rows times Iw^-1 (symmetric), modal as is
        for a in range(3):
            Wr[a, 0] = Jr[a, 0] / mass
            Wr[a, 1] = Jr[a, 1] / mass
            Wr[a, 2] = Jr[a, 2] / mass
            for b in range(3):
                Wr[a, 3 + b] = Jr[a, 3] * Iw_inv[0, b] + Jr[a, 4] * Iw_inv[1, b] + Jr[a, 5] * Iw_inv[2, b]
            for mm in range(6, m):
                Wr[a, mm] = Jr[a, mm]


@numba.njit(cache=True, inline="always")
def _velocity(Jr, V, o, m, out):
    for a in range(3):
        s = 0.0
        for c in range(m):
            s += Jr[a, c] * V[o + c]
        out[a] = s


@numba.njit(cache=True)
def contact_velocities(ba, bb, J, Jb, V, off, msz):
    """Relative world velocities (k, 3) [m/s] of the contacts: ``J_a V_a - J_b V_b``."""
    k = ba.shape[0]
    out = np.zeros((k, 3))
    t = np.empty(3)
    for i in range(k):
        _velocity(J[i], V, off[ba[i]], msz[ba[i]], t)
        out[i, 0], out[i, 1], out[i, 2] = t[0], t[1], t[2]
        if bb[i] >= 0:
            _velocity(Jb[i], V, off[bb[i]], msz[bb[i]], t)
            out[i, 0] -= t[0]
            out[i, 1] -= t[1]
            out[i, 2] -= t[2]
    return out


@numba.njit(cache=True)
def _uniform_guess(ba, bb, J, WJ, Jb, WJb, V, off, msz, n, target, shift, lam, lam_n):
    """Initial normal impulses: one common value at every contact, the one that meets the contacts' mean
    normal target (found matrix-free by applying a unit impulse at every contact once), if positive.
    For a body resting or sliding on a face (many coplanar contacts sharing the load) this is close to
    the solution, so the sweeps that follow converge in a few passes instead of dozens."""
    k = ba.shape[0]
    dV = np.zeros(V.shape[0])
    for i in range(k):
        oa = off[ba[i]]
        for c in range(msz[ba[i]]):
            dV[oa + c] += WJ[i, 0, c] * n[i, 0] + WJ[i, 1, c] * n[i, 1] + WJ[i, 2, c] * n[i, 2]
        if bb[i] >= 0:
            ob = off[bb[i]]
            for c in range(msz[bb[i]]):
                dV[ob + c] -= WJb[i, 0, c] * n[i, 0] + WJb[i, 1, c] * n[i, 1] + WJb[i, 2, c] * n[i, 2]
    u = np.empty(3)
    t = np.empty(3)
    resid = 0.0
    slope = 0.0
    for i in range(k):
        _velocity(J[i], V, off[ba[i]], msz[ba[i]], u)
        _velocity(J[i], dV, off[ba[i]], msz[ba[i]], t)
        vn = n[i, 0] * (u[0] + shift[i, 0]) + n[i, 1] * (u[1] + shift[i, 1]) + n[i, 2] * (u[2] + shift[i, 2])
        dn = n[i, 0] * t[0] + n[i, 1] * t[1] + n[i, 2] * t[2]
        if bb[i] >= 0:
            _velocity(Jb[i], V, off[bb[i]], msz[bb[i]], u)
            _velocity(Jb[i], dV, off[bb[i]], msz[bb[i]], t)
            vn -= n[i, 0] * u[0] + n[i, 1] * u[1] + n[i, 2] * u[2]
            dn -= n[i, 0] * t[0] + n[i, 1] * t[1] + n[i, 2] * t[2]
        resid += target[i] - vn
        slope += dn
    if not (slope > 0.0) or not (resid > 0.0):
        return
    g = resid / slope
    for c in range(V.shape[0]):
        V[c] += g * dV[c]
    for i in range(k):
        lam_n[i] = g
        lam[i, 0] = g * n[i, 0]
        lam[i, 1] = g * n[i, 1]
        lam[i, 2] = g * n[i, 2]


@numba.njit(cache=True)
def solve(ba, bb, J, WJ, Jb, WJb, V, off, msz, n, target, mu, shift, iters, lam, jt, lam_n, guess=False):
    """Sequential impulses (projected Gauss-Seidel) over the contacts, in place on V.

    Per contact i and sweep: the relative velocity ``u = J_a V_a - J_b V_b + shift_i`` (shift: a
    velocity the solve must also see, e.g. the rest of a step's load), the normal impulse towards
    ``n . u = target_i`` clamped to >= 0 (accumulated), then friction: the tangential impulse that
    stops the sliding with the scalar effective mass along it, accumulated and clamped to the
    Coulomb disc ``|jt| <= mu_i lam_n``; V changes by ``W J^T delta`` on each side. The 3 x 3
    effective-mass blocks ``A_ii = J W J^T`` (both sides summed) are formed once. Stops after ``iters``
    sweeps or when a sweep changes no impulse by more than 1e-12 of the largest.

    Args:
        ba, bb: (k,) body of each side (bb -1: static obstacle).
        J, WJ, Jb, WJb: (k, 3, M) rows of sides a and b (``Jb`` unused where bb < 0).
        V: stacked generalised velocities (changed in place).
        off, msz: (bodies,) offsets into V and sizes m_b.
        n: (k, 3) contact normals (pointing from b to a). target: (k,) [m/s]. mu: (k,) friction.
        shift: (k, 3) [m/s]. iters: sweeps.
        lam: (k, 3) total impulses [N s] (out); jt: (k, 3) friction impulses (out); lam_n (k,) normal.
        guess: start from ``_uniform_guess`` instead of zero impulses.

    Returns:
        the number of sweeps done.
    """
    k = ba.shape[0]
    if guess and k > 1:
        _uniform_guess(ba, bb, J, WJ, Jb, WJb, V, off, msz, n, target, shift, lam, lam_n)
    A = np.zeros((k, 3, 3))
    for i in range(k):
        ma = msz[ba[i]]
        for a in range(3):
            for b in range(3):
                s = 0.0
                for c in range(ma):
                    s += J[i, a, c] * WJ[i, b, c]
                if bb[i] >= 0:
                    mb = msz[bb[i]]
                    for c in range(mb):
                        s += Jb[i, a, c] * WJb[i, b, c]
                A[i, a, b] = s
    Wn = np.empty(k)
    for i in range(k):
        s = 0.0
        for a in range(3):
            for b in range(3):
                s += n[i, a] * A[i, a, b] * n[i, b]
        Wn[i] = s
    u = np.empty(3)
    t = np.empty(3)
    d = np.empty(3)
    for sweep in range(iters):
        change = 0.0
        big = 0.0
        for i in range(k):
            oa = off[ba[i]]
            ma = msz[ba[i]]
            _velocity(J[i], V, oa, ma, u)
            b_ = bb[i]
            if b_ >= 0:
                _velocity(Jb[i], V, off[b_], msz[b_], t)
                u[0] -= t[0]
                u[1] -= t[1]
                u[2] -= t[2]
            u[0] += shift[i, 0]
            u[1] += shift[i, 1]
            u[2] += shift[i, 2]
            n0, n1, n2 = n[i, 0], n[i, 1], n[i, 2]
            vn = n0 * u[0] + n1 * u[1] + n2 * u[2]
            new = lam_n[i] + (target[i] - vn) / Wn[i]
            new = max(new, 0.0)
            dn = new - lam_n[i]
            lam_n[i] = new
            d[0], d[1], d[2] = dn * n0, dn * n1, dn * n2
            if mu[i] > 0.0:
                # velocity after the normal update: u + A d
                ui0 = u[0] + A[i, 0, 0] * d[0] + A[i, 0, 1] * d[1] + A[i, 0, 2] * d[2]
                ui1 = u[1] + A[i, 1, 0] * d[0] + A[i, 1, 1] * d[1] + A[i, 1, 2] * d[2]
                ui2 = u[2] + A[i, 2, 0] * d[0] + A[i, 2, 1] * d[1] + A[i, 2, 2] * d[2]
                un = n0 * ui0 + n1 * ui1 + n2 * ui2
                ut0, ut1, ut2 = ui0 - n0 * un, ui1 - n1 * un, ui2 - n2 * un
                speed = math.sqrt(ut0 * ut0 + ut1 * ut1 + ut2 * ut2)
                c0, c1, c2 = jt[i, 0], jt[i, 1], jt[i, 2]
                if speed > 0.0:
                    t0, t1, t2 = ut0 / speed, ut1 / speed, ut2 / speed
                    tat = 0.0
                    tv = (t0, t1, t2)
                    for a in range(3):
                        for b in range(3):
                            tat += tv[a] * A[i, a, b] * tv[b]
                    s = speed / tat
                    c0 -= s * t0
                    c1 -= s * t1
                    c2 -= s * t2
                lim = mu[i] * new
                norm = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                if norm > lim:
                    f = lim / norm
                    c0 *= f
                    c1 *= f
                    c2 *= f
                d[0] += c0 - jt[i, 0]
                d[1] += c1 - jt[i, 1]
                d[2] += c2 - jt[i, 2]
                jt[i, 0], jt[i, 1], jt[i, 2] = c0, c1, c2
            if d[0] != 0.0 or d[1] != 0.0 or d[2] != 0.0:
                lam[i, 0] += d[0]
                lam[i, 1] += d[1]
                lam[i, 2] += d[2]
                for c in range(ma):
                    V[oa + c] += WJ[i, 0, c] * d[0] + WJ[i, 1, c] * d[1] + WJ[i, 2, c] * d[2]
                if b_ >= 0:
                    ob = off[b_]
                    for c in range(msz[b_]):
                        V[ob + c] -= WJb[i, 0, c] * d[0] + WJb[i, 1, c] * d[1] + WJb[i, 2, c] * d[2]
                for a in range(3):
                    ad = abs(d[a])
                    change = max(change, ad)
        for i in range(k):
            for a in range(3):
                al = abs(lam[i, a])
                big = max(big, al)
        if change <= 1e-12 * big:
            return sweep + 1
    return iters



@numba.njit(cache=True)
def normal_velocities(vertex, local, modal, vm, R, nm, n, v, w, qdot):
    """``n . (J_j V)`` (k,) [m/s] of one body's contact vertices without storing rows: the same products
    summed in the same order as ``rows`` + ``contact_velocities`` (bit-identical but for the sign of a zero:
    modes with ``qdot`` exactly 0 are skipped), so event decisions are the same whichever computes them (r = R local; modal columns over the first ``nm`` modes where
    ``modal``)."""
    k = vertex.shape[0]
    out = np.empty(k)
    jr = np.empty((3, 6))
    moving = np.empty(nm, dtype=np.int64)  # modes with qdot != 0 (the others add an exact zero)
    nmv = 0
    for mm in range(nm):
        if qdot[mm] != 0.0:
            moving[nmv] = mm
            nmv += 1
    for i in range(k):
        x0, x1, x2 = local[i, 0], local[i, 1], local[i, 2]
        r0 = R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2
        r1 = R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2
        r2 = R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2
        jr[:, :] = 0.0
        jr[0, 0] = 1.0
        jr[1, 1] = 1.0
        jr[2, 2] = 1.0
        jr[0, 4], jr[0, 5] = r2, -r1
        jr[1, 3], jr[1, 5] = -r2, r0
        jr[2, 3], jr[2, 4] = r1, -r0
        j = vertex[i]
        u0 = 0.0
        u1 = 0.0
        u2 = 0.0
        for c in range(3):
            u0 += jr[0, c] * v[c]
            u1 += jr[1, c] * v[c]
            u2 += jr[2, c] * v[c]
        for c in range(3):
            u0 += jr[0, 3 + c] * w[c]
            u1 += jr[1, 3 + c] * w[c]
            u2 += jr[2, 3 + c] * w[c]
        for t in range(nmv):
            mm = moving[t]
            if modal[i]:
                p0 = float(vm[j, mm, 0])
                p1 = float(vm[j, mm, 1])
                p2 = float(vm[j, mm, 2])
                u0 += (R[0, 0] * p0 + R[0, 1] * p1 + R[0, 2] * p2) * qdot[mm]
                u1 += (R[1, 0] * p0 + R[1, 1] * p1 + R[1, 2] * p2) * qdot[mm]
                u2 += (R[2, 0] * p0 + R[2, 1] * p1 + R[2, 2] * p2) * qdot[mm]
            else:
                u0 += 0.0 * qdot[mm]
                u1 += 0.0 * qdot[mm]
                u2 += 0.0 * qdot[mm]
        out[i] = n[i, 0] * u0 + n[i, 1] * u1 + n[i, 2] * u2
    return out


@numba.njit(cache=True)
def closest_triangles(p, qi, tri, X, T, tie_rel):
    """The closest triangle of a deformed surface per query point, from BVH candidate pairs.

    Args:
        p: (n, 3) query points [m] (world). qi, tri: (P,) candidate pairs (query index, triangle).
        X: (nv, 3) the surface's vertices [m] (world); T: (nt, 3) its outward triangles.
        tie_rel: relative distance within which two triangles tie (a shared edge or corner).

    Returns:
        ``(best, bary, gap, normal)``: (n,) triangle index (-1: no candidate), (n, 3) barycentric weights of
        the closest point, (n,) signed distance [m] (negative inside: behind the closest triangle's face;
        where triangles tie the point is outside if one of them says so, as a face normal alone misjudges
        points beside an edge), (n, 3) unit normal pointing out of the surface (from the closest point to
        the point when outside and apart, else the face normal).
    """
    n = p.shape[0]
    best = np.full(n, -1, dtype=np.int64)
    dbest = np.full(n, np.inf)
    sbest = np.zeros(n)
    bary = np.zeros((n, 3))
    x = np.empty((4, 3))
    w = np.empty(3)
    for k in range(qi.shape[0]):
        i = qi[k]
        t = tri[k]
        a, b, c = T[t, 0], T[t, 1], T[t, 2]
        for d in range(3):
            x[0, d] = p[i, d]
            x[1, d] = X[a, d]
            x[2, d] = X[b, d]
            x[3, d] = X[c, d]
        dist = point_triangle_closest(x, w)
        f0 = (x[2, 1] - x[1, 1]) * (x[3, 2] - x[1, 2]) - (x[2, 2] - x[1, 2]) * (x[3, 1] - x[1, 1])
        f1 = (x[2, 2] - x[1, 2]) * (x[3, 0] - x[1, 0]) - (x[2, 0] - x[1, 0]) * (x[3, 2] - x[1, 2])
        f2 = (x[2, 0] - x[1, 0]) * (x[3, 1] - x[1, 1]) - (x[2, 1] - x[1, 1]) * (x[3, 0] - x[1, 0])
        side = 0.0
        for d in range(3):
            q = w[0] * x[1, d] + w[1] * x[2, d] + w[2] * x[3, d]
            side += (p[i, d] - q) * (f0 if d == 0 else (f1 if d == 1 else f2))
        cur = dbest[i]
        if dist < cur * (1.0 - tie_rel) - 1e-300:
            take = True
        elif dist <= cur * (1.0 + tie_rel) + 1e-300:  # a tie: prefer a triangle that says outside
            take = side >= 0.0 and sbest[i] < 0.0
        else:
            take = False
        if take:
            best[i] = t
            dbest[i] = min(dist, cur)
            sbest[i] = side
            bary[i, 0], bary[i, 1], bary[i, 2] = w[0], w[1], w[2]
    gap = np.zeros(n)
    normal = np.zeros((n, 3))
    for i in range(n):
        t = best[i]
        if t < 0:
            continue
        a, b, c = T[t, 0], T[t, 1], T[t, 2]
        f0 = (X[b, 1] - X[a, 1]) * (X[c, 2] - X[a, 2]) - (X[b, 2] - X[a, 2]) * (X[c, 1] - X[a, 1])
        f1 = (X[b, 2] - X[a, 2]) * (X[c, 0] - X[a, 0]) - (X[b, 0] - X[a, 0]) * (X[c, 2] - X[a, 2])
        f2 = (X[b, 0] - X[a, 0]) * (X[c, 1] - X[a, 1]) - (X[b, 1] - X[a, 1]) * (X[c, 0] - X[a, 0])
        fl = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        if fl > 0.0:
            f0, f1, f2 = f0 / fl, f1 / fl, f2 / fl
        d = dbest[i]
        if sbest[i] >= 0.0:
            gap[i] = d
            if d > 0.0:
                for k in range(3):
                    q = bary[i, 0] * X[a, k] + bary[i, 1] * X[b, k] + bary[i, 2] * X[c, k]
                    normal[i, k] = (p[i, k] - q) / d
                continue
        else:
            gap[i] = -d
        normal[i, 0], normal[i, 1], normal[i, 2] = f0, f1, f2
    return best, bary, gap, normal
