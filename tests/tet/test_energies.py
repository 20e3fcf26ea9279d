"""Energies of tetrahedra: finite-difference gradient and Hessian of every term (upright and inverted),
projection to positive semi-definite, the corotational stress built by polar decomposition, volume
spring forces along area-weighted opposite-face normals, and the barrier's blow-up as V -> 0."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.tet import energies as en
from modalfem.tet import kinematics as kin
from modalfem._threads import thread_count

CELLS = np.array([[0, 1, 2, 3]])
TERMS = {
    "corotated": en.Corotated(1.3, 2.1),
    "stable": en.StableCorotated(1.3, 2.1),
    "volume_spring": en.VolumeSpringDensity(3.0),
    "barrier": en.VolumeBarrierDensity(3.0),
}


def _rest(seed=0):
    rng = np.random.default_rng(seed)
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) + 0.1 * rng.standard_normal((4, 3))
    grad, vol = kin.shape_gradients(X, CELLS)
    return X, grad, vol


def _funcs(term, grad, vol):
    def sv(x):
        return kin.svd_rv(kin.deformation_gradient(x.reshape(4, 3), CELLS, grad))

    def E(x):
        _, s, _ = sv(x)
        return float(vol @ term.derivs(s, 0).psi)

    def G(x):
        U, s, V = sv(x)
        P = en.first_piola(U, V, term.derivs(s, 1).d1)
        return (vol[:, None, None] * np.einsum("mij,maj->mai", P, grad)).ravel()

    def H(x, project=False):
        U, s, V = sv(x)
        return en.element_hessians(U, V, term.derivs(s, 2), grad, vol, project=project)[0]

    return E, G, H


def _configs(X, rng, inverted):
    x = X + 0.25 * rng.standard_normal((4, 3))
    if inverted:  # reflect vertex 3 through the plane of the others: negative volume
        n = np.cross(x[1] - x[0], x[2] - x[0])
        n /= np.linalg.norm(n)
        x[3] -= 1.5 * n * (n @ (x[3] - x[0]))
    return x.ravel()


@pytest.mark.parametrize("inverted", [False, True], ids=["upright", "inverted"])
@pytest.mark.parametrize("name", list(TERMS))
def test_gradient_and_hessian_match_finite_differences(name, inverted):
    if name == "barrier" and inverted:
        pytest.skip("the barrier is infinite on inverted elements (tested below)")
    rng = np.random.default_rng(list(TERMS).index(name) + 10 * inverted)
    X, grad, vol = _rest(1)
    E, G, H = _funcs(TERMS[name], grad, vol)
    for _ in range(3):
        x = _configs(X, rng, inverted)
        F = kin.deformation_gradient(x.reshape(4, 3), CELLS, grad)
        assert (np.linalg.det(F)[0] < 0) == inverted
        h = 1e-6
        eye = np.eye(12)
        gfd = np.array([(E(x + h * e) - E(x - h * e)) / (2 * h) for e in eye])
        Hfd = np.array([(G(x + h * e) - G(x - h * e)) / (2 * h) for e in eye])
        g, Hx = G(x), H(x)
        assert np.abs(g - gfd).max() <= 1e-6 * np.abs(g).max()
        assert np.abs(Hx - Hfd).max() <= 1e-6 * np.abs(Hx).max()
        np.testing.assert_allclose(Hx, Hx.T, atol=1e-12 * np.abs(Hx).max())


@pytest.mark.parametrize("name", list(TERMS))
def test_projected_hessian_is_psd_and_exact_where_convex(name):
    rng = np.random.default_rng(7)
    X, grad, vol = _rest(2)
    _, _, H = _funcs(TERMS[name], grad, vol)
    for _ in range(5):
        x = _configs(X, rng, inverted=(name != "barrier") and rng.random() < 0.5)
        Hp = H(x, project=True)
        w = np.linalg.eigvalsh(Hp)
        assert w.min() >= -1e-10 * w.max()
    Hp, Hu = H(X.ravel(), project=True), H(X.ravel(), project=False)  # at rest the Hessian is PSD already
    np.testing.assert_allclose(Hp, Hu, atol=1e-10 * np.abs(Hu).max())


def test_corotated_stress_is_rotated_linear_stress():
    """P = R (2 mu (S - I) + lam tr(S - I) I), with F = R S the polar decomposition (stiffness warping)."""
    rng = np.random.default_rng(3)
    mu, lam = 1.3, 2.1
    F = np.eye(3) + 0.4 * rng.standard_normal((50, 3, 3))
    R, S = kin.polar(F)
    eps = S - np.eye(3)
    lin = 2 * mu * eps + lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    U, s, V = kin.svd_rv(F)
    P = en.first_piola(U, V, en.Corotated(mu, lam).derivs(s, 1).d1)
    np.testing.assert_allclose(P, R @ lin, atol=1e-12)


def test_energies_vanish_and_push_back_from_inversion():
    rng = np.random.default_rng(4)
    s_rest = np.ones((1, 3))
    for term in TERMS.values():
        d = term.derivs(s_rest, 1)
        assert abs(d.psi[0]) < 1e-15 and np.abs(d.d1).max() < 1e-15
    s_inv = np.sort(rng.uniform(0.5, 1.5, (20, 3)), axis=1)[:, ::-1].copy()
    s_inv[:, 2] *= -0.3
    for name in ("corotated", "stable", "volume_spring"):
        d = TERMS[name].derivs(s_inv, 1)
        assert np.all(d.d1[:, 2] < 0), name  # energy decreases as the negative singular value grows


def test_volume_spring_forces_along_opposite_face_normals():
    """Volume spring force on vertex a is K (V - V0) A_a n_a / 3 (current area-weighted outward normal of
    the opposite face): a too large element pulls each vertex towards its opposite face."""
    rng = np.random.default_rng(5)
    X, grad, vol = _rest(3)
    k = 3.0
    _, G, _ = _funcs(TERMS["volume_spring"], grad, vol)
    x = X + 0.2 * rng.standard_normal((4, 3))
    V = float(np.linalg.det((x[1:] - x[0]).T)) / 6.0
    normals = kin.area_weighted_normals(x, CELLS)[0]
    K = k / vol[0]
    expected = K * (V - vol[0]) * normals / 3.0  # force = -dE/dx; dV/dx_a = -A_a n_a / 3
    np.testing.assert_allclose(-G(x.ravel()).reshape(4, 3), expected, rtol=1e-10, atol=1e-14)
    E, _, _ = _funcs(TERMS["volume_spring"], grad, vol)
    assert np.isclose(E(x.ravel()), 0.5 * K * (V - vol[0]) ** 2, rtol=1e-10)


def test_barrier_goes_to_infinity_as_volume_vanishes():
    J = np.array([1.0, 0.5, 1e-2, 1e-4, 1e-8, 1e-12])
    s = np.stack([np.ones_like(J), np.ones_like(J), J], axis=1)
    psi = TERMS["barrier"].derivs(s, 0).psi
    assert psi[0] == 0 and np.all(np.diff(psi) > 0) and psi[-1] > 20 * 3.0
    bad = TERMS["barrier"].derivs(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, -0.5]]), 2)
    assert np.all(np.isinf(bad.psi))


def test_chunked_and_upper_hessians_are_the_same_matrices():
    """Many elements: the (m, 12, 12) blocks are symmetric, the same on one thread and on all, the same as
    one element at a time, and the ``upper`` layout holds exactly their upper triangles."""
    rng = np.random.default_rng(3)
    X, grad1, vol1 = _rest(3)
    m = 23
    grad, vol = np.repeat(grad1, m, axis=0), np.repeat(vol1, m)
    x = X[None] + 0.3 * rng.standard_normal((m, 4, 3))
    F = np.einsum("mai,maj->mij", x, grad)
    U, s, V = kin.svd_rv(F)
    d = TERMS["stable"].derivs(s, 2)
    whole = en.element_hessians(U, V, d, grad, vol, project=False)
    with thread_count(1):
        serial = en.element_hessians(U, V, d, grad, vol, project=False)
    np.testing.assert_array_equal(serial, whole)
    np.testing.assert_allclose(whole, np.swapaxes(whole, 1, 2), atol=1e-13 * np.abs(whole).max())
    upper = en.element_hessians(U, V, d, grad, vol, project=True, upper=True)
    projected = en.element_hessians(U, V, d, grad, vol, project=True)
    np.testing.assert_array_equal(upper, projected[:, en.TRIU[0], en.TRIU[1]].T)
    ref = np.stack([en.element_hessians(U[i:i + 1], V[i:i + 1], en.SigmaDerivs(
        d.psi[i:i + 1], d.d1[i:i + 1], d.d2[i:i + 1], d.twist[i:i + 1], d.flip[i:i + 1]), grad[i:i + 1],
        vol[i:i + 1], project=False)[0] for i in range(m)])
    np.testing.assert_allclose(whole, ref, atol=1e-13 * np.abs(whole).max())


def _deformed(seed: int, rest_seed: int, m: int):
    """m copies of one rest element with random deformations: gradients, volumes, F (m, 3, 3)."""
    rng = np.random.default_rng(seed)
    X, grad1, vol1 = _rest(rest_seed)
    grad, vol = np.repeat(grad1, m, axis=0), np.repeat(vol1, m)
    x = X[None] + 0.3 * rng.standard_normal((m, 4, 3))
    return grad, vol, np.einsum("mai,maj->mij", x, grad)


def test_forces_and_hessians_in_one_pass_match_the_separate_ones():
    grad, vol, F = _deformed(4, 4, 17)
    U, s, V = kin.svd_rv(F)
    d = TERMS["stable"].derivs(s, 2)
    f, H = en.element_forces_and_hessians(U, V, d, grad, vol)
    P = en.first_piola(U, V, d.d1)
    f_ref = vol[:, None, None] * np.einsum("mij,maj->mai", P, grad)  # (m, 4, 3)
    np.testing.assert_allclose(np.moveaxis(f, -1, 0), f_ref, atol=1e-13 * np.abs(f_ref).max())
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-13 * np.abs(f_ref).max())  # no net force
    np.testing.assert_array_equal(H, en.element_hessians(U, V, d, grad, vol, project=True, upper=True))


def test_stable_corotated_one_pass_derivatives_match_the_sum_of_terms():
    rng = np.random.default_rng(5)
    s = 1 + 0.3 * rng.standard_normal((40, 3))
    s[:5, 2] = -np.abs(s[:5, 2])  # inverted elements
    term = TERMS["stable"]
    d = term.derivs(s, 2)
    J1 = np.prod(s, axis=1) - 1.0
    lam = term.lam
    ref = en._arap(s, term.mu, 2) + en._volumetric(s, 0.5 * lam * J1**2, lam * J1, np.full(len(s), lam), 2)
    for name in ("psi", "d1", "d2", "twist", "flip"):
        np.testing.assert_allclose(getattr(d, name), getattr(ref, name), rtol=1e-13, atol=1e-13)
    # the line search's order-0 path (psi only) is the same energy
    np.testing.assert_allclose(term.derivs(s, 0).psi, ref.psi, rtol=1e-13, atol=1e-13)
    assert term.derivs(s, 0).d1 is None


def test_element_last_layout_gives_the_same_forces_and_hessians():
    """The solver passes U, V (3, 3, m) from ``svd_rv_t`` and gradients (4, 3, m): same results as (m, ...)."""
    grad, vol, F = _deformed(6, 5, 13)
    U, s, V = kin.svd_rv(F)
    Ut, st, Vt = kin.svd_rv_t(np.moveaxis(F, 0, -1))
    d = TERMS["stable"].derivs(s, 2)
    f, H = en.element_forces_and_hessians(U, V, d, grad, vol)
    ft, Ht = en.element_forces_and_hessians(Ut, Vt, d, np.moveaxis(grad, 0, -1), vol, element_last=True)
    np.testing.assert_array_equal(st, s)
    np.testing.assert_array_equal(ft, f)
    np.testing.assert_array_equal(Ht, H)


def test_exact_hessians_in_one_pass_match_the_unprojected_ones():
    """``project=False`` keeps the negative twist / flip curvature (compressed elements): the upper triangles
    are those of ``element_hessians(project=False)``, which differ from the projected ones there."""
    grad, vol, F = _deformed(4, 6, 23)
    U, s, V = kin.svd_rv(F)
    d = TERMS["stable"].derivs(s, 2)
    assert (np.concatenate([d.twist, d.flip], axis=1) < 0).any()  # the case has negative curvature
    _, H = en.element_forces_and_hessians(U, V, d, grad, vol, project=False)
    np.testing.assert_array_equal(H, en.element_hessians(U, V, d, grad, vol, project=False, upper=True))
    _, Hp = en.element_forces_and_hessians(U, V, d, grad, vol, project=True)
    assert not np.array_equal(H, Hp)


def test_forces_alone_match_the_forces_of_the_one_pass_kernel():
    from modalfem.tet import _kernels

    grad, vol, F = _deformed(5, 7, 29)
    Ut, s, Vt = kin.svd_rv_t(np.moveaxis(F, 0, -1))
    d = TERMS["stable"].derivs(s, 2)
    gt = np.ascontiguousarray(np.moveaxis(grad, 0, -1))
    f_ref, _ = en.element_forces_and_hessians(Ut, Vt, d, gt, vol, element_last=True)
    f = np.empty_like(f_ref)
    _kernels.element_forces(np.ascontiguousarray(Ut), np.ascontiguousarray(Vt), np.ascontiguousarray(d.d1.T), gt,
                            vol, f)
    # the same sums in another order: equal to a few roundoffs of the largest force
    np.testing.assert_allclose(f, f_ref, rtol=0, atol=16 * np.finfo(float).eps * np.abs(f_ref).max())
