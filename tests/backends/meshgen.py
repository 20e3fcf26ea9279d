"""Test meshes for the backend tests: Kuhn-subdivided boxes (6 tetrahedra per hexahedron), optionally
jittered and with shuffled point/cell numbering so that ordering and orientation bugs cannot hide."""

from __future__ import annotations

import itertools

import numpy as np

from modalfem.mesh.core import Mesh, signed_volumes

__all__ = ["box_mesh"]


def box_mesh(
    nx: int,
    ny: int,
    nz: int,
    *,
    size=(1.0, 0.1, 0.1),
    jitter: float = 0.0,
    shuffle: bool = False,
    seed: int = 0,
) -> Mesh:
    """Box [0, Lx] x [0, Ly] x [0, Lz] [m] of ``nx*ny*nz`` hexahedra, 6 positive tetrahedra each.

    Args:
        nx, ny, nz: hexahedra per axis.
        size: box edge lengths (3,) [m].
        jitter: interior-point perturbation as a fraction of the cell size (0 = structured).
        shuffle: randomly renumber points, permute cells and rotate each cell's vertex list.
        seed: random seed for jitter and shuffle.
    """
    rng = np.random.default_rng(seed)
    n = np.array([nx, ny, nz])
    h = np.asarray(size, dtype=float) / n
    g = np.stack(np.meshgrid(*[np.arange(k + 1) for k in n], indexing="ij"), axis=-1).reshape(-1, 3)
    points = g * h
    if jitter:
        interior = np.all((g > 0) & (g < n), axis=1)
        points[interior] += jitter * h * rng.uniform(-0.5, 0.5, (int(interior.sum()), 3))
    idx = lambda i, j, k: (i * (n[1] + 1) + j) * (n[2] + 1) + k
    base = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), axis=-1).reshape(-1, 3)
    tets = []
    for perm in itertools.permutations(range(3)):
        path = [np.zeros(3, int)]
        for a in perm:
            step = path[-1].copy()
            step[a] = 1
            path.append(step)
        tets.append(np.stack([idx(*(base + s).T) for s in path], axis=1))
    cells = np.concatenate(tets)
    neg = signed_volumes(points, cells) < 0
    cells[neg] = cells[neg][:, [1, 0, 2, 3]]
    if shuffle:
        new = rng.permutation(len(points))
        pts = np.empty_like(points)
        pts[new] = points
        points, cells = pts, new[cells]
        cells = cells[rng.permutation(len(cells))]
        # even permutations of the 4 vertices keep the orientation
        even = np.array([[0, 1, 2, 3], [1, 2, 0, 3], [2, 0, 1, 3], [1, 0, 3, 2], [3, 2, 1, 0], [0, 2, 3, 1]])
        cells = np.take_along_axis(cells, even[rng.integers(0, len(even), len(cells))], axis=1)
    return Mesh(points, cells)
