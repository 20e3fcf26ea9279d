"""Kinematics of tetrahedra: F, dF/dx, rotation-variant SVD with the sign fix, polar decomposition,
and the finite-volume force form (P times area-weighted normals) equal to the FEM form."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.mesh import box
from modalfem.tet import kinematics as kin


@pytest.fixture(scope="module")
def mesh():
    return box(size=(0.3, 0.2, 0.1), cells=(3, 2, 1))


def _rot(rng):
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_affine_map_gives_constant_F(mesh):
    rng = np.random.default_rng(0)
    A = rng.standard_normal((3, 3))
    grad, vol = kin.shape_gradients(mesh.points, mesh.cells)
    F = kin.deformation_gradient(mesh.points @ A.T + 1.0, mesh.cells, grad)
    np.testing.assert_allclose(F, np.broadcast_to(A, F.shape), atol=1e-12)
    np.testing.assert_allclose(vol, mesh.volumes, rtol=1e-12)
    np.testing.assert_allclose(grad.sum(axis=1), 0.0, atol=1e-9)


def test_dF_dx_is_the_jacobian(mesh):
    rng = np.random.default_rng(1)
    grad, _ = kin.shape_gradients(mesh.points, mesh.cells)
    x = mesh.points + 0.01 * rng.standard_normal(mesh.points.shape)
    B = kin.dF_dx(grad)
    xe = x[mesh.cells].reshape(-1, 12)
    F = kin.deformation_gradient(x, mesh.cells, grad)
    np.testing.assert_allclose(np.einsum("mij,mj->mi", B, xe), F.reshape(-1, 9), atol=1e-12)


def test_svd_sign_fix_moves_reflection_to_smallest_singular_value():
    rng = np.random.default_rng(2)
    F = rng.standard_normal((200, 3, 3))
    U, s, V = kin.svd_rv(F)
    np.testing.assert_allclose(np.linalg.det(U), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(V), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("mik,mk,mjk->mij", U, s, V), F, atol=1e-12)
    assert np.all(s[:, 0] >= s[:, 1]) and np.all(s[:, 1] >= np.abs(s[:, 2]))
    np.testing.assert_array_equal(s[:, 2] < 0, np.linalg.det(F) < 0)
    assert (np.linalg.det(F) < 0).sum() > 50  # the test sees both kinds


def test_polar_of_rotated_stretch():
    rng = np.random.default_rng(3)
    R0 = np.stack([_rot(rng) for _ in range(20)])
    S0 = rng.standard_normal((20, 3, 3))
    S0 = S0 @ np.swapaxes(S0, 1, 2) + 0.5 * np.eye(3)
    R, S = kin.polar(R0 @ S0)
    np.testing.assert_allclose(R, R0, atol=1e-10)
    np.testing.assert_allclose(S, S0, atol=1e-10)


def test_area_weighted_normals_identity(mesh):
    grad, vol = kin.shape_gradients(mesh.points, mesh.cells)
    n = kin.area_weighted_normals(mesh.points, mesh.cells)
    np.testing.assert_allclose(vol[:, None, None] * grad, -n / 3.0, atol=1e-15)
    # outward: the normal of the face opposite vertex a points away from a
    c = mesh.points[mesh.cells]
    away = np.einsum("mai,mai->ma", n, c.mean(axis=1, keepdims=True) - c)
    assert np.all(away > 0)


def test_finite_volume_forces_equal_fem_forces(mesh):
    """f_a = -V0 P grad N_a (FEM) equals P (A_a N_a) / 3 (area-weighted rest normal of the opposite face)."""
    rng = np.random.default_rng(4)
    grad, vol = kin.shape_gradients(mesh.points, mesh.cells)
    P = rng.standard_normal((mesh.cell_count, 3, 3))
    fem = -vol[:, None, None] * np.einsum("mij,maj->mai", P, grad)
    normals = kin.area_weighted_normals(mesh.points, mesh.cells)
    fv = np.einsum("mij,maj->mai", P, normals) / 3.0
    np.testing.assert_allclose(fv, fem, rtol=1e-12, atol=1e-12 * np.abs(fem).max())
    np.testing.assert_allclose(fem.sum(axis=1), 0.0, atol=1e-12 * np.abs(fem).max())  # no net force


def test_scatter_vertices_sums_contributions(mesh):
    vals = np.ones((mesh.cell_count, 4, 3))
    out = kin.scatter_vertices(vals, mesh.cells, mesh.point_count)
    counts = np.bincount(mesh.cells.ravel(), minlength=mesh.point_count)
    np.testing.assert_array_equal(out, np.repeat(counts[:, None], 3, axis=1))


def test_svd_degenerate_cases_and_input_untouched():
    rng = np.random.default_rng(5)
    R = _rot(rng)
    cases = [np.eye(3), np.zeros((3, 3)), np.diag([1.0, 1.0, 0.0]), np.diag([2.0, 0.0, 0.0]),
             R @ np.diag([1.0, 1.0, 0.0]) @ _rot(rng).T, R @ np.diag([3.0, 3.0, -1.0]), np.diag([1e-9, 1.0, 1.0]),
             R @ np.diag([1.0, 1.0, 1.0 - 1e-13])]
    for F in cases:
        F1 = F[None].copy()
        U, s, V = kin.svd_rv(F1)
        np.testing.assert_array_equal(F1[0], F)  # the input is not modified (a single matrix is contiguous)
        np.testing.assert_allclose(np.einsum("mik,mk,mjk->mij", U, s, V)[0], F, atol=1e-13)
        np.testing.assert_allclose(U[0].T @ U[0], np.eye(3), atol=1e-13)
        np.testing.assert_allclose(V[0].T @ V[0], np.eye(3), atol=1e-13)
        assert np.linalg.det(U[0]) > 0 and np.linalg.det(V[0]) > 0
        np.testing.assert_allclose(np.abs(s[0]), np.linalg.svd(F, compute_uv=False), atol=1e-13)


def test_svd_matches_lapack_singular_values_in_bulk():
    rng = np.random.default_rng(6)
    F = np.eye(3) + 0.5 * rng.standard_normal((500, 3, 3))
    _, s, _ = kin.svd_rv(F)
    np.testing.assert_allclose(np.abs(s), np.linalg.svd(F, compute_uv=False), rtol=1e-12, atol=1e-14)


def test_svd_warm_start_gives_the_same_decomposition():
    rng = np.random.default_rng(7)
    F = np.eye(3) + 0.4 * rng.standard_normal((300, 3, 3))
    _, _, V_cold = kin.svd_rv(F)
    F2 = F + 1e-3 * rng.standard_normal(F.shape)
    U, s, V = kin.svd_rv(F2, V_cold)
    np.testing.assert_allclose(s, kin.svd_rv(F2)[1], atol=1e-13)
    np.testing.assert_allclose(np.einsum("mik,mk,mjk->mij", U, s, V), F2, atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(U), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(V), 1.0, atol=1e-12)


def test_element_last_forms_match_the_batched_ones(mesh):
    rng = np.random.default_rng(11)
    grad, _ = kin.shape_gradients(mesh.points, mesh.cells)
    x = mesh.points + 0.02 * rng.standard_normal(mesh.points.shape)
    F = kin.deformation_gradient(x, mesh.cells, grad)
    Ft = kin.deformation_gradient_t(x, mesh.cells, np.ascontiguousarray(np.moveaxis(grad, 0, -1)))
    np.testing.assert_allclose(np.moveaxis(Ft, -1, 0), F, rtol=1e-13, atol=1e-13)
    for a, b in zip(kin.svd_rv(F), kin.svd_rv(Ft, element_last=True)):
        np.testing.assert_allclose(a, b, atol=1e-13)


def test_svd_warm_start_with_few_elements_changed():
    # most elements start converged, so the last sweeps rotate only a few of them (the subset update)
    rng = np.random.default_rng(12)
    F = np.eye(3) + 0.4 * rng.standard_normal((400, 3, 3))
    _, _, V_cold = kin.svd_rv(F)
    F2 = F.copy()
    F2[::37] += 0.05 * rng.standard_normal(F2[::37].shape)
    U, s, V = kin.svd_rv(F2, V_cold)
    np.testing.assert_allclose(np.abs(s), np.linalg.svd(F2, compute_uv=False), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.einsum("mik,mk,mjk->mij", U, s, V), F2, atol=1e-13)
    np.testing.assert_allclose(np.einsum("mki,mkj->mij", V, V), np.broadcast_to(np.eye(3), V.shape), atol=1e-13)


def test_svd_rv_t_is_svd_rv_with_the_element_index_last():
    """The solver's layout: same U, s, V as ``svd_rv`` (cold and warm), for stretched, inverted, flat and
    rotated elements, and at tiny and huge scales (where the fast form of hypot falls back)."""
    rng = np.random.default_rng(13)
    F = np.eye(3) + 0.4 * rng.standard_normal((300, 3, 3))
    F[::7, :, 2] *= -1.0  # inverted
    F[::11, 2] = 0.0  # flat
    F[::13] = np.stack([_rot(rng) for _ in range(len(F[::13]))])  # pure rotations: repeated singular values
    _, _, V0 = kin.svd_rv(F + 0.01)
    for Fs in (F, 1e-100 * F, 1e75 * F):
        Ft = np.ascontiguousarray(np.moveaxis(Fs, 0, -1))
        for warm in (None, V0):
            U, s, V = kin.svd_rv(Fs, warm)
            Ut, st, Vt = kin.svd_rv_t(Ft, None if warm is None else np.moveaxis(warm, 0, -1))
            assert Ut.shape == Vt.shape == (3, 3, len(F)) and st.shape == (len(F), 3)
            np.testing.assert_array_equal(np.moveaxis(Ut, -1, 0), U)
            np.testing.assert_array_equal(np.moveaxis(Vt, -1, 0), V)
            np.testing.assert_array_equal(st, s)
            scale = np.abs(Fs).max()
            np.testing.assert_allclose(np.einsum("mik,mk,mjk->mij", U, s, V), Fs, atol=1e-13 * scale)
            np.testing.assert_allclose(np.abs(s), np.linalg.svd(Fs, compute_uv=False), rtol=1e-11,
                                       atol=1e-13 * scale)
            assert np.all(np.sign(s[:, 2]) * np.sign(np.linalg.det(Fs)) >= 0)
