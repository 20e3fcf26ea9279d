"""A wavy grid surface for the coherent search's tests (shared by test_coherent_walk_gap and test_coherent_vf_prepass)."""

from __future__ import annotations

import numpy as np


def grid_surface(n: int, h: float):
    """An n x n grid of 1 mm cells [m] waved by up to ``h`` [m] in z: vertices (n*n, 3), triangles (2 (n-1)^2, 3),
    edges (sorted unique pairs)."""
    g = np.arange(n) * 1e-3
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = h * np.sin(X * 900.0) * np.cos(Y * 700.0)
    V = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    T = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            T += [(a, b, d), (a, d, c)]
    T = np.array(T, dtype=np.int64)
    E = np.unique(np.sort(np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]]), axis=1), axis=0)
    return V, T, np.ascontiguousarray(E)
