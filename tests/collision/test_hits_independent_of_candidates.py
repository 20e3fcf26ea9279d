"""The pipeline's answer does not depend on how its candidate pairs were kept: the CCD hands its hits on in a
canonical order (``_stages.ccd_hits``: edge-edge pairs with the smaller edge first, all sorted by vertex
indices), and the set of colliding pairs is that of the trajectories alone (every store holds every pair whose
trajectory boxes come within eta, tests/collision/test_candidate_reuse.py). So the store's bookkeeping (the
spare box margin ``SLACK``, the union of a re-searched vertex's old and new boxes and its ``DIRTY_GROW``, the
fraction of dirty vertices above which the pairs are searched afresh) only changes the time taken: a falling
pile gives the same positions, bit for bit, under every setting, with no intersection."""

from __future__ import annotations

import numpy as np
from modalfem.cloth import scenes
from modalfem.collision import _stages


def _run(monkeypatch, steps, **settings):
    for name, value in settings.items():
        monkeypatch.setattr(_stages, name, value)
    setup = scenes.pile(20)
    sc = setup.scene
    for _ in range(steps):
        sc.step(setup.dt)
    return sc.x.copy(), scenes.intersections(setup)


def test_pile_positions_are_the_same_under_every_candidate_bookkeeping(monkeypatch):
    steps = 60  # the layers meet from step ~30 on: CCD hits and impact zones in most later steps
    calls = {"hits": 0, "ee": 0}
    ccd_hits = _stages.ccd_hits

    def counted(*a, **k):
        out = ccd_hits(*a, **k)
        calls["hits"] += sum(len(q) for _, q, _ in out)
        calls["ee"] += sum(len(q) for kind, q, _ in out if kind == "ee")
        return out

    monkeypatch.setattr(_stages, "ccd_hits", counted)
    ref, inter = _run(monkeypatch, steps)
    assert inter == 0
    assert calls["ee"] > 100 and calls["hits"] > calls["ee"]  # the orders mattered: many hits, both kinds
    for settings in ({"SLACK": 0.03}, {"SLACK": 0.3, "DIRTY_GROW": 3.0}, {"FRESH_SEARCH": 0.0},
                     {"FRESH_SEARCH": 2.0, "DIRTY_GROW": 1.0}):
        with monkeypatch.context() as m:
            x, inter = _run(m, steps, **settings)
        assert inter == 0, settings
        assert np.array_equal(x, ref), f"{settings}: positions differ by {np.abs(x - ref).max():.3g} m"
