"""Compiled union-find of the impact zones (numba ``njit``, cached on disk): the only implementation of
:class:`modalfem.collision.zones.UnionFind`'s merges.

Every parent pointer points to a smaller or equal index (a merge links the larger root under the smaller),
so each set's root is its smallest member, whatever the order of the merges, and one pass in index order
compresses every path.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["compress", "union_pairs", "union_quads"]


@numba.njit(cache=True, inline="always")
def _find(parent: np.ndarray, i: int) -> int:
    """Root of node ``i`` (path halving: each visited node is pointed at its grandparent)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True)
def union_pairs(parent: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """In place: merge the sets of ``a[k]`` and ``b[k]`` for every k (the larger root under the smaller)."""
    for k in range(len(a)):
        ra, rb = _find(parent, a[k]), _find(parent, b[k])
        if ra < rb:
            parent[rb] = ra
        elif rb < ra:
            parent[ra] = rb


@numba.njit(cache=True)
def union_quads(parent: np.ndarray, quads: np.ndarray) -> None:
    """In place: merge the four vertices of every row of ``quads`` (k, 4) into one set."""
    for k in range(len(quads)):
        r0 = _find(parent, quads[k, 0])
        for j in range(1, 4):
            r = _find(parent, quads[k, j])
            if r < r0:
                parent[r0] = r
                r0 = r
            elif r > r0:
                parent[r] = r0


@numba.njit(cache=True)
def compress(parent: np.ndarray) -> None:
    """In place: every node points at its root (in index order: a node's parent, smaller, is done first)."""
    for i in range(len(parent)):
        parent[i] = parent[parent[i]]
