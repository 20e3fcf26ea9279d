"""The dirty search's walk of the flagged triangles' own boxes against the tree
(``BroadPhaseBVH.dirty_pairs``, ``_bvh_kernels.traverse_dirty``): every overlapping triangle pair holding a
flagged triangle, each once, against brute force and against the pruned self-traversal; the same pairs in the
same order on one and two threads."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from _meshes import folded_sheet, stacked_sheets

from modalfem.collision.bvh import BroadPhaseBVH
from modalfem._threads import thread_count


def _brute(tlo, thi, dirty):
    """Unordered triangle pairs (i < j) whose boxes overlap and that hold a flagged triangle."""
    ok = ((tlo[:, None] <= thi[None]) & (tlo[None] <= thi[:, None])).all(axis=2)
    ok &= dirty[:, None] | dirty[None, :]
    i, j = np.nonzero(np.triu(ok, 1))
    return set(zip(i.tolist(), j.tolist()))


def _cases():
    pts, tri = stacked_sheets(3, 8, gap=0.02, seed=3)
    rng = np.random.default_rng(11)
    x0 = pts + 0.01 * rng.standard_normal(pts.shape)
    yield pts, tri, x0, x0 + 0.02 * rng.standard_normal(pts.shape), rng
    x, tri, rest = folded_sheet(8, gap=0.01)
    yield rest, tri, x, x + 0.005 * rng.standard_normal(x.shape), rng


@pytest.mark.parametrize("leaf_size", [1, 4, 8])
def test_dirty_pairs_equal_brute_force_and_the_pruned_traversal(leaf_size):
    checked = 0
    for ref, tri, x0, x1, rng in _cases():
        bvh = BroadPhaseBVH(tri, ref, leaf_size=leaf_size)
        bvh.refit(x0, x1, margin=2e-3)
        m = len(tri)
        # one box grown (as a re-searched triangle's box is): its ancestors' boxes refitted
        grow = rng.choice(m, 5, replace=False)
        vlo = np.minimum(x0, x1) - 2e-3
        vhi = np.maximum(x0, x1) + 2e-3
        vlo[tri[grow].ravel()] -= 0.03
        vhi[tri[grow].ravel()] += 0.03
        bvh.refit_triangles(np.arange(m), vlo, vhi)
        for count in (0, 1, 7, m // 3, m):
            dirty = np.zeros(m, dtype=bool)
            dirty[rng.choice(m, count, replace=False)] = True
            dirty[grow[:1]] = count > 0
            got = bvh.dirty_pairs(dirty)
            pairs = [tuple(p) for p in got.tolist()]
            assert len(set(pairs)) == len(pairs)  # each pair once
            assert all(dirty[a] for a, _ in pairs)  # a flagged triangle first
            assert all(a < b for a, b in pairs if dirty[b])  # two flagged ones as (smaller, larger)
            canon = {(min(a, b), max(a, b)) for a, b in pairs}
            assert canon == _brute(bvh.tri_lo, bvh.tri_hi, dirty)
            old = {tuple(sorted(p)) for p in bvh.self_pairs(culling=False, dirty=dirty)[0].tolist()}
            assert canon == old
            checked += len(canon)
    assert checked > 2000


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_dirty_pairs_are_the_same_on_one_and_two_threads():
    pts, tri = stacked_sheets(4, 16, gap=0.01, seed=4)
    rng = np.random.default_rng(4)
    x0 = pts + 0.004 * rng.standard_normal(pts.shape)
    bvh = BroadPhaseBVH(tri, pts, leaf_size=4)
    bvh.refit(x0, x0 + 0.01 * rng.standard_normal(pts.shape), margin=2e-3)
    dirty = rng.random(len(tri)) < 0.3
    out = {}
    for t in (1, 2):
        with thread_count(t):
            out[t] = bvh.dirty_pairs(dirty)
    assert len(out[1]) > 5000  # many chunks of tasks
    np.testing.assert_array_equal(out[1], out[2])
