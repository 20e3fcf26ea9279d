"""Rayleigh-Ritz bases: backend agreement, projection identity, rigid zeros, min-max bounds, uniform
strain, and rank deficiency on a thin plate."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from modalfem.forms.ritz import evaluate_fields, field_count, frame_for
from modalfem.forms.skfem_ritz import reduced_matrices_skfem

from modalfem.backends import have_fenicsx
from modalfem.backends.skfem import assemble
from modalfem.errors import InputError
from modalfem.material import STEEL
from modalfem.mesh import box
from modalfem.reduction.ritz import field_matrix, ritz_modes, solve_reduced

needs_fenicsx = pytest.mark.skipif(not have_fenicsx(), reason="dolfinx not installed")


@pytest.fixture(scope="module")
def block():
    return box(size=(0.3, 0.1, 0.08), cells=(3, 2, 2), origin=(0.1, -0.2, 0.05))


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.mark.parametrize(("kind", "degree", "clamp"), [("affine", 1, None), ("quadratic", 2, None), ("affine", 2, (0, 0.1))])
def test_skfem_ritz_equals_projection_of_assembled_fem(block, kind, degree, clamp):
    # the fields lie exactly in the FE space (affine in P1, quadratic and clamped affine in P2), so
    # integrating them directly must equal B^T K B, B^T M B of the assembled FEM matrices
    frame = frame_for(block.points, clamp=clamp)
    K_r, M_r = reduced_matrices_skfem(block, STEEL, kind, frame=frame)
    K, M = assemble(block, STEEL, degree=degree)
    B = field_matrix(kind, frame, block.dof_points(degree))
    assert K_r.shape == (field_count(kind),) * 2
    assert _rel(K_r, B.T @ K @ B) < 1e-10
    assert _rel(M_r, B.T @ M @ B) < 1e-10


@pytest.mark.fenicsx
@needs_fenicsx
@pytest.mark.parametrize("kind", ["affine", "quadratic"])
def test_ufl_and_skfem_ritz_agree(block, kind):
    from modalfem.forms.ritz import reduced_matrices_ufl

    for clamp in (None, (0, 0.1)) if kind == "affine" else (None,):
        frame = frame_for(block.points, clamp=clamp)
        K1, M1 = reduced_matrices_ufl(block, STEEL, kind, frame=frame)
        K2, M2 = reduced_matrices_skfem(block, STEEL, kind, frame=frame)
        assert _rel(K1, K2) < 1e-10 and _rel(M1, M2) < 1e-10


@pytest.mark.slow
@pytest.mark.fenicsx
@needs_fenicsx
def test_ufl_and_skfem_ritz_agree_clamped_quadratic(block):
    from modalfem.forms.ritz import reduced_matrices_ufl

    frame = frame_for(block.points, clamp=(0, 0.1))
    K1, M1 = reduced_matrices_ufl(block, STEEL, "quadratic", frame=frame)
    K2, M2 = reduced_matrices_skfem(block, STEEL, "quadratic", frame=frame)
    assert _rel(K1, K2) < 1e-10 and _rel(M1, M2) < 1e-10


@pytest.mark.parametrize("kind", ["affine", "quadratic"])
def test_free_body_has_six_exact_rigid_modes(block, kind):
    K_r, M_r = reduced_matrices_skfem(block, STEEL, kind)
    lam, C, dropped = solve_reduced(K_r, M_r)
    assert dropped == 0
    assert np.all(np.abs(lam[:6]) <= 1e-8 * lam[-1])
    assert lam[6] > 1e-4 * lam[-1]
    np.testing.assert_allclose(C.T @ M_r @ C, np.eye(len(lam)), atol=1e-9)
    rm = ritz_modes(block, STEEL, kind=kind, backend="skfem")
    assert rm.rigid_mode_count == 6 and len(rm.omega) == field_count(kind) - 6


def test_clamped_fields_have_no_rigid_mode(block):
    rm = ritz_modes(block, STEEL, kind="quadratic", clamp=(0, 0.1), backend="skfem")
    assert rm.rigid_mode_count == 0
    # every field vanishes on the clamp plane x = 0.1
    on_plane = block.points[np.isclose(block.points[:, 0], 0.1)]
    assert np.abs(rm.shapes_at(on_plane)).max() == 0.0


@pytest.mark.parametrize(("kind", "degree"), [("affine", 1), ("quadratic", 2)])
def test_ritz_eigenvalues_bound_fem_eigenvalues_from_above(block, kind, degree):
    import modalfem

    rm = ritz_modes(block, STEEL, kind=kind, backend="skfem")
    k = min(6, len(rm.omega))
    fem = modalfem.modes(block, STEEL, k=k, degree=degree, backend="skfem", solver="scipy")
    assert np.all(rm.omega[:k] >= fem.omega * (1 - 1e-9))  # min-max: the Ritz space lies in the FE space


def test_affine_fields_capture_uniform_strain_energy_exactly(block):
    rng = np.random.default_rng(3)
    G = rng.normal(size=(3, 3)) * 1e-3
    eps = 0.5 * (G + G.T)
    frame = frame_for(block.points)
    p = block.dof_points(1)
    u = (p @ G.T + np.array([1e-4, -2e-4, 3e-4])).ravel()
    B = field_matrix("affine", frame, p)
    c, *_ = np.linalg.lstsq(B, u, rcond=None)
    assert np.max(np.abs(B @ c - u)) < 1e-15 * 10  # u lies in the affine span
    K_r, _ = reduced_matrices_skfem(block, STEEL, "affine", frame=frame)
    mu, lam = STEEL.shear_modulus, STEEL.lame_lambda
    energy = block.volume * (2 * mu * np.sum(eps * eps) + lam * np.trace(eps) ** 2)  # int sigma : eps [J * 2]
    assert abs(c @ K_r @ c - energy) < 1e-10 * energy


def test_thin_plate_quadratic_basis_is_reduced_with_a_warning():
    plate = box(size=(1.0, 1.0, 1e-4), cells=(3, 3, 1))
    with pytest.warns(RuntimeWarning, match=r"rank-deficient.*dropped 3 of 30"):
        rm = ritz_modes(plate, STEEL, kind="quadratic", backend="skfem")
    assert rm.dropped == 3 and rm.rigid_mode_count == 6
    assert np.all(np.isfinite(rm.omega)) and np.all(rm.omega > 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the affine basis is still full rank there
        assert ritz_modes(plate, STEEL, kind="affine", backend="skfem").dropped == 0


def test_field_gradients_match_finite_differences():
    frame = frame_for(np.array([[0, 0, 0], [2.0, 1.0, 0.5]]), clamp=(1, 0.2))
    x = np.random.default_rng(0).uniform(0, 1, size=(3, 7))
    _, g = evaluate_fields("quadratic", frame, x)
    h = 1e-6
    for j in range(3):
        dx = np.zeros((3, 1))
        dx[j] = h
        fd = (evaluate_fields("quadratic", frame, x + dx)[0] - evaluate_fields("quadratic", frame, x - dx)[0]) / (2 * h)
        np.testing.assert_allclose(g[:, :, j], fd, atol=1e-7)


def test_bad_input_is_rejected(block):
    with pytest.raises(InputError, match="unknown Ritz basis"):
        ritz_modes(block, STEEL, kind="cubic")
    with pytest.raises(InputError, match="square"):
        solve_reduced(np.eye(3), np.eye(4))
    with pytest.raises(InputError, match="clamp"):
        frame_for(block.points, clamp=(5, 0.0))


def test_rigid_coefficients_are_rigid_motions_with_zero_energy(block):
    from modalfem.forms.ritz import rigid_coefficients

    frame = frame_for(block.points)
    R = rigid_coefficients("quadratic", frame)
    p = block.points
    U = (field_matrix("quadratic", frame, p) @ R).reshape(len(p), 3, 6)
    c = np.asarray(frame.centre)
    for k in range(3):
        np.testing.assert_allclose(U[:, :, k], np.tile(np.eye(3)[k], (len(p), 1)), atol=1e-15)
        np.testing.assert_allclose(U[:, :, 3 + k], np.cross(np.eye(3)[k], p - c), atol=1e-15)
    K_r, _ = reduced_matrices_skfem(block, STEEL, "quadratic", frame=frame)
    assert np.abs(K_r @ R).max() <= 1e-12 * np.abs(K_r).max() * frame.scale
    with pytest.raises(InputError, match="clamped"):
        rigid_coefficients("affine", frame_for(p, clamp=(0, 0.1)))


def test_chunked_integration_gives_the_same_matrices(block, monkeypatch):
    import modalfem.forms.skfem_ritz as skr

    K1, M1 = reduced_matrices_skfem(block, STEEL, "quadratic")
    monkeypatch.setattr(skr, "_CHUNK_POINTS", 50)  # a few cells per chunk
    K2, M2 = reduced_matrices_skfem(block, STEEL, "quadratic")
    assert _rel(K2, K1) < 1e-13 and _rel(M2, M1) < 1e-13
    if have_fenicsx():
        import modalfem.forms.ritz as ritz_forms

        K3, M3 = ritz_forms.reduced_matrices_ufl(block, STEEL, "affine")
        monkeypatch.setattr(ritz_forms, "_EVAL_VALUES", 2000)
        K4, M4 = ritz_forms.reduced_matrices_ufl(block, STEEL, "affine")
        assert _rel(K4, K3) < 1e-13 and _rel(M4, M3) < 1e-13
