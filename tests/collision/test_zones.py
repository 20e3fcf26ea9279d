"""Impact zones: union-find, momentum conservation of free zones, kinematic zones follow their pins and
the finite motion of turning handles."""

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


def test_union_find_roots_are_the_smallest_member_of_each_connected_set():
    """Random merges (pairs and quadruples, in several batches) against scipy's connected components: the
    same sets, each rooted at its smallest node."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(4)
    n = 500
    uf = UnionFind(n)
    a_all, b_all = [], []
    for _ in range(3):
        a, b = rng.integers(0, n, 120), rng.integers(0, n, 120)
        uf.union(a, b)
        q = rng.integers(0, n, (40, 4))
        uf.union_quads(q)
        a_all += [a] + [q[:, 0]] * 3
        b_all += [b, q[:, 1], q[:, 2], q[:, 3]]
        a_cat, b_cat = np.concatenate(a_all), np.concatenate(b_all)
        _, lab = connected_components(coo_matrix((np.ones(len(a_cat)), (a_cat, b_cat)), shape=(n, n)), directed=False)
        smallest = np.full(lab.max() + 1, n)
        np.minimum.at(smallest, lab, np.arange(n))
        r = uf.roots()
        assert np.array_equal(r, smallest[lab])
        assert 1 < len(np.unique(r)) < n


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


def _turn(axis_angle):
    """Rotation matrix (Rodrigues) of the vector ``axis_angle`` [rad]."""
    a = np.linalg.norm(axis_angle)
    k = axis_angle / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _chord_zone(rng, kinematic, dt=0.01):
    """A zone of 8 vertices whose ``kinematic`` ones are scripted by a finite rotation + translation over
    ``dt`` (chord velocities, as a turning handle gives them); the others have random velocities."""
    X = rng.normal(size=(8, 3))
    if kinematic == "collinear":
        X[:3] = X[0] + np.outer([0.0, 0.4, 1.0], rng.normal(size=3))
        kin = np.arange(3)
    else:
        kin = np.arange(4)
    R, T = _turn(rng.normal(size=3) * 0.3), rng.normal(size=3) * 0.05
    V = rng.normal(size=(8, 3))
    V[kin] = (X[kin] @ R.T + T - X[kin]) / dt
    invm = np.ones(8)
    invm[kin] = 0.0
    return X, V, invm, kin, R, dt


def _volumes(P, quads):
    return np.linalg.det(np.stack([P[quads[:, k]] - P[quads[:, 0]] for k in (1, 2, 3)], axis=1))


def test_zone_with_a_turning_handle_follows_its_finite_motion_and_cannot_cross():
    rng = np.random.default_rng(2)
    for kinematic in ("general", "collinear"):
        X, V, invm, kin, R, dt = _chord_zone(rng, kinematic)
        roots = np.zeros(8, dtype=np.int64)
        Vn, bad = rigid_zone_velocities(X, V, invm, roots, [], 0.0)
        assert len(bad) == 0, kinematic
        assert np.array_equal(Vn[kin], V[kin])  # scripted vertices keep their velocities
        Y = X + dt * Vn
        # the whole zone ends rigidly moved: all pairwise distances kept ...
        D0 = np.linalg.norm(X[:, None] - X[None], axis=2)
        assert np.allclose(np.linalg.norm(Y[:, None] - Y[None], axis=2), D0, rtol=1e-9, atol=1e-12), kinematic
        # ... by the handle's rotation (collinear handles leave the turn about their line to the others)
        if kinematic == "general":
            assert np.allclose((Y[1:] - Y[0]) @ R, X[1:] - X[0], atol=1e-9)
        else:
            line = X[kin[1]] - X[kin[0]]
            assert np.allclose((Y[kin[1]] - Y[kin[0]]) @ R, line, atol=1e-12)
        # no tetrahedron of members flips during the step (the straight-line motion stays invertible)
        quads = np.array([q for q in rng.choice(8, size=(60, 4)) if len(set(q)) == 4])

        vol0 = _volumes(X, quads)
        solid = np.abs(vol0) > 1e-6  # (three collinear handle vertices make flat ones)
        assert solid.sum() > 20
        for s in np.linspace(0, 1, 11):
            assert np.all(np.sign(_volumes(X + s * dt * Vn, quads))[solid] == np.sign(vol0)[solid])


def test_pin_and_turning_handle_in_one_zone_are_inconsistent():
    rng = np.random.default_rng(5)
    X, V, invm, kin, _, _ = _chord_zone(rng, "general")
    V[kin[0]] = 0.0  # one of them pinned instead
    _, bad = rigid_zone_velocities(X, V, invm, np.zeros(8, dtype=np.int64), [], 0.0)
    assert list(bad) == [0]
