"""Block Krylov-Schur (``modalfem.eigen.block``) against dense generalized eigensolutions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp
from _eigen_bounds import dense_bounds, residual_bounds
from scipy.sparse.linalg import splu

from modalfem.eigen.block import block_krylov_schur
from modalfem.errors import SolverError


def _elastic_pencil(fixed: bool):
    from modalfem.backends.skfem import assemble
    from modalfem.material import STEEL
    from modalfem.mesh import box

    mesh = box(size=(0.6, 0.1, 0.08), cells=(6, 2, 2))
    K, M = assemble(mesh, STEEL, degree=1)
    if fixed:
        free = np.repeat(mesh.points[:, 0] > 1e-9, 3)
        K, M = K[free][:, free], M[free][:, free]
    return sp.csr_matrix(K), sp.csr_matrix(M)


def _solve_with(K, M, shift, m, **kw):
    """shift ~ -lambda_1 / 5 as modes() picks it (a tiny |shift| lets the rigid modes dominate T
    and its roundoff, see modalfem.modes)."""
    lu = splu(sp.csc_matrix(K - shift * M))
    theta, X, info = block_krylov_schur(lu.solve, M, m, **kw)
    return shift + 1.0 / theta, X, info


def _check(K, M, lam, X, m):
    """Each eigenvalue within the two results' own error bounds of the dense one (tests/eigen/_eigen_bounds.py:
    the dense solve's rounding depends on the CPU's code path, so no tolerance read off one machine)."""
    ref = sl.eigh(K.toarray(), M.toarray(), eigvals_only=True, subset_by_index=[0, m - 1])
    bound = residual_bounds(K, M, X, lam) + dense_bounds(K, M, ref)
    assert np.all(np.abs(lam - ref) <= bound), (lam - ref, bound)
    np.testing.assert_allclose(X.T @ (M @ X), np.eye(m), atol=1e-10)
    R = K @ X - (M @ X) * lam
    assert np.linalg.norm(R, axis=0).max() <= 1e-7 * np.linalg.norm(K @ X, axis=0).max()


@pytest.mark.parametrize("fixed", [True, False])
def test_lowest_pairs_match_dense_eigh(fixed):
    K, M = _elastic_pencil(fixed)
    m = 10
    lam, X, info = _solve_with(K, M, -3e7, m, block=6)
    assert np.all(np.diff(lam) >= -1e-6 * abs(lam).max())  # ascending lambda (descending theta)
    _check(K, M, lam, X, m)
    assert info["solves"] == 6 * info["blocks"]
    if not fixed:  # the six rigid modes, a six-fold cluster at zero, all found
        assert np.sum(np.abs(lam) < 1e-6 * lam[-1]) == 6


def test_thick_restarts_converge_to_the_same_pairs():
    K, M = _elastic_pencil(False)
    m = 12
    lam, X, info = _solve_with(K, M, -3e7, m, block=4, max_dim=m + 8)
    assert info["restarts"] > 0
    _check(K, M, lam, X, m)


def test_an_invariant_start_block_is_completed_with_new_directions():
    """Start in an invariant subspace of T (unit vectors of a diagonal pencil): T P lies in span(P),
    the block is rank deficient, and the wanted (other) eigenvalues must still be found."""
    n = 60
    d = np.arange(1.0, n + 1.0)
    K, M = sp.diags(d[::-1].copy()).tocsr(), sp.identity(n, format="csr")  # smallest eigenvalues at the end
    start = np.eye(n)[:, :4]  # eigenvectors of the LARGEST eigenvalues 60..57
    lam, _, _ = _solve_with(K, M, -0.5, 5, block=4, start=start)
    np.testing.assert_allclose(lam, d[:5], rtol=1e-10)


def test_bad_arguments_are_refused():
    _, M = _elastic_pencil(True)
    with pytest.raises(SolverError, match="m="):
        block_krylov_schur(lambda B: B, M, 0)
    with pytest.raises(SolverError, match="too small"):
        block_krylov_schur(lambda B: B, M, 10, block=8, max_dim=12)
