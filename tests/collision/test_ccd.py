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
