"""The chunk order of the pipeline's CCD pass (``_ccd_kernels.spread_order``): a permutation of the chunks that
gives each thread of numba's static schedule (a contiguous range of the loop's iterations) chunks from all over the
pairs, and the pass's answer (hits ascending, same on 1 and 2 threads) does not depend on it."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem._threads import chunk_count, thread_count
from modalfem.collision import _ccd_kernels
from modalfem.collision.ccd import MAX_INTERVALS
from modalfem.collision._stages import PIPELINE_DEPTH


def _static_shares(n: int, threads: int) -> list[range]:
    """The iterations of a loop of ``n`` each thread takes: contiguous, near-equal (numba's static schedule)."""
    return [range((t * n) // threads, ((t + 1) * n) // threads) for t in range(threads)]


@pytest.mark.parametrize("chunks", list(range(1, 70)) + [127, 128, 129])
def test_spread_order_is_a_permutation(chunks):
    order = _ccd_kernels.spread_order(chunks)
    assert order.dtype == np.int64
    assert sorted(order.tolist()) == list(range(chunks))


@pytest.mark.parametrize("threads", [2, 4, 8])
def test_each_thread_takes_every_tth_chunk(threads):
    chunks = 64  # _threads.MAX_CHUNKS: the count of every large block
    order = _ccd_kernels.spread_order(chunks)
    for share in _static_shares(chunks, threads):
        mine = np.sort(order[share.start:share.stop])
        assert len(mine) == chunks // threads
        assert (np.diff(mine) == threads).all(), mine


@pytest.mark.parametrize("chunks", [5, 17, 37, 50, 63])
def test_two_threads_both_halves(chunks):
    """Not a power of two: each of two threads still takes chunks from both halves of the pairs."""
    order = _ccd_kernels.spread_order(chunks)
    for share in _static_shares(chunks, 2):
        mine = order[share.start:share.stop]
        assert mine.min() < chunks / 2 <= mine.max()


def test_block_answer_independent_of_threads():
    """Pairs colliding only in the block's first part (a dense region, as a fold in the search's spatial order):
    the hits ascending and the same on 1 and 2 threads."""
    rng = np.random.default_rng(11)
    k = 40 * _ccd_kernels.CCD_CHUNK
    x0 = rng.uniform(-1.0, 1.0, size=(4 * k, 3))
    x1 = x0.copy()
    quads = np.arange(4 * k, dtype=np.int32).reshape(k, 4)
    dense = quads[: k // 5]
    # the first fifth: a point moving through a small triangle (vf) half the time, the others far apart and still
    tri = 0.01 * rng.uniform(-1.0, 1.0, size=(len(dense), 3, 3))
    x0[dense[:, 1:]] = x0[dense[:, :1]] + tri
    x1[dense[:, 1:]] = x0[dense[:, 1:]]
    cross = rng.random(len(dense)) < 0.5
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    centre = x0[dense[:, 1:]].mean(axis=1)
    x0[dense[:, 0]] = centre + 0.02 * normal
    x1[dense[:, 0]] = np.where(cross[:, None], centre - 0.02 * normal, centre + 0.03 * normal)
    assert chunk_count(k, _ccd_kernels.CCD_CHUNK) == 40
    none_b, none_i = np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64)
    eta = 1e-4
    out = []
    for t in (1, 2):
        with thread_count(t):
            out.append(_ccd_kernels.ccd_block(True, x0, x1, quads, none_b, none_b, np.ones(len(x0), dtype=bool),
                                              none_i, eta, PIPELINE_DEPTH, MAX_INTERVALS,
                                              _ccd_kernels.diagonal_intervals(x0, x1),
                                              _ccd_kernels.diagonal_gap(x0, x1, eta)))
    (i1, t1), (i2, t2) = out
    assert np.array_equal(i1, i2) and np.array_equal(t1, t2)
    assert (np.diff(i1) > 0).all()
    # every crossing point is hit, near its plane's crossing at half the step; no pair outside the dense part
    assert np.array_equal(i1, np.flatnonzero(cross))
    assert np.all(np.abs(t1 - 0.5) < 0.01)
