"""The candidate searches' box-diagonal filter (``System.candidates(diagonals=True | within=h)``,
``System.dirty_candidates(diagonals=True)``): it only removes pairs whose answer downstream is known, so the
pairs it keeps are the unfiltered search's in the same order, every pair a CCD or the proximity test needs is
kept, and the pipeline's answers are the same bit for bit with and without it."""

from __future__ import annotations

import numpy as np
from _meshes import stacked_sheets

from modalfem.cloth import scenes
from modalfem.collision import _ccd_kernels, _pair_kernels
from modalfem.collision._system import System, diagonal_test
from modalfem.collision.ccd import MAX_INTERVALS
from modalfem.collision.repulsion import repulsion_pairs

_DIAGONALS = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, -1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0]])


def _subsequence(sub: np.ndarray, full: np.ndarray) -> bool:
    """The rows of ``sub`` are rows of ``full`` in the same order."""
    j = 0
    for row in sub:
        while j < len(full) and not np.array_equal(full[j], row):
            j += 1
        if j == len(full):
            return False
        j += 1
    return True


def _box_intervals(vlo, vhi):
    """(N, 4) lows and highs of the vertex boxes on the four diagonals, over the boxes' eight corners."""
    corners = np.stack([np.where(np.array(c)[None, :] == 1, vhi, vlo) for c in np.ndindex(2, 2, 2)])  # (8, N, 3)
    proj = corners @ _DIAGONALS.T  # (8, N, 4)
    return proj.min(axis=0), proj.max(axis=0)


def _dropped(full: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """The rows of ``full`` not in ``kept``."""
    rows = {tuple(r) for r in kept.tolist()}
    return np.array([r for r in full.tolist() if tuple(r) not in rows], dtype=np.int64).reshape(-1, 4)


def _apart(q, first, lo, hi, gap):
    """(k,) bool: the primitives of vertices ``q[:, first]`` and of the others have intervals more than ``gap``
    apart on some diagonal."""
    rest = [c for c in range(4) if c not in first]
    alo, ahi = lo[q[:, first]].min(axis=1), hi[q[:, first]].max(axis=1)
    blo, bhi = lo[q[:, rest]].min(axis=1), hi[q[:, rest]].max(axis=1)
    return ((alo > bhi + gap) | (blo > ahi + gap)).any(axis=1)


def test_box_diagonals_hold_every_point_of_the_boxes_and_are_attained_at_corners():
    rng = np.random.default_rng(0)
    c = rng.uniform(-2.0, 2.0, size=(500, 3))
    vlo, vhi = c - rng.uniform(0, 0.1, size=c.shape), c + rng.uniform(0, 0.1, size=c.shape)
    diag, gap = diagonal_test(vlo, vhi)
    assert diag.shape == (500, 8) and 0 < gap < 1e-9
    lo, hi = _box_intervals(vlo, vhi)
    # the corners attain the intervals (up to the rounding the gap covers)
    assert np.abs(diag[:, :4] - lo).max() <= gap and np.abs(diag[:, 4:] - hi).max() <= gap
    pts = vlo[None] + rng.uniform(0, 1, size=(20, 500, 3)) * (vhi - vlo)[None]
    proj = pts @ _DIAGONALS.T
    assert (proj >= diag[None, :, :4] - gap).all() and (proj <= diag[None, :, 4:] + gap).all()


def _sheets(seed: int):
    """Three jittered sheets 4 mm apart, moved so that layers cross within the step."""
    x0, tri = stacked_sheets(3, 10, gap=4e-3, seed=seed)
    rng = np.random.default_rng(seed)
    x1 = x0 + rng.normal(0.0, 3e-3, size=x0.shape)
    return x0, x1, tri


def test_swept_filter_keeps_the_unfiltered_pairs_in_order_and_every_ccd_hit():
    eta = 1e-4
    hits_seen = 0
    for seed in range(3):
        x0, x1, tri = _sheets(seed)
        system = System(tri, ())
        system.build_cloth_bvh(x0)
        margin = 0.5 * eta + 2e-4
        full = system.candidates(x0, x1, margin=margin, self_collision=True, culling=False)
        kept = system.candidates(x0, x1, margin=margin, self_collision=True, culling=False, diagonals=True)
        vlo, vhi = system.vertex_boxes(x0, x1, margin)
        lo, hi = _box_intervals(vlo, vhi)
        movable = np.ones(len(x0), dtype=bool)
        none = np.zeros(0, dtype=np.int64)
        for kind, q_full, q_kept, first in (("vf", full.vf, kept.vf, [0]), ("ee", full.ee, kept.ee, [0, 1])):
            assert len(q_kept) < len(q_full) and _subsequence(q_kept, q_full)
            dropped = _dropped(q_full, q_kept)
            # every dropped pair's boxes are apart on a diagonal (their corners' projections, by numpy)
            assert _apart(dropped, first, lo, hi, 0.0).all()
            # no dropped pair collides (the CCD on the unfiltered pairs)
            idx, _ = _ccd_kernels.ccd_candidates(kind == "vf", x0, x1, q_full, movable, none, eta, 20, MAX_INTERVALS)
            hit = q_full[idx]
            hits_seen += len(hit)
            kept_rows = {tuple(r) for r in q_kept.tolist()}
            assert all(tuple(r) in kept_rows for r in hit.tolist())
    assert hits_seen > 10  # the sheets do collide: the check above was not vacuous


def test_dirty_search_filter_keeps_the_unfiltered_pairs_in_order():
    x0, x1, tri = _sheets(4)
    system = System(tri, ())
    system.build_cloth_bvh(x0)
    margin = 3e-4
    system.candidates(x0, x1, margin=margin, self_collision=True, culling=False)
    vlo, vhi = system.vertex_boxes(x0, x1, margin)
    dirty = np.zeros(len(x0), dtype=bool)
    dirty[::7] = True
    vlo[dirty] -= 2e-3
    vhi[dirty] += 2e-3
    full = system.dirty_candidates(vlo, vhi, dirty, self_collision=True)
    kept = system.dirty_candidates(vlo, vhi, dirty, self_collision=True, diagonals=True)
    lo, hi = _box_intervals(vlo, vhi)
    for q_full, q_kept, first in ((full.vf, kept.vf, [0]), (full.ee, kept.ee, [0, 1])):
        assert len(q_kept) < len(q_full) and _subsequence(q_kept, q_full)
        dropped = _dropped(q_full, q_kept)
        assert _apart(dropped, first, lo, hi, 0.0).all()


def test_proximity_filter_gives_the_same_close_pairs():
    h = 6e-3
    for seed in range(3):
        x0, _, tri = _sheets(seed)
        system = System(tri, ())
        system.build_cloth_bvh(x0)
        full = system.candidates(x0, x0, margin=0.5 * h, self_collision=True, culling=True)
        kept = system.candidates(x0, x0, margin=0.5 * h, self_collision=True, culling=True, within=h)
        assert len(kept.vf) + len(kept.ee) < 0.8 * (len(full.vf) + len(full.ee))
        assert _subsequence(kept.vf, full.vf) and _subsequence(kept.ee, full.ee)
        near_full = repulsion_pairs(x0, full.vf, full.ee, thickness=h, dt=0.01)
        near_kept = repulsion_pairs(x0, kept.vf, kept.ee, thickness=h, dt=0.01)
        assert len(near_full[0]) > 100
        for a, b in zip(near_full, near_kept):
            assert np.array_equal(a, b)


def test_pipeline_answers_are_the_same_bit_for_bit_with_and_without_the_filter(monkeypatch):
    """A 20x20 pile stepped twice side by side, the second with the filter switched off (the searches called
    without ``diagonals`` / ``within``): the same positions and velocities at every step, with collisions."""
    candidates, dirty_candidates = System.candidates, System.dirty_candidates

    def plain(self, *a, **k):
        k.pop("diagonals", None)
        k.pop("within", None)
        return candidates(self, *a, **k)

    def plain_dirty(self, *a, **k):
        k.pop("diagonals", None)
        return dirty_candidates(self, *a, **k)

    on, off = scenes.pile(20), scenes.pile(20)
    hits = fewer = 0
    for _ in range(45):
        monkeypatch.setattr(System, "candidates", candidates)
        monkeypatch.setattr(System, "dirty_candidates", dirty_candidates)
        st_on = on.scene.step(on.dt).collision
        monkeypatch.setattr(System, "candidates", plain)
        monkeypatch.setattr(System, "dirty_candidates", plain_dirty)
        st_off = off.scene.step(off.dt).collision
        assert np.array_equal(on.scene.x, off.scene.x) and np.array_equal(on.scene.v, off.scene.v)
        hits += sum(st_on.ccd_hits) + st_on.proximities
        fewer += st_on.candidates_vf + st_on.candidates_ee < st_off.candidates_vf + st_off.candidates_ee
    assert scenes.intersections(on) == 0
    assert hits > 100 and fewer > 10  # collisions were handled, and the filter removed pairs
