"""unique_rows packs integer rows into int64 keys: same results as np.unique(axis=0)."""

import numpy as np
import pytest

from modalfem.mesh.core import unique_rows


@pytest.mark.parametrize("width", [2, 3])
@pytest.mark.parametrize("kwargs", [{}, {"return_inverse": True, "return_counts": True}, {"return_index": True}])
def test_unique_rows_matches_numpy(width, kwargs):
    rows = np.random.default_rng(width).integers(0, 40, (3000, width))
    got, ref = unique_rows(rows, 40, **kwargs), np.unique(rows, axis=0, **kwargs)
    got, ref = (got, ref) if isinstance(ref, tuple) else ((got,), (ref,))
    assert len(got) == len(ref)
    for a, b in zip(got, ref):
        np.testing.assert_array_equal(np.ravel(a), np.ravel(b))


def test_unique_rows_falls_back_to_row_comparison_when_keys_would_overflow():
    n = 3_000_000  # n ** 3 > 2 ** 63
    rows = np.array([[n - 1, n - 2, n - 3], [0, 1, 2], [n - 1, n - 2, n - 3], [5, n - 1, 0]])
    np.testing.assert_array_equal(unique_rows(rows, n), np.unique(rows, axis=0))
