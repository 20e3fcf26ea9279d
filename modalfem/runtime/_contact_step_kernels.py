"""Compiled sustained-contact step of one modal body on static obstacles (numba ``njit(cache=True)``).

``sustained_step`` is the whole of ``ModalSolver.step``'s contact part (``contact.step_with_contacts`` +
``contact.push_out`` + the energy guard of ``ModalSolver._contact_step_without_gain``) for its commonest case,
in one call: a body in sustained contact (resting or sliding) whose contact response is rigid (every mode
faster than the step, ``contact._rigid_response``), under a constant load force through the centre of mass
(gravity), with no impact predicted within the step and no friction stop inside it (contacts touching and
approaching now get the Python impact solve first: ``after_impact``). Then the Python event loop does exactly
this: the impact prediction, a free half step, the mid-step gaps (of the rest shape), the rigid sustained solve
(``_contact_body_kernels.resolve_rigid``), the stop test, a free half step, the push-out with its energy
payment, and the energy check. The kernel does the same arithmetic in the same order (the state is the Python
path's bit for bit; tests/runtime/test_contact_fast.py) and returns 0 (2: touching contacts, an impact solve
first) without touching the state whenever a condition fails, so the caller falls back to the Python path,
which handles impacts, stops and the halving of a step that gained energy.

Shared pieces (the deformation bound, the skipped modes, the push-out's energy payment, the guard's energy, the
stop share) are compiled functions that the Python path calls too, so both compute them with the same
operations.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.runtime._contact_body_kernels import (_conjugate, crossings, gaps_at, normal_velocities, push_shift,
                                                    resolve_rigid)

from modalfem.runtime.body import NEGLIGIBLE  # a mode's skipped contribution [m]
from modalfem.runtime.solver import ENERGY_RTOL  # the energy guard's tolerance

__all__ = ["energy", "modal_terms", "pay_lift", "push_and_pay", "settle", "stop_share", "sustained_step"]


@numba.njit(cache=True)
def settle(q, qdot, pos, v, L, tiny):
    """The end of ``ModalSolver._step``: modal values ``|q_i|``, ``|qdot_i|`` below ``tiny`` set to 0 (in place),
    then True when the state is finite (the sum of q, qdot, position, velocity and angular momentum is finite:
    no NaN or infinity among them, and no overflow)."""
    s = 0.0
    for i in range(q.shape[0]):
        if abs(q[i]) < tiny:
            q[i] = 0.0
        s += q[i]
    for i in range(qdot.shape[0]):
        if abs(qdot[i]) < tiny:
            qdot[i] = 0.0
        s += qdot[i]
    for i in range(3):
        s += pos[i] + v[i] + L[i]
    return math.isfinite(s)



@numba.njit(cache=True)
def modal_terms(q, scale, radius):
    """``(skip, bound)`` of modal coordinates q (r,): the modes whose contribution ``|q_i| scale_i`` [m] is
    below ``NEGLIGIBLE``, and an upper bound [m] of every vertex's deformation, ``sqrt(3) sum |q_i| scale_i``
    (+ 1e-6 of it and 1e-12 of (1 + radius [m]) as rounding slack); see ``contact.deformation_bound``."""
    r = q.shape[0]
    skip = np.empty(r, dtype=np.bool_)
    s = 0.0
    for i in range(r):
        a = abs(q[i])
        skip[i] = a * scale[i] < NEGLIGIBLE
        s += a * scale[i]
    return skip, math.sqrt(3.0) * s * (1.0 + 1e-6) + 1e-12 * (1.0 + radius)


@numba.njit(cache=True)
def pay_lift(mass, accel, total, R, inertia_inv, v, L, qdot):
    """Take the potential energy ``-mass accel . total`` [J] that a push-out by ``total`` (3,) [m] added from
    the kinetic energy: v [m/s], L [kg m^2/s] and qdot scaled in place by one factor (to 0 if the kinetic
    energy is smaller). R (3, 3) body -> world; inertia_inv (3, 3) body axes."""
    if total[0] == 0.0 and total[1] == 0.0 and total[2] == 0.0:
        return
    gain = -mass * (accel[0] * total[0] + accel[1] * total[1] + accel[2] * total[2])
    if gain <= 0.0:
        return
    b0 = R[0, 0] * L[0] + R[1, 0] * L[1] + R[2, 0] * L[2]  # Lb = R^T L
    b1 = R[0, 1] * L[0] + R[1, 1] * L[1] + R[2, 1] * L[2]
    b2 = R[0, 2] * L[0] + R[1, 2] * L[1] + R[2, 2] * L[2]
    rot = (b0 * (inertia_inv[0, 0] * b0 + inertia_inv[0, 1] * b1 + inertia_inv[0, 2] * b2)
           + b1 * (inertia_inv[1, 0] * b0 + inertia_inv[1, 1] * b1 + inertia_inv[1, 2] * b2)
           + b2 * (inertia_inv[2, 0] * b0 + inertia_inv[2, 1] * b1 + inertia_inv[2, 2] * b2))
    modal = 0.0
    for i in range(qdot.shape[0]):
        modal += qdot[i] * qdot[i]
    kinetic = 0.5 * (mass * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + rot + modal)
    scale = math.sqrt(max(0.0, 1.0 - gain / kinetic)) if kinetic > 0.0 else 0.0
    for a in range(3):
        v[a] *= scale
        L[a] *= scale
    for i in range(qdot.shape[0]):
        qdot[i] *= scale


@numba.njit(cache=True)
def _push_scaled(s, q0, qd0, q, qdot, kinds, params, rest, vm, row_scale, radius, eps, R, c0, c, passes, no, nv):
    """The push-out (``push_shift``) of the body with its vibration scaled by s: q = s q0, qdot = s qd0, c from c0
    (all in place); returns the shift (3,) [m]."""
    for i in range(q.shape[0]):
        q[i] = s * q0[i]
        qdot[i] = s * qd0[i]
    c[0], c[1], c[2] = c0[0], c0[1], c0[2]
    skip, bound = modal_terms(q, row_scale, radius)
    slack = 4.0 * (q.shape[0] + 2) * eps * bound
    return push_shift(kinds, params, rest, vm, q, skip, R, c, bound, slack, passes, no, nv)


@numba.njit(cache=True)
def push_and_pay(kinds, params, rest, vm, row_scale, radius, eps, omega2, R, c, mass, accel, inertia_inv, v, L, q,
                 qdot, passes, no, nv):
    """``contact.push_out`` with its energy payment (both paths call this): translate the body (c (3,) [m], in
    place) so that no vertex is inside an obstacle and take the potential energy ``-mass accel . shift`` [J] the
    lift adds from the body's motion, so that the push-out adds no energy.

    The kinetic energy (rigid and modal) pays when it can (``pay_lift``: v, L, qdot scaled by one factor). When it
    cannot, the vertices inside are there because of the body's vibration (a body at rest whose modes, faster than
    the step and left out of the sustained solve, swing its vertices into the support; lifting the whole body by
    their amplitude costs more than the vibration holds; the velocities were zeroed, the deformation kept, and the
    next step released it again: a 7.85 kg steel bar resting across a box narrower than it had every 1 ms step
    halved seven levels deep by the energy guard, 39 ms per step instead of 0.13): the vibration is shrunk
    instead, q and qdot scaled by the largest s in [0, 1] (bisection, 40 halvings) for which the lift of the
    shrunk body is paid by the vibration energy removed plus the kinetic energy left, and the rest is paid as
    above. Shrinking the vibration only removes energy (the contact that stops it is inelastic). If even the rest
    shape needs an unpaid lift (the rigid body sunk into the support), the rest shape is lifted and the guard
    sees the gain. Returns the shift (3,) [m]. R (3, 3) body -> world; inertia_inv (3, 3) body axes; omega2 (r,)
    [rad^2/s^2]; no, nv: the obstacles and points of ``push_shift`` (box-edge points after the body's nv
    vertices, each held out of its own plane, obstacle ``no + i``)."""
    nm = q.shape[0]
    skip, bound = modal_terms(q, row_scale, radius)
    slack = 4.0 * (nm + 2) * eps * bound
    c0 = c.copy()
    total = push_shift(kinds, params, rest, vm, q, skip, R, c, bound, slack, passes, no, nv)
    gain = -mass * (accel[0] * total[0] + accel[1] * total[1] + accel[2] * total[2])
    if gain <= 0.0:
        return total
    b0 = R[0, 0] * L[0] + R[1, 0] * L[1] + R[2, 0] * L[2]  # the rigid kinetic energy as pay_lift forms it
    b1 = R[0, 1] * L[0] + R[1, 1] * L[1] + R[2, 1] * L[2]
    b2 = R[0, 2] * L[0] + R[1, 2] * L[1] + R[2, 2] * L[2]
    rot = (b0 * (inertia_inv[0, 0] * b0 + inertia_inv[0, 1] * b1 + inertia_inv[0, 2] * b2)
           + b1 * (inertia_inv[1, 0] * b0 + inertia_inv[1, 1] * b1 + inertia_inv[1, 2] * b2)
           + b2 * (inertia_inv[2, 0] * b0 + inertia_inv[2, 1] * b1 + inertia_inv[2, 2] * b2))
    kin_r = 0.5 * (mass * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + rot)
    kin_m = 0.0
    el = 0.0
    for i in range(nm):
        kin_m += 0.5 * qdot[i] * qdot[i]
        el += 0.5 * omega2[i] * q[i] * q[i]
    if gain <= kin_r + kin_m or (kin_m == 0.0 and el == 0.0):
        pay_lift(mass, accel, total, R, inertia_inv, v, L, qdot)  # (the motion pays, or there is no vibration)
        return total
    q0, qd0 = q.copy(), qdot.copy()
    vib = kin_m + el
    lo, hi = 0.0, 1.0  # hi: its lift not paid
    total = _push_scaled(0.0, q0, qd0, q, qdot, kinds, params, rest, vm, row_scale, radius, eps, R, c0, c, passes, no,
                         nv)
    need = -mass * (accel[0] * total[0] + accel[1] * total[1] + accel[2] * total[2]) - vib
    if need <= kin_r:
        for _ in range(40):
            s = 0.5 * (lo + hi)
            t = _push_scaled(s, q0, qd0, q, qdot, kinds, params, rest, vm, row_scale, radius, eps, R, c0, c, passes,
                             no, nv)
            nd = -mass * (accel[0] * t[0] + accel[1] * t[1] + accel[2] * t[2]) - (1.0 - s * s) * vib
            if nd <= kin_r + s * s * kin_m:
                lo = s
            else:
                hi = s
        total = _push_scaled(lo, q0, qd0, q, qdot, kinds, params, rest, vm, row_scale, radius, eps, R, c0, c,
                             passes, no, nv)
        need = -mass * (accel[0] * total[0] + accel[1] * total[1] + accel[2] * total[2]) - (1.0 - lo * lo) * vib
    if need > 0.0:  # the rest from the kinetic energy left (all of it if it is smaller)
        kin = kin_r + lo * lo * kin_m
        f = math.sqrt(max(0.0, 1.0 - need / kin)) if kin > 0.0 else 0.0
        for a in range(3):
            v[a] *= f
            L[a] *= f
        for i in range(nm):
            qdot[i] *= f
    return total


@numba.njit(cache=True)
def _matrix(qt):
    """``rotation.quat_to_matrix`` (the same expressions)."""
    w, x, y, z = qt[0], qt[1], qt[2], qt[3]
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    return R


@numba.njit(cache=True)
def matrix_into(qt, out):
    """``_matrix`` written into ``out`` (3, 3) (returning a new array from compiled code costs ~1.7 us)."""
    out[:, :] = _matrix(qt)


@numba.njit(cache=True)
def _free_rotation(qt, L, axes, moments, h):
    """``rotation.free_rotation_step`` in place on the quaternion qt (the same expressions and order)."""
    w, x, y, z = qt[0], qt[1], qt[2], qt[3]
    vx, vy, vz = L[0], L[1], L[2]
    ux, uy, uz = -x, -y, -z
    tx, ty, tz = 2 * (uy * vz - uz * vy), 2 * (uz * vx - ux * vz), 2 * (ux * vy - uy * vx)
    lx = vx + w * tx + (uy * tz - uz * ty)
    ly = vy + w * ty + (uz * tx - ux * tz)
    lz = vz + w * tz + (ux * ty - uy * tx)
    for step in range(5):  # rotation._SPLIT: x(h/2) y(h/2) z(h) y(h/2) x(h/2)
        k = (0, 1, 2, 1, 0)[step]
        frac = 1.0 if step == 2 else 0.5
        ax, ay, az = axes[k, 0], axes[k, 1], axes[k, 2]
        angle = frac * h * (ax * lx + ay * ly + az * lz) / moments[k]
        c, s = math.cos(0.5 * angle), math.sin(0.5 * angle)
        bx, by, bz = s * ax, s * ay, s * az
        w, x, y, z = (w * c - x * bx - y * by - z * bz, w * bx + x * c + y * bz - z * by,
                      w * by - x * bz + y * c + z * bx, w * bz + x * by - y * bx + z * c)
        ca, sa = math.cos(angle), -math.sin(angle)
        d = (ax * lx + ay * ly + az * lz) * (1.0 - ca)
        cx, cy, cz = ay * lz - az * ly, az * lx - ax * lz, ax * ly - ay * lx
        lx, ly, lz = lx * ca + cx * sa + ax * d, ly * ca + cy * sa + ay * d, lz * ca + cz * sa + az * d
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0:
        n = -n
    qt[0], qt[1], qt[2], qt[3] = w / n, x / n, y / n, z / n


@numba.njit(cache=True)
def _advance_free(pos, qt, v, L, q, qdot, force, torque, fmodal, mass, axes, moments, co, h):
    """``ModalSolver.advance_free`` with loads (no state-dependent effect) over h [s], in place; co (6, r): the
    integrator's coefficients of h (a11, a12, a21, a22, b1, b2)."""
    hh = 0.5 * h * h
    for a in range(3):
        acc = force[a] / mass
        pos[a] += h * v[a] + hh * acc
        v[a] += h * acc
        L[a] += 0.5 * h * torque[a]
    if L[0] != 0.0 or L[1] != 0.0 or L[2] != 0.0:
        _free_rotation(qt, L, axes, moments, h)
    for a in range(3):
        L[a] += 0.5 * h * torque[a]
    for i in range(q.shape[0]):
        q1 = co[0, i] * q[i] + co[1, i] * qdot[i]
        v1 = co[2, i] * q[i] + co[3, i] * qdot[i]
        q1 += co[4, i] * fmodal[i]
        v1 += co[5, i] * fmodal[i]
        q[i] = q1
        qdot[i] = v1


@numba.njit(cache=True)
def energy(mass, inertia_inv, omega2, pos, qt, v, L, q, qdot, force):
    """``(own, mechanical)``: rigid kinetic + modal energy [J] (``ModalSolver.energy``), and that minus
    ``force . pos`` (the potential of a constant force [N] at the position [m]): the energy guard's measure
    (mass [kg], inertia_inv (3, 3) body axes, omega2 (r,) [rad^2/s^2], the state's arrays)."""
    R = _matrix(qt)
    b = np.empty(3)
    for a in range(3):
        b[a] = R[0, a] * L[0] + R[1, a] * L[1] + R[2, a] * L[2]
    rot = 0.0
    for a in range(3):
        wa = 0.0
        for c in range(3):
            wa += R[a, c] * (inertia_inv[c, 0] * b[0] + inertia_inv[c, 1] * b[1] + inertia_inv[c, 2] * b[2])
        rot += L[a] * wa
    kin = 0.5 * mass * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + 0.5 * rot
    m0 = 0.0
    m1 = 0.0
    for i in range(q.shape[0]):
        m0 += qdot[i] * qdot[i]
        m1 += omega2[i] * q[i] * q[i]
    own = kin + 0.5 * (m0 + m1)
    return own, own - (force[0] * pos[0] + force[1] * pos[1] + force[2] * pos[2])


@numba.njit(cache=True)
def stop_share(mass, normal, lam_n, mu, v_start, v_after, accel, span):
    """``contact._stop_fraction``: the share (0, 1) of a sustained sub-step of span [s] after which the friction
    of its solve (normal impulses lam_n (k,) [N s] at normals (k, 3), friction mu (k,)) stops the sliding of the
    centre of mass (velocity v_start at the start, v_after after the mid-step impulse [m/s]; load acceleration
    accel [m/s^2]), or NaN when it does not stop inside (see there)."""
    k = lam_n.shape[0]
    if k == 0:
        return math.nan
    cone = 0.0
    best = 0
    anyp = False
    for i in range(k):
        cone += mu[i] * lam_n[i]
        if lam_n[i] > lam_n[best]:
            best = i
        if lam_n[i] > 0.0:
            anyp = True
    if not anyp or cone <= 0.0:
        return math.nan
    n0, n1, n2 = normal[best, 0], normal[best, 1], normal[best, 2]
    v0, v1, v2 = v_start[0], v_start[1], v_start[2]
    vn = n0 * v0 + n1 * v1 + n2 * v2
    t0, t1, t2 = v0 - n0 * vn, v1 - n1 * vn, v2 - n2 * vn
    s0 = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    if s0 == 0.0:
        return math.nan
    e0 = v_after[0] + 0.5 * span * accel[0]  # end-of-sub-step velocity
    e1 = v_after[1] + 0.5 * span * accel[1]
    e2 = v_after[2] + 0.5 * span * accel[2]
    en = n0 * e0 + n1 * e1 + n2 * e2
    e0, e1, e2 = e0 - n0 * en, e1 - n1 * en, e2 - n2 * en
    if math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) > 1e-3 * s0:  # still sliding at the end: friction was saturated
        return math.nan
    rate = cone / span - mass * (accel[0] * t0 + accel[1] * t1 + accel[2] * t2) / s0  # [N]
    if rate <= 0.0:
        return math.nan
    share = mass * s0 / (rate * span)
    if 1e-3 < share < 1.0 - 1e-6:
        return share
    return math.nan


@numba.njit(cache=True)
def sustained_step(kinds, params, first, margin, threshold, friction, modal_e, vertex, effect, local, gap, normal,
                   rest, vm, row_scale, radius, omega2, mass, inertia, inertia_inv, axes, moments, eps,
                   co_half, force, torque, fmodal, accel, h, iters, passes,
                   pos, qt, v, L, w, q, qdot, gap_mid, n_mid, lam_n, after_impact, own0, e0, rest_c, vm_c, no):
    """One contact step of h [s] as a single sustained sub-step, when that is what the Python path does.

    Args:
        kinds, params, first, margin, threshold, friction, modal_e: the obstacles and effects (``contact._Plan``:
            per obstacle its kind, parameters and margin [m]; per effect its first obstacle, bounce threshold
            [m/s], friction and modal flag); vertex, effect, local (k,): the contacts found at the start of the
            step (vertex, effect, obstacle within the effect), gap (k,) [m], normal (k, 3).
        rest, vm, row_scale, radius: the body's rest positions (nv, 3) [m], vertex-major modes, the modes'
            largest vertex displacement per unit q [m / (sqrt(kg) m)] (r,), radius [m]; omega2 (r,)
            [rad^2/s^2]; mass [kg]; inertia, inertia_inv (3, 3) body axes; axes (3, 3) principal axes (rows),
            moments (3,); eps: machine epsilon of the mode shapes' dtype.
        co_half: (6, r) integrator coefficients of h / 2; force, torque (3,) [N, N m] (torque 0), fmodal (r,)
            (0): the step's loads; accel (3,) = force / mass [m/s^2]; iters: solve sweeps; passes: push-out
            passes.
        pos, qt, v, L, q, qdot: the state (changed only when the step is done here); w (3,) [rad/s]: its
            angular velocity ``R I^-1 R^T L`` as the Python path forms it (``contact.normal_velocities``: the
            same normal velocities, so the same decisions on touching and impacts).
        gap_mid, n_mid, lam_n: (k,), (k, 3), (k,) outputs: mid-step gaps and normals, normal impulses [N s].
        after_impact: the state is the one after the impact solve of the contacts touching and approaching
            at the start of the step (the caller's, as the Python path's step 1.): no touching test then, and
            own0, e0 [J] are the energies (``energy``) before that solve, for the energy guard (else unused).
        rest_c, vm_c, no: the contacts' body points (``contact._EdgePoints``: the body's vertices, then the box-edge
            points; else ``rest``, ``vm``) and the number of real obstacles (the first ``no`` of ``kinds``,
            ``params``; the rest are the box-edge contacts' planes: the push-out holds each point out of its own).

    Returns:
        1 when the step was done (state and outputs written); 2 when contacts touch and approach now (an impact
        solve first: the caller's) and 0 when the Python path must do the step (an impact predicted in the
        step, a friction stop inside it, or energy gained); the state untouched in both.
    """
    k = vertex.shape[0]
    nm = q.shape[0]
    obstacle = np.empty(k, dtype=np.int64)
    slop = np.empty(k)  # 0.1 margin [m]
    thr = np.empty(k)
    mu = np.empty(k)
    modal = np.empty(k, dtype=np.bool_)
    anymodal = False
    for i in range(k):
        e = effect[i]
        o = first[e] + local[i]
        obstacle[i] = o
        slop[i] = 0.1 * margin[o]
        thr[i] = threshold[e]
        mu[i] = friction[e]
        modal[i] = modal_e[e]
        if modal[i]:
            anymodal = True
    R0 = _matrix(qt)
    skip, _ = modal_terms(q, row_scale, radius)
    vn = normal_velocities(vertex, rest_c, vm_c, q, skip, modal, R0, nm if anymodal else 0, normal, v, w, qdot)
    if not after_impact:
        for i in range(k):  # 1. an impact now: the caller's
            if gap[i] <= 1e-8 * slop[i] and vn[i] < 0.0:
                return 2
    t_fast, j, t_slow = crossings(gap, vn, normal, accel, thr, h)
    if j >= 0:  # 2. an impact predicted within the step
        return 0
    if not after_impact:
        own0, e0 = energy(mass, inertia_inv, omega2, pos, qt, v, L, q, qdot, force)
    # 3. one sustained sub-step over the whole step, on copies of the state
    p1, qt1, v1, L1, q1, qd1 = pos.copy(), qt.copy(), v.copy(), L.copy(), q.copy(), qdot.copy()
    _advance_free(p1, qt1, v1, L1, q1, qd1, force, torque, fmodal, mass, axes, moments, co_half, 0.5 * h)
    Rm = _matrix(qt1)
    rigid = np.ones(nm, dtype=np.bool_)  # the solve sees the rest shape: the modes it leaves out swing about it
    gm, nmid = gaps_at(vertex, obstacle, kinds, params, rest_c, vm_c, q1, rigid, Rm, p1)
    jt = np.empty((k, 3))
    resolve_rigid(vertex, rest_c, vm_c, q1, rigid, Rm, inertia, inertia_inv, mass, v1, L1, nmid, gm, mu, accel, h,
                  iters, lam_n, jt)
    if not math.isnan(stop_share(mass, nmid, lam_n, mu, v, v1, accel, h)):
        return 0
    _advance_free(p1, qt1, v1, L1, q1, qd1, force, torque, fmodal, mass, axes, moments, co_half, 0.5 * h)
    # push-out (contact.push_out with its energy payment)
    Re = _matrix(qt1)
    push_and_pay(kinds, params, rest_c, vm_c, row_scale, radius, eps, omega2, Re, p1, mass, accel, inertia_inv, v1, L1,
                 q1, qd1, passes, no, rest.shape[0])
    # energy guard (ModalSolver._contact_step_without_gain)
    own1, e1 = energy(mass, inertia_inv, omega2, p1, qt1, v1, L1, q1, qd1, force)
    fn = math.sqrt(force[0] * force[0] + force[1] * force[1] + force[2] * force[2])
    d0, d1, d2 = p1[0] - pos[0], p1[1] - pos[1], p1[2] - pos[2]
    scale = own1 + own0 + fn * (math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) + radius)
    if not e1 <= e0 + ENERGY_RTOL * scale:
        return 0
    pos[:] = p1
    qt[:] = qt1
    v[:] = v1
    L[:] = L1
    q[:] = q1
    qdot[:] = qd1
    gap_mid[:] = gm
    n_mid[:, :] = nmid
    return 1
