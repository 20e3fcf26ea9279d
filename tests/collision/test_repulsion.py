"""Pair impulses against plain loops over the pairs: the per-vertex averaging of many pairs' changes (CCD
passes) and the pair-by-pair sweeps of stage (a)."""

from __future__ import annotations

import numpy as np

from modalfem.collision._impulse_kernels import ROUNDING
from modalfem.collision.repulsion import apply_pair_impulses, sequential_pair_impulses


def _reference(V, invm, quads, w, n, target, friction):
    """One pair at a time: the change each pair wants, summed per vertex and divided by the vertex's
    summed weights |w| (when above 1)."""
    dV = np.zeros_like(V)
    cnt = np.zeros(len(V))
    active = 0
    for q, wk, nk, tk in zip(quads, w, n, target):
        vr = wk @ V[q]
        vn = vr @ nk
        dvn = max(tk - vn, 0.0)
        den = np.sum(wk * wk * invm[q])
        if not (dvn > ROUNDING * (abs(tk) + abs(vn)) and den > 0):
            continue
        active += 1
        dv_rel = dvn * nk
        vt = vr - vn * nk
        tn = np.linalg.norm(vt)
        if friction > 0:
            dv_rel = dv_rel - min(friction * dvn / (tn if tn > 0 else 1.0), 1.0) * vt
        for j in range(4):
            dV[q[j]] += wk[j] * invm[q[j]] / den * dv_rel
            cnt[q[j]] += abs(wk[j]) * (invm[q[j]] > 0)
    return dV / np.maximum(cnt, 1.0)[:, None], active


def test_pair_impulses_match_a_loop_over_the_pairs():
    rng = np.random.default_rng(2)
    N, k = 40, 300  # many pairs per vertex
    V = rng.standard_normal((N, 3))
    invm = rng.uniform(0.5, 2.0, N)
    invm[:5] = 0.0  # kinematic vertices
    quads = np.array([rng.choice(N, 4, replace=False) for _ in range(k)])
    w = rng.standard_normal((k, 4))
    n = rng.standard_normal((k, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    target = rng.uniform(-0.5, 1.0, k)
    for friction in (0.0, 0.4):
        dV, active = apply_pair_impulses(V, invm, quads, w, n, target, friction=friction)
        ref, ref_active = _reference(V, invm, quads, w, n, target, friction)
        assert active == ref_active > 0
        assert np.allclose(dV, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
        assert not dV[:5].any()  # kinematic vertices never move


def _sequential_reference(V, invm, quads, w, n, target, friction, sweeps):
    """Pair by pair, forwards then backwards in turn: each pair's whole change at once."""
    V = V.copy()
    done = active = 0
    for s in range(sweeps):
        done, active = s + 1, 0
        order = range(len(quads)) if s % 2 == 0 else range(len(quads) - 1, -1, -1)
        for p in order:
            q, wk, nk = quads[p], w[p], n[p]
            vr = wk @ V[q]
            vn = vr @ nk
            dvn = max(target[p] - vn, 0.0)
            den = np.sum(wk * wk * invm[q])
            if not (dvn > ROUNDING * (abs(target[p]) + abs(vn)) and den > 0):
                continue
            active += 1
            dv_rel = dvn * nk
            vt = vr - vn * nk
            if friction > 0:
                tn = np.linalg.norm(vt)
                dv_rel = dv_rel - min(friction * dvn / (tn if tn > 0 else 1.0), 1.0) * vt
            for j in range(4):
                V[q[j]] += wk[j] * invm[q[j]] / den * dv_rel
        if active == 0:
            break
    return V, done, active


def _random_pairs(seed, N=40, k=300):
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((N, 3))
    invm = rng.uniform(0.5, 2.0, N)
    invm[:5] = 0.0
    quads = np.array([rng.choice(N, 4, replace=False) for _ in range(k)])
    w = rng.standard_normal((k, 4))
    n = rng.standard_normal((k, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    return V, invm, quads, w, n, rng.uniform(-0.5, 1.0, k)


def test_sequential_sweeps_match_a_loop_over_the_pairs():
    V, invm, quads, w, n, target = _random_pairs(3)
    for friction in (0.0, 0.4):
        for sweeps in (1, 2, 7):
            got, done, active = sequential_pair_impulses(V, invm, quads, w, n, target, friction=friction,
                                                         sweeps=sweeps)
            ref, ref_done, ref_active = _sequential_reference(V, invm, quads, w, n, target, friction, sweeps)
            assert (done, active) == (ref_done, ref_active) and done == sweeps and active > 0
            assert np.allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
            assert np.array_equal(got[:5], V[:5])  # kinematic vertices never move


def test_sequential_sweeps_converge_where_averaged_passes_lag():
    """Without friction the sweeps are projected Gauss-Seidel on the pairs' constraints: they end with
    every pair at or above its target, and, pass for pass, leave less approach than averaged passes."""
    V, invm, quads, w, n, target = _random_pairs(4, N=60, k=200)

    def worst(Vx):
        return float(np.max(target - np.einsum("kj,kji,ki->k", w, Vx[quads], n)))

    got, done, active = sequential_pair_impulses(V, invm, quads, w, n, target, sweeps=5000)
    assert active == 0 and done < 5000 and worst(got) <= 1e-9  # m/s, velocities of order 1
    Vj = V.copy()
    for _ in range(10):
        Vj = Vj + apply_pair_impulses(Vj, invm, quads, w, n, target)[0]
    assert worst(sequential_pair_impulses(V, invm, quads, w, n, target, sweeps=10)[0]) < 0.8 * worst(Vj)


def test_repulsion_impulses_stop_pressed_layers_approaching():
    """Stage (a) as a function: two sheets 2 mm apart (h = 4 mm) pressed together; with enough sweeps no
    close pair approaches faster than its target allows, and the sheets' momentum is kept (frictionless,
    equal masses, no kinematic vertex: the impulses are internal)."""
    from _meshes import all_pairs, stacked_sheets

    from modalfem.collision.repulsion import repulsion_impulses, repulsion_pairs

    x0, tri = stacked_sheets(2, 5, gap=0.002, seed=1)
    V = np.zeros_like(x0)
    V[:, 2] = np.where(x0[:, 2] > 0.001, -0.5, 0.5)
    invm = np.ones(len(x0))
    vf, ee = all_pairs(tri)
    dV, count = repulsion_impulses(x0, V, invm, vf, ee, thickness=0.004, dt=0.01, friction=0.0, sweeps=500)
    quads, w, n, target = repulsion_pairs(x0, vf, ee, thickness=0.004, dt=0.01)
    assert count == len(quads) > 0
    vn = np.einsum("kj,kji,ki->k", w, (V + dV)[quads], n)
    assert np.max(target - vn) < 1e-6  # m/s
    assert np.allclose((V + dV).sum(axis=0), V.sum(axis=0), atol=1e-9)


def _spread_pairs(seed, N=3000, k=6000):
    """Pairs of nearby vertices along a 1 m strip (each pair within 30 consecutive vertices in x), many per
    vertex, some vertices kinematic: enough pairs for several groups of the parallel sweeps."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(0.0, 1.0, (N, 3)) * np.array([1.0, 0.05, 0.05])
    X = X[np.argsort(X[:, 0])]
    V = rng.standard_normal((N, 3))
    invm = rng.uniform(0.5, 2.0, N)
    invm[rng.choice(N, 50, replace=False)] = 0.0
    start = rng.integers(0, N - 30, k)
    quads = np.array([s + rng.choice(30, 4, replace=False) for s in start])
    w = rng.standard_normal((k, 4))
    n = rng.standard_normal((k, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    return X, V, invm, quads, w, n, rng.uniform(-0.5, 1.0, k)


def test_grouped_sweeps_stop_where_the_sequential_sweeps_stop():
    """The parallel sweeps run a sweep's last colour and the next sweep's first in one loop; the sweeps they report
    and the velocities are still those of the sequential sweeps that stop after the first sweep in which no pair
    acts: every pair already at its target (no pair acts in sweep 1), or vertex-disjoint pairs below it (each
    acts once in sweep 1, none in sweep 2), on 1 and 2 threads."""
    from modalfem._threads import thread_count
    from modalfem.collision.repulsion import pair_order

    X, V, invm, quads, w, n, _ = _spread_pairs(8)
    order = pair_order(X, invm > 0, quads)
    p = order.perm
    vn = np.einsum("kj,kji,ki->k", w, V[quads], n)
    used = np.zeros(len(X), dtype=bool)
    low = []
    for k in range(0, len(quads), 7):  # vertex-disjoint pairs with a movable vertex
        if not used[quads[k]].any() and (invm[quads[k]] > 0).any():
            used[quads[k]] = True
            low.append(k)
    assert len(low) > 100
    for lifted, want in ((False, 1), (True, 2)):
        target = vn - 1.0  # m/s below what every pair has
        if lifted:
            target[low] = vn[low] + 0.01
        for sweeps in (1, 2, 5):
            ref, ref_done, ref_active = _sequential_reference(V, invm, quads[p], w[p], n[p], target[p], 0.0, sweeps)
            assert ref_done == min(want, sweeps) and ref_active == (len(low) if ref_done == 1 and lifted else 0)
            for threads in (1, 2):
                with thread_count(threads):
                    got, done, active = sequential_pair_impulses(V, invm, quads, w, n, target, sweeps=sweeps,
                                                                 order=order)
                assert (done, active) == (ref_done, ref_active)
                assert np.allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_grouped_sweeps_are_the_sequential_sweeps_in_the_groups_order_on_any_thread_count():
    """The parallel order: a permutation of the pairs into groups, no two groups of one colour sharing a movable
    vertex; the sweeps are then the sequential sweeps over the permuted pairs, to the last bit on 1 and 2 threads."""
    import numba
    import pytest

    from modalfem._threads import thread_count
    from modalfem.collision.repulsion import PairOrder, pair_order

    X, V, invm, quads, w, n, target = _spread_pairs(7)
    order = pair_order(X, invm > 0, quads)
    assert np.array_equal(np.sort(order.perm), np.arange(len(quads)))
    # slabs wider than a pair's reach: only neighbouring slabs share vertices, two colours, several groups each
    assert order.colour_count == 2 and np.diff(order.cptr).min() >= 2
    for c in range(order.colour_count):
        seen = np.zeros(len(X), dtype=int)
        for g in range(order.cptr[c], order.cptr[c + 1]):
            verts = np.unique(quads[order.perm[order.tptr[g]:order.tptr[g + 1]]])
            seen[verts[invm[verts] > 0]] += 1
        assert seen.max() <= 1  # groups of one colour never write the same vertex
    p = order.perm
    for friction in (0.0, 0.4):
        got, done, active = sequential_pair_impulses(V, invm, quads, w, n, target, friction=friction, sweeps=3,
                                                     order=order)
        ref, ref_done, ref_active = _sequential_reference(V, invm, quads[p], w[p], n[p], target[p], friction, 3)
        assert (done, active) == (ref_done, ref_active) and active > 0
        assert np.allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    if numba.config.NUMBA_NUM_THREADS >= 2:
        runs = []
        for threads in (1, 2):
            with thread_count(threads):
                runs.append(sequential_pair_impulses(V, invm, quads, w, n, target, friction=0.3, sweeps=10,
                                                     order=order))
        np.testing.assert_array_equal(runs[0][0], runs[1][0])
        assert runs[0][1:] == runs[1][1:]
    with pytest.raises(ValueError, match="pair order"):
        sequential_pair_impulses(V, invm, quads[:-1], w[:-1], n[:-1], target[:-1], order=order)
    with pytest.raises(ValueError, match="pair order"):  # a movable vertex the order lets no impulse write
        sequential_pair_impulses(V, invm, quads, w, n, target, order=PairOrder(p, order.cptr, order.tptr,
                                                                                 invm == 0))
