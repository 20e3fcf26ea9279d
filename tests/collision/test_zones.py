"""Impact zones: union-find, momentum conservation of free zones, kinematic zones follow their pins."""

from __future__ import annotations

import numpy as np

from modalfem.collision.obstacles import Sphere
from modalfem.collision.zones import UnionFind, rigid_zone_velocities


def test_union_find_merges_transitively():
    uf = UnionFind(8)
    uf.union([0, 5], [3, 6])
    uf.union([3], [6])
    r = uf.roots()
    assert r[0] == r[3] == r[5] == r[6] == 0 and len(set(r)) == 5


def test_free_zone_conserves_linear_and_angular_momentum_and_is_rigid():
    rng = np.random.default_rng(0)
    X, V = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    m = rng.uniform(0.5, 2.0, 7)
    roots = np.array([0, 0, 0, 0, 0, 5, 6])
    Vn, bad = rigid_zone_velocities(X, V, 1 / m, roots, [], 0.0)
    z = slice(0, 5)
    assert np.allclose((m[z, None] * Vn[z]).sum(0), (m[z, None] * V[z]).sum(0))
    xc = (m[z, None] * X[z]).sum(0) / m[z].sum()
    L0 = (m[z, None] * np.cross(X[z] - xc, V[z])).sum(0)
    L1 = (m[z, None] * np.cross(X[z] - xc, Vn[z])).sum(0)
    assert np.allclose(L0, L1)
    # rigid: the velocity field preserves pairwise distances to first order
    d = X[z][:, None] - X[z][None]
    dv = Vn[z][:, None] - Vn[z][None]
    assert np.allclose(np.einsum("ijk,ijk->ij", d, dv), 0, atol=1e-12)
    assert np.array_equal(Vn[5:], V[5:]) and len(bad) == 0


def test_kinematic_zones_follow_pins_and_obstacles():
    rng = np.random.default_rng(1)
    X, V = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    invm = np.ones(5)
    invm[0] = 0.0  # a pin moving with V[0]
    roots = np.array([0, 0, 0, 3, 3, 3])  # node 5: the sphere, in the zone of vertices 3, 4
    ball = Sphere([0, 0, 0], 0.1, velocity=[1.0, 0, 0], angular_velocity=[0, 0, 2.0])
    Vn, bad = rigid_zone_velocities(X, V, invm, roots, [ball], 0.0)
    assert np.allclose(Vn[:3], V[0]) and np.array_equal(Vn[0], V[0])
    assert np.allclose(Vn[3:5], ball.velocity_at(X[3:5], 0.0))
    assert len(bad) == 0
    # two pins moving apart cannot move rigidly together: reported inconsistent
    V[1] = V[0] + [5.0, 0, 0]
    invm[1] = 0.0
    _, bad = rigid_zone_velocities(X, V, invm, roots, [ball], 0.0)
    assert list(bad) == [0]
