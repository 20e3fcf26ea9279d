"""Small triangle meshes and adversarial configurations for the collision tests."""

from __future__ import annotations

import numpy as np


def grid(nx: int, ny: int, *, size: float = 1.0, z: float = 0.0, origin=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A flat (nx x ny quads) sheet in the plane z, two triangles per quad: (points [m], triangles)."""
    xs, ys = np.meshgrid(np.linspace(0, size, nx + 1), np.linspace(0, size, ny + 1), indexing="ij")
    pts = np.stack([xs.ravel() + origin[0], ys.ravel() + origin[1], np.full(xs.size, z)], axis=1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return pts, tri


def stacked_sheets(layers: int, n: int, *, gap: float, size: float = 1.0, seed: int = 0):
    """``layers`` parallel sheets ``gap`` apart, slightly jittered in-plane: (points, triangles)."""
    rng = np.random.default_rng(seed)
    pts, tris = [], []
    for k in range(layers):
        p, t = grid(n, n, size=size, z=k * gap)
        p[:, :2] += rng.uniform(-0.2, 0.2, size=(len(p), 2)) * size / n
        tris.append(t + sum(len(q) for q in pts))
        pts.append(p)
    return np.concatenate(pts), np.concatenate(tris)


def folded_sheet(n: int, *, gap: float, size: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sheet folded in half over itself (the upper half ``gap`` above the lower, joined by a rounded
    fold): (points [m], triangles, rest points [m])."""
    rest, tri = grid(2 * n, n, size=size)
    rest[:, 1] *= 0.5
    u = rest[:, 0]
    x = rest.copy()
    half = 0.5 * size
    upper = u > half
    x[upper, 0] = 2 * half - u[upper]
    x[upper, 2] = gap
    near = np.abs(u - half) <= 1e-12
    x[near, 0] = half + 0.5 * gap
    x[near, 2] = 0.5 * gap
    return x, tri, rest


def all_pairs(tri):
    """Every vertex-face and edge-edge pair not sharing a vertex (brute force, no BVH)."""
    n = tri.max() + 1
    v = np.repeat(np.arange(n), len(tri))
    f = np.tile(np.arange(len(tri)), n)
    ok = (tri[f] != v[:, None]).all(axis=1)
    vf = np.concatenate([v[ok, None], tri[f[ok]]], axis=1)
    e = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1), axis=0)
    i, j = np.triu_indices(len(e), 1)
    ee = np.concatenate([e[i], e[j]], axis=1)
    ee = ee[(ee[:, :2, None] != ee[:, None, 2:]).all(axis=(1, 2))]
    return vf, ee
