"""Incremental candidate search: after velocity changes, the pair store updated for the dirty vertices
only holds every pair a fresh search (no culling) finds, and no pair twice."""

from __future__ import annotations

import numpy as np
import pytest
from _meshes import stacked_sheets

from modalfem.collision import _pair_kernels
from modalfem.collision._system import PairStore, System


def _keys(q, kind):
    q = q.copy()
    if kind == "ee":
        q[:, :2].sort(axis=1)
        q[:, 2:].sort(axis=1)
        swap = q[:, 0] > q[:, 2]
        q[swap] = q[swap][:, [2, 3, 0, 1]]
    return {tuple(map(int, r)) for r in q}


@pytest.mark.parametrize("indexed", [1, 10**9])  # every block through its vertex index / every block scanned
def test_dirty_updates_keep_every_pair_of_a_fresh_search(indexed, monkeypatch):
    monkeypatch.setattr(PairStore, "INDEXED", indexed)
    rng = np.random.default_rng(3)
    x0, tri = stacked_sheets(3, 6, gap=0.01, seed=3)
    dt, margin = 0.01, 0.002
    v = rng.normal(scale=0.3, size=x0.shape)
    system = System(tri, ())
    system.build_cloth_bvh(x0)
    reference = System(tri, ())  # fresh searches on a tree of its own (they refit every box)
    reference.build_cloth_bvh(x0)
    store = PairStore(system.candidates(x0, x0 + dt * v, margin=margin, self_collision=True, culling=False))
    lo, hi = system.vertex_boxes(x0, x0 + dt * v, margin)
    for _ in range(4):
        moved = rng.random(len(x0)) < 0.1
        v[moved] += rng.normal(scale=1.0, size=(moved.sum(), 3))
        x1 = x0 + dt * v
        dirty = ((np.minimum(x0, x1) < lo) | (np.maximum(x0, x1) > hi)).any(axis=1)
        assert dirty.any()
        lo[dirty], hi[dirty] = system.vertex_boxes(x0[dirty], x1[dirty], margin)
        store.drop(dirty)
        store.add(system.dirty_candidates(lo, hi, dirty, self_collision=True))
        fresh = reference.candidates(x0, x1, margin=margin, self_collision=True, culling=False)
        for kind, q in (("vf", fresh.vf), ("ee", fresh.ee)):
            have = store.pairs(kind)
            assert len(_keys(have, kind)) == len(have)  # no duplicates
            assert _keys(q, kind) <= _keys(have, kind)
        only = np.zeros(len(x0), bool)
        only[np.flatnonzero(dirty)[:3]] = True
        sub = store.pairs("ee", only)
        assert len(sub) and only[sub].any(axis=1).all()


def test_stamped_drops_and_selections_equal_masks():
    """A drop stamps the dirty vertices with a new epoch; the pairs of a block found at epoch e that hold a vertex
    stamped above e are gone: the same pairs as clearing an alive mask (numpy) at every drop, through the
    vertex index or by a scan, int32 or int64 pairs."""
    rng = np.random.default_rng(8)
    N, k = 300, 5000
    for dtype in (np.int32, np.int64):
        q = np.array([rng.choice(N, 4, replace=False) for _ in range(k)], dtype=dtype)
        ptr, pid = _pair_kernels.vertex_index(q, N)
        for p in (0, 17, k - 1):  # every pair is listed under each of its vertices
            for v in q[p]:
                assert p in pid[ptr[v]:ptr[v + 1]]
        assert ptr[-1] == 4 * k
        stamp = np.zeros(N, dtype=np.int64)
        alive = np.ones(k, dtype=bool)
        for epoch, frac in enumerate((0.01, 0.05, 0.5), start=1):
            dirty = rng.random(N) < frac / 2
            stamp[dirty] = epoch
            alive &= ~dirty[q].any(axis=1)
            flags = rng.random(N) < frac
            want = q[alive & flags[q].any(axis=1)]
            assert 0 < len(want) < k
            got = _pair_kernels.select_indexed(q, stamp, 0, ptr, pid, np.flatnonzero(flags))
            np.testing.assert_array_equal(got, want)  # same pairs, same order
            np.testing.assert_array_equal(_pair_kernels.select_pairs(q, stamp, 0, flags), want)
            np.testing.assert_array_equal(_pair_kernels.select_pairs(q, stamp, 0, np.zeros(0, bool)), q[alive])
            # a block found after the last drop keeps every pair
            np.testing.assert_array_equal(_pair_kernels.select_pairs(q, stamp, epoch, np.zeros(0, bool)), q)


@pytest.mark.parametrize("indexed", [1, 10**9])  # every block to the CCD as stored / every block selected first
def test_ccd_of_store_segments_equals_the_ccd_of_the_selected_pairs(indexed, monkeypatch):
    """``ccd_hits`` hands large blocks to the CCD with their alive masks and the flagged vertices (filtered in
    its pass): the hits and times are those of the CCD of the selected pairs, on 1 and 2 threads, in the
    canonical order (an edge-edge pair's smaller edge first, then sorted by the four vertex indices)."""
    from modalfem._threads import thread_count
    from modalfem.collision import _ccd_kernels, _stages
    from modalfem.collision.ccd import MAX_INTERVALS

    monkeypatch.setattr(PairStore, "INDEXED", indexed)
    rng = np.random.default_rng(5)
    x0, tri = stacked_sheets(3, 8, gap=0.004, seed=5)
    dt, margin, eta = 0.01, 0.002, 1e-5
    v = rng.normal(scale=0.3, size=x0.shape)
    system = System(tri, ())
    system.build_cloth_bvh(x0)
    store = PairStore(system.candidates(x0, x0 + dt * v, margin=margin, self_collision=True, culling=False))
    lo, hi = system.vertex_boxes(x0, x0 + dt * v, margin)
    moved = rng.random(len(x0)) < 0.15
    v[moved] += rng.normal(scale=1.0, size=(moved.sum(), 3))
    x1 = x0 + dt * v
    dirty = ((np.minimum(x0, x1) < lo) | (np.maximum(x0, x1) > hi)).any(axis=1)
    lo[dirty], hi[dirty] = system.vertex_boxes(x0[dirty], x1[dirty], margin)
    store.drop(dirty)
    store.add(system.dirty_candidates(lo, hi, dirty, self_collision=True))
    assert len(store.blocks) > 2
    V = (x1 - x0) / dt
    X1 = x0 + dt * V  # the end positions ccd_hits computes
    invm = np.ones(len(x0))
    roots = np.arange(len(x0))
    roots[: len(x0) // 3] = 0  # one zone: its inner pairs are skipped
    total = 0
    for only in (None, rng.random(len(x0)) < 0.2):
        want = []
        for kind in ("vf", "ee"):
            q = store.pairs(kind, only)
            idx, toi = _ccd_kernels.ccd_candidates(kind == "vf", x0, X1, q, invm > 0, roots, eta,
                                                   _stages.PIPELINE_DEPTH, MAX_INTERVALS)
            if len(idx):
                qh = q[idx].copy()
                if kind == "ee":
                    swap = [tuple(r[2:]) < tuple(r[:2]) for r in qh.tolist()]
                    qh[swap] = qh[swap][:, [2, 3, 0, 1]]
                order = sorted(range(len(qh)), key=lambda i: tuple(qh[i].tolist()))
                want.append((kind, qh[order], toi[order]))
        total += sum(len(w[1]) for w in want)
        for t in (1, 2):
            with thread_count(t):
                got = _stages.ccd_hits(system, x0, V, dt, store, invm, eta, roots=roots, only=only)
            assert [g[0] for g in got] == [w[0] for w in want]
            for (_, qg, tg), (_, qw, tw) in zip(got, want):
                np.testing.assert_array_equal(qg, qw)
                np.testing.assert_array_equal(tg, tw)
    assert total > 20  # hits to compare


def test_outgrown_vertices_and_dirty_query_pairs_equal_their_numpy_definitions():
    rng = np.random.default_rng(11)
    N, dt, grow = 400, 0.01, 1e-4
    X0 = rng.normal(size=(N, 3))
    V = rng.normal(size=(N, 3))
    X1 = X0 + dt * V
    lo, hi = np.minimum(X0, X1) - 2e-4, np.maximum(X0, X1) + 2e-4
    V[rng.random(N) < 0.1] *= 1.5  # some trajectories leave their boxes
    got_x1, got, head, total = _pair_kernels.outgrown(X0, V, dt, grow, lo, hi, V, np.inf, N // 2)
    want_x1 = X0 + dt * V
    want = ((np.minimum(X0, want_x1) - grow < lo) | (np.maximum(X0, want_x1) + grow > hi)).any(axis=1)
    assert np.array_equal(got_x1, want_x1) and np.array_equal(got, want) and 0 < want.sum() < N
    assert head == want[: N // 2].sum() and total == want.sum()
    m = 50
    dirty_tri = rng.random(m) < 0.3
    ids = np.flatnonzero(dirty_tri)
    found = np.stack([rng.integers(0, len(ids), 300), rng.integers(0, m, 300)], axis=1)
    found = found[np.argsort(found[:, 0], kind="stable")]
    a, t = ids[found[:, 0]], found[:, 1]
    ok = (a != t) & (~dirty_tri[t] | (a < t))
    got = _pair_kernels.dirty_self_pairs(ids, found[:, 0], found[:, 1], dirty_tri)
    assert np.array_equal(got, np.stack([a[ok], t[ok]], axis=1)) and 0 < ok.sum() < len(ok)
