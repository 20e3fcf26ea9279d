"""MAC, frequency errors and mode matching."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from modalfem.errors import InputError
from modalfem.reduction.compare import (
    compare_modes,
    frequency_errors,
    mac_matrix,
    match_modes,
)


@pytest.fixture
def system():
    rng = np.random.default_rng(1)
    n = 40
    d = rng.uniform(0.5, 2.0, n)
    M = sp.diags(d).tocsr()
    X = rng.normal(size=(n, 6))
    # M-orthonormalise so the shapes are M-orthogonal
    L = np.linalg.cholesky(X.T @ (M @ X))
    return M, X @ np.linalg.inv(L).T


def test_mac_is_one_on_identical_and_zero_on_orthogonal(system):
    M, Phi = system
    mac = mac_matrix(Phi, Phi, M=M)
    np.testing.assert_allclose(mac, np.eye(6), atol=1e-12)
    assert np.allclose(np.diag(mac_matrix(Phi, Phi)), 1.0)


def test_mac_is_invariant_to_scaling_and_sign(system):
    M, Phi = system
    scaled = Phi * np.array([-3.0, 1e-6, 2.0, -1.0, 7.0, 0.5])
    np.testing.assert_allclose(mac_matrix(scaled, Phi, M=M), mac_matrix(Phi, Phi, M=M), atol=1e-12)
    np.testing.assert_allclose(mac_matrix(scaled, Phi), mac_matrix(Phi, Phi), atol=1e-12)


def test_matching_undoes_a_permutation_and_frequency_errors_follow_it(system):
    M, Phi = system
    f_ref = np.array([10.0, 20.0, 30.0, 40.0, 50.0, 60.0])
    perm = np.array([2, 0, 1, 5, 3, 4])
    f_approx = f_ref[perm] * 1.01
    noisy = Phi[:, perm] + 1e-3 * np.random.default_rng(2).normal(size=Phi.shape)
    assert np.array_equal(match_modes(mac_matrix(noisy, Phi, M=M)), np.argsort(perm))
    c = compare_modes(f_approx, noisy, f_ref, Phi, M=M, count=4)
    np.testing.assert_allclose(c.frequency_error, 0.01, rtol=1e-12)
    assert c.min_mac > 0.99 and c.mass_weighted
    assert abs(c.max_frequency_error - 0.01) < 1e-12


def test_frequency_errors_and_bad_input():
    np.testing.assert_allclose(frequency_errors([11.0, 18.0], [10.0, 20.0]), [0.1, -0.1])
    with pytest.raises(InputError, match="shape"):
        frequency_errors([1.0], [1.0, 2.0])
    with pytest.raises(InputError, match="DOF counts"):
        mac_matrix(np.ones((3, 1)), np.ones((4, 1)))
    with pytest.raises(InputError, match="zero shape"):
        mac_matrix(np.zeros((3, 1)), np.ones((3, 1)))
    with pytest.raises(InputError, match="at least as many"):
        match_modes(np.ones((1, 2)))
