"""The candidate walk of the coherent pair search (``_coherent_kernels._walk_all``) skips the exact distance test
of a leaf entry whose deformed corners' box is farther than the radius from the query's box (a lower bound of the
distance). It must still list every (query, entry) pair within the radius, with the distances the exact test
gives (``point_triangle_closest``, ``edge_edge_closest``), and nothing else: compared here with every pair tested.
The surface is deformed by up to ``bound`` from the rest positions its tree was fitted to, as a modal body's is.

The lazy walk (vertex-face candidates of ``coherent_pairs``) writes, instead of the exact distance, the box gap
lowered by the rounding band: every pair within the radius must be listed, and each listed bound must be below the
exact test's distance (the evaluations skip a pair on it)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem.collision._distance_kernels import edge_edge_closest, point_triangle_closest
from modalfem.collision.bvh import BroadPhaseBVH
from modalfem.world import _coherent_kernels as CK

from _grid_surface import grid_surface


@numba.njit(cache=False)
def _all_pairs(edges, y, Xb, Fb, radius):
    """Every (query, entry) pair within ``radius`` by the exact test: (query, entry, distance) rows."""
    x = np.empty((4, 3))
    w = np.empty(3)
    out = []
    for i in range(y.shape[0]):
        x[0] = y[i, 0]
        x[1] = y[i, 1]
        for t in range(Fb.shape[0]):
            if edges:
                x[2], x[3] = Xb[Fb[t, 0]], Xb[Fb[t, 1]]
                d = edge_edge_closest(x)[0]
            else:
                x[1], x[2], x[3] = Xb[Fb[t, 0]], Xb[Fb[t, 1]], Xb[Fb[t, 2]]
                d = point_triangle_closest(x, w)
            if d <= radius:
                out.append((i, t, d))
    return out


def _setup(seed, edges, bound=0.3e-3, m=150):
    """A grid surface deformed by up to ``bound`` [m], its rest tree, and ``m`` queries (points or short segments)
    around it."""
    rng = np.random.default_rng(seed)
    rest, T, E = grid_surface(10, 0.4e-3)
    radius = 1.5e-3
    # deformed surface: every vertex within ``bound`` of its rest position (the tree holds the rest boxes)
    u = rng.normal(size=rest.shape)
    Xb = rest + u * (rng.uniform(0.0, bound, len(rest)) / np.linalg.norm(u, axis=1))[:, None]
    F = np.ascontiguousarray(np.column_stack([E[:, 0], E[:, 1], E[:, 1]])) if edges else T
    tree = BroadPhaseBVH(F, rest, leaf_size=4)
    tree.refit(rest, margin=0.0)
    # queries over the surface: points (or short segments) from below it to beyond the radius above it
    p = np.column_stack([rng.uniform(-1e-3, 10e-3, m), rng.uniform(-1e-3, 10e-3, m), rng.uniform(-1.5e-3, 2.5e-3, m)])
    if edges:
        v = rng.normal(size=(m, 3))
        v *= (rng.uniform(0.2e-3, 1.2e-3, m) / np.linalg.norm(v, axis=1))[:, None]
        y = np.ascontiguousarray(np.stack([p, p + v], axis=1))
    else:
        y = np.ascontiguousarray(p[:, None, :])
    grow = radius + bound
    qlo, qhi = y.min(axis=1) - grow, y.max(axis=1) + grow
    return Xb, F, tree, y, qlo, qhi, radius


def _gap(yq, corners):
    """The distance between the box of the query's points and the box of the entry's corners [m]."""
    g = np.maximum(np.maximum(corners.min(0) - yq.max(0), yq.min(0) - corners.max(0)), 0.0)
    return float(np.sqrt(np.sum(g * g)))


@pytest.mark.parametrize("undeformed", [False, True])
@pytest.mark.parametrize("edges", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_walk_lists_every_pair_within_radius(seed, edges, undeformed):
    # undeformed (bound 0): the tree's boxes are the entries' own, so its nodes' pruning (box, then the sum of the
    # boxes' gaps) sees pairs whose gap is all but the radius
    Xb, F, tree, y, qlo, qhi, radius = _setup(seed, edges, *((0.0, 600) if undeformed else ()))
    m = y.shape[0]
    ids = np.arange(100, 100 + m, dtype=np.int64)  # the ids written for the queries
    got_v, got_t, got_d = CK._walk_all(edges, False, ids, y, qlo, qhi, Xb, F, radius, tree.P, tree.lo, tree.hi,
                                       tree.nonempty, tree.slot_tri, tree._slo, tree._shi)
    assert np.all(np.diff(got_v) >= 0)  # grouped by query in increasing order
    ref = _all_pairs(edges, y if edges else np.ascontiguousarray(np.repeat(y, 2, axis=1)), Xb, F, radius)
    want = {(100 + i, t): d for i, t, d in ref}
    got = {(int(v), int(t)): float(d) for v, t, d in zip(got_v, got_t, got_d)}
    assert len(got) == got_v.size  # no pair twice
    assert got == want  # the same pairs, the exact test's distances bit for bit
    # the test sees a lax skip: pairs within the radius whose boxes' gap is most of it
    cols = 2 if edges else 3
    far_gap = sum(_gap(y[i], Xb[F[t, :cols]]) > (0.99 if undeformed else 0.9) * radius for i, t, _ in ref)
    assert far_gap >= 5, far_gap


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lazy_walk_lists_every_pair_within_radius_with_lower_bounds(seed):
    Xb, F, tree, y, qlo, qhi, radius = _setup(seed, False)
    m = y.shape[0]
    ids = np.arange(100, 100 + m, dtype=np.int64)
    got_v, got_t, got_lb = CK._walk_all(False, True, ids, y, qlo, qhi, Xb, F, radius, tree.P, tree.lo, tree.hi,
                                        tree.nonempty, tree.slot_tri, tree._slo, tree._shi)
    assert np.all(np.diff(got_v) >= 0)  # grouped by query in increasing order
    got = {(int(v), int(t)): float(d) for v, t, d in zip(got_v, got_t, got_lb)}
    assert len(got) == got_v.size  # no pair twice
    ref = _all_pairs(False, np.ascontiguousarray(np.repeat(y, 2, axis=1)), Xb, F, radius)
    assert {(100 + i, t) for i, t, _ in ref} <= set(got)  # every pair within the radius
    x = np.empty((4, 3))
    w = np.empty(3)
    tight = 0
    for (v, t), lb in got.items():
        i = v - 100
        x[0], x[1:] = y[i, 0], Xb[F[t]]
        d = point_triangle_closest(x, w)
        gap = _gap(y[i], Xb[F[t]])
        band = CK._CUT_EPS * (np.abs(y[i, 0]).max() + radius)
        # listed on the box gap (a pair farther than the radius by more than the band is left out)
        assert gap <= radius + 2 * band
        # the bound: the gap lowered by the rounding band, below the exact distance
        assert lb <= d
        assert max(gap - 2 * band, 0.0) <= lb <= max(gap - 0.5 * band, 0.0)
        tight += d - lb < 1e-3 * radius
    assert tight >= 20, tight  # the test sees bounds as tight as the distances (a lax bound would exceed them)
