"""BVH candidate pairs against brute force; normal-cone culling removes only safe tests."""

from __future__ import annotations

import numpy as np
from _meshes import grid, stacked_sheets

from modalfem.collision.bvh import BroadPhaseBVH


def _brute(lo, hi, lo2=None, hi2=None):
    if lo2 is None:
        ov = ((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None])).all(axis=2)
        i, j = np.nonzero(np.triu(ov, 1))
    else:
        ov = ((lo[:, None] <= hi2[None]) & (lo2[None] <= hi[:, None])).all(axis=2)
        i, j = np.nonzero(ov)
    return {(int(a), int(b)) for a, b in zip(i, j)}


def _crumpled(seed=0):
    x, tri = stacked_sheets(2, 8, gap=0.05, seed=seed)
    rng = np.random.default_rng(seed)
    x1 = x + rng.normal(scale=0.05, size=x.shape)
    return x, x1, tri


def test_self_pairs_without_culling_equal_brute_force():
    for seed in range(3):
        x0, x1, tri = _crumpled(seed)
        bvh = BroadPhaseBVH(tri, x0, leaf_size=4)
        bvh.refit(x0, x1, margin=0.01)
        pairs, tests = bvh.self_pairs(culling=False)
        got = {tuple(sorted(map(int, p))) for p in pairs}
        assert len(got) == len(pairs)
        assert got == _brute(bvh.tri_lo, bvh.tri_hi)
        assert tests >= len(pairs)


def test_cross_pairs_equal_brute_force():
    x0, x1, tri = _crumpled(1)
    half = len(tri) // 2
    a = BroadPhaseBVH(tri[:half], x0)
    b = BroadPhaseBVH(tri[half:], x0)
    a.refit(x0, x1, margin=0.002)
    b.refit(x0, x1, margin=0.002)
    pairs, _ = a.cross_pairs(b)
    assert {tuple(map(int, p)) for p in pairs} == _brute(a.tri_lo, a.tri_hi, b.tri_lo, b.tri_hi)


def test_culling_flat_sheet_and_stacked_sheets():
    x, tri = grid(12, 12)
    bvh = BroadPhaseBVH(tri, x)
    bvh.refit(x, x, margin=0.01)
    pairs, tests = bvh.self_pairs(culling=True)
    assert tests == 0 and len(pairs) == 0  # one flat connected patch cannot self-intersect
    assert bvh.self_pairs(culling=False)[1] > 0
    # two stacked sheets: each sheet is culled, but every pair between the sheets is kept
    x, tri = stacked_sheets(2, 8, gap=0.005)
    bvh = BroadPhaseBVH(tri, x, leaf_size=4)
    bvh.refit(x, x, margin=0.004)
    culled, t_c = bvh.self_pairs(culling=True)
    full, t_f = bvh.self_pairs(culling=False)
    half = len(tri) // 2
    between = {tuple(sorted(map(int, p))) for p in full if (p[0] < half) != (p[1] < half)}
    got = {tuple(sorted(map(int, p))) for p in culled}
    assert between <= got and t_c < t_f
    assert not bvh.connected[1]  # the two sheets are not one patch: the root is never culled
