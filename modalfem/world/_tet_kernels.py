"""Compiled parts of a tet body's contacts in its implicit step (numba, cached on disk): the penalty's energy,
force and stiffness (``tetcontact._psi``), the 6-unknown minimisation eliminating a touched modal body's rigid
displacement (``tetcontact._minimise``), and the Coulomb friction pass over the contacts (``World._tet_friction``).

They are the NumPy versions' expressions in loops: the NumPy versions spent their time on per-call overhead
(arrays of ~10-100 contacts, a Python Newton loop per energy evaluation, a Python loop over contacts).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def penalty(z, k, e):
    """``(psi, f, h)`` (c,) each: energy [J], force [N] and stiffness [N/m] of the penalty at depths ``z`` [m]
    (``tetcontact._psi``: ``0.5 k z^2`` where ``e == 0``, else C2 with the onset ``k z^3 / (6 e)`` below ``e``)."""
    c = len(z)
    psi, f, h = np.zeros(c), np.zeros(c), np.zeros(c)
    for i in range(c):
        zi = z[i]
        if zi <= 0.0:
            continue
        ki, ei = k[i], e[i]
        if ei > 0.0 and zi < ei:
            q = ki * zi / ei
            psi[i] = q * zi * zi / 6.0
            f[i] = 0.5 * q * zi
            h[i] = q
        elif ei > 0.0:
            psi[i] = ki * (0.5 * zi * zi - 0.5 * ei * zi + ei * ei / 6.0)
            f[i] = ki * (zi - 0.5 * ei)
            h[i] = ki
        else:
            psi[i] = 0.5 * ki * zi * zi
            f[i] = ki * zi
            h[i] = ki
    return psi, f, h


@numba.njit(cache=True)
def _spd_solve(H, g):
    """``H^-1 g`` for a small SPD ``H`` (Cholesky; a non-positive pivot gets the diagonal's roundoff)."""
    n = len(g)
    L = np.zeros((n, n))
    for j in range(n):
        s = H[j, j]
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if s <= 0.0:
            s = 1e-300 + 1e-16 * abs(H[j, j])
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, n):
            s = H[i, j]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            L[i, j] = s / L[j, j]
    y = np.zeros(n)
    for i in range(n):
        s = g[i]
        for p in range(i):
            s -= L[i, p] * y[p]
        y[i] = s / L[i, i]
    x = np.zeros(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for p in range(i + 1, n):
            s -= L[p, i] * x[p]
        x[i] = s / L[i, i]
    return x


@numba.njit(cache=True)
def _objective(S, A, k, e, d, u):
    z = d + A @ u
    return 0.5 * (u @ (S @ u)) + penalty(z, k, e)[0].sum()


@numba.njit(cache=True)
def minimise(S, A, k, e, d, u):
    """``argmin_u 0.5 u^T S u + sum psi(d + A u)`` (convex, S SPD): Newton with a backtracking line search from
    ``u``, until the step is below roundoff of ``u`` (``tetcontact._minimise``)."""
    u = u.copy()
    dmax = 0.0
    for i in range(len(d)):
        dmax = max(dmax, abs(d[i]))
    amax = 0.0
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            amax = max(amax, abs(A[i, j]))
    scale = 1e-14 * (1.0 + dmax * amax)
    for _ in range(100):
        z = d + A @ u
        pz, fz, hz = penalty(z, k, e)
        H = S + (A.T * hz) @ A
        g = S @ u + A.T @ fz
        du = -_spd_solve(H, g)
        slope = g @ du
        if slope >= 0.0:  # at the minimiser to roundoff
            return u
        f0, t = 0.5 * (u @ (S @ u)) + pz.sum(), 1.0
        while t > 1e-12 and _objective(S, A, k, e, d, u + t * du) > f0 + 1e-4 * t * slope:
            t *= 0.5
        u = u + t * du
        step = 0.0
        Adu = A @ du
        for i in range(len(Adu)):
            step = max(step, abs(t * Adu[i]))
        if step <= scale:
            return u
    return u


@numba.njit(cache=True)
def friction(act, verts, w, masses, extra, v, vo, nrm, f, mu, dt):
    """Coulomb friction over the active contacts ``act`` in order (``World._tet_friction``): the tangential
    velocity of each contact's point ``sum_j w_j v_j`` relative to its obstacle's ``vo`` (c, 3) [m/s] shrinks by
    at most ``mu f dt / m_eff``, ``m_eff = 1 / (sum_j w_j^2 / m_j + extra)`` (``extra`` [1/kg]: the other
    body's), the change spread over the free vertices by their weights; ``v`` (n, 3) [m/s] updated in place. A
    contact between two tet bodies stepped together has signed weights summing to zero (``vo`` and ``extra`` 0):
    its impulses on the two sides are equal and opposite.
    Returns the impulses (c, 3) [N s] on the tet's points (zero where none)."""
    J = np.zeros((len(f), 3))
    for c in act:
        inv = 0.0
        for j in range(verts.shape[1]):
            i = verts[c, j]
            if i >= 0 and math.isfinite(masses[i]):
                inv += w[c, j] * w[c, j] / masses[i]
        if inv == 0.0:
            continue
        inv += extra[c]
        rel = np.zeros(3)
        for j in range(verts.shape[1]):
            i = verts[c, j]
            if i >= 0:
                rel += w[c, j] * v[i]
        rel -= vo[c]
        n = nrm[c]
        vt = rel - n * (rel @ n)
        sp = math.sqrt(vt @ vt)
        if sp <= 0.0:
            continue
        Jt = -min(sp, mu * f[c] * dt * inv) / sp * vt / inv
        for j in range(verts.shape[1]):
            i = verts[c, j]
            if i >= 0 and math.isfinite(masses[i]):
                v[i] += w[c, j] / masses[i] * Jt
        J[c] = Jt
    return J


@numba.njit(cache=True)
def penalty_hessian(stiff, verts, w, nrm):
    """The active contacts' Hessian ``k (w w^T) (x) (n n^T)`` as DOF entries ``(rows, cols, vals)``
    (``PenaltyContacts.hessian_entries``): ``stiff`` (c,) [N/m] (0: inactive), ``verts`` (c, k) (-1: unused)."""
    total = 0
    for c in range(len(stiff)):
        if stiff[c] > 0.0:
            u = 0
            for j in range(verts.shape[1]):
                if verts[c, j] >= 0:
                    u += 1
            total += 9 * u * u
    rows = np.empty(total, np.int64)
    cols = np.empty(total, np.int64)
    vals = np.empty(total)
    p = 0
    for c in range(len(stiff)):
        if stiff[c] <= 0.0:
            continue
        for i in range(verts.shape[1]):
            vi = verts[c, i]
            if vi < 0:
                continue
            for j in range(verts.shape[1]):
                vj = verts[c, j]
                if vj < 0:
                    continue
                kij = stiff[c] * w[c, i] * w[c, j]
                for a in range(3):
                    for b in range(3):
                        rows[p] = 3 * vi + a
                        cols[p] = 3 * vj + b
                        vals[p] = kij * nrm[c, a] * nrm[c, b]
                        p += 1
    return rows, cols, vals


@numba.njit(cache=True)
def penalty_low_rank(stiff, verts, w, nrm, arms, bodies, inertia, n):
    """``(V (3 n, 6 B), S (6 B, 6 B), any)`` of ``PenaltyContacts.hessian_low_rank``: the cross derivatives of the
    active contacts' energy in the tet's positions and each body's displacement (``bodies`` (c,), -1: none), and
    the bodies' blocks ``inertia`` (B, 6, 6) plus ``k a a^T``; ``any``: V has a non-zero entry."""
    B = inertia.shape[0]
    V = np.zeros((3 * n, 6 * B))
    S = np.zeros((6 * B, 6 * B))
    for b in range(B):
        S[6 * b:6 * b + 6, 6 * b:6 * b + 6] = inertia[b]
    nonzero = False
    for c in range(len(stiff)):
        b = bodies[c]
        if b < 0 or stiff[c] <= 0.0:
            continue
        k = stiff[c]
        for p in range(6):
            for q in range(6):
                S[6 * b + p, 6 * b + q] += k * arms[c, p] * arms[c, q]
        for j in range(verts.shape[1]):
            v = verts[c, j]
            if v < 0:
                continue
            for d in range(3):
                f = -k * w[c, j] * nrm[c, d]
                for q in range(6):
                    x = f * arms[c, q]
                    V[3 * v + d, 6 * b + q] += x
                    nonzero = nonzero or x != 0.0
    return V, S, nonzero
