"""The vertex filters of the pipeline's CCD pass (``_ccd_kernels.ccd_block``: ``only``, ``gone``, ``movable``,
zone ``roots``): the pairs it tests are exactly those a plain numpy selection keeps, with the same times of
impact as the unfiltered pass, in the block's order."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.collision import _ccd_kernels
from modalfem.collision.ccd import MAX_INTERVALS
from modalfem.collision._stages import PIPELINE_DEPTH

NONE_B = np.zeros(0, dtype=bool)
NONE_I = np.zeros(0, dtype=np.int64)


def _clusters(rng, k):
    """k clusters of 6 vertices within a few centimetres moving by up to a centimetre, and every cluster's quads
    over its vertices (several quads per vertex, so that a vertex's flags matter in more than one pair)."""
    centre = rng.uniform(-1.0, 1.0, size=(k, 1, 3))
    x0 = centre + rng.uniform(-0.02, 0.02, size=(k, 6, 3))
    x1 = x0 + rng.uniform(-0.012, 0.012, size=(k, 6, 3))
    local = np.array([[0, 1, 2, 3], [4, 1, 2, 5], [0, 4, 3, 5], [5, 0, 1, 2], [2, 3, 4, 0], [1, 5, 3, 4]])
    quads = (np.arange(k)[:, None, None] * 6 + local[None]).reshape(-1, 4)
    return x0.reshape(-1, 3), x1.reshape(-1, 3), np.ascontiguousarray(quads, dtype=np.int32)


def _block(vf, X0, X1, quads, gone, only, movable, roots, eta):
    return _ccd_kernels.ccd_block(vf, X0, X1, quads, gone, only, movable, roots, eta, PIPELINE_DEPTH, MAX_INTERVALS,
                                  _ccd_kernels.diagonal_intervals(X0, X1), _ccd_kernels.diagonal_gap(X0, X1, eta))


@pytest.mark.parametrize("vf", [True, False])
def test_filtered_pass_tests_exactly_the_selected_pairs(vf):
    rng = np.random.default_rng(7 if vf else 8)
    eta = 1e-3
    X0, X1, quads = _clusters(rng, 1500)
    N = len(X0)
    everything = np.ones(N, dtype=bool)
    all_idx, all_toi = _block(vf, X0, X1, quads, NONE_B, NONE_B, everything, NONE_I, eta)
    assert len(all_idx) > 200  # enough colliding pairs for the filters to matter
    toi_of = dict(zip(all_idx.tolist(), all_toi.tolist()))
    q = quads.astype(np.int64)
    for case in range(6):
        only = rng.random(N) < 0.4 if case % 2 == 0 else NONE_B
        gone = rng.random(N) < 0.1 if case % 3 != 2 else NONE_B
        movable = rng.random(N) < (0.3 if case < 3 else 0.9)
        # zones: every even cluster one zone (its pairs inside it skipped), the others' vertices alone
        cluster = np.arange(N) // 6
        roots = np.where(cluster % 2 == 0, 6 * cluster, np.arange(N)) if case >= 4 else NONE_I
        keep = movable[q].any(axis=1)
        if len(only):
            keep &= only[q].any(axis=1)
        if len(gone):
            keep &= ~gone[q].any(axis=1)
        if len(roots):
            keep &= ~(roots[q] == roots[q[:, :1]]).all(axis=1)
        want = [i for i in all_idx.tolist() if keep[i]]
        idx, toi = _block(vf, X0, X1, quads, gone, only, movable, roots, eta)
        assert idx.tolist() == want, f"case {case}: the filtered pass's hits differ from the selection"
        assert toi.tolist() == [toi_of[i] for i in want]
        assert 0 < len(want) < len(all_idx) or case % 2 == 1
