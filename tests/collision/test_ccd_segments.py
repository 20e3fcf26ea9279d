"""One parallel region over all the pair store's segments (``_ccd_kernels.ccd_segments``, issue 20): the same hits and
times, bit for bit, as one ``ccd_block`` per segment, on one and two threads, for segments of both kinds with and
without their ``gone`` / ``only`` flags, empty segments and segments of one and of many chunks."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem._threads import thread_count
from modalfem.collision import _ccd_kernels
from modalfem.collision._stages import PIPELINE_DEPTH
from modalfem.collision.ccd import MAX_INTERVALS

THREADS = (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,)
NONE_B = np.zeros(0, dtype=bool)
NONE_I = np.zeros(0, dtype=np.int64)


def _scene(seed: int, clusters: int):
    """Clusters of 6 vertices within a few centimetres moving by up to a centimetre; every cluster's quads over
    its vertices (many of them collide)."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-1.0, 1.0, size=(clusters, 1, 3))
    x0 = centre + rng.uniform(-0.02, 0.02, size=(clusters, 6, 3))
    x1 = x0 + rng.uniform(-0.012, 0.012, size=(clusters, 6, 3))
    local = np.array([[0, 1, 2, 3], [4, 1, 2, 5], [0, 4, 3, 5], [5, 0, 1, 2], [2, 3, 4, 0], [1, 5, 3, 4]])
    quads = (np.arange(clusters)[:, None, None] * 6 + local[None]).reshape(-1, 4)
    return rng, x0.reshape(-1, 3), x1.reshape(-1, 3), quads.astype(np.int32)


def _segments(rng, quads, N):
    """Segments as PairStore.segments gives them: slices of the quads (a permutation, so every segment holds
    pairs from all over), some with gone and only flags, one empty, one of a single pair."""
    q = quads[rng.permutation(len(quads))]
    cuts = [0, 1, 300, 300, 2000, 2700, 7000, len(q)]
    segs = []
    for s, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        gone = rng.random(N) < 0.1 if s % 3 == 1 else NONE_B
        only = rng.random(N) < 0.5 if s % 2 == 0 else NONE_B
        segs.append((s % 4 != 3, np.ascontiguousarray(q[a:b]), gone, only))
    return segs


@pytest.mark.parametrize("zones", [False, True])
def test_one_region_gives_the_hits_of_one_pass_per_segment(zones):
    eta = 1e-3
    rng, X0, X1, quads = _scene(5 + zones, 1800)
    N = len(X0)
    movable = rng.random(N) < 0.9
    cluster = np.arange(N) // 6
    roots = np.where(cluster % 3 == 0, 6 * cluster, np.arange(N)) if zones else NONE_I
    segs = _segments(rng, quads, N)
    diag, gap = _ccd_kernels.diagonal_intervals(X0, X1), _ccd_kernels.diagonal_gap(X0, X1, eta)
    want = [_ccd_kernels.ccd_block(vf, X0, X1, q, gone, only, movable, roots, eta, PIPELINE_DEPTH, MAX_INTERVALS,
                                   diag, gap) for vf, q, gone, only in segs]
    assert sum(len(i) for i, _ in want) > 250  # enough hits, in several segments
    assert sum(len(i) > 0 for i, _ in want) >= 4
    for t in THREADS:
        with thread_count(t):
            got = _ccd_kernels.ccd_segments(segs, X0, X1, movable, roots, eta, PIPELINE_DEPTH, MAX_INTERVALS, diag,
                                            gap)
        assert len(got) == len(segs)
        for s, ((wi, wt), (gi, gt)) in enumerate(zip(want, got)):
            assert gi.tolist() == wi.tolist(), f"segment {s}, {t} threads: other pairs"
            assert gt.tobytes() == wt.tobytes(), f"segment {s}, {t} threads: other times"


def test_no_segments_and_bad_arrays():
    rng, X0, X1, quads = _scene(1, 10)
    movable = np.ones(len(X0), dtype=bool)
    diag, gap = _ccd_kernels.diagonal_intervals(X0, X1), _ccd_kernels.diagonal_gap(X0, X1, 1e-3)
    args = (X0, X1, movable, NONE_I, 1e-3, PIPELINE_DEPTH, MAX_INTERVALS, diag, gap)
    assert _ccd_kernels.ccd_segments([], *args) == []
    with pytest.raises(ValueError):  # handed by address: anything but contiguous int32 pairs is refused
        _ccd_kernels.ccd_segments([(True, quads.astype(np.int64), NONE_B, NONE_B)], *args)
    with pytest.raises(ValueError):
        _ccd_kernels.ccd_segments([(True, quads[::2], NONE_B, NONE_B)], *args)
    with pytest.raises(ValueError):  # flags of another length would be read out of bounds
        _ccd_kernels.ccd_segments([(True, quads, np.ones(len(X0) - 1, dtype=bool), NONE_B)], *args)
