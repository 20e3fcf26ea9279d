"""Expected rigid-mode counts per piece and constraint, and the rigid basis (exact null space of K)."""

import numpy as np
import pytest

from modalfem.constraints import Fix, fixed_mask
from modalfem.eigen.rigid import expected_rigid_count, rigid_basis


def _plate_held_in_z(plate, degree):
    return fixed_mask(plate, degree, [Fix(t, components="z") for t in ("x0", "x1", "y0", "y1")])


@pytest.mark.parametrize("degree", [1, 2])
def test_counts(cube, plate, two_cubes, degree):
    assert expected_rigid_count(cube, degree, fixed_mask(cube, degree, None)) == 6
    assert expected_rigid_count(cube, degree, fixed_mask(cube, degree, "x0")) == 0
    assert expected_rigid_count(plate, degree, _plate_held_in_z(plate, degree)) == 3
    assert expected_rigid_count(two_cubes, degree, fixed_mask(two_cubes, degree, None)) == 12
    # roller on one face: in-plane translations and the rotation about the normal survive
    assert expected_rigid_count(cube, degree, fixed_mask(cube, degree, Fix("z0", components="z"))) == 3
    # one piece clamped, the other free
    left = fixed_mask(two_cubes, degree, lambda p: p[:, 0] < 1e-9)
    assert expected_rigid_count(two_cubes, degree, left) == 6


def test_single_point_leaves_rotations(cube):
    mask = fixed_mask(cube, 1, lambda p: np.all(p < 1e-9, axis=1))
    assert expected_rigid_count(cube, 1, mask) == 3


@pytest.mark.parametrize("case", ["free", "plate", "two"])
def test_basis_is_m_orthonormal_null_space(case, cube, plate, two_cubes, assemble_km, steel):
    mesh = {"free": cube, "plate": plate, "two": two_cubes}[case]
    fixed = _plate_held_in_z(plate, 2) if case == "plate" else fixed_mask(mesh, 2, None)
    K, M = assemble_km(mesh, steel, degree=2)
    free = ~fixed
    Kf, Mf = K[free][:, free], M[free][:, free]
    B = rigid_basis(mesh, 2, fixed, Mf)
    assert B.shape[1] == expected_rigid_count(mesh, 2, fixed)
    np.testing.assert_allclose(B.T @ (Mf @ B), np.eye(B.shape[1]), atol=1e-12)
    knorm = abs(Kf).sum(axis=1).max()
    assert np.abs(Kf @ B).max() <= 1e-12 * knorm * np.abs(B).max()
