"""The pipeline's row masks (or of three columns) give numpy's ``any(axis=1)`` exactly."""

import numpy as np

from modalfem.collision._stages import _rows_any
from modalfem.collision._system import _flagged_triangles


def test_rows_any_matches_numpy():
    rng = np.random.default_rng(3)
    for k, p in ((0, 0.5), (1, 0.5), (257, 0.05), (4200, 0.3)):
        a = rng.random((k, 3)) < p
        assert np.array_equal(_rows_any(a), a.any(axis=1))
    v, w = rng.random((50, 3)), rng.random((50, 3))
    w[::3] = v[::3]
    w[1::7, 2] = v[1::7, 2] + 1e-300  # a change in one coordinate only
    assert np.array_equal(_rows_any(v != w), np.any(v != w, axis=1))


def test_flagged_triangles_matches_numpy():
    rng = np.random.default_rng(4)
    tris = rng.integers(0, 300, size=(800, 3))
    for p in (0.0, 0.01, 0.3, 1.0):
        flags = rng.random(300) < p
        assert np.array_equal(_flagged_triangles(flags, tris), flags[tris].any(axis=1))
    assert _flagged_triangles(np.ones(3, dtype=bool), np.zeros((0, 3), dtype=np.int64)).shape == (0,)
