"""The rigid solve's block test (issue 17): ``_contact_body_kernels._applies`` decides for a block of contacts at
once (vectorised, branch-free) whether the Gauss-Seidel sweep of ``solve_rigid`` would update any of them, and the
sweep skips a block it clears. Both are checked against a plain-Python transcription of the sweep (the same
operations in the same order on IEEE doubles, so the same bits): the per-contact decision exactly at its threshold,
and the whole solve bit for bit on problems whose sweeps mix skipped and updated blocks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from modalfem.runtime import _contact_body_kernels as KB


def _setup(r, mass, Iw_inv, n):
    """solve_rigid's B (k, 3, 3), A (k, 3, 3) and Wn (k,), written out (the same expressions)."""
    k = len(r)
    im = 1.0 / mass
    B = [[[0.0] * 3 for _ in range(3)] for _ in range(k)]
    A = [[[0.0] * 3 for _ in range(3)] for _ in range(k)]
    Wn = [0.0] * k
    I = [[float(x) for x in row] for row in Iw_inv]
    for i in range(k):
        r0, r1, r2 = (float(x) for x in r[i])
        for a in range(3):
            B[i][a][0] = I[a][1] * r2 - I[a][2] * r1
            B[i][a][1] = -I[a][0] * r2 + I[a][2] * r0
            B[i][a][2] = I[a][0] * r1 - I[a][1] * r0
        for b in range(3):
            x0, x1, x2 = B[i][0][b], B[i][1][b], B[i][2][b]
            A[i][0][b] = x1 * r2 - x2 * r1
            A[i][1][b] = x2 * r0 - x0 * r2
            A[i][2][b] = x0 * r1 - x1 * r0
            A[i][b][b] += im
        s = 0.0
        for a in range(3):
            for b in range(3):
                s += float(n[i, a]) * A[i][a][b] * float(n[i, b])
        Wn[i] = 1.0 / s
    return B, A, Wn


def _update(i, r, n, target, mu, shift, A, Wn, lam_n, jt, v, w):
    """The sweep's update of contact i at v, w: (new, (c0, c1, c2), (d0, d1, d2), step)."""
    r0, r1, r2 = (float(x) for x in r[i])
    v0, v1, v2 = v
    w0, w1, w2 = w
    u0 = v0 + (w1 * r2 - w2 * r1) + float(shift[i, 0])
    u1 = v1 + (w2 * r0 - w0 * r2) + float(shift[i, 1])
    u2 = v2 + (w0 * r1 - w1 * r0) + float(shift[i, 2])
    n0, n1, n2 = (float(x) for x in n[i])
    vn = n0 * u0 + n1 * u1 + n2 * u2
    old = float(lam_n[i])
    new = max(old + (float(target[i]) - vn) * Wn[i], 0.0)
    dn = new - old
    d0, d1, d2 = dn * n0, dn * n1, dn * n2
    j0, j1, j2 = (float(x) for x in jt[i])
    c0, c1, c2 = j0, j1, j2
    a = A[i]
    if mu[i] > 0.0:
        ui0 = u0 + a[0][0] * d0 + a[0][1] * d1 + a[0][2] * d2
        ui1 = u1 + a[1][0] * d0 + a[1][1] * d1 + a[1][2] * d2
        ui2 = u2 + a[2][0] * d0 + a[2][1] * d1 + a[2][2] * d2
        un = n0 * ui0 + n1 * ui1 + n2 * ui2
        ut0, ut1, ut2 = ui0 - n0 * un, ui1 - n1 * un, ui2 - n2 * un
        s2 = ut0 * ut0 + ut1 * ut1 + ut2 * ut2
        if s2 > 0.0:
            tat = (ut0 * (a[0][0] * ut0 + a[0][1] * ut1 + a[0][2] * ut2)
                   + ut1 * (a[1][0] * ut0 + a[1][1] * ut1 + a[1][2] * ut2)
                   + ut2 * (a[2][0] * ut0 + a[2][1] * ut1 + a[2][2] * ut2))
            f = s2 / tat
            c0 -= f * ut0
            c1 -= f * ut1
            c2 -= f * ut2
        lim = float(mu[i]) * new
        n2c = c0 * c0 + c1 * c1 + c2 * c2
        if n2c > lim * lim:
            f = lim / math.sqrt(n2c)
            c0 *= f
            c1 *= f
            c2 *= f
        d0 += c0 - j0
        d1 += c1 - j1
        d2 += c2 - j2
    e0 = a[0][0] * d0 + a[0][1] * d1 + a[0][2] * d2
    e1 = a[1][0] * d0 + a[1][1] * d1 + a[1][2] * d2
    e2 = a[2][0] * d0 + a[2][1] * d1 + a[2][2] * d2
    return new, (c0, c1, c2), (d0, d1, d2), max(abs(e0), abs(e1), abs(e2))


def _reference_solve(r, mass, Iw_inv, V, n, target, mu, shift, iters, lam, jt, lam_n, guess):
    """solve_rigid written out contact by contact (no blocks), in place on V, lam, jt, lam_n; returns the sweeps."""
    k = len(r)
    im = 1.0 / mass
    B, A, Wn = _setup(r, mass, Iw_inv, n)
    v = [float(x) for x in V[:3]]
    w = [float(x) for x in V[3:]]
    if guess and k > 1:
        d = [0.0] * 3
        e = [0.0] * 3
        for i in range(k):
            for a in range(3):
                d[a] += float(n[i, a]) * im
                e[a] += B[i][a][0] * float(n[i, 0]) + B[i][a][1] * float(n[i, 1]) + B[i][a][2] * float(n[i, 2])
        resid = slope = 0.0
        for i in range(k):
            r0, r1, r2 = (float(x) for x in r[i])
            u0 = v[0] + (w[1] * r2 - w[2] * r1) + float(shift[i, 0])
            u1 = v[1] + (w[2] * r0 - w[0] * r2) + float(shift[i, 1])
            u2 = v[2] + (w[0] * r1 - w[1] * r0) + float(shift[i, 2])
            t0 = d[0] + (e[1] * r2 - e[2] * r1)
            t1 = d[1] + (e[2] * r0 - e[0] * r2)
            t2 = d[2] + (e[0] * r1 - e[1] * r0)
            resid += float(target[i]) - (float(n[i, 0]) * u0 + float(n[i, 1]) * u1 + float(n[i, 2]) * u2)
            slope += float(n[i, 0]) * t0 + float(n[i, 1]) * t1 + float(n[i, 2]) * t2
        if slope > 0.0 and resid > 0.0:
            gg = resid / slope
            v = [v[a] + gg * d[a] for a in range(3)]
            w = [w[a] + gg * e[a] for a in range(3)]
            for i in range(k):
                lam_n[i] = gg
                lam[i] = [gg * float(n[i, 0]), gg * float(n[i, 1]), gg * float(n[i, 2])]
    rmax = vs = 0.0
    for i in range(k):
        rmax = max(rmax, math.sqrt(sum(float(x) * float(x) for x in r[i])))  # (r0^2 + r1^2) + r2^2, as the kernel
        vs = max(vs, abs(float(target[i])), math.sqrt(float(shift[i, 0]) * float(shift[i, 0])
                                                      + float(shift[i, 1]) * float(shift[i, 1])
                                                      + float(shift[i, 2]) * float(shift[i, 2])))
    vs += math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]) * rmax
    tol = KB.TOLERANCE * vs
    done = iters
    for sweep in range(iters):
        change = 0.0
        for i in range(k):
            new, c, dd, step = _update(i, r, n, target, mu, shift, A, Wn, lam_n, jt, v, w)
            if step <= tol:
                continue
            lam_n[i] = new
            jt[i] = c
            lam[i] += dd
            for a in range(3):
                v[a] += dd[a] * im
                w[a] += B[i][a][0] * dd[0] + B[i][a][1] * dd[1] + B[i][a][2] * dd[2]
            change = max(change, step)
        if change <= tol:
            done = sweep + 1
            break
    V[:] = v + w
    return done


def _problem(seed, k, friction, spread):
    """Contacts of a body on a tilted face: lever arms, unit normals, targets (spread: how far they are from
    uniform: 0 is a resting body's equal targets), friction mu, a uniform load shift."""
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(3, 3))
    Iw_inv = np.linalg.inv(M @ M.T + 0.05 * np.eye(3))
    r = rng.uniform(-0.2, 0.2, size=(k, 3))
    r[:, 2] = -0.05 + 0.01 * r[:, 0]
    n = np.tile(np.array([0.05, 0.0, 1.0]) / np.linalg.norm([0.05, 0.0, 1.0]), (k, 1))
    target = 0.01 + spread * rng.uniform(-0.01, 0.01, size=k)
    mu = np.where(rng.uniform(size=k) < 0.2, 0.0, friction)
    shift = np.tile([0.0, 0.0, -0.0049], (k, 1))
    V = np.array([0.02, -0.01, -0.005, 0.3, -0.1, 0.05]) * (1.0 if spread else 0.0)
    return r, 2.5, Iw_inv, V, n, target, mu, shift


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("friction", [0.0, 0.6])
@pytest.mark.parametrize("spread", [0.0, 1e-9, 0.5])
@pytest.mark.parametrize("k", [1, 31, 70])
def test_solve_rigid_with_block_skipping_equals_the_contact_by_contact_sweep_bit_for_bit(seed, friction, spread, k):
    """Resting (equal targets: the uniform guess meets them, the first sweep skips every block), nearly resting
    (a few contacts updated, most blocks skipped) and disturbed contacts; k across the block size (32)."""
    r, mass, Iw_inv, V0, n, target, mu, shift = _problem(seed, k, friction, spread)
    _assert_same_as_reference(r, mass, Iw_inv, V0, n, target, mu, shift, np.zeros((k, 3)), np.zeros(k), True)


def _assert_same_as_reference(r, mass, Iw_inv, V0, n, target, mu, shift, jt0, lam_n0, guess):
    """solve_rigid and _reference_solve (25 sweeps) from copies of the same start: the same sweep count and the same
    bits of V, lam, jt and lam_n. Returns solve_rigid's jt."""
    out = []
    for solve in (KB.solve_rigid, _reference_solve):
        V, lam, jt, lam_n = V0.copy(), np.zeros((len(r), 3)), jt0.copy(), lam_n0.copy()
        sweeps = solve(r, mass, Iw_inv, V, n, target, mu, shift, 25, lam, jt, lam_n, guess)
        out.append((sweeps, V, lam, jt, lam_n))
    (s1, *a1), (s2, *a2) = out
    assert s1 == s2
    for x, y in zip(a1, a2):
        assert np.array_equal(x, y)
    return out[0][3]


def _soa(r, n, shift, A, jt):
    k = len(r)
    At = np.empty((9, k))
    for i in range(k):
        for a in range(3):
            for b in range(3):
                At[3 * a + b, i] = A[i][a][b]
    return (np.ascontiguousarray(r.T), np.ascontiguousarray(n.T), np.ascontiguousarray(shift.T), At,
            np.ascontiguousarray(jt.T))


def test_block_test_decides_each_contact_as_the_sweep_to_the_last_bit():
    """Per contact: _applies counts 0 with tol exactly the sweep's velocity change of that contact and 1 with the
    next smaller double; contacts with and without friction, clamped to the cone or not, with an old impulse and
    a friction impulse from earlier sweeps, and one with no tangential velocity (its s2 = 0 branch)."""
    k = 40
    r, mass, Iw_inv, _, n, target, mu, shift = _problem(5, k, 0.4, 1.0)
    rng = np.random.default_rng(8)
    mu[::3] = rng.uniform(0.0, 2.0, size=len(mu[::3]))  # mixed friction: some cones clamp, some do not
    n[1:] = rng.normal(size=(k - 1, 3))  # normals every way: each velocity component the largest somewhere
    n[1:] /= np.linalg.norm(n[1:], axis=1)[:, None]
    lam_n = np.where(rng.uniform(size=k) < 0.5, rng.uniform(0.0, 0.02, size=k), 0.0)
    jt = rng.normal(scale=0.003, size=(k, 3))
    jt[::4] = 0.0
    r[0] = 0.0  # contact 0: no lever arm, velocity along its normal only: no tangential part
    n[0] = (0.0, 0.0, 1.0)
    shift[0] = (0.0, 0.0, -0.0049)
    B, A, Wn = _setup(r, mass, Iw_inv, n)
    v, w = [0.0, 0.0, -0.2], [0.0, 0.0, 0.0]
    steps = [_update(i, r, n, target, mu, shift, A, Wn, lam_n, jt, v, w)[3] for i in range(k)]
    for i in range(1, k):  # (the others at a common shift of 0: a uniform shift with its contact 0 kept)
        shift[i] = (0.0, 0.0, -0.0049)
    rT, nT, sT, At, jT = _soa(r, n, shift, A, jt)
    Wn = np.array(Wn)
    clamped = 0
    largest = set()
    for i in range(k):
        s = steps[i]
        at = KB._applies(i, i + 1, rT, nT, target, mu, sT, At, Wn, lam_n, jT, *v, *w, s)
        below = KB._applies(i, i + 1, rT, nT, target, mu, sT, At, Wn, lam_n, jT, *v, *w, np.nextafter(s, -1.0))
        assert (at, below) == (0, 1), i
        new, c, _, _ = _update(i, r, n, target, mu, shift, A, Wn, lam_n, jt, v, w)
        clamped += mu[i] > 0.0 and abs(math.hypot(*c) - mu[i] * new) <= 1e-12 * mu[i] * new
        dd = _update(i, r, n, target, mu, shift, A, Wn, lam_n, jt, v, w)[2]
        e = [abs(A[i][a][0] * dd[0] + A[i][a][1] * dd[1] + A[i][a][2] * dd[2]) for a in range(3)]
        largest.add(int(np.argmax(e)))
    assert 0 < clamped < k  # both branches of the cone taken
    assert sum(s > 0.0 for s in steps) > k // 2
    assert largest == {0, 1, 2}
    order = np.argsort(steps)
    tol = steps[order[k // 2]]
    assert KB._applies(0, k, rT, nT, target, mu, sT, At, Wn, lam_n, jT, *v, *w, tol) == sum(s > tol for s in steps)
    assert KB._applies(5, 37, rT, nT, target, mu, sT, At, Wn, lam_n, jT, *v, *w, tol) == sum(
        s > tol for s in steps[5:37])


def test_block_test_counts_a_nan_update_as_applied():
    k = 3
    r, mass, Iw_inv, _, n, target, mu, shift = _problem(2, k, 0.5, 1.0)
    B, A, Wn = _setup(r, mass, Iw_inv, n)
    target[1] = np.nan
    rT, nT, sT, At, jT = _soa(r, n, shift, A, np.zeros((k, 3)))
    assert KB._applies(0, k, rT, nT, target, mu, sT, At, np.array(Wn), np.zeros(k), jT, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                       math.inf) == 1


@pytest.mark.parametrize("k", [20, 45])
def test_solve_rigid_warm_started_outside_the_friction_cone_equals_the_contact_by_contact_sweep(k):
    """A body at rest given normal impulses already meeting every target (no normal update) and friction impulses
    outside their cones: the sweep's updates are the clamps alone, which a block test that saw other friction
    impulses than the sweep's (say none) would skip. Bit for bit against the written-out sweep."""
    r, mass, Iw_inv, V0, n, target, mu, shift = _problem(4, k, 0.5, 1.0)
    mu[:] = 0.5
    V0[:] = 0.0  # at rest, no load shift: no tangential velocity either (a zero-impulse guess would see nothing)
    shift[:] = 0.0
    lam_n0 = np.full(k, 0.01)
    rng = np.random.default_rng(6)
    t = rng.normal(size=(k, 3))
    t -= (t * n).sum(axis=1)[:, None] * n
    t /= np.linalg.norm(t, axis=1)[:, None]
    jt0 = 3.0 * 0.5 * 0.01 * t  # three times the cone
    v, w = [float(x) for x in V0[:3]], [float(x) for x in V0[3:]]
    for i in range(k):  # targets equal to the contacts' normal velocities: x = old exactly
        r0, r1, r2 = (float(x) for x in r[i])
        u = (v[0] + (w[1] * r2 - w[2] * r1) + float(shift[i, 0]), v[1] + (w[2] * r0 - w[0] * r2) + float(shift[i, 1]),
             v[2] + (w[0] * r1 - w[1] * r0) + float(shift[i, 2]))
        target[i] = float(n[i, 0]) * u[0] + float(n[i, 1]) * u[1] + float(n[i, 2]) * u[2]
    jt = _assert_same_as_reference(r, mass, Iw_inv, V0, n, target, mu, shift, jt0, lam_n0, False)
    assert not np.array_equal(jt, jt0)  # the clamps were applied
