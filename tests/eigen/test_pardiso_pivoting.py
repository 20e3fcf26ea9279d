"""PARDISO diagonal pivoting: same inertia as dense, Bunch-Kaufman when a pivot would be perturbed or the
factor's backward error is poor."""

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp

from modalfem.eigen import scipy_solver
from modalfem.eigen.pardiso import PardisoLDLT, have_pardiso
from modalfem.eigen.scipy_solver import _pardiso_inertia
from modalfem.errors import SolverError

pytestmark = pytest.mark.skipif(not have_pardiso(), reason="MKL PARDISO not loadable here")


def pencil(n: int = 400, seed: int = 0):
    """A sparse SPD pencil (K, M) and its dense eigenvalues."""
    rng = np.random.default_rng(seed)
    t = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    K = (t @ t + sp.diags(rng.uniform(0.0, 0.01, n))).tocsr() * 1e3
    M = (sp.diags(rng.uniform(0.5, 2.0, n)) + 0.1 * sp.diags([np.ones(n - 1), np.ones(n - 1)], [-1, 1])).tocsr()
    K.sort_indices()
    M.sort_indices()
    return K, M, sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)


def test_diagonal_pivots_solve_and_count_like_dense():
    K, M, w = pencil()
    A = (K + M).tocsr()
    A.sort_indices()
    with PardisoLDLT(A, pivoting="diagonal") as f:
        f.refactor()
        assert f.pivoting_used == "diagonal" and f.perturbed_pivots == 0
        b = np.random.default_rng(1).standard_normal((A.shape[0], 3))
        np.testing.assert_allclose(A @ f.solve(b), b, rtol=1e-9, atol=1e-10)
        for sigma in (0.5 * (w[4] + w[5]), 0.5 * (w[30] + w[31])):
            assert _pardiso_inertia(f, K, M, sigma) == int(np.sum(w < sigma))


def test_diagonal_pivoting_falls_back_to_bunch_kaufman_on_a_zero_diagonal():
    # [[0, 1], [1, 0]] blocks: no 1x1 diagonal pivot exists, so the factor is redone with 2x2 pivots
    J = sp.block_diag([np.array([[0.0, 1.0], [1.0, 0.0]])] * 50, format="csr")
    with PardisoLDLT(J, pivoting="diagonal") as f:
        f.refactor()
        assert f.pivoting_used == "bunch-kaufman"
        assert f.perturbed_pivots == 0 and f.inertia == (50, 0, 50)


def test_inertia_redoes_a_diagonal_factor_whose_backward_error_is_not_small_enough(monkeypatch):
    K, M, w = pencil(seed=2)
    monkeypatch.setattr(scipy_solver, "_FACTOR_BACKWARD_TOL", 0.0)  # no factor passes: Bunch-Kaufman
    sigma = 0.5 * (w[9] + w[10])
    with PardisoLDLT((K - 0.0 * M).tocsr(), pivoting="diagonal") as f:
        assert _pardiso_inertia(f, K, M, sigma) == 10
        assert f.pivoting_used == "bunch-kaufman"


def test_unknown_pivoting_is_refused():
    with pytest.raises(SolverError, match="pivoting"):
        PardisoLDLT(sp.identity(3, format="csr"), pivoting="rook")
