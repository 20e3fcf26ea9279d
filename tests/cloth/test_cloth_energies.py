"""Membrane and bending energies: finite-difference gradients and Hessians, invariances, analytic values."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.cloth.energies import Bending, Membrane, dihedral_angles
from modalfem.cloth.mesh import grid

MESH = grid((0.3, 0.2), (4, 3))


def _fd_grad(E, x, eps=1e-6):
    g = np.zeros_like(x)
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.flat[i] += eps
        xm.flat[i] -= eps
        g.flat[i] = (E.energy(xp) - E.energy(xm)) / (2 * eps)
    return g


def _fd_hess(E, x, eps=1e-6):
    H = np.zeros((x.size, x.size))
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp.flat[i] += eps
        xm.flat[i] -= eps
        H[:, i] = ((E.gradient(xp) - E.gradient(xm)) / (2 * eps)).reshape(-1)
    return H


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return q * np.sign(np.linalg.det(q))


@pytest.fixture(params=[0, 1])
def deformed(request):
    rng = np.random.default_rng(request.param)
    return MESH.points * np.array([1.3, 0.8, 1.0]) + 0.03 * rng.standard_normal(MESH.points.shape)


@pytest.mark.parametrize("energy", [Membrane(MESH, 10.0, 5.0), Bending(MESH, 1e-3)], ids=["membrane", "bending"])
def test_gradient_and_exact_hessian_match_finite_differences(energy, deformed):
    g = energy.gradient(deformed)
    assert np.abs(g).max() > 1e-6
    assert np.allclose(g, _fd_grad(energy, deformed), atol=1e-7 * np.abs(g).max() + 1e-12)
    H = energy.hessian(deformed, project=False).toarray()
    assert np.allclose(H, H.T, atol=1e-9 * np.abs(H).max())
    assert np.allclose(H, _fd_hess(energy, deformed), atol=1e-6 * np.abs(H).max())


@pytest.mark.parametrize("energy", [Membrane(MESH, 10.0, 5.0), Bending(MESH, 1e-3)], ids=["membrane", "bending"])
def test_projected_hessian_is_psd(energy, deformed):
    Hp = energy.hessian(deformed).toarray()
    H = energy.hessian(deformed, project=False).toarray()
    scale = np.abs(H).max()
    assert np.linalg.eigvalsh(H).min() < -1e-3 * scale  # the exact one is indefinite here
    assert np.linalg.eigvalsh(Hp).min() > -1e-10 * scale


def test_membrane_projection_only_adds_psd_terms(deformed):
    E = Membrane(MESH, 10.0, 5.0)
    for x in (deformed, MESH.points * np.array([0.5, 1.2, 1.0])):
        d = E.hessian_blocks(x) - E.hessian_blocks(x, project=False)
        assert np.linalg.eigvalsh(d).min() > -1e-10 * np.abs(d).max() - 1e-12


@pytest.mark.parametrize("energy", [Membrane(MESH, 10.0, 5.0), Bending(MESH, 1e-3)], ids=["membrane", "bending"])
def test_rigid_motions_store_no_energy(energy):
    x = MESH.points @ _rotation(3).T + np.array([0.4, -1.0, 2.0])
    assert abs(energy.energy(x)) < 1e-20
    assert np.abs(energy.gradient(x)).max() < 1e-10


def test_membrane_uniaxial_stretch_matches_the_closed_form():
    mu, lam, s = 10.0, 5.0, 1.25
    E = Membrane(MESH, mu, lam)
    x = MESH.points * np.array([s, 1.0, 1.0])
    area = MESH.areas.sum()
    assert np.isclose(E.energy(x @ _rotation(5).T), area * (mu + lam / 2) * (s - 1) ** 2, rtol=1e-12)
    # the elastic force pulls the stretched x = max edge back: -P_xx * height, P_xx = (2 mu + lam)(s - 1)
    f = -E.gradient(x)
    right = np.isclose(MESH.points[:, 0], 0.3)
    assert np.isclose(f[right, 0].sum(), -(2 * mu + lam) * (s - 1) * 0.2, rtol=1e-12)


def test_membrane_hessian_at_rest_gives_the_linear_plane_stress_stiffness():
    E = Membrane(MESH, 10.0, 5.0)
    x = MESH.points
    d = np.random.default_rng(7).standard_normal(x.shape) * 1e-4
    d[:, 2] = 0.0  # in-plane perturbation: energy = 1/2 d^T K d to second order
    K = E.hessian(x).toarray()
    assert np.isclose(E.energy(x + d), 0.5 * d.reshape(-1) @ K @ d.reshape(-1), rtol=1e-3)


def test_bending_cylinder_matches_plate_theory():
    kb, r, nu, nv = 2e-3, 0.5, 21, 5
    m = grid((0.8, 0.2), (nu, nv))
    p = m.points
    x = np.stack([r * np.sin(p[:, 0] / r), p[:, 1], r * (1 - np.cos(p[:, 0] / r))], axis=1)
    W = Bending(m, kb).energy(x)
    # hinges on the two boundary columns are missing: (nu - 2) of (nu - 1) columns bend
    expected = kb / (2 * r**2) * 0.8 * 0.2 * (nu - 2) / (nu - 1)
    assert np.isclose(W, expected, rtol=1e-9)


def test_dihedral_angle_sign_and_value():
    # hinge along x; a in the xy plane at +y, b folded up by 30 degrees from -y
    x = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -np.cos(np.pi / 6), np.sin(np.pi / 6)]])
    theta, _ = dihedral_angles(x, np.array([[0, 1, 2, 3]]))
    assert np.isclose(abs(theta[0]), np.pi / 6)
    x[3, 2] *= -1
    theta2, _ = dihedral_angles(x, np.array([[0, 1, 2, 3]]))
    assert np.isclose(theta2[0], -theta[0])


def test_bending_gauss_newton_hessian_is_exact_at_the_rest_angle():
    B = Bending(MESH, 1e-3)
    x = MESH.points @ _rotation(11).T
    assert np.allclose(B.hessian(x).toarray(), _fd_hess(B, x), atol=1e-6 * np.abs(B.hessian(x).toarray()).max())


def _first_piola(F, mu, lam):
    """2 mu (F - R) + lam (tr S - 2) R with the polar factors from numpy's SVD (an independent reference)."""
    U, s, Vt = np.linalg.svd(F, full_matrices=False)
    R = U @ Vt
    return 2 * mu * (F - R) + lam * (s.sum() - 2) * R


@pytest.mark.parametrize("stretch", [(1.3, 0.8), (0.5, 1.2), (0.6, 0.7)])
def test_compiled_projected_membrane_hessian_is_the_eigenvalue_clamped_one(stretch):
    # reference: the F-space Hessian by central differences of an SVD-based stress, every negative
    # eigenvalue clamped at zero by numpy's eigh, mapped to the vertices; the kernel clamps only the
    # eigenvalues its closed form says can be negative
    mu, lam = 10.0, 5.0
    E = Membrane(MESH, mu, lam)
    rng = np.random.default_rng(3)
    x = MESH.points * np.array([*stretch, 1.0]) + 0.02 * rng.standard_normal(MESH.points.shape)
    K = E.hessian_blocks(x)
    for t in range(len(MESH.triangles)):
        G = E._G[t]
        F = x[MESH.triangles[t]].T @ G
        H = np.zeros((6, 6))
        for c in range(6):
            dF = np.zeros(6)
            dF[c] = 1e-6
            H[:, c] = ((_first_piola(F + dF.reshape(3, 2), mu, lam)
                        - _first_piola(F - dF.reshape(3, 2), mu, lam)) / 2e-6).reshape(-1)
        w, V = np.linalg.eigh(0.5 * (H + H.T))
        Hp = (V * np.maximum(w, 0)) @ V.T
        ref = E._area[t] * np.einsum("aj,ijkl,bl->aibk", G, Hp.reshape(3, 2, 3, 2), G).reshape(9, 9)
        assert np.allclose(K[t], ref, atol=1e-5 * np.abs(ref).max())


def test_bending_gradient_and_factors_from_one_angle_evaluation_equal_the_separate_calls():
    b = Bending(MESH, 1e-3)
    x = MESH.points @ _rotation(7).T + 0.01 * np.random.default_rng(7).standard_normal(MESH.points.shape)
    grad, w, g = b.gradient_and_factors(x)
    w2, g2 = b.gauss_newton_factors(x)
    assert np.abs(grad).max() > 0
    assert np.array_equal(grad, b.gradient(x)) and np.array_equal(w, w2) and np.array_equal(g, g2)
