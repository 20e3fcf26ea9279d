"""CCD: analytic cases (crossing, near miss, coplanar, degenerate) and zero false negatives against
an independent time-sampled crossing test on random queries."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.collision.ccd import edge_edge_ccd, vertex_face_ccd
from modalfem.errors import InputError

TRI = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def _vf(p0, p1, tri0=TRI, tri1=TRI, eta=0.0):
    x0 = np.vstack([p0, tri0])[None]
    x1 = np.vstack([p1, tri1])[None]
    hit, toi = vertex_face_ccd(x0, x1, eta=eta)
    return bool(hit[0]), float(toi[0])


def test_point_through_triangle_hits_at_the_right_time():
    hit, toi = _vf([0.2, 0.2, 1.0], [0.2, 0.2, -1.0])
    assert hit and 0.45 <= toi <= 0.55
    hit, _ = _vf([0.2, 0.2, 1.0], [0.2, 0.2, 0.01])
    assert not hit
    hit, _ = _vf([0.2, 0.2, 1.0], [0.2, 0.2, 0.01], eta=0.02)  # within the minimum separation
    assert hit


def test_point_passing_beside_the_triangle_misses():
    assert not _vf([0.8, 0.8, 1.0], [0.8, 0.8, -1.0])[0]
    assert not _vf([-0.01, 0.5, 1.0], [-0.01, 0.5, -1.0])[0]
    assert _vf([0.0, 0.5, 1.0], [0.0, 0.5, -1.0])[0]  # exactly through an edge


def test_coplanar_and_degenerate_motions():
    # coplanar throughout (the cubic is identically zero): sliding into the triangle, and beside it
    assert _vf([-1.0, 0.2, 0.0], [0.5, 0.2, 0.0])[0]
    assert not _vf([-1.0, 2.0, 0.0], [2.0, 2.0, 0.0])[0]
    # nothing moves: touching or apart
    assert _vf([0.3, 0.3, 0.0], [0.3, 0.3, 0.0])[0]
    assert not _vf([0.3, 0.3, 0.1], [0.3, 0.3, 0.1])[0]
    # degenerate triangle (collinear corners) swept through by a point
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert _vf([0.5, 0.0, 1.0], [0.5, 0.0, -1.0], flat, flat)[0]
    # triangle moving onto a resting point; cubic degenerating to a quadratic (triangle translates)
    assert _vf([0.2, 0.2, 0.0], [0.2, 0.2, 0.0], TRI + [0, 0, 1], TRI - [0, 0, 1])[0]


def test_edge_edge_cases():
    a = np.array([[-1.0, 0, 0], [1, 0, 0]])
    b0 = np.array([[0.0, -1, 1], [0, 1, 1]])
    b1 = b0 - [0, 0, 2]
    hit, toi = edge_edge_ccd(np.vstack([a, b0])[None], np.vstack([a, b1])[None])
    assert hit[0] and 0.45 <= toi[0] <= 0.55
    b1 = b0 - [0, 0, 0.9]
    assert not edge_edge_ccd(np.vstack([a, b0])[None], np.vstack([a, b1])[None])[0][0]
    # parallel edges brought into contact, and parallel edges sliding past at a distance
    c0 = np.array([[-1.0, 0, 1], [1, 0, 1]])
    assert edge_edge_ccd(np.vstack([a, c0])[None], np.vstack([a, c0 - [0, 0, 1]])[None])[0][0]
    assert not edge_edge_ccd(np.vstack([a, c0])[None], np.vstack([a, c0 + [3, 0, 0]])[None])[0][0]


def test_bad_shapes_raise():
    with pytest.raises(InputError):
        vertex_face_ccd(np.zeros((2, 3, 3)), np.zeros((2, 3, 3)))


def _orient(a, b, c, d):
    return np.einsum("...i,...i->...", np.cross(b - a, c - a), d - a)


def _sampled_truth_vf(x0, x1, n=400):
    """Independent reference: a sign change of the volume between samples with the point inside the
    triangle (by same-side tests) at the linearly interpolated crossing time."""
    s = np.linspace(0, 1, n)
    X = x0[:, None] + s[None, :, None, None] * (x1 - x0)[:, None]
    f = _orient(X[..., 1, :], X[..., 2, :], X[..., 3, :], X[..., 0, :])
    out = np.zeros(len(x0), dtype=bool)
    for k in range(n - 1):
        ch = f[:, k] * f[:, k + 1] <= 0
        sk = s[k] + (s[k + 1] - s[k]) * f[:, k] / np.where(f[:, k] != f[:, k + 1], f[:, k] - f[:, k + 1], 1)
        Y = x0 + sk[:, None, None] * (x1 - x0)
        p, a, b, c = Y[:, 0], Y[:, 1], Y[:, 2], Y[:, 3]
        n_ = np.cross(b - a, c - a)
        inside = np.ones(len(x0), dtype=bool)
        for u, v in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("ki,ki->k", np.cross(v - u, p - u), n_) >= -1e-12
        out |= ch & inside & (np.linalg.norm(n_, axis=1) > 1e-9)
    return out


def test_no_false_negatives_on_random_vertex_face_queries():
    rng = np.random.default_rng(3)
    x0 = rng.uniform(-1, 1, size=(3000, 4, 3))
    x1 = x0 + rng.normal(scale=0.8, size=x0.shape)
    truth = _sampled_truth_vf(x0, x1)
    hit, _ = vertex_face_ccd(x0, x1)
    assert truth.sum() > 50
    assert not (truth & ~hit).any()
    # false positives are rare away from degeneracy
    assert (hit & ~truth).sum() <= 0.02 * len(hit)


def _passing(rng, k, size, speed, gap):
    """Small primitives (about ``size`` [m]) meeting a fast partner (``speed`` [m per step]) at distance
    ``gap`` [m] at a random time: (t in [0, 1], start (k, 4, 3), end (k, 4, 3)) for vertex-face (point,
    triangle) and edge-edge (edge a, edge b) queries."""
    s = rng.uniform(0.05, 0.95, size=k)[:, None]
    base0 = rng.uniform(-1, 1, size=(k, 1, 3)) + rng.normal(scale=size, size=(k, 3, 3))
    base1 = base0 + rng.normal(scale=0.01, size=(k, 1, 3)) + rng.normal(scale=0.1 * size, size=(k, 3, 3))
    at = base0 + s[:, :, None] * (base1 - base0)  # the small primitive at the meeting time
    w = rng.normal(scale=speed, size=(k, 3))
    # vertex-face: the point meets an interior point of the triangle, `gap` off its plane
    bary = rng.dirichlet([2.0, 2.0, 2.0], size=k)
    n = np.cross(at[:, 1] - at[:, 0], at[:, 2] - at[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    p = np.einsum("kj,kji->ki", bary, at) + gap * n
    vf0 = np.concatenate([(p - s * w)[:, None], base0], axis=1)
    vf1 = np.concatenate([(p + (1 - s) * w)[:, None], base1], axis=1)
    # edge-edge: edge a = the small primitive's first side; edge b crosses it `gap` away along their
    # common normal, through interior points of both
    a0, a1 = at[:, 0], at[:, 1]
    d = rng.normal(size=(k, 3))
    m = np.cross(a1 - a0, d)
    m /= np.linalg.norm(m, axis=1)[:, None]
    mid_a = a0 + rng.uniform(0.2, 0.8, size=(k, 1)) * (a1 - a0)
    dn = d / np.linalg.norm(d, axis=1)[:, None] * size
    u = rng.uniform(0.2, 0.8, size=(k, 1))
    b0, b1 = mid_a + gap * m - u * dn, mid_a + gap * m + (1 - u) * dn
    ee0 = np.stack([base0[:, 0], base0[:, 1], b0 - s * w, b1 - s * w], axis=1)
    ee1 = np.stack([base1[:, 0], base1[:, 1], b0 + (1 - s) * w, b1 + (1 - s) * w], axis=1)
    return s[:, 0], (vf0, vf1), (ee0, ee1)


@pytest.mark.parametrize("size", [1e-3, 1e-2, 0.1])
def test_small_primitives_meeting_a_fast_partner_within_eta_always_hit(size):
    """The coplanarity tolerance is bounded by the edge lengths |e1| |e2| (not the coordinate scale, which a
    fast partner makes large): queries passing at eta / 2 must all report a hit."""
    rng = np.random.default_rng(11)
    eta = 1e-5
    _, vf, ee = _passing(rng, 400, size, speed=1.0, gap=0.5 * eta)
    for fun, (x0, x1) in ((vertex_face_ccd, vf), (edge_edge_ccd, ee)):
        hit, toi = fun(x0, x1, eta=eta)
        assert hit.all()
        assert ((toi >= 0) & (toi <= 1)).all()


def test_indexed_entry_gives_the_same_answers():
    from modalfem.collision.ccd import ccd_pairs

    rng = np.random.default_rng(5)
    x0 = rng.uniform(-1, 1, size=(500, 4, 3))
    x1 = x0 + rng.normal(scale=0.8, size=x0.shape)
    quads = rng.permutation(2000).reshape(500, 4)
    X0, X1 = np.empty((2000, 3)), np.empty((2000, 3))
    X0[quads], X1[quads] = x0, x1
    for kind, fun in (("vf", vertex_face_ccd), ("ee", edge_edge_ccd)):
        hit, toi = fun(x0, x1, eta=1e-3)
        h2, toi2 = ccd_pairs(kind, X0, X1, quads, eta=1e-3)
        assert hit.sum() > 20 and np.array_equal(hit, h2) and np.array_equal(toi, toi2)
    with pytest.raises(InputError, match="k, 4"):
        ccd_pairs("vf", X0, X1, quads[:, :3])
    with pytest.raises(InputError, match="outside"):
        ccd_pairs("ee", X0[:10], X1[:10], quads)
