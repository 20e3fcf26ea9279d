"""Compiled matrix-free sequential impulses over contacts between any bodies (numba, cached on disk).

Generalised velocities of every body sit in one vector ``V``: a modal body's ``(v, w, qdot)`` (6 + r), a tet
or cloth vertex's velocity (3). Contact ``c`` has entries ``e`` in ``ptr[c]:ptr[c + 1]``, each a block of
``nd[e]`` velocities at ``off[e]`` with its Jacobian ``J_e`` (3 x nd, the contact point's velocity is
``sum_e J_e V_e``, the second body's entries negated) and ``W_e J_e^T`` (nd x 3, W the inverse mass).
An iteration costs O(sum nd) per contact (6 + r for a modal body, 3 per vertex): no contacts x contacts
matrix is ever formed.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def add_effective_mass(K, c, ptr, nd, jptr, J, WJt):
    """Adds contact c's ``sum_e J_e W_e J_e^T`` [1/kg] over its entries ``ptr[c]:ptr[c + 1]`` to ``K[c]`` (3, 3)."""
    for e in range(ptr[c], ptr[c + 1]):
        n = nd[e]
        base = jptr[e]
        for a in range(3):
            for b in range(3):
                s = 0.0
                for j in range(n):
                    s += J[base + a * n + j] * WJt[base + j * 3 + b]
                K[c, a, b] += s


@numba.njit(cache=True)
def effective_masses(ptr, off, nd, jptr, J, WJt):
    """Per contact the 3 x 3 ``K_c = sum_e J_e W_e J_e^T`` [1/kg] (velocity per unit impulse), (k, 3, 3)."""
    k = len(ptr) - 1
    K = np.zeros((k, 3, 3))
    for c in range(k):
        add_effective_mass(K, c, ptr, nd, jptr, J, WJt)
    return K


@numba.njit(cache=True, inline="always")
def _velocity(V, ptr, off, nd, jptr, J, c):
    u0 = u1 = u2 = 0.0
    for e in range(ptr[c], ptr[c + 1]):
        n = nd[e]
        base = jptr[e]
        o = off[e]
        for j in range(n):
            vj = V[o + j]
            u0 += J[base + j] * vj
            u1 += J[base + n + j] * vj
            u2 += J[base + 2 * n + j] * vj
    return u0, u1, u2


@numba.njit(cache=True, inline="always")
def _impulse(V, ptr, off, nd, jptr, WJt, c, d0, d1, d2):
    """``V += W J_c^T (d0, d1, d2)``: the velocity change of an impulse [N s] at contact ``c``."""
    for e in range(ptr[c], ptr[c + 1]):
        m = nd[e]
        base = jptr[e]
        o = off[e]
        for j in range(m):
            V[o + j] += WJt[base + 3 * j] * d0 + WJt[base + 3 * j + 1] * d1 + WJt[base + 3 * j + 2] * d2


@numba.njit(cache=True)
def contact_velocities(V, ptr, off, nd, jptr, J):
    """Relative velocities (k, 3) [m/s] of the contacts at ``V``."""
    k = len(ptr) - 1
    out = np.empty((k, 3))
    for c in range(k):
        u0, u1, u2 = _velocity(V, ptr, off, nd, jptr, J, c)
        out[c, 0], out[c, 1], out[c, 2] = u0, u1, u2
    return out


@numba.njit(cache=True)
def sequential_impulses(V, ptr, off, nd, jptr, J, WJt, K, normal, target, mu, iterations, lam_n, lam_t, vtol,
                        island):
    """Projected Gauss-Seidel on the contacts, in place on ``V``; returns the most sweeps an island took.

    Each contact wants its normal relative velocity ``>= target[c]`` [m/s] with a normal impulse
    ``lam_n[c] >= 0`` [N s], and Coulomb friction ``|lam_t[c]| <= mu[c] lam_n[c]`` against its sliding
    (the tangential impulse along the sliding velocity that stops it, clamped to the disc). The contacts are
    in islands (``island`` (k,) int64, labels in ``[0, k)``; contacts of different islands must share no
    velocity): each island stops on its own, after ``iterations`` sweeps, or once a sweep changes none of its
    impulses by more than 1e-10 of its largest, or none of its contacts' velocities by more than ``vtol``
    [m/s] (the change of its impulse times its normal effective inverse mass); an island that stopped is not
    swept again. An island's result is that of solving it alone (its contacts visited in the same order),
    bit for bit; all labels 0 is one shared stop (every contact swept until all have converged).

    A contact without impulse is first tested on its normal row ``n^T J`` alone (a third of the work of its
    velocity): when that shows it separating (its normal velocity above the target by more than a bound on
    the rounding of both sums) its visit would change nothing, and it is passed; else it is visited in full.
    The result is that of visiting every contact (bit for bit over the last 100 steps of the benchmark's pile,
    where 86 % of the contacts end a solve without impulse and the solve took 2.2x less CPU).
    """
    k = len(ptr) - 1
    # every contact's normal rows n^T J_e, laid out as its entries (nd[e] values from jptr[e] / 3)
    nrow = np.empty(J.shape[0] // 3)
    for c in range(k):
        n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
        for e in range(ptr[c], ptr[c + 1]):
            n = nd[e]
            base = jptr[e]
            for j in range(n):
                nrow[base // 3 + j] = n0 * J[base + j] + n1 * J[base + n + j] + n2 * J[base + 2 * n + j]
    kns = np.empty(k)
    for c in range(k):
        n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
        kns[c] = (n0 * (K[c, 0, 0] * n0 + K[c, 0, 1] * n1 + K[c, 0, 2] * n2)
                  + n1 * (K[c, 1, 0] * n0 + K[c, 1, 1] * n1 + K[c, 1, 2] * n2)
                  + n2 * (K[c, 2, 0] * n0 + K[c, 2, 1] * n1 + K[c, 2, 2] * n2))
    nis = 0
    for c in range(k):
        nis = max(nis, island[c] + 1)
    change = np.zeros(nis)
    vchange = np.zeros(nis)
    scale = np.zeros(nis)
    done = np.ones(nis, dtype=np.bool_)
    for c in range(k):
        done[island[c]] = False  # labels without contacts are done from the start
    active = 0
    for i in range(nis):
        if not done[i]:
            active += 1
    sweeps = 0
    for it in range(iterations):
        if active == 0:
            break
        sweeps += 1
        change[:] = 0.0
        vchange[:] = 0.0
        scale[:] = 0.0
        for c in range(k):
            isl = island[c]
            if done[isl]:
                continue
            kn = kns[c]
            if not kn > 0.0:
                continue
            if lam_n[c] == 0.0 and lam_t[c, 0] == 0.0 and lam_t[c, 1] == 0.0 and lam_t[c, 2] == 0.0:
                # its normal velocity from the normal rows, and the sum of the terms' sizes: a sum of m terms
                # rounds by at most ~m 1.1e-16 of that, so 1e-11 of it bounds the rounding of this sum and of the
                # full visit's for contacts of up to ~10^4 velocities; past it the full visit would find the
                # contact separating too, take no impulse and change nothing
                vr = 0.0
                mag = 0.0
                for e in range(ptr[c], ptr[c + 1]):
                    n = nd[e]
                    b3 = jptr[e] // 3
                    o = off[e]
                    for j in range(n):
                        t = nrow[b3 + j] * V[o + j]
                        vr += t
                        mag += abs(t)
                if vr - target[c] > 1e-11 * (mag + abs(target[c])):
                    continue
            n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
            u0, u1, u2 = _velocity(V, ptr, off, nd, jptr, J, c)
            vn = u0 * n0 + u1 * n1 + u2 * n2
            new = max(0.0, lam_n[c] + (target[c] - vn) / kn)
            dn = new - lam_n[c]
            lam_n[c] = new
            d0, d1, d2 = dn * n0, dn * n1, dn * n2
            if mu[c] > 0.0:
                # velocity after the normal change, its tangential part
                w0 = u0 + K[c, 0, 0] * d0 + K[c, 0, 1] * d1 + K[c, 0, 2] * d2
                w1 = u1 + K[c, 1, 0] * d0 + K[c, 1, 1] * d1 + K[c, 1, 2] * d2
                w2 = u2 + K[c, 2, 0] * d0 + K[c, 2, 1] * d1 + K[c, 2, 2] * d2
                wn = w0 * n0 + w1 * n1 + w2 * n2
                t0, t1, t2 = w0 - wn * n0, w1 - wn * n1, w2 - wn * n2
                speed = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
                c0, c1, c2 = lam_t[c, 0], lam_t[c, 1], lam_t[c, 2]
                if speed > 0.0:
                    e0, e1, e2 = t0 / speed, t1 / speed, t2 / speed
                    kt = (e0 * (K[c, 0, 0] * e0 + K[c, 0, 1] * e1 + K[c, 0, 2] * e2)
                          + e1 * (K[c, 1, 0] * e0 + K[c, 1, 1] * e1 + K[c, 1, 2] * e2)
                          + e2 * (K[c, 2, 0] * e0 + K[c, 2, 1] * e1 + K[c, 2, 2] * e2))
                    if kt > 0.0:
                        s = speed / kt
                        c0, c1, c2 = c0 - s * e0, c1 - s * e1, c2 - s * e2
                lim = mu[c] * new
                norm = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
                if norm > lim:
                    f = lim / norm
                    c0, c1, c2 = c0 * f, c1 * f, c2 * f
                d0 += c0 - lam_t[c, 0]
                d1 += c1 - lam_t[c, 1]
                d2 += c2 - lam_t[c, 2]
                lam_t[c, 0], lam_t[c, 1], lam_t[c, 2] = c0, c1, c2
            if d0 != 0.0 or d1 != 0.0 or d2 != 0.0:
                _impulse(V, ptr, off, nd, jptr, WJt, c, d0, d1, d2)
                change[isl] = max(change[isl], abs(d0) + abs(d1) + abs(d2))
                vchange[isl] = max(vchange[isl], kn * (abs(d0) + abs(d1) + abs(d2)))
            scale[isl] = max(scale[isl], lam_n[c])
        for i in range(nis):
            if not done[i] and (change[i] <= 1e-10 * scale[i] or vchange[i] <= vtol):
                done[i] = True
                active -= 1
    return sweeps


@numba.njit(cache=True)
def apply_impulses(V, ptr, off, nd, jptr, WJt, lam):
    """``V += sum_c W J_c^T lam[c]`` (lam (k, 3) [N s]): the warm start of ``sequential_impulses``."""
    k = len(ptr) - 1
    for c in range(k):
        d0, d1, d2 = lam[c, 0], lam[c, 1], lam[c, 2]
        if d0 != 0.0 or d1 != 0.0 or d2 != 0.0:
            _impulse(V, ptr, off, nd, jptr, WJt, c, d0, d1, d2)


@numba.njit(cache=True)
def modal_energy_change(dV, V0, off, size, mass, R, inertia, shift):
    """The kinetic energy change of velocity changes ``dV`` from ``V0`` on modal bodies, as ``(work, quad)``:
    ``work = sum dv . M (v0 - shift)`` and ``quad = sum dv . M dv`` over the bodies' blocks ``(v, w, qdot)`` of
    ``size[i]`` velocities at ``off[i]`` (the change is ``work + quad / 2`` [J]); M holds the mass [kg], the world
    inertia ``R I R^T`` [kg m^2] (R (m, 3, 3) rotations, ``inertia`` (m, 3, 3) in body axes) and unit modal masses;
    ``shift`` (m, 3) [m/s] is taken off the linear velocity (``g dt``: see ``World._inverse_mass_blocks``)."""
    work = 0.0
    quad = 0.0
    Iw = np.empty((3, 3))
    for i in range(off.shape[0]):
        o = off[i]
        m = mass[i]
        for a in range(3):
            for b in range(3):
                s = 0.0
                for c in range(3):
                    for d in range(3):
                        s += R[i, a, c] * inertia[i, c, d] * R[i, b, d]
                Iw[a, b] = s
        for a in range(3):
            work += m * dV[o + a] * (V0[o + a] - shift[i, a])
            quad += m * dV[o + a] * dV[o + a]
        for a in range(3):
            s0 = 0.0
            s1 = 0.0
            for b in range(3):
                s0 += Iw[a, b] * V0[o + 3 + b]
                s1 += Iw[a, b] * dV[o + 3 + b]
            work += dV[o + 3 + a] * s0
            quad += dV[o + 3 + a] * s1
        for j in range(o + 6, o + size[i]):
            work += dV[j] * V0[j]
            quad += dV[j] * dV[j]
    return work, quad


@numba.njit(cache=True)
def exchanged(body, other, point, lam, n):
    """What each body received from each other body through the contacts with ``other[c] >= 0``: per ordered pair
    ``body * n + other`` that has contacts (increasing), the sums in contact order of the impulses ``lam`` (k, 3)
    [N s] and of their moments ``point x lam`` about the origin [N m s] (``point`` (k, 3) [m]): ``(keys, J, L)``
    (dense n * n sums: n is the solve's body count)."""
    J = np.zeros((n * n, 3))
    L = np.zeros((n * n, 3))
    seen = np.zeros(n * n, dtype=np.bool_)
    for c in range(body.shape[0]):
        if other[c] < 0:
            continue
        s = body[c] * n + other[c]
        seen[s] = True
        a0, a1, a2 = point[c, 0], point[c, 1], point[c, 2]
        b0, b1, b2 = lam[c, 0], lam[c, 1], lam[c, 2]
        J[s, 0] += b0
        J[s, 1] += b1
        J[s, 2] += b2
        L[s, 0] += a1 * b2 - a2 * b1
        L[s, 1] += a2 * b0 - a0 * b2
        L[s, 2] += a0 * b1 - a1 * b0
    keys = np.flatnonzero(seen)
    return keys, J[keys], L[keys]


@numba.njit(cache=True)
def solve_start(V, ptr, off, nd, jptr, J, WJt, normal, vobs_n, gap, margin, restitution, mu, warm, dt, push_out,
                threshold, soff, gdt):
    """What the solid solve (``_solid_stage._solve``) needs before its sweeps, in one pass, in place on ``V``.

    From the warm start ``warm`` (k, 3) [N s]: ``lam_n = max(warm . n, 0)`` and its tangential part clamped to the
    friction disc ``|lam_t| <= mu lam_n``. Each contact's target normal velocity [m/s]: ``-(gap - skin) / dt`` past
    its skin (half its ``margin`` [m]), else ``push_out (skin - gap) / dt``; a contact within its margin approaching
    faster than ``threshold`` [m/s] at the step start (``V`` less each body's ``gdt`` (m, 3) [m/s] on its linear
    velocities at ``soff`` (m,)) with ``restitution`` e > 0 bounces (target at least ``-e`` times that approach);
    ``vobs_n`` [m/s] (an obstacle's normal velocity) is added. Then the warm impulses are applied to ``V``.

    Returns ``(lam_n, lam_t, target, bounce, V0, min_skin)``: V0 the velocities before the warm impulses. The
    formulas of the numpy expressions it replaced, with each dot product summed in order (numpy's einsum summed
    them in another order: the targets can differ from those by an ulp)."""
    k = len(ptr) - 1
    lam_n = np.empty(k)
    lam_t = np.empty((k, 3))
    for c in range(k):
        n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
        w0, w1, w2 = warm[c, 0], warm[c, 1], warm[c, 2]
        p = w0 * n0 + w1 * n1 + w2 * n2
        lam_n[c] = max(p, 0.0)
        t0, t1, t2 = w0 - p * n0, w1 - p * n1, w2 - p * n2
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        lim = mu[c] * lam_n[c]
        f = 1.0 if tn <= lim else lim / (tn if tn > 0 else 1.0)
        lam_t[c, 0], lam_t[c, 1], lam_t[c, 2] = t0 * f, t1 * f, t2 * f
    Vs = V.copy()
    for i in range(soff.shape[0]):
        for a in range(3):
            Vs[soff[i] + a] -= gdt[i, a]
    target = np.empty(k)
    bounce = np.zeros(k, dtype=np.bool_)
    min_skin = np.inf
    for c in range(k):
        n0, n1, n2 = normal[c, 0], normal[c, 1], normal[c, 2]
        u0, u1, u2 = _velocity(V, ptr, off, nd, jptr, J, c)
        vn = (u0 * n0 + u1 * n1 + u2 * n2) - vobs_n[c]
        skin = 0.5 * margin[c]
        min_skin = min(min_skin, skin)
        g = gap[c]
        tg = -(g - skin) / dt if g > skin else push_out * (skin - g) / dt
        u0, u1, u2 = _velocity(Vs, ptr, off, nd, jptr, J, c)
        v_in = (u0 * n0 + u1 * n1 + u2 * n2) - vobs_n[c]
        e = restitution[c]
        if v_in < -threshold and e > 0 and g <= margin[c]:
            bounce[c] = True
            tg = max(tg, -e * v_in)
        target[c] = tg + vobs_n[c]
    V0 = V.copy()
    apply_impulses(V, ptr, off, nd, jptr, WJt, lam_n.reshape(k, 1) * normal + lam_t)
    return lam_n, lam_t, target, bounce, V0, min_skin


@numba.njit(cache=True)
def gravity_lifts(dv, g, dt):
    """``_solid_stage.gravity_lifts`` compiled: per body (``dv``, ``g`` (m, 3) [m/s], [m/s^2]) the position change
    ``-dt / 2 min(max(dv . up, 0), |g| dt) up`` (m, 3) [m], ``up = -g / |g|``, and whether it is non-zero (m,)."""
    m = dv.shape[0]
    lift = np.zeros((m, 3))
    has = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        g0, g1, g2 = g[i, 0], g[i, 1], g[i, 2]
        gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) * dt
        d = gn if gn > 0.0 else 1.0
        u0, u1, u2 = -g0 * dt / d, -g1 * dt / d, -g2 * dt / d
        c = min(max(dv[i, 0] * u0 + dv[i, 1] * u1 + dv[i, 2] * u2, 0.0), gn)
        s = -0.5 * dt * c
        lift[i, 0], lift[i, 1], lift[i, 2] = s * u0, s * u1, s * u2
        has[i] = c != 0.0
    return lift, has
