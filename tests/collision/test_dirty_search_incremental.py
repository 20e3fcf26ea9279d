"""A dirty search's O(dirty) parts give the numbers of the O(N) passes they replace: the boxes' diagonal intervals
and gap kept in the pipeline's step cache and updated on the dirty rows only (``_system.update_diagonal_test``), the
dirty triangles from the dirty vertices' triangle lists (``_pair_kernels.dirty_triangles``), and the serial
expansion of a few triangle pairs into kept work arrays (``_pair_kernels.primitive_pairs_serial``)."""

from __future__ import annotations

import numpy as np

from modalfem.cloth import scenes
from modalfem.collision import _pair_kernels
from modalfem.collision._system import System, diagonal_test, update_diagonal_test


def _boxes(rng, N):
    x = rng.uniform(-3.0, 3.0, (N, 3))
    lo = x - rng.uniform(0.0, 0.1, (N, 3))
    hi = x + rng.uniform(0.0, 0.1, (N, 3))
    return lo, hi


def test_updated_diagonal_test_equals_a_fresh_one_bit_for_bit():
    rng = np.random.default_rng(5)
    lo, hi = _boxes(rng, 500)
    diag = diagonal_test(lo, hi)
    diag = (diag[0].copy(), diag[1])
    for grow in (1e-3, 0.5, 10.0):  # the last one moves the coordinate scale (the gap) up
        ids = np.sort(rng.choice(500, 7, replace=False))
        lo[ids] = np.minimum(lo[ids], lo[ids] - rng.uniform(0, grow, (7, 3)))
        hi[ids] = np.maximum(hi[ids], hi[ids] + rng.uniform(0, grow, (7, 3)))
        diag = update_diagonal_test(diag, lo, hi, ids)
        fresh = diagonal_test(lo, hi)
        assert np.array_equal(diag[0], fresh[0])
        assert diag[1] == fresh[1]


def test_dirty_triangles_equal_the_flagged_triangles():
    rng = np.random.default_rng(2)
    setup = scenes.pile(8)
    tris = np.ascontiguousarray(setup.scene.pipeline._system.tris)
    n = int(tris.max()) + 1
    ptr, vtri = _pair_kernels.vertex_triangles(tris, n)
    for k in (0, 1, 5, n):
        flags = np.zeros(n + 3, dtype=bool)  # 3 more vertices (an obstacle's): not read
        flags[rng.choice(n + 3, k, replace=False)] = True
        mask, ids = _pair_kernels.dirty_triangles(flags, ptr, vtri, len(tris))
        want = _pair_kernels.flagged_triangles(flags, tris)
        assert np.array_equal(mask, want)
        assert np.array_equal(ids, np.flatnonzero(want))


def test_serial_expansion_equals_the_parallel_one_with_reused_work_arrays():
    rng = np.random.default_rng(9)
    system = setup_system = scenes.pile(8).scene.pipeline._system
    m = system.m_cloth
    N = system.n_total
    lo, hi = _boxes(rng, N)
    lo, hi = 0.05 * lo, 0.05 * hi  # a crowded cloth: many boxes overlap
    diag = diagonal_test(lo, hi)
    for trial in range(4):  # the kept work arrays (and their marks) serve every call
        tp = rng.integers(0, m, (int(rng.integers(1, 200)), 2))
        tp = tp[tp[:, 0] != tp[:, 1]]
        dirty = rng.random(N) < 0.3
        got = setup_system._primitive_pairs(tp, lo, hi, dirty, diag)
        want = _pair_kernels.primitive_pairs(np.ascontiguousarray(tp), system.tris, system.edges, system.owned_verts,
                                             system.owned_edges, lo, hi, dirty, diag[0], diag[1])
        assert system._work is not None and not system._work[5].any()
        assert len(want[0]) + len(want[1]) > 0
        for a, b in zip(got, want):
            assert np.array_equal(a, b)


def test_pipeline_dirty_searches_get_the_diagonal_test_of_their_boxes(monkeypatch):
    """Every dirty search of a falling pile gets the cached intervals and gap equal to those of its current boxes:
    a dirty row left stale (or a gap not raised) fails here."""
    setup = scenes.pile(16)
    sc = setup.scene
    seen = {"dirty": 0}
    dirty_candidates = System.dirty_candidates

    def checked(self, vlo, vhi, dirty, **kw):
        diag = kw.get("diag")
        assert diag is not None, "the pipeline hands its cached diagonal test to the dirty search"
        fresh = diagonal_test(vlo, vhi)
        assert np.array_equal(diag[0], fresh[0]) and diag[1] == fresh[1]
        seen["dirty"] += 1
        return dirty_candidates(self, vlo, vhi, dirty, **kw)

    monkeypatch.setattr(System, "dirty_candidates", checked)
    for _ in range(setup.steps):
        sc.step(setup.dt)
        if seen["dirty"] >= 20:
            break
    assert seen["dirty"] >= 20
