"""``_coherent_kernels.box_pairs`` (the modal contacts' body pairs whose boxes meet within the search radius) against
the boxes' test written with numpy over every ordered pair: the same pairs in the same order, the same radii."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.world import _coherent_kernels as CK


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_box_pairs_equal_numpy(seed):
    rng = np.random.default_rng(seed)
    n = 25
    lo = rng.uniform(0.0, 1.0, (n, 3))
    hi = lo + rng.uniform(0.01, 0.3, (n, 3))
    marg = rng.uniform(0.0, 2e-3, n)
    reach = rng.uniform(0.0, 5e-3, n)
    # some boxes exactly at the search radius from another along one axis (the test is <=: they meet)
    for a, b in ((0, 1), (2, 3), (4, 5)):
        r = max(marg[a], marg[b]) + reach[a] + reach[b]
        lo[b] = lo[a]
        hi[b] = hi[a]
        lo[b, 0] = hi[a, 0] + r
        hi[b, 0] = lo[b, 0] + 0.1
    mm = np.maximum(marg[:, None], marg[None, :])
    rr = mm + reach[:, None] + reach[None, :]
    meet = np.all((lo[:, None, :] - rr[:, :, None] <= hi[None, :, :])
                  & (lo[None, :, :] - rr[:, :, None] <= hi[:, None, :]), axis=2)
    ia, ib = np.nonzero(np.triu(meet, 1))
    ga, gb, grr, gmm = CK.box_pairs(lo, hi, marg, reach)
    assert ga.dtype == np.int64 and gb.dtype == np.int64
    assert np.array_equal(ga, ia) and np.array_equal(gb, ib)
    assert np.array_equal(grr, rr[ia, ib]) and np.array_equal(gmm, mm[ia, ib])
    assert 0 < ia.size < n * (n - 1) // 2  # some pairs meet, some do not
    assert all(meet[a, b] for a, b in ((0, 1), (2, 3), (4, 5)))
    assert CK.box_pairs(lo[:1], hi[:1], marg[:1], reach[:1])[0].size == 0
