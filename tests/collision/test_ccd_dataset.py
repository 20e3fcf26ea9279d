"""Zero false negatives on the 7,279 exact-answer CCD queries (Wang et al. 2021 sample)."""

from __future__ import annotations

import pytest

from modalfem.bench.ccd_bench import default_data_dir, load_queries
from modalfem.collision.ccd import edge_edge_ccd, vertex_face_ccd

DATA = default_data_dir()
pytestmark = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"CCD sample queries not found at {DATA} (../shared/data relative to the repo root)"
)


def test_no_false_negatives_on_dataset():
    sets = load_queries(DATA)
    total = colliding = fp = 0
    for qs in sets:
        fun = vertex_face_ccd if qs.kind == "vertex-face" else edge_edge_ccd
        hit, toi = fun(qs.x0, qs.x1)
        missed = qs.truth & ~hit
        assert not missed.any(), f"{qs.scene}/{qs.kind}: {int(missed.sum())} false negatives"
        assert ((toi[hit] >= 0) & (toi[hit] <= 1)).all()
        total += len(qs.truth)
        colliding += int(qs.truth.sum())
        fp += int((hit & ~qs.truth).sum())
    assert total == 7279 and colliding == 435
    print(f"CCD dataset: {total} queries, {colliding} colliding, 0 FN, {fp} FP")
    assert fp < 0.1 * (total - colliding)
