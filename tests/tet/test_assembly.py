"""The fixed CSR pattern assembles the same matrix as a plain COO sum, and Dirichlet rows/columns become
the identity."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from modalfem.mesh import box
from modalfem.tet.assembly import HessianPattern


def test_pattern_assembly_matches_coo():
    mesh = box(size=(0.2, 0.1, 0.1), cells=(2, 1, 1))
    rng = np.random.default_rng(0)
    blocks = rng.standard_normal((mesh.cell_count, 12, 12))
    diag = rng.standard_normal(3 * mesh.point_count)
    pat = HessianPattern(mesh.cells, mesh.point_count)
    A = pat.matrix(pat.assemble(blocks, diag)).toarray()
    dofs = (3 * mesh.cells[:, :, None] + np.arange(3)).reshape(-1, 12)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    N = 3 * mesh.point_count
    ref = sp.coo_matrix((blocks.ravel(), (rows, cols)), shape=(N, N)).toarray() + np.diag(diag)
    np.testing.assert_allclose(A, ref, atol=1e-12)
    np.testing.assert_allclose(pat.diagonal(pat.assemble(blocks, diag)), np.diag(ref), atol=1e-12)


def test_dirichlet_rows_become_identity():
    mesh = box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1))
    pat = HessianPattern(mesh.cells, mesh.point_count)
    blocks = np.ones((mesh.cell_count, 12, 12))
    fixed = np.zeros(3 * mesh.point_count, dtype=bool)
    fixed[[0, 4, 11]] = True
    data = pat.assemble(blocks)
    A = pat.matrix(pat.apply_dirichlet(data, fixed)).toarray()
    np.testing.assert_array_equal(A[fixed][:, fixed], np.eye(3))
    assert not A[fixed][:, ~fixed].any() and not A[~fixed][:, fixed].any()
    np.testing.assert_array_equal(A[~fixed][:, ~fixed], pat.matrix(data).toarray()[~fixed][:, ~fixed])


def test_upper_triangle_assembly_matches_full_blocks():
    mesh = box(size=(0.2, 0.1, 0.1), cells=(2, 2, 1))
    rng = np.random.default_rng(1)
    blocks = rng.standard_normal((mesh.cell_count, 12, 12))
    blocks = blocks + np.swapaxes(blocks, 1, 2)  # element Hessians are symmetric
    diag = rng.standard_normal(3 * mesh.point_count)
    pat = HessianPattern(mesh.cells, mesh.point_count)
    iu = np.triu_indices(12)
    upper = np.ascontiguousarray(blocks[:, iu[0], iu[1]].T)  # (78, m)
    np.testing.assert_allclose(pat.assemble(upper, diag, upper=True), pat.assemble(blocks, diag), atol=1e-12)


def test_dirichlet_mask_is_recomputed_when_it_changes():
    mesh = box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1))
    pat = HessianPattern(mesh.cells, mesh.point_count)
    data = pat.assemble(np.ones((mesh.cell_count, 12, 12)))
    for held in ([0, 4], [5], [0, 4]):
        fixed = np.zeros(3 * mesh.point_count, dtype=bool)
        fixed[held] = True
        A = pat.matrix(pat.apply_dirichlet(data, fixed)).toarray()
        np.testing.assert_array_equal(A[fixed][:, fixed], np.eye(len(held)))
        assert not A[fixed][:, ~fixed].any()
        np.testing.assert_array_equal(A[~fixed][:, ~fixed], pat.matrix(data).toarray()[~fixed][:, ~fixed])


def test_dirichlet_in_place_changes_the_data_it_is_given():
    mesh = box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1))
    pat = HessianPattern(mesh.cells, mesh.point_count)
    data = pat.assemble(np.ones((mesh.cell_count, 12, 12)))
    fixed = np.zeros(3 * mesh.point_count, dtype=bool)
    fixed[[1, 7]] = True
    copied = pat.apply_dirichlet(data, fixed)
    assert copied is not data and not np.array_equal(copied, data)
    same = pat.apply_dirichlet(data, fixed, copy=False)
    assert same is data
    np.testing.assert_array_equal(same, copied)
