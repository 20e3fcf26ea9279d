"""The CCD's box-diagonal filter (``_ccd_kernels.diagonal_intervals`` / ``_diagonal_apart``): the projections
are those of their definition, and a pair it declares apart stays farther than eta at every sampled time of
the step (the filter proves separation; it never drops a colliding pair)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.collision import _ccd_kernels
from modalfem.collision.distance import edge_edge, point_triangle

AXES = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, -1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0]])


def _trajectories(rng, k):
    """k random 4-vertex configurations within a few centimetres, moving by up to a centimetre."""
    centre = rng.uniform(-1.0, 1.0, size=(k, 1, 3))
    x0 = centre + rng.uniform(-0.02, 0.02, size=(k, 4, 3))
    x1 = x0 + rng.uniform(-0.01, 0.01, size=(k, 4, 3))
    return x0.reshape(-1, 3), x1.reshape(-1, 3), np.arange(4 * k).reshape(k, 4)


def test_diagonal_intervals_equal_their_definition():
    rng = np.random.default_rng(0)
    X0, X1, _ = _trajectories(rng, 500)
    got = _ccd_kernels.diagonal_intervals(X0, X1)
    p0, p1 = X0 @ AXES.T, X1 @ AXES.T
    np.testing.assert_allclose(got[:, :4], np.minimum(p0, p1), rtol=0, atol=1e-15)
    np.testing.assert_allclose(got[:, 4:], np.maximum(p0, p1), rtol=0, atol=1e-15)
    eta = 1e-3
    assert _ccd_kernels.diagonal_gap(X0, X1, eta) >= eta * np.sqrt(3.0)


@pytest.mark.parametrize("vf", [True, False])
def test_pairs_apart_on_a_diagonal_stay_farther_than_eta(vf):
    rng = np.random.default_rng(1 if vf else 2)
    eta = 2e-3
    X0, X1, quads = _trajectories(rng, 3000)
    diag = _ccd_kernels.diagonal_intervals(X0, X1)
    gap = _ccd_kernels.diagonal_gap(X0, X1, eta)
    apart = np.array([_ccd_kernels._diagonal_apart(vf, diag, *map(int, q), gap) for q in quads])
    # the test is not vacuous: both answers occur
    assert 0.1 < apart.mean() < 0.9
    s = np.linspace(0.0, 1.0, 201)
    for q in quads[apart]:
        x = X0[q][None] + s[:, None, None] * (X1[q] - X0[q])[None]  # (201, 4, 3) positions over the step
        d = point_triangle(x[:, 0], x[:, 1], x[:, 2], x[:, 3])[0] if vf else edge_edge(*x.transpose(1, 0, 2))[0]
        assert d.min() > eta
