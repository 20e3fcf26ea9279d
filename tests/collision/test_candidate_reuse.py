"""The swept candidates kept between the pipeline's passes and calls of a step (the re-check after smoothing
included) hold every pair a fresh search of the current trajectories finds, at every CCD of a falling pile.

The argument (``modalfem.collision._stages.resolve``'s ``candidates``): the store holds every pair whose
vertex boxes overlap (a full search with those boxes; a vertex whose trajectory grown by eta / 2 leaves
its box is dirty, its pairs dropped and searched again with its new box). A clean vertex's trajectory grown
by eta / 2 is inside its box, so two primitives whose trajectory boxes come within eta (the CCD's own box
test) have overlapping stored boxes: their pair is in the store. The searches also leave out pairs whose
boxes are apart on a box diagonal (``System.candidates(diagonals=True)``); boxes holding the trajectory boxes
are apart there only if those are too, so the fresh search needed is the one with that filter. Checked here
against an independent system (its own tree, so the pipeline's tree is not refitted by the check) at every
CCD call."""

from __future__ import annotations

import numpy as np

from modalfem.cloth import scenes
from modalfem.collision import _stages
from modalfem.collision._system import PairStore, System


def _keys(kind: str, q: np.ndarray) -> set:
    """Pairs as hashable keys independent of the order the search wrote them in (an edge-edge pair's two
    edges come in its triangle pair's order, which depends on the traversal)."""
    if kind == "vf":
        return {tuple(r) for r in q.tolist()}
    return {tuple(sorted(((r[0], r[1]), (r[2], r[3])))) for r in q.tolist()}


def test_kept_candidates_hold_every_pair_of_a_fresh_search_over_a_falling_pile(monkeypatch):
    setup = scenes.pile(24)
    sc = setup.scene
    pipe = sc.pipeline
    eta = pipe.config.eta
    checker = System(pipe.triangles, pipe.obstacles, pipe._system.n_cloth)
    calls = {"ccd": 0, "stores": 0, "needed": 0, "dirty": 0}
    stores = set()
    ccd_hits = _stages.ccd_hits
    dirty_candidates = System.dirty_candidates

    def checked_ccd_hits(system, X0, V, dt, store, invm, eta_, **kw):
        X0 = np.ascontiguousarray(X0)
        X1 = X0 + dt * V
        # what the CCD's box test needs: trajectory boxes within eta, i.e. grown by eta / 2 each, overlapping (on
        # the axes and on the diagonals)
        fresh = checker.candidates(X0, X1, margin=0.5 * eta, self_collision=True, culling=False, diagonals=True)
        for kind, q in (("vf", fresh.vf), ("ee", fresh.ee)):
            missing = _keys(kind, q) - _keys(kind, store.pairs(kind))
            assert not missing, f"{len(missing)} {kind} pairs of a fresh search missing from the kept candidates"
            calls["needed"] += len(q)
        calls["ccd"] += 1
        if id(store) not in stores:
            stores.add(id(store))
            calls["stores"] += 1
        return ccd_hits(system, X0, V, dt, store, invm, eta_, **kw)

    def counted_dirty(self, *a, **k):
        calls["dirty"] += 1
        return dirty_candidates(self, *a, **k)

    monkeypatch.setattr(_stages, "ccd_hits", checked_ccd_hits)
    monkeypatch.setattr(System, "dirty_candidates", counted_dirty)
    checker.build_cloth_bvh(sc.x)  # grouped by the start shape, as the pipeline's (any grouping: the same pairs)
    monkeypatch.setattr(PairStore, "INDEXED", 256)  # large blocks (taken by the CCD as they are) in a small pile
    for _ in range(40):  # the first layers meet by step 30
        sc.step(setup.dt)
    assert scenes.intersections(setup) == 0
    # the kept candidates were used: several CCD calls per store, and dirty vertices searched again
    assert calls["ccd"] > 3 * calls["stores"] and calls["dirty"] > 0 and calls["needed"] > 0
