"""The pipeline call after smoothing (same start positions, other velocities) keeps the first call's candidate pairs
and searches again only the vertices whose trajectory grown by eta / 2 leaves the box their pairs were found with
(``modalfem.collision._stages.resolve``'s ``candidates``). The eta / 2 is what makes the kept pairs hold every pair
the CCD needs: two primitives whose trajectories come within eta have trajectory boxes grown by eta / 2 that
overlap, so if each vertex's trajectory grown by eta / 2 is inside its stored box, the stored boxes overlap too.

Here a vertex and a triangle, out of each other's stored boxes at the first call, both move to just inside the
facing sides of their boxes at the second call (0.4 eta inside): their trajectories end 0.9 eta apart, so the pair
must be a candidate. A reuse test with less than 0.4 eta of growth (none: the trajectory inside the box; or eta / 4)
keeps the vertices clean and drops the pair: this test fails then (checked with ``_pair_kernels.outgrown`` given
0 and eta / 4). Checked against an independent fresh search at every CCD call of the second call."""

from __future__ import annotations

import numpy as np
from _meshes import grid

from modalfem.collision import _stages
from modalfem.collision._system import System
from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline

H = 0.01  # thickness [m]
DT = 0.01  # step [s]


def _scene(height: float):
    """Triangle A (0, 1, 2) in the plane z = 0, triangle B (3, 4, 5) with vertex 3 ``height`` [m] above A's inside
    and its other vertices higher, and a far sheet of 36 idle vertices (so that 4 moving vertices are fewer than
    ``_stages.FRESH_SEARCH`` of them: the second call takes the reuse path, not a fresh search)."""
    a = np.array([[-0.01, -0.01, 0.0], [0.01, -0.01, 0.0], [0.0, 0.01, 0.0]])
    b = np.array([[0.0, -0.002, height], [0.01, 0.0, height + 0.01], [-0.01, 0.0, height + 0.01]])
    far, ftri = grid(5, 5, size=0.05, z=1.0)
    x = np.concatenate([a, b, far])
    tri = np.concatenate([np.array([[0, 1, 2], [3, 4, 5]]), ftri + 6])
    assert 4 < _stages.FRESH_SEARCH * len(x)
    return x, tri


def _keys(kind: str, q: np.ndarray) -> set:
    if kind == "vf":
        return {tuple(r) for r in q.tolist()}
    return {tuple(sorted(((r[0], r[1]), (r[2], r[3])))) for r in q.tolist()}


def test_recheck_reuse_searches_again_a_vertex_whose_grown_trajectory_leaves_its_box(monkeypatch):
    cfg = CollisionConfig(thickness=H, repulsion=False)  # no repulsion: only the swept candidates act
    eta = cfg.eta
    # the box margin the pipeline gives a still vertex (read from a first call, not restated here)
    x, tri = _scene(0.1)
    probe = CollisionPipeline(tri, config=cfg)
    probe.resolve(x, np.zeros_like(x), np.ones(len(x)), DT)
    margin = probe._system.step_cache["hi"][3, 2] - x[3, 2]
    assert 10 * eta < margin < 0.01

    # vertex 3 0.1 eta farther from A than the two still boxes reach: not a candidate at the first call
    x, tri = _scene(2 * margin + 0.1 * eta)
    pipe = CollisionPipeline(tri, config=cfg)
    masses = np.ones(len(x))
    checker = System(tri, (), len(x))
    checker.build_cloth_bvh(x)
    seen = {"ccd": 0, "needed": 0, "fresh_searches": 0, "dirty_searches": 0}
    ccd_hits, candidates, dirty_candidates = _stages.ccd_hits, System.candidates, System.dirty_candidates

    def checked_ccd_hits(system, X0, V, dt, store, invm, eta_, **kw):
        X0 = np.ascontiguousarray(X0)
        fresh = checker.candidates(X0, X0 + dt * V, margin=0.5 * eta, self_collision=True, culling=False,
                                   diagonals=True)
        for kind, q in (("vf", fresh.vf), ("ee", fresh.ee)):
            missing = _keys(kind, q) - _keys(kind, store.pairs(kind))
            assert not missing, f"{kind} pairs {sorted(missing)} of a fresh search missing from the kept candidates"
            seen["needed"] += len(q)
        seen["ccd"] += 1
        return ccd_hits(system, X0, V, dt, store, invm, eta_, **kw)

    def counted_candidates(self, *a, **k):
        if self is pipe._system:
            seen["fresh_searches"] += 1
        return candidates(self, *a, **k)

    def counted_dirty(self, *a, **k):
        seen["dirty_searches"] += 1
        return dirty_candidates(self, *a, **k)

    monkeypatch.setattr(_stages, "ccd_hits", checked_ccd_hits)
    monkeypatch.setattr(System, "candidates", counted_candidates)
    monkeypatch.setattr(System, "dirty_candidates", counted_dirty)
    pipe.resolve(x, np.zeros_like(x), masses, DT)
    assert seen["fresh_searches"] == 1 and seen["needed"] == 0
    assert (3, 0, 1, 2) not in _keys("vf", pipe._system.step_cache["store"].pairs("vf"))
    seen.update(ccd=0, fresh_searches=0, dirty_searches=0)

    # the second call: vertex 3 down and A up, each to 0.4 eta inside the facing side of its stored box
    step = margin - 0.4 * eta
    v = np.zeros_like(x)
    v[3, 2] = -step / DT
    v[:3, 2] = step / DT
    end_gap = (x[3, 2] + DT * v[3, 2]) - (x[0, 2] + DT * v[0, 2])
    assert 0.5 * eta < end_gap < eta
    v_new, stats = pipe.resolve(x, v, masses, DT)
    # the reuse path ran (no fresh search), the pair was needed, and every needed pair was kept
    assert seen["fresh_searches"] == 0 and seen["dirty_searches"] >= 1 and seen["ccd"] >= 1
    assert seen["needed"] >= 1
    assert stats.unresolved == 0
    # and the answer moves vertex 3 and A apart: their end positions no closer than at the start of the call
    gap = (x[3, 2] + DT * v_new[3, 2]) - (x[:3, 2] + DT * v_new[:3, 2]).max()
    assert gap > end_gap
