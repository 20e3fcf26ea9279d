"""The solid solve's sweeps stop per island (``_kernels.sequential_impulses``'s ``island`` labels, issue 17): an island
whose impulses have converged is not swept again while others go on, and each island's result is that of solving it
alone, bit for bit (same contacts in the same order, same arithmetic). Before, every island was swept until all had
converged (one shared stop), so an island's impulses depended on the others' convergence.

The contacts here are synthetic: bodies with blocks of 6 + r velocities, random Jacobians and symmetric positive
definite inverse masses, so each contact's effective inverse mass is positive definite; islands of very different
difficulty (one contact alone converges in a couple of sweeps, a chain of coupled bodies needs many), so a shared
stop gives other numbers than the islands alone."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.world import _kernels


def _contacts(rng, groups, size, per_pair, obstacle):
    """Solve arrays of contacts among bodies of ``size`` velocities each: within every group of body indices, ``per_pair``
    contacts between consecutive bodies and ``obstacle`` contacts of each body with a fixed obstacle; the contacts of
    all groups interleaved (so skipping a converged island happens mid-sweep)."""
    m = 1 + max(max(g) for g in groups)
    Minv = []
    for _ in range(m):
        A = rng.normal(size=(size, size))
        Minv.append(A @ A.T / size + 0.5 * np.eye(size))
    pairs = []
    for g in groups:
        for b in g:
            pairs += [(b, -1)] * obstacle
        for a, b in zip(g[:-1], g[1:]):
            pairs += [(a, b)] * per_pair
    pairs = [pairs[i] for i in rng.permutation(len(pairs))]
    ptr, off, nd, jptr, J, WJt, body = [0], [], [], [], [], [], []
    jl = 0
    for a, b in pairs:
        for side, x in ((1.0, a), (-1.0, b)):
            if x < 0:
                continue
            Jx = side * rng.normal(size=(3, size))
            off.append(x * size)
            nd.append(size)
            jptr.append(jl)
            J.append(Jx.reshape(-1))
            WJt.append((Minv[x] @ Jx.T).reshape(-1))
            jl += 3 * size
        ptr.append(len(off))
        body.append(a)
    i64 = lambda v: np.asarray(v, dtype=np.int64)  # noqa: E731
    data = {"ptr": i64(ptr), "off": i64(off), "nd": i64(nd), "jptr": i64(jptr), "J": np.concatenate(J),
            "WJt": np.concatenate(WJt)}
    data["K"] = _kernels.effective_masses(data["ptr"], data["off"], data["nd"], data["jptr"], data["J"], data["WJt"])
    k = len(pairs)
    nrm = rng.normal(size=(k, 3))
    data["normal"] = nrm / np.linalg.norm(nrm, axis=1)[:, None]
    data["V"] = rng.normal(size=m * size)
    u = _kernels.contact_velocities(data["V"], data["ptr"], data["off"], data["nd"], data["jptr"], data["J"])
    vn = np.einsum("ij,ij->i", u, data["normal"])
    data["target"] = vn + rng.uniform(-0.3, 1.0, k)  # most approaching, some separating
    data["mu"] = rng.choice([0.0, 0.5], k)
    data["lam_n"] = np.where(rng.uniform(size=k) < 0.3, rng.uniform(0.0, 0.1, k), 0.0)
    data["body"] = i64(body)
    label = np.empty(m, dtype=np.int64)
    for i, g in enumerate(groups):
        label[list(g)] = i
    data["island"] = label[data["body"]]
    return data


def _run(data, sel, island, iterations, vtol):
    """``sequential_impulses`` over the contacts ``sel`` (in order) with labels ``island``: (V, lam_n, lam_t, sweeps)."""
    sub = {}
    ptr = data["ptr"]
    ents = np.concatenate([np.arange(ptr[c], ptr[c + 1]) for c in sel])
    sub["ptr"] = np.concatenate([[0], np.cumsum(ptr[sel + 1] - ptr[sel])]).astype(np.int64)
    sub["off"], sub["nd"], sub["jptr"] = data["off"][ents], data["nd"][ents], data["jptr"][ents]
    V, lam_n, lam_t = data["V"].copy(), data["lam_n"][sel].copy(), np.zeros((len(sel), 3))
    sweeps = _kernels.sequential_impulses(V, sub["ptr"], sub["off"], sub["nd"], sub["jptr"], data["J"], data["WJt"],
                                          data["K"][sel], np.ascontiguousarray(data["normal"][sel]),
                                          data["target"][sel], data["mu"][sel], iterations, lam_n, lam_t, vtol,
                                          island)
    return V, lam_n, lam_t, sweeps


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("vtol", [0.0, 1e-6])
def test_each_island_stops_on_its_own_as_if_alone(seed, vtol):
    rng = np.random.default_rng(seed)
    size = 8
    groups = [(0,), (1, 2, 3), (4, 5), (6,)]
    data = _contacts(rng, groups, size, per_pair=3, obstacle=2)
    k = len(data["body"])
    iterations = 2000
    every = np.arange(k)
    V, lam_n, lam_t, sweeps = _run(data, every, data["island"], iterations, vtol)
    alone_sweeps = []
    for i, g in enumerate(groups):
        sel = np.flatnonzero(data["island"] == i)
        Va, ln_a, lt_a, sw = _run(data, sel, np.zeros(len(sel), dtype=np.int64), iterations, vtol)
        alone_sweeps.append(sw)
        vel = np.concatenate([np.arange(b * size, (b + 1) * size) for b in g])
        # bit for bit: the same contacts in the same order, the same arithmetic, whatever the other islands do
        assert np.array_equal(V[vel], Va[vel]), f"island {i}"
        assert np.array_equal(lam_n[sel], ln_a) and np.array_equal(lam_t[sel], lt_a), f"island {i}"
    assert sweeps == max(alone_sweeps)
    # the islands took different sweep counts (else this test could not tell a shared stop from per-island ones),
    # and the shared stop (one label) sweeps the fast islands on: other numbers there
    assert min(alone_sweeps) < max(alone_sweeps) < iterations
    _, ln_s, _, _ = _run(data, every, np.zeros(k, dtype=np.int64), iterations, vtol)
    assert not np.array_equal(ln_s, lam_n)


def test_labels_need_not_be_dense():
    """Labels with gaps (an island label no contact carries) stop as the dense ones."""
    rng = np.random.default_rng(5)
    data = _contacts(rng, [(0, 1), (2,)], 8, per_pair=4, obstacle=2)
    k = len(data["body"])
    a = _run(data, np.arange(k), data["island"], 100, 0.0)
    b = _run(data, np.arange(k), 3 * data["island"] + 1, 100, 0.0)
    assert a[3] == b[3]
    for x, y in zip(a[:3], b[:3]):
        assert np.array_equal(x, y)


def _dense(data, nv):
    """Per contact its Jacobian (3, nv) and W J^T (nv, 3), dense, from the entries."""
    ptr = data["ptr"]
    k = len(ptr) - 1
    Js, Ws = np.zeros((k, 3, nv)), np.zeros((k, nv, 3))
    for c in range(k):
        for e in range(ptr[c], ptr[c + 1]):
            o, m, b = data["off"][e], data["nd"][e], data["jptr"][e]
            Js[c][:, o:o + m] += data["J"][b:b + 3 * m].reshape(3, m)
            Ws[c][o:o + m, :] += data["WJt"][b:b + 3 * m].reshape(m, 3)
    return Js, Ws


@pytest.mark.parametrize("seed", [0, 1])
def test_solve_start_is_the_warm_start_targets_and_bounces(seed):
    """``_kernels.solve_start`` (the solve's set-up in one compiled pass) against the formulas of ``_solid_stage._solve``
    written out here with dense Jacobians: the warm start's normal part and its tangential part clamped to the
    friction disc (elementwise, the same operations: equal), the targets (gap closing, push-out, restitution on the
    approach at the step start, the obstacle's velocity) and bounces, and the velocities with the warm impulses
    applied. Tolerances: a sum of m products rounds by at most m eps of the sum of their sizes."""
    from modalfem.world._shared import BOUNCE_THRESHOLD, PUSH_OUT

    rng = np.random.default_rng(seed)
    size = 8
    data = _contacts(rng, [(0, 1, 2), (3,)], size, per_pair=12, obstacle=8)
    V = data["V"]
    nv, k = len(V), len(data["body"])
    n = data["normal"]
    dt = 1e-3
    margin = rng.choice([1e-3, 2e-3], k)
    gap = rng.uniform(-1e-3, 3e-3, k)
    e = rng.choice([0.0, 0.3], k)
    vobs = np.where(rng.uniform(size=k) < 0.3, rng.normal(size=k), 0.0)
    mu = rng.choice([0.0, 0.2, 1.0], k)
    warm = np.where(rng.uniform(size=(k, 1)) < 0.8, rng.normal(size=(k, 3)), 0.0)
    soff = np.arange(4, dtype=np.int64) * size
    gdt = rng.normal(size=(4, 3)) * 0.01
    V1 = V.copy()
    lam_n, lam_t, target, bounce, V0, min_skin = _kernels.solve_start(
        V1, data["ptr"], data["off"], data["nd"], data["jptr"], data["J"], data["WJt"], n, vobs, gap, margin, e, mu,
        warm, dt, PUSH_OUT, BOUNCE_THRESHOLD, soff, gdt)
    # warm start
    p = warm[:, 0] * n[:, 0] + warm[:, 1] * n[:, 1] + warm[:, 2] * n[:, 2]
    ln = np.maximum(p, 0.0)
    t = warm - p[:, None] * n
    tn = np.sqrt(t[:, 0] * t[:, 0] + t[:, 1] * t[:, 1] + t[:, 2] * t[:, 2])
    lim = mu * ln
    lt = t * np.where(tn <= lim, 1.0, lim / np.where(tn > 0, tn, 1.0))[:, None]
    assert np.array_equal(lam_n, ln) and np.array_equal(lam_t, lt)
    assert np.count_nonzero(ln) > 0.2 * k and np.count_nonzero(np.linalg.norm(lt, axis=1) < tn) > 0.1 * k
    # targets: approach at the end (V) and at the start (V less g dt on the linear velocities)
    Js, Ws = _dense(data, nv)
    Vs = V.copy()
    for i in range(len(soff)):
        Vs[soff[i]:soff[i] + 3] -= gdt[i]
    eps = np.finfo(float).eps
    m = nv + 3
    v_in = np.einsum("kdj,j,kd->k", Js, Vs, n) - vobs
    tol_in = m * eps * (np.einsum("kdj,j,kd->k", np.abs(Js), np.abs(Vs), np.abs(n)) + np.abs(vobs))
    skin = 0.5 * margin
    tg = np.where(gap > skin, -(gap - skin) / dt, PUSH_OUT * (skin - gap) / dt)
    want = (v_in < -BOUNCE_THRESHOLD) & (e > 0) & (gap <= margin)
    sure = np.abs(v_in + BOUNCE_THRESHOLD) > tol_in  # away from the threshold by more than the rounding
    assert np.array_equal(bounce[sure], want[sure]) and 0 < np.count_nonzero(want) < k
    tgt = np.where(want, np.maximum(tg, -e * v_in), tg) + vobs
    assert np.all(np.abs(target - tgt)[sure] <= e[sure] * tol_in[sure] + 4 * eps * (np.abs(tgt) + np.abs(vobs))[sure])
    assert min_skin == skin.min()
    # the warm impulses applied
    assert np.array_equal(V0, V)
    d = ln[:, None] * n + lt
    dV = np.einsum("kjd,kd->j", Ws, d)
    size_dV = np.einsum("kjd,kd->j", np.abs(Ws), np.abs(d))
    assert np.all(np.abs(V1 - (V + dV)) <= (k * 3 + 2) * eps * (size_dV + np.abs(V)))
