"""Guard rows of the coherent pair search (``_coherent_kernels._guard``): at a pair's full walk they list the
vertices and edges of one body that may come within reach of the other's surface before the next full walk. They
must hold every primitive within ``reach`` of the other body's surface (else a partial re-walk could miss a
contact), and they skip, without changing axes, the primitives farther than ``reach`` from the other body's world
box."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem.collision._distance_kernels import edge_edge_closest, point_triangle_closest
from modalfem.world import _coherent_kernels as CK


def _rotation(axis, angle):
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@numba.njit(cache=False)
def _distances(xa, Ea, Xw, tris, Eb):
    """Brute force: each vertex of a's distance to b's nearest triangle, each edge of a's to b's nearest edge [m]."""
    x = np.empty((4, 3))
    w = np.empty(3)
    dv = np.full(xa.shape[0], np.inf)
    de = np.full(Ea.shape[0], np.inf)
    for j in range(xa.shape[0]):
        x[0] = xa[j]
        for t in range(tris.shape[0]):
            x[1], x[2], x[3] = Xw[tris[t, 0]], Xw[tris[t, 1]], Xw[tris[t, 2]]
            dv[j] = min(dv[j], point_triangle_closest(x, w))
    for e in range(Ea.shape[0]):
        x[0], x[1] = xa[Ea[e, 0]], xa[Ea[e, 1]]
        for f in range(Eb.shape[0]):
            x[2], x[3] = Xw[Eb[f, 0]], Xw[Eb[f, 1]]
            de[e] = min(de[e], edge_edge_closest(x)[0])
    return dv, de


def _rod(rng):
    """Body b: a thin rod of triangles along its own x axis (2 x 0.02 x 0.02 m), turned 45 degrees about the world
    z axis, so that its box in its own axes reaches, grown by ``reach``, points that are farther than ``reach``
    from its world box (near its ends)."""
    n = 40
    xs = np.linspace(-1.0, 1.0, n)
    Xl = np.concatenate([np.c_[xs, np.full(n, y), np.full(n, z)] for y, z in ((-0.01, -0.01), (0.01, -0.01),
                                                                              (0.01, 0.01), (-0.01, 0.01))])
    tris, edges = [], []
    for k in range(4):
        o, o2 = k * n, ((k + 1) % 4) * n
        for i in range(n - 1):
            tris += [(o + i, o + i + 1, o2 + i), (o + i + 1, o2 + i + 1, o2 + i)]
            edges += [(o + i, o + i + 1), (o + i, o2 + i)]
        edges.append((o + n - 1, o2 + n - 1))
    Rb = _rotation((0, 0, 1), np.pi / 4) @ _rotation((1, 0, 0), rng.uniform(0, 0.1))
    pb = rng.uniform(-0.1, 0.1, 3)
    Xw = Xl @ Rb.T + pb
    return Xl, Xw, np.array(tris), np.array(edges), Rb, pb


@pytest.mark.parametrize("seed", range(3))
def test_guard_rows_hold_every_primitive_within_reach_and_none_far_from_the_world_box(seed):
    rng = np.random.default_rng(seed)
    Xl, Xw, tris, Eb, Rb, pb = _rod(rng)
    reach = 0.03
    # body a: points scattered about the rod (near its ends too), in the world; a's edges join random neighbours
    s = rng.uniform(-1.1, 1.1, 3000)
    xa = pb + np.outer(s, Rb[:, 0]) + rng.normal(0, 0.03, (3000, 3))
    Ea = np.c_[np.arange(2999), np.arange(1, 3000)]
    llo, lhi, wlo, whi = Xl.min(0), Xl.max(0), Xw.min(0), Xw.max(0)
    dv, de = _distances(xa, Ea, Xw, tris, Eb)

    gv = CK._guard(False, xa, Ea[:0], Rb, pb, llo, lhi, wlo, whi, reach)
    listed = set(gv[:, 0].astype(int))
    assert np.sum(dv <= reach) > 100
    assert set(np.nonzero(dv <= reach)[0]) <= listed
    for r in gv:
        j = int(r[0])
        np.testing.assert_allclose(r[1:], Rb.T @ (xa[j] - pb), rtol=0, atol=1e-15)
    far_w = [j for j in listed if np.any(xa[j] > whi + reach) or np.any(xa[j] < wlo - reach)]
    assert far_w == []
    # the local box alone would have listed some of those (the test's rod puts them there)
    y = (xa - pb) @ Rb
    in_local = np.all((y >= llo - reach) & (y <= lhi + reach), axis=1)
    in_world = np.all((xa >= wlo - reach) & (xa <= whi + reach), axis=1)
    assert np.sum(in_local & ~in_world) > 0
    assert listed == set(np.nonzero(in_local & in_world)[0])

    ge = CK._guard(True, xa, Ea, Rb, pb, llo, lhi, wlo, whi, reach)
    listed = set(ge[:, 0].astype(int))
    assert np.sum(de <= reach) > 100
    assert set(np.nonzero(de <= reach)[0]) <= listed
    for r in ge:
        i, j = Ea[int(r[0])]
        np.testing.assert_allclose(r[1:4], Rb.T @ (xa[i] - pb), rtol=0, atol=1e-15)
        np.testing.assert_allclose(r[4:7], Rb.T @ (xa[j] - pb), rtol=0, atol=1e-15)
        assert not (np.any(np.minimum(xa[i], xa[j]) > whi + reach) or np.any(np.maximum(xa[i], xa[j]) < wlo - reach))
