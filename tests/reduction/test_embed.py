"""Barycentric embedding: exact linear/quadratic reproduction, outside points, distances, properties."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.errors import InputError
from modalfem.mesh import Mesh, box
from modalfem.reduction.embed import embed_points, point_triangle_distance

A = np.array([[1.0, -2.0, 0.5], [0.3, 0.7, -1.1], [2.0, 0.1, 0.4]])
b = np.array([0.2, -0.3, 0.9])


def _jiggled_box(seed: int) -> Mesh:
    """A box mesh with randomly displaced interior vertices (irregular tetrahedra, still valid)."""
    m = box(size=(1.0, 0.5, 0.4), cells=(5, 3, 3), origin=(-0.2, 0.1, 0.0))
    p = m.points.copy()
    lo, hi = m.bounds
    interior = np.all((p > lo + 1e-9) & (p < hi - 1e-9), axis=1)
    p[interior] += np.random.default_rng(seed).uniform(-0.02, 0.02, size=(interior.sum(), 3))
    return Mesh(p, m.cells, m.tags)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_linear_fields_are_reproduced_inside_and_outside(seed):
    m = _jiggled_box(seed)
    rng = np.random.default_rng(10 + seed)
    lo, hi = m.bounds
    q = rng.uniform(lo - 0.1, hi + 0.1, size=(400, 3))  # some inside, some outside
    e = embed_points(m, q)
    assert e.outside.any() and (~e.outside).any()
    np.testing.assert_allclose(e.bary.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(e.bary[~e.outside].min(axis=1) >= -1e-10)
    np.testing.assert_allclose(e.interpolate(m.points @ A.T + b), q @ A.T + b, atol=1e-12)
    inside = np.all((q >= lo) & (q <= hi), axis=1)
    assert np.array_equal(e.outside, ~inside)  # the jiggled box keeps its flat faces


def test_quadratic_fields_are_reproduced_by_p2_interpolation():
    m = _jiggled_box(4)
    q = np.random.default_rng(5).uniform(*m.bounds, size=(300, 3))

    def f(p):
        return np.column_stack([p[:, 0] ** 2 - p[:, 1] * p[:, 2], p[:, 1] ** 2 + 3 * p[:, 0], p[:, 2] * p[:, 0]])

    e = embed_points(m, q)
    np.testing.assert_allclose(e.interpolate(f(m.dof_points(2)), degree=2), f(q), atol=1e-12)
    # node-major DOF vectors (3 components per node), several columns
    dofs = np.column_stack([f(m.dof_points(2)).ravel(), 2 * f(m.dof_points(2)).ravel()])
    np.testing.assert_allclose(e.transfer(dofs, degree=2), np.column_stack([f(q).ravel(), 2 * f(q).ravel()]), atol=1e-12)


def test_mesh_nodes_embed_onto_themselves():
    m = _jiggled_box(6)
    vals = np.random.default_rng(7).normal(size=(m.point_count, 2))
    e = embed_points(m, m.points)
    assert not e.outside.any()
    np.testing.assert_allclose(e.interpolate(vals), vals, atol=1e-12)


def test_outside_points_use_the_nearest_tetrahedron_and_report_the_distance():
    m = box(size=(1.0, 1.0, 1.0), cells=(3, 3, 3))
    q = np.array([[1.25, 0.5, 0.5], [0.5, -0.1, 0.5], [1.3, 1.4, 0.5], [0.5, 0.5, 0.5]])
    e = embed_points(m, q)
    np.testing.assert_array_equal(e.outside, [True, True, True, False])
    np.testing.assert_allclose(e.distance, [0.25, 0.1, np.hypot(0.3, 0.4), 0.0], atol=1e-12)
    # the nearest cell touches the nearest boundary point
    near = np.array([[1.0, 0.5, 0.5], [0.5, 0.0, 0.5], [1.0, 1.0, 0.5]])
    for i in range(3):
        cell_pts = m.points[m.cells[e.cell[i]]]
        lo, hi = cell_pts.min(axis=0), cell_pts.max(axis=0)
        assert np.all(near[i] >= lo - 1e-12) and np.all(near[i] <= hi + 1e-12)


def test_point_triangle_distance_matches_dense_sampling():
    rng = np.random.default_rng(8)
    a, b2, c = rng.normal(size=(3, 50, 3))
    p = rng.normal(size=(50, 3)) * 2
    d = point_triangle_distance(p, a, b2, c)
    s = rng.uniform(size=(20000, 2))
    s = np.where(s.sum(axis=1, keepdims=True) > 1, 1 - s, s)
    for i in range(0, 50, 7):
        pts = a[i] + s[:, :1] * (b2[i] - a[i]) + s[:, 1:] * (c[i] - a[i])
        sampled = np.linalg.norm(pts - p[i], axis=1).min()
        assert d[i] <= sampled + 1e-12 and sampled - d[i] < 0.05 * max(1.0, sampled)


def test_bad_query_points_are_rejected():
    m = box(size=(1.0, 1.0, 1.0), cells=(1, 1, 1))
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        embed_points(m, np.zeros((4, 2)))
    with pytest.raises(InputError):
        embed_points(m, np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(InputError, match="degree"):
        embed_points(m, np.zeros((1, 3))).matrix(degree=3)


def test_coarse_modes_carried_to_a_fine_mesh_match_the_fine_modes():
    import modalfem
    from modalfem.backends.skfem import assemble
    from modalfem.reduction.compare import compare_modes
    from modalfem.reduction.embed import carry_modes

    coarse, fine = box(size=(1.0, 0.1, 0.05), cells=(10, 1, 1)), box(size=(1.0, 0.1, 0.05), cells=(20, 2, 2))
    kw = {"k": 4, "degree": 2, "fixed": "x0", "backend": "skfem", "solver": "scipy"}
    rc, rf = modalfem.modes(coarse, modalfem.STEEL, **kw), modalfem.modes(fine, modalfem.STEEL, **kw)
    carried = carry_modes(rc, coarse, fine.dof_points(2))
    M = assemble(fine, modalfem.STEEL, degree=2)[1]
    c = compare_modes(rc.frequencies_hz, carried, rf.frequencies_hz, rf.shapes, M=M)
    assert np.array_equal(c.matched, np.arange(4))
    assert c.min_mac > 0.995
    assert np.all(c.frequency_error > 0) and c.max_frequency_error < 0.1  # coarser P2 is stiffer
