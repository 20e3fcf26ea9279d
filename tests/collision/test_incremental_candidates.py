"""Incremental candidate search: after velocity changes, the pair store updated for the dirty vertices
only holds every pair a fresh search (no culling) finds, and no pair twice."""

from __future__ import annotations

import numpy as np
from _meshes import stacked_sheets

from modalfem.collision._system import PairStore, System


def _keys(q, kind):
    q = q.copy()
    if kind == "ee":
        q[:, :2].sort(axis=1)
        q[:, 2:].sort(axis=1)
        swap = q[:, 0] > q[:, 2]
        q[swap] = q[swap][:, [2, 3, 0, 1]]
    return {tuple(map(int, r)) for r in q}


def test_dirty_updates_keep_every_pair_of_a_fresh_search():
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
