"""Corotational elasticity reduces to linear elasticity for small deformations: the tangent at rest is
the P1 stiffness K of the core forms (scikit-fem backend), rotated rest states give R K R^T (stiffness
warping), and forces at strain 1e-6 match -K u."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.backends.skfem import assemble
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetSolver

MAT = Material(E=2e6, nu=0.3, rho=1000.0)


@pytest.fixture(scope="module")
def setup():
    mesh = box(size=(0.4, 0.1, 0.1), cells=(4, 2, 2))
    K, _ = assemble(mesh, MAT, degree=1)
    model = tet_model(mesh, MAT, energy="corotated")
    solver = TetSolver(model)
    return mesh, K.toarray(), model, solver


def _tangent(solver, x):
    _, g, blocks = solver._elastic(x, 2)
    return g.ravel(), solver.pattern.matrix(solver.pattern.assemble(blocks)).toarray()


def _rotation(angle, axis):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    W = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * W + (1 - np.cos(angle)) * W @ W


def _smooth_displacement(points, strain):
    """A smooth non-affine field with largest displacement gradient ~ ``strain``."""
    x, y, z = (points - points.mean(axis=0)).T / 0.4
    u = np.stack([np.sin(3 * x) * y + z * z, np.cos(2 * x) * z + x * y, x * x - y * z + 0.3 * x], axis=1)
    return strain * 0.4 * u / 3.0


@pytest.mark.parametrize("energy", ["corotated", "stable"])
def test_tangent_at_rest_is_linear_K(setup, energy):
    mesh, K, _, _ = setup
    solver = TetSolver(tet_model(mesh, MAT, energy=energy))
    g, H = _tangent(solver, mesh.points.copy())
    assert np.abs(g).max() < 1e-12 * np.abs(K).max() * 0.1
    assert np.abs(H - K).max() <= 1e-10 * np.abs(K).max()


def test_rotated_tangent_is_warped_K(setup):
    mesh, K, _, solver = setup
    R = _rotation(1.1, (1.0, 2.0, -0.5))
    _, H = _tangent(solver, mesh.points @ R.T + 0.3)
    Rb = np.kron(np.eye(mesh.point_count), R)
    assert np.abs(H - Rb @ K @ Rb.T).max() <= 1e-9 * np.abs(K).max()


@pytest.mark.parametrize("angle", [0.0, 2.0])
def test_forces_at_small_strain_match_linear_K(setup, angle):
    """At strain 1e-6 the corotational force equals R (-K u) to relative 1e-8 in its odd part (the even,
    quadratic part is O(strain) relative: 1e-6) and to 1e-5 as a whole."""
    mesh, K, _, solver = setup
    R = _rotation(angle, (0.3, -1.0, 0.4))
    u = _smooth_displacement(mesh.points, 1e-6)
    Rb = np.kron(np.eye(mesh.point_count), R)
    lin = Rb @ (K @ u.ravel())  # internal force gradient dE/dx = K u, rotated

    def grad_at(uu):
        return solver._elastic((mesh.points + uu) @ R.T, 1)[1].ravel()

    gp, gm = grad_at(u), grad_at(-u)
    scale = np.linalg.norm(lin)
    assert np.linalg.norm(0.5 * (gp - gm) - lin) <= 1e-8 * scale
    assert np.linalg.norm(gp - lin) <= 1e-5 * scale
    assert np.linalg.norm(0.5 * (gp + gm)) <= 1e-5 * scale
