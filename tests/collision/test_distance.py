"""Distances against dense sampling; lower bounds never above the true distance (slivers, parallel edges)."""

from __future__ import annotations

import numpy as np

from modalfem.collision.distance import (
    edge_edge,
    edge_edge_lower_bound,
    point_triangle,
    point_triangle_lower_bound,
)

RNG = np.random.default_rng(7)


def _sampled_point_triangle(p, a, b, c, n=60):
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    m = u + v <= 1
    w = np.stack([1 - u[m] - v[m], u[m], v[m]], 1)
    q = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
    return np.linalg.norm(q - p, axis=1).min()


def _sampled_edge_edge(a0, a1, b0, b1, n=200):
    s = np.linspace(0, 1, n)[:, None]
    pa, pb = a0 + s * (a1 - a0), b0 + s * (b1 - b0)
    return np.linalg.norm(pa[:, None] - pb[None], axis=2).min()


def test_point_triangle_matches_sampling_and_closest_point():
    for _ in range(40):
        p, a, b, c = RNG.normal(size=(4, 3))
        d, w = point_triangle(p[None], a[None], b[None], c[None])
        q = w[0, 0] * a + w[0, 1] * b + w[0, 2] * c
        assert np.isclose(np.linalg.norm(p - q), d[0])
        assert (w >= -1e-12).all() and np.isclose(w.sum(), 1)
        ds = _sampled_point_triangle(p, a, b, c)
        assert d[0] <= ds + 1e-12 and ds - d[0] < 0.05
        lb = point_triangle_lower_bound(p[None], a[None], b[None], c[None])
        assert lb[0] <= d[0] + 1e-12


def test_edge_edge_matches_sampling_including_parallel():
    cases = [RNG.normal(size=(4, 3)) for _ in range(30)]
    a0, a1 = np.zeros(3), np.array([1.0, 0, 0])
    cases.append(np.array([a0, a1, [0.3, 0.2, 0], [1.4, 0.2, 0]]))  # parallel, overlapping
    cases.append(np.array([a0, a1, [1.5, 0.2, 0], [2.4, 0.2, 0]]))  # parallel, disjoint
    cases.append(np.array([a0, a1, [0.5, 0.0, 0], [0.5, 0.0, 0]]))  # zero-length edge on a
    for a0, a1, b0, b1 in cases:
        d, s, t = edge_edge(a0[None], a1[None], b0[None], b1[None])
        pa, pb = a0 + s[0] * (a1 - a0), b0 + t[0] * (b1 - b0)
        assert np.isclose(np.linalg.norm(pa - pb), d[0])
        ds = _sampled_edge_edge(a0, a1, b0, b1)
        assert d[0] <= ds + 1e-12 and ds - d[0] < 0.02
        assert edge_edge_lower_bound(a0[None], a1[None], b0[None], b1[None])[0] <= d[0] + 1e-12


def test_lower_bounds_on_nearly_parallel_crossing_edges_and_slivers():
    # two edges crossing at a tiny angle: the true distance is 0
    for ang in (1e-3, 1e-6, 1e-9, 1e-12):
        a0, a1 = np.array([-1.0, 0, 0]), np.array([1.0, 0, 0])
        b0, b1 = np.array([-1.0, -ang, 0]), np.array([1.0, ang, 0])
        lb = edge_edge_lower_bound(a0[None], a1[None], b0[None], b1[None])[0]
        assert lb <= 1e-12
    # a point on a sliver triangle: distance 0
    for h in (1e-3, 1e-7, 1e-12):
        a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.5, h, 0])
        p = np.array([0.5, 0.5 * h, 0])
        assert point_triangle_lower_bound(p[None], a[None], b[None], c[None])[0] <= 1e-12
    # random: lower bound <= distance, and tight away from degeneracy
    p, a, b, c = (RNG.normal(size=(500, 3)) for _ in range(4))
    d, _ = point_triangle(p, a, b, c)
    lb = point_triangle_lower_bound(p, a, b, c)
    assert (lb <= d + 1e-12).all() and np.median(lb / d) > 0.5
    d, _, _ = edge_edge(p, a, b, c)
    lb = edge_edge_lower_bound(p, a, b, c)
    assert (lb <= d + 1e-12).all() and np.median(lb / d) > 0.5


def test_lower_bounds_stay_below_the_distance_on_degenerate_batches():
    """The compiled lower bounds (the CCD's) never exceed the exact distances, also for slivers, nearly
    parallel and zero-length edges."""
    rng = np.random.default_rng(8)
    X = rng.standard_normal((3000, 4, 3))
    X[1000:1500, 3] = X[1000:1500, 2] + 1e-9 * rng.standard_normal((500, 3))  # slivers / short edges
    X[1500:2000, 3] = X[1500:2000, 2]  # zero length
    X[2000:2500, 3] = X[2000:2500, 2] + (X[2000:2500, 1] - X[2000:2500, 0]) * (1 + 1e-7)  # parallel edges
    cols = [X[:, i] for i in range(4)]
    d_pt, _ = point_triangle(*cols)
    d_ee = edge_edge(*cols)[0]
    for bound, d in ((point_triangle_lower_bound, d_pt), (edge_edge_lower_bound, d_ee)):
        lb = bound(*cols)
        assert lb.shape == (3000,) and np.all(lb >= 0) and np.all(lb <= d + 1e-12)
        assert np.median(lb / d) > 0.5  # and not trivially zero
