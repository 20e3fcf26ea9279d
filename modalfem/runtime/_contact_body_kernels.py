"""Compiled kernels of one modal body's contact step with static obstacles (numba ``njit(cache=True)``).

Each kernel replaces a chain of small numpy calls of ``runtime.contact`` with one call, so that a body
resting on the ground costs a few compiled calls per step instead of dozens of array operations:

* ``find``: contact candidates (rigid positions within the margin grown by a deformation bound), their
  exact deformed positions and gaps, and the selection, in one pass;
* ``crossings``: the first downward zero crossings of the contacts' gap trajectories (impact prediction);
* ``push_shift``: the translation that takes every vertex out of the obstacles (``contact.push_out``);
* ``solve_rigid``: the sequential-impulse solve of a body whose contact response is rigid (no modal
  columns: the sustained solve leaves out the modes faster than its sub-step), with the body's six
  velocities in registers: one contact's update is a few dozen flops with no memory round trip, where the
  general row-based solve (``_contact_kernels.solve``) is latency-bound on loads and stores of V. Blocks of
  contacts whose updates would all be skipped are found by a vectorised test first (``_applies``).

Obstacles are ``(kind, params)`` as in ``_contact_kernels``; mode shapes vertex-major ``vm`` (nv, r, 3)
[m/sqrt(kg)] in the body's dtype, sums in float64.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.runtime._contact_kernels import _rigid_gaps, _signed
from modalfem.runtime.obstacles import PLANE
from modalfem.runtime._contact_kernels import normal_velocities as _normal_velocities

__all__ = ["TOLERANCE", "crossings", "find", "gaps_at", "lever_arms", "normal_velocities", "push_shift", "resolve_rigid", "solve_rigid"]

#: ``solve_rigid`` does not apply an update that changes its contact's velocity by at most this share of the
#: problem's velocity scale (|v| + |w| max|r| + the largest target and load shift), and stops after a sweep
#: without a larger one. A stop on impulses (no change above 1e-12 of the largest, as ``_contact_kernels.solve``)
#: made a 50k-vertex body resting on a face sweep 10 times over corrections of ~1e-17 m/s, below the
#: rounding of its velocities; 1e-9 of the impulse instead let a bouncing block end 1e-10 m inside the ground
#: and gain 1e-10 J from the push-out (tests/runtime/test_contact.py).
TOLERANCE = 1e-12

#: the sweeps of ``resolve_rigid`` (at most: it stops when converged, ``TOLERANCE``) with box-edge contacts
#: (``contact._sweeps``). Ten sweeps (the ``Obstacles`` default) left a bar resting on a box
#: with its centre of mass over its last supported row ~20 nm short at a pivot vertex, whose push-out the energy
#: guard then halved the step for; converged, it holds, and a body across a narrow box's edges rests on the
#: box-edge contacts (``_contact_edge_kernels``) instead of tipping over its one supported row
#: (tests/runtime/test_contact_box_edges.py). Without them the default stays: a 1,802-vertex bar resting on the
#: ground does not reach the tolerance in ten sweeps, and sweeping on cost it 1.4x per step (151 -> 210 us, Intel
#: Xeon) for nothing the tests could see (and 2.3x on a box wider than it).
RIGID_SWEEPS = 200


@numba.njit(cache=True)
def _active(skip):
    """Indices of the modes not skipped (as int64 array)."""
    n = 0
    for m in range(skip.shape[0]):
        if not skip[m]:
            n += 1
    out = np.empty(n, dtype=np.int64)
    n = 0
    for m in range(skip.shape[0]):
        if not skip[m]:
            out[n] = m
            n += 1
    return out


@numba.njit(cache=True, inline="always")
def _world(j, rest, vm, q, act, R, c):
    """World position ``c + R (X_j + Phi_j q)`` of vertex j over the modes ``act`` (``_active``; float64 sums
    in mode order, as ``local_positions`` + ``world_positions``)."""
    a0, a1, a2 = 0.0, 0.0, 0.0
    for t in range(act.shape[0]):
        m = act[t]
        qm = q[m]
        a0 += float(vm[j, m, 0]) * qm
        a1 += float(vm[j, m, 1]) * qm
        a2 += float(vm[j, m, 2]) * qm
    x0, x1, x2 = a0 + rest[j, 0], a1 + rest[j, 1], a2 + rest[j, 2]
    return (c[0] + R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2,
            c[1] + R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2,
            c[2] + R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2)


@numba.njit(cache=True)
def find(kinds, params, margins, rest, vm, q, skip, R, c, bound):
    """Vertices within ``margins[o]`` [m] of obstacle o (see ``contact.find_contacts``).

    A vertex is a candidate when its rigid position ``c + R X_j`` is within ``margins[o] + bound`` (bound:
    an upper bound of any vertex's deformation [m]); a candidate is kept when its exact deformed position is
    within ``margins[o]``. Returns ``(vertex, obstacle, gap, normal)``: (k,) int64, (k,) int64, (k,) [m],
    (k, 3), obstacle-major.
    """
    nv = rest.shape[0]
    no = kinds.shape[0]
    vs = np.empty(nv * no, dtype=np.int64)
    os_ = np.empty(nv * no, dtype=np.int64)
    gap = np.empty(nv * no)
    nrm = np.empty((nv * no, 3))
    n = find_into(kinds, params, margins, rest, vm, q, skip, R, c, bound, vs, os_, gap, nrm)
    return vs[:n].copy(), os_[:n].copy(), gap[:n].copy(), nrm[:n].copy()


@numba.njit(cache=True)
def find_into(kinds, params, margins, rest, vm, q, skip, R, c, bound, vs, os_, gap, nrm):
    """``find`` into caller's buffers ``vs``, ``os_`` (int64), ``gap`` and ``nrm`` ((n, 3)) of at least
    ``nv * len(kinds)`` rows; returns the count found (its first rows). Returning the four arrays from compiled code
    costs ~1.7 us each (boxing); ``contact.find_contacts`` copies the rows out of thread-local buffers instead."""
    act = _active(skip)
    nv = rest.shape[0]
    no = kinds.shape[0]
    g = np.empty(nv)
    n = 0
    for o in range(no):
        _rigid_gaps(kinds[o], params[o], rest, R, c, g)
        lim = margins[o] + bound
        for j in range(nv):
            if g[j] < lim:
                x0, x1, x2 = _world(j, rest, vm, q, act, R, c)
                d, a, b, e = _signed(kinds[o], params[o], x0, x1, x2)
                if d < margins[o]:
                    vs[n] = j
                    os_[n] = o
                    gap[n] = d
                    nrm[n, 0], nrm[n, 1], nrm[n, 2] = a, b, e
                    n += 1
    return n


@numba.njit(cache=True)
def crossings(gap, vn, normal, accel, thr, horizon):
    """First downward zero crossings of the gaps ``gap + vn t + an t^2 / 2`` [m] in (0, horizon] [s]
    (an = normal . accel); see ``contact._crossings``.

    Returns:
        ``(t_fast, j, t_slow)``: the earliest crossing faster than its contact's threshold ``thr`` [m/s] and
        its contact index (NaN, -1 if none), the earliest slower one (NaN if none). Roots in the
        cancellation-free form q = -(b + sign(b) sqrt(D)) / 2, t = q / a and c / q.
    """
    k = gap.shape[0]
    t_fast, j_fast, t_slow = math.inf, -1, math.inf
    for i in range(k):
        an = normal[i, 0] * accel[0] + normal[i, 1] * accel[1] + normal[i, 2] * accel[2]
        a, b, cc = 0.5 * an, vn[i], gap[i]
        disc = b * b - 4.0 * a * cc
        ok = disc >= 0.0
        sq = math.sqrt(disc) if ok else 0.0
        qq = -0.5 * (b + (sq if b >= 0.0 else -sq))
        if a != 0.0:
            r1 = qq / a
        elif b != 0.0:
            r1 = -cc / b
        else:
            r1 = math.inf
        r2 = cc / qq if qq != 0.0 else math.inf
        first, speed = math.inf, 0.0
        for r in (r1, r2):
            if ok and math.isfinite(r) and r > 0.0 and r <= horizon and r < first:
                v = b + an * r
                if v < 0.0:
                    first, speed = r, v
        if cc <= 0.0 and b <= thr[i]:  # touching or inside and not leaving: a slow crossing now
            first, speed = 0.0, min(b, 0.0)
        if not math.isfinite(first):
            continue
        if speed < -thr[i]:
            if first > 0.0 and first < t_fast:  # (a fast one at t = 0 is the impact solve's)
                t_fast, j_fast = first, i
        elif first < t_slow:
            t_slow = first
    return (t_fast if j_fast >= 0 else math.nan), j_fast, (t_slow if math.isfinite(t_slow) else math.nan)


@numba.njit(cache=True)
def push_shift(kinds, params, rest, vm, q, skip, R, c, bound, slack, passes, no, nv):
    """Translate ``c`` (in place) so that no vertex is inside an obstacle; returns the total shift (3,) [m].

    The first ``no`` obstacles apply to the first ``nv`` points of ``rest`` (the body's vertices); obstacle
    ``no + i`` (a box-edge contact's plane, ``contact._EdgePoints``) applies to point ``nv + i`` alone.

    Per pass and obstacle: the vertices whose rigid position is within ``slack + bound`` [m] get their exact
    positions; if the deepest is closer than ``slack / 2`` (or inside), the body moves along its normal
    to ``slack`` above. Stops after a pass that moved nothing (or after the first with a single plane).
    """
    act = _active(skip)
    g = np.empty(nv)
    total = np.zeros(3)
    for _ in range(passes):
        moved = False
        for o in range(kinds.shape[0]):
            lim = slack + bound
            best, bn0, bn1, bn2 = math.inf, 0.0, 0.0, 0.0
            found = False
            if o < no:
                if rest.shape[0] == nv:  # (no box-edge points: the array as is, not a slice of it)
                    _rigid_gaps(kinds[o], params[o], rest, R, c, g)
                else:
                    _rigid_gaps(kinds[o], params[o], rest[:nv], R, c, g)
                for j in range(nv):
                    if g[j] < lim:
                        x0, x1, x2 = _world(j, rest, vm, q, act, R, c)
                        d, a, b, e = _signed(kinds[o], params[o], x0, x1, x2)
                        if not found or d < best:
                            best, bn0, bn1, bn2 = d, a, b, e
                            found = True
            else:  # a box-edge point against its own plane
                x0, x1, x2 = _world(nv + o - no, rest, vm, q, act, R, c)
                best, bn0, bn1, bn2 = _signed(kinds[o], params[o], x0, x1, x2)
                found = True
            if found and (best < 0.5 * slack or best < 0.0):
                f = (slack - best) * (1.0 + 1e-9)
                s0, s1, s2 = f * bn0, f * bn1, f * bn2
                c[0] += s0
                c[1] += s1
                c[2] += s2
                total[0] += s0
                total[1] += s1
                total[2] += s2
                moved = True
        if not moved or (kinds.shape[0] == 1 and kinds[0] == PLANE):
            break  # (one plane: the move lifted every vertex by the same amount, the deepest to slack)
    return total


#: contacts per block of ``solve_rigid``'s sweep that ``_applies`` tests at once
_BLOCK = 32


@numba.njit(cache=True, error_model="numpy")
def _applies(i0, i1, rT, nT, target, mu, sT, A, Wn, lam_n, jT, v0, v1, v2, w0, w1, w2, tol):
    """How many of the contacts i0..i1-1 the sweep of ``solve_rigid`` would update at the velocities (v, w) [m/s,
    rad/s]: its update of each (the same operations in the same order on the same values, so the same bits) with
    the branches written as selects, so that the loop is vectorised (~3x faster than the sweep, whose updates
    wait on each other's v and w). A contact counted 0 is one the sweep skips (its velocity change within tol);
    a NaN counts 1. The sweep changes nothing while it skips, so a block counted 0 is skipped whole: a resting
    body's converged sweep is then this test alone. Arrays contact-minor: rT, nT, sT, jT (3, k) lever arms,
    normals, load shifts, friction impulses; A (9, k) rows ``A_i[a, b]`` at ``3 a + b``. (error_model numpy: a
    division by zero in a branch not taken gives an infinity or NaN that the select drops, not an exception.)"""
    bad = 0
    for i in range(np.uint64(i0), np.uint64(i1)):  # (unsigned: no negative-index wrap, which stops vectorising)
        r0, r1, r2 = rT[0, i], rT[1, i], rT[2, i]
        u0 = v0 + (w1 * r2 - w2 * r1) + sT[0, i]
        u1 = v1 + (w2 * r0 - w0 * r2) + sT[1, i]
        u2 = v2 + (w0 * r1 - w1 * r0) + sT[2, i]
        n0, n1, n2 = nT[0, i], nT[1, i], nT[2, i]
        vn = n0 * u0 + n1 * u1 + n2 * u2
        old = lam_n[i]
        x = old + (target[i] - vn) * Wn[i]
        new = x if x > 0.0 else 0.0  # (the sweep's max(x, 0.0), but for the sign of a zero, which changes no
        dn = new - old               # nonzero value below: the decision is the same)
        d0, d1, d2 = dn * n0, dn * n1, dn * n2
        j0, j1, j2 = jT[0, i], jT[1, i], jT[2, i]
        ui0 = u0 + A[0, i] * d0 + A[1, i] * d1 + A[2, i] * d2
        ui1 = u1 + A[3, i] * d0 + A[4, i] * d1 + A[5, i] * d2
        ui2 = u2 + A[6, i] * d0 + A[7, i] * d1 + A[8, i] * d2
        un = n0 * ui0 + n1 * ui1 + n2 * ui2
        ut0, ut1, ut2 = ui0 - n0 * un, ui1 - n1 * un, ui2 - n2 * un
        s2 = ut0 * ut0 + ut1 * ut1 + ut2 * ut2
        tat = (ut0 * (A[0, i] * ut0 + A[1, i] * ut1 + A[2, i] * ut2)
               + ut1 * (A[3, i] * ut0 + A[4, i] * ut1 + A[5, i] * ut2)
               + ut2 * (A[6, i] * ut0 + A[7, i] * ut1 + A[8, i] * ut2))
        slide = s2 > 0.0
        f = s2 / tat
        c0 = j0 - f * ut0 if slide else j0
        c1 = j1 - f * ut1 if slide else j1
        c2 = j2 - f * ut2 if slide else j2
        lim = mu[i] * new
        n2c = c0 * c0 + c1 * c1 + c2 * c2
        clamp = n2c > lim * lim
        g = lim / math.sqrt(n2c)
        c0 = c0 * g if clamp else c0
        c1 = c1 * g if clamp else c1
        c2 = c2 * g if clamp else c2
        fric = mu[i] > 0.0
        d0 = d0 + (c0 - j0) if fric else d0
        d1 = d1 + (c1 - j1) if fric else d1
        d2 = d2 + (c2 - j2) if fric else d2
        e0 = A[0, i] * d0 + A[1, i] * d1 + A[2, i] * d2
        e1 = A[3, i] * d0 + A[4, i] * d1 + A[5, i] * d2
        e2 = A[6, i] * d0 + A[7, i] * d1 + A[8, i] * d2
        skip = (abs(e0) <= tol) & (abs(e1) <= tol) & (abs(e2) <= tol) & ((x > 0.0) | (x <= 0.0))
        bad += 0 if skip else 1
    return bad


@numba.njit(cache=True)
def solve_rigid(r, mass, Iw_inv, V, n, target, mu, shift, iters, lam, jt, lam_n, guess):
    """Sequential impulses of one rigid body against static obstacles, in place on V = (v, w) (6,).

    The same projected Gauss-Seidel as ``_contact_kernels.solve`` with the rows ``J_i = [I, -[r_i]x]``:
    contact velocity ``u = v + w x r_i + shift_i``; an impulse d changes ``v += d / m`` and
    ``w += Iw^-1 (r_i x d)``. The friction update is written without square roots and with one division.
    An update changing its contact's velocity by at most ``TOLERANCE`` of the velocity scale is not
    applied (see the module docstring). The sweep goes in blocks of ``_BLOCK`` contacts: while it has applied
    nothing since the last block, it first tests the next block whole (``_applies``, vectorised) and skips it
    when no update in it would be applied, which changes nothing (the same results bit for bit; a resting body's
    converged sweep costs ~1/3: bar of 451 contacts, kernel ~65 -> ~58 us, Intel Xeon).

    Args:
        r: (k, 3) lever arms from the centre of mass to the contact points [m], world.
        mass: [kg]; Iw_inv: (3, 3) world inverse inertia [1/(kg m^2)].
        V: (6,) velocity and angular velocity [m/s, rad/s] (changed in place).
        n, target, mu, shift, iters, lam, jt, lam_n, guess: as in ``_contact_kernels.solve``.

    Returns:
        the number of sweeps done.
    """
    k = r.shape[0]
    im = 1.0 / mass
    # B_i = Iw^-1 [r_i]x (angular velocity per unit impulse) and A_i = I/m - [r_i]x B_i
    B = np.empty((k, 3, 3))
    A = np.empty((9, k))  # A[3 a + b, i] = A_i[a, b]: contact-minor, as _applies reads it
    Wn = np.empty(k)
    rT = np.empty((3, k))  # r, n, shift and (per sweep) jt contact-minor, for _applies
    nT = np.empty((3, k))
    sT = np.empty((3, k))
    jT = np.empty((3, k))
    for i in range(k):
        r0, r1, r2 = r[i, 0], r[i, 1], r[i, 2]
        for a in range(3):
            rT[a, i], nT[a, i], sT[a, i] = r[i, a], n[i, a], shift[i, a]
        for a in range(3):  # B[:, col] = Iw_inv @ [r]x[:, col]; [r]x columns: (0, r2, -r1), (-r2, 0, r0), (r1, -r0, 0)
            B[i, a, 0] = Iw_inv[a, 1] * r2 - Iw_inv[a, 2] * r1
            B[i, a, 1] = -Iw_inv[a, 0] * r2 + Iw_inv[a, 2] * r0
            B[i, a, 2] = Iw_inv[a, 0] * r1 - Iw_inv[a, 1] * r0
        for b in range(3):  # A[:, b] = e_b / m - r x B[:, b]... (B[:, b] x r)
            x0, x1, x2 = B[i, 0, b], B[i, 1, b], B[i, 2, b]
            A[b, i] = x1 * r2 - x2 * r1
            A[3 + b, i] = x2 * r0 - x0 * r2
            A[6 + b, i] = x0 * r1 - x1 * r0
            A[4 * b, i] += im
        s = 0.0
        for a in range(3):
            for b in range(3):
                s += n[i, a] * A[3 * a + b, i] * n[i, b]
        Wn[i] = 1.0 / s
    v0, v1, v2, w0, w1, w2 = V[0], V[1], V[2], V[3], V[4], V[5]
    if guess and k > 1:
        # one common normal impulse meeting the contacts' mean target (matrix-free, as _uniform_guess)
        d0 = d1 = d2 = e0 = e1 = e2 = 0.0
        for i in range(k):
            d0 += n[i, 0] * im
            d1 += n[i, 1] * im
            d2 += n[i, 2] * im
            e0 += B[i, 0, 0] * n[i, 0] + B[i, 0, 1] * n[i, 1] + B[i, 0, 2] * n[i, 2]
            e1 += B[i, 1, 0] * n[i, 0] + B[i, 1, 1] * n[i, 1] + B[i, 1, 2] * n[i, 2]
            e2 += B[i, 2, 0] * n[i, 0] + B[i, 2, 1] * n[i, 1] + B[i, 2, 2] * n[i, 2]
        resid = 0.0
        slope = 0.0
        for i in range(k):
            r0, r1, r2 = r[i, 0], r[i, 1], r[i, 2]
            u0 = v0 + (w1 * r2 - w2 * r1) + shift[i, 0]
            u1 = v1 + (w2 * r0 - w0 * r2) + shift[i, 1]
            u2 = v2 + (w0 * r1 - w1 * r0) + shift[i, 2]
            t0 = d0 + (e1 * r2 - e2 * r1)
            t1 = d1 + (e2 * r0 - e0 * r2)
            t2 = d2 + (e0 * r1 - e1 * r0)
            resid += target[i] - (n[i, 0] * u0 + n[i, 1] * u1 + n[i, 2] * u2)
            slope += n[i, 0] * t0 + n[i, 1] * t1 + n[i, 2] * t2
        if slope > 0.0 and resid > 0.0:
            gg = resid / slope
            v0, v1, v2 = v0 + gg * d0, v1 + gg * d1, v2 + gg * d2
            w0, w1, w2 = w0 + gg * e0, w1 + gg * e1, w2 + gg * e2
            for i in range(k):
                lam_n[i] = gg
                lam[i, 0], lam[i, 1], lam[i, 2] = gg * n[i, 0], gg * n[i, 1], gg * n[i, 2]
    # velocity scale of the problem [m/s]: an update that changes its contact's velocity by less than TOLERANCE
    # of it is rounding noise and is not applied, and a sweep with none larger is the last
    rmax = 0.0
    vs = 0.0
    for i in range(k):
        rmax = max(rmax, math.sqrt(r[i, 0] * r[i, 0] + r[i, 1] * r[i, 1] + r[i, 2] * r[i, 2]))
        vs = max(vs, abs(target[i]), math.sqrt(shift[i, 0] * shift[i, 0] + shift[i, 1] * shift[i, 1]
                                                + shift[i, 2] * shift[i, 2]))
    vs += math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) + math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) * rmax
    tol = TOLERANCE * vs
    done = iters
    for sweep in range(iters):
        change = 0.0
        for i in range(k):  # (a contact updated in this sweep is not visited again in it: jT stays its jt)
            jT[0, i], jT[1, i], jT[2, i] = jt[i, 0], jt[i, 1], jt[i, 2]
        test = True  # blocks of contacts tested first (_applies) while the sweep has applied nothing since
        for b0 in range(0, k, _BLOCK):
            b1 = min(b0 + _BLOCK, k)
            if test and _applies(b0, b1, rT, nT, target, mu, sT, A, Wn, lam_n, jT, v0, v1, v2, w0, w1, w2, tol) == 0:
                continue  # the sweep would skip every contact of the block (nothing changes between them)
            test = True
            for i in range(b0, b1):
                r0, r1, r2 = r[i, 0], r[i, 1], r[i, 2]
                u0 = v0 + (w1 * r2 - w2 * r1) + shift[i, 0]
                u1 = v1 + (w2 * r0 - w0 * r2) + shift[i, 1]
                u2 = v2 + (w0 * r1 - w1 * r0) + shift[i, 2]
                n0, n1, n2 = n[i, 0], n[i, 1], n[i, 2]
                vn = n0 * u0 + n1 * u1 + n2 * u2
                old = lam_n[i]
                new = max(old + (target[i] - vn) * Wn[i], 0.0)
                dn = new - old
                d0, d1, d2 = dn * n0, dn * n1, dn * n2
                c0, c1, c2 = jt[i, 0], jt[i, 1], jt[i, 2]
                if mu[i] > 0.0:
                    # velocity after the normal update u + A d, its tangential part ut; the impulse that stops
                    # it along its direction is ut |ut|^2 / (ut . A ut)
                    ui0 = u0 + A[0, i] * d0 + A[1, i] * d1 + A[2, i] * d2
                    ui1 = u1 + A[3, i] * d0 + A[4, i] * d1 + A[5, i] * d2
                    ui2 = u2 + A[6, i] * d0 + A[7, i] * d1 + A[8, i] * d2
                    un = n0 * ui0 + n1 * ui1 + n2 * ui2
                    ut0, ut1, ut2 = ui0 - n0 * un, ui1 - n1 * un, ui2 - n2 * un
                    s2 = ut0 * ut0 + ut1 * ut1 + ut2 * ut2
                    if s2 > 0.0:
                        tat = (ut0 * (A[0, i] * ut0 + A[1, i] * ut1 + A[2, i] * ut2)
                               + ut1 * (A[3, i] * ut0 + A[4, i] * ut1 + A[5, i] * ut2)
                               + ut2 * (A[6, i] * ut0 + A[7, i] * ut1 + A[8, i] * ut2))
                        f = s2 / tat
                        c0 -= f * ut0
                        c1 -= f * ut1
                        c2 -= f * ut2
                    lim = mu[i] * new
                    n2c = c0 * c0 + c1 * c1 + c2 * c2
                    if n2c > lim * lim:
                        f = lim / math.sqrt(n2c)
                        c0 *= f
                        c1 *= f
                        c2 *= f
                    d0 += c0 - jt[i, 0]
                    d1 += c1 - jt[i, 1]
                    d2 += c2 - jt[i, 2]
                # the contact's velocity change A d
                e0 = A[0, i] * d0 + A[1, i] * d1 + A[2, i] * d2
                e1 = A[3, i] * d0 + A[4, i] * d1 + A[5, i] * d2
                e2 = A[6, i] * d0 + A[7, i] * d1 + A[8, i] * d2
                step = max(abs(e0), abs(e1), abs(e2))
                if step <= tol:  # within the convergence tolerance: nothing applied, the next contact need not wait
                    continue
                lam_n[i] = new
                jt[i, 0], jt[i, 1], jt[i, 2] = c0, c1, c2
                test = False
                lam[i, 0] += d0
                lam[i, 1] += d1
                lam[i, 2] += d2
                v0 += d0 * im
                v1 += d1 * im
                v2 += d2 * im
                w0 += B[i, 0, 0] * d0 + B[i, 0, 1] * d1 + B[i, 0, 2] * d2
                w1 += B[i, 1, 0] * d0 + B[i, 1, 1] * d1 + B[i, 1, 2] * d2
                w2 += B[i, 2, 0] * d0 + B[i, 2, 1] * d1 + B[i, 2, 2] * d2
                change = max(change, step)
        if change <= tol:
            done = sweep + 1
            break
    V[0], V[1], V[2], V[3], V[4], V[5] = v0, v1, v2, w0, w1, w2
    return done


@numba.njit(cache=True)
def gaps_at(vertex, obstacle, kinds, params, rest, vm, q, skip, R, c):
    """Gaps (k,) [m] and normals (k, 3) of the deformed vertices ``vertex`` at the pose (R, c), each against
    its own obstacle ``obstacle[i]`` (index into kinds / params)."""
    act = _active(skip)
    k = vertex.shape[0]
    gap = np.empty(k)
    nrm = np.empty((k, 3))
    for i in range(k):
        x0, x1, x2 = _world(vertex[i], rest, vm, q, act, R, c)
        o = obstacle[i]
        d, a, b, e = _signed(kinds[o], params[o], x0, x1, x2)
        gap[i] = d
        nrm[i, 0], nrm[i, 1], nrm[i, 2] = a, b, e
    return gap, nrm


@numba.njit(cache=True)
def lever_arms(vertex, rest, vm, q, skip, R):
    """``R (X_j + Phi_j q)`` (k, 3) [m]: the deformed vertices relative to the centre of mass, world."""
    act = _active(skip)
    k = vertex.shape[0]
    out = np.empty((k, 3))
    zero = np.zeros(3)
    for i in range(k):
        out[i, 0], out[i, 1], out[i, 2] = _world(vertex[i], rest, vm, q, act, R, zero)
    return out


@numba.njit(cache=True)
def _conjugate(R, M):
    """``R M R^T`` (3, 3)."""
    out = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            s = 0.0
            for c in range(3):
                s += R[a, c] * (M[c, 0] * R[b, 0] + M[c, 1] * R[b, 1] + M[c, 2] * R[b, 2])
            out[a, b] = s
    return out


@numba.njit(cache=True)
def resolve_rigid(vertex, rest, vm, q, skip, R, inertia, inertia_inv, mass, velocity, L, n, gap, mu, accel, dt, iters,
                  lam_n, jt):
    """The sustained contact solve of one body with no mode taking part, in one call (see
    ``contact.resolve_contacts``): lever arms of the deformed contact vertices, end-of-step targets
    ``0.25 dt n . a - 2 gap / dt`` with the load shift ``a dt / 2``, ``solve_rigid`` from the uniform guess,
    and the energy guard (impulses scaled back to the largest share that adds no kinetic energy); changes
    ``velocity`` [m/s] and ``L`` [kg m^2/s] in place and writes the normal (k,) and friction (k, 3) impulses
    [N s] into ``lam_n`` and ``jt``.

    Args:
        vertex: (k,) contact vertices; rest, vm, q, skip: the body's rest positions (nv, 3) [m] about the
            centre of mass, vertex-major modes, modal coordinates and skipped modes; R (3, 3) body -> world.
        inertia, inertia_inv: (3, 3) body-axes inertia [kg m^2] and its inverse; mass [kg].
        n: (k, 3) normals; gap: (k,) mid-step gaps [m]; mu: (k,) friction; accel: (3,) load acceleration
            [m/s^2]; dt: the sub-step [s]; iters: most sweeps (``contact._Plan.rigid_sweeps``).
    """
    k = vertex.shape[0]
    Iw_inv = _conjugate(R, inertia_inv)
    Iw = _conjugate(R, inertia)
    r = lever_arms(vertex, rest, vm, q, skip, R)
    shift = np.empty((k, 3))
    target = np.empty(k)
    for i in range(k):
        shift[i, 0], shift[i, 1], shift[i, 2] = 0.5 * dt * accel[0], 0.5 * dt * accel[1], 0.5 * dt * accel[2]
        an = n[i, 0] * accel[0] + n[i, 1] * accel[1] + n[i, 2] * accel[2]
        target[i] = 0.25 * dt * an - 2.0 * gap[i] / dt
    V0 = np.empty(6)
    V0[0:3] = velocity
    for a in range(3):
        V0[3 + a] = Iw_inv[a, 0] * L[0] + Iw_inv[a, 1] * L[1] + Iw_inv[a, 2] * L[2]
    V = V0.copy()
    lam = np.zeros((k, 3))
    lam_n[:] = 0.0
    jt[:, :] = 0.0
    solve_rigid(r, mass, Iw_inv, V, n, target, mu, shift, iters, lam, jt, lam_n, True)
    dv = V[0:3] - V0[0:3]
    dw = V[3:6] - V0[3:6]
    Idw = np.empty(3)
    for a in range(3):
        Idw[a] = Iw[a, 0] * dw[0] + Iw[a, 1] * dw[1] + Iw[a, 2] * dw[2]
    work = mass * (dv[0] * velocity[0] + dv[1] * velocity[1] + dv[2] * velocity[2]) + (
        dw[0] * L[0] + dw[1] * L[1] + dw[2] * L[2])
    quad = mass * (dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]) + (dw[0] * Idw[0] + dw[1] * Idw[1] + dw[2] * Idw[2])
    if work + 0.5 * quad > 1e-12 * quad:  # would add energy: keep the largest share that does not
        scale = min(1.0, -2.0 * (1.0 - 1e-9) * work / quad) if work < 0.0 and quad > 0.0 else 0.0
        dv *= scale
        Idw *= scale
        lam_n *= scale
        jt *= scale
    for a in range(3):
        velocity[a] += dv[a]
        L[a] += Idw[a]


@numba.njit(cache=True)
def normal_velocities(vertex, rest, vm, q, skip, modal, R, nm, n, v, w, qdot):
    """``n . (J_j V)`` (k,) [m/s] of the contact vertices at the deformed positions ``X_j + Phi_j q`` (body
    axes, computed here): ``_contact_kernels.normal_velocities`` without a separate positions pass."""
    act = _active(skip)
    k = vertex.shape[0]
    local = np.empty((k, 3))
    zero = np.zeros(3)
    eye = np.eye(3)
    for i in range(k):
        local[i, 0], local[i, 1], local[i, 2] = _world(vertex[i], rest, vm, q, act, eye, zero)
    return _normal_velocities(vertex, local, modal, vm, R, nm, n, v, w, qdot)
