"""The evaluation of kept vertex-face candidates in the coherent pair search (``_coherent_kernels._vf_eval``):
before its tree-order pass it measures each vertex's candidate of smallest distance bound and skips the candidates
whose bound, lowered by the motion since (``drop``), is beyond that distance. The contacts must be those of testing
every candidate in order with ``_vf_test`` (the brute-force selection, ties included), and the bounds it leaves
must stay lower bounds of the current distances (the next step skips by them)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem.collision._distance_kernels import point_triangle_closest
from modalfem.world import _coherent_kernels as CK
from modalfem.world._solid_kernels import _to_local, _vf_found, _vf_test

from _grid_surface import grid_surface


@numba.njit(cache=False)
def _reference(xa, Rb, pb, Xb, Tb, reach, cv, ct):
    """Every candidate tested in order (no skip): the selection the tree-order walk makes, and the distances."""
    n = cv.shape[0]
    m = 0
    prev = -1
    for k in range(n):
        if cv[k] != prev:
            m += 1
            prev = cv[k]
    vid = np.empty(m, dtype=np.int64)
    best = np.full(m, -1, dtype=np.int64)
    dbest = np.full(m, np.inf)
    gbest = np.zeros(m)
    bary = np.zeros((m, 3))
    nloc = np.zeros((m, 3))
    dist = np.empty(n)
    x = np.empty((4, 3))
    w = np.empty(3)
    y = np.empty(3)
    i = -1
    prev = -1
    for k in range(n):
        if cv[k] != prev:
            i += 1
            prev = cv[k]
            vid[i] = prev
            _to_local(xa[prev], Rb, pb, y)
        dist[k] = _vf_test(y, Xb, Tb, ct[k], reach, x, w, i, best, dbest, gbest, bary, nloc)
    return _vf_found(vid, best, gbest, bary, nloc, Rb), dist


@numba.njit(cache=False)
def _all_distances(y, Xb, Tb):
    x = np.empty((4, 3))
    w = np.empty(3)
    d = np.empty((y.shape[0], Tb.shape[0]))
    for j in range(y.shape[0]):
        x[0] = y[j]
        for t in range(Tb.shape[0]):
            x[1], x[2], x[3] = Xb[Tb[t, 0]], Xb[Tb[t, 1]], Xb[Tb[t, 2]]
            d[j, t] = point_triangle_closest(x, w)
    return d


def _rotation(rng):
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q * np.sign(np.linalg.det(Q))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_prepass_equals_every_candidate_tested(seed):
    rng = np.random.default_rng(seed)
    Xb, Tb, _ = grid_surface(12, 0.4e-3)
    Rb, pb = _rotation(rng), rng.normal(size=3)
    reach, radius, move = 2.0e-3, 3.0e-3, 0.6e-3
    skipped_within_reach = 0
    # a's vertices in b's axes: over the surface, some exactly on grid vertices and edges (equal distances to
    # several triangles: the tie rule's cases)
    m = 60
    y = np.column_stack([rng.uniform(1e-3, 10e-3, m), rng.uniform(1e-3, 10e-3, m), rng.uniform(-1e-3, 2.5e-3, m)])
    y[:10, :2] = np.round(y[:10, :2] * 1e3) * 1e-3
    y[10:20, 0] = np.round(y[10:20, 0] * 1e3) * 1e-3
    d0 = _all_distances(y, Xb, Tb)
    cv, ct = [], []
    for j in range(m):
        near = np.flatnonzero(d0[j] <= radius)
        near = rng.permutation(near)  # any order stands for the tree's
        cv += [j] * near.size
        ct += list(near)
    cv, ct = np.array(cv, dtype=np.int64), np.array(ct, dtype=np.int64)
    lb = d0[cv, ct] - rng.uniform(0.0, 0.2e-3, cv.size) * (rng.random(cv.size) < 0.3)  # lower bounds, some loose
    for step in range(12):
        # each vertex moves by at most ``move`` (b's triangles do not): distances drop by at most that
        u = rng.normal(size=(m, 3))
        u *= (rng.uniform(0.0, move, m) / np.linalg.norm(u, axis=1))[:, None]
        if step % 2 == 0:
            u[:20] = 0.0  # the vertices on grid points and lines stay there (ties) every other step
        y = y + u
        xa = y @ Rb.T + pb  # world positions: y = Rb^T (x - pb)
        (ref, dist) = _reference(xa, Rb, pb, Xb, Tb, reach, cv, ct)
        # then again with no motion since (drop 0: the bounds are the distances just measured, as after a walk)
        for drop in (move, 0.0):
            lb_new = lb.copy()
            out = CK._vf_eval(xa, Rb, pb, Xb, Tb, reach, cv, ct, lb_new, drop)
            for got, want in zip(out, ref):
                assert got.dtype == want.dtype and np.array_equal(got, want), (seed, step, drop)
            # the bounds left: lower bounds of the distances now (skipped: lowered by the move; tested: equal)
            assert np.all(lb_new <= dist), (seed, step, drop)
            within = lb - drop <= reach
            skipped_within_reach += int(np.sum((lb_new < dist) & within))
            lb = lb_new
    # candidates within reach were skipped (else this test would not see a lax skip)
    assert skipped_within_reach > 0
