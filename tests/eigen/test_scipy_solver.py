"""SciPy solver against dense ``scipy.linalg.eigh`` (an independent reference) and its inertia count."""

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp
from _eigen_bounds import dense_bounds, residual_bounds

from modalfem.constraints import fixed_mask
from modalfem.eigen.pardiso import have_pardiso
from modalfem.eigen.scipy_solver import inertia_count, solve_scipy
from modalfem.errors import SolverError


@pytest.fixture(scope="module")
def free_beam_km(beam, steel, assemble_km):
    K, M = assemble_km(beam, steel, degree=2)  # 1,275 DOFs: ARPACK path, dense reference affordable
    return K.tocsr(), M.tocsr(), sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)


@pytest.fixture(scope="module")
def cantilever_km(beam, steel, assemble_km):
    K, M = assemble_km(beam, steel, degree=2)
    free = ~fixed_mask(beam, 2, "x0")
    K, M = K[free][:, free].tocsr(), M[free][:, free].tocsr()
    return K, M, sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)


FACTORS = ["superlu", pytest.param("pardiso", marks=pytest.mark.skipif(not have_pardiso(), reason="no MKL PARDISO"))]


@pytest.mark.parametrize("method", ["arpack", "block"])
@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize("case", ["free", "clamped"])
def test_matches_dense_eigh(case, factor, method, free_beam_km, cantilever_km):
    K, M, ref = free_beam_km if case == "free" else cantilever_km
    r = 6 if case == "free" else 0
    nev = r + 10
    raw = solve_scipy(K, M, nev=nev, shift=-1e6, factor=factor, method=method)
    assert raw.info["method"] == ("arpack shift-invert" if method == "arpack" else "block krylov-schur shift-invert")
    assert raw.info["factor"].startswith(factor)
    assert raw.info["inertia_method"] == ("pardiso-ldlt" if factor == "pardiso" else "superlu-ldlt")
    lam = raw.eigenvalues
    assert len(lam) >= nev + 4
    # dense eigh resolves eigenvalues to ~eps * lambda_max (2e-9 relative at lambda_1 here): each pair within
    # the two results' own error bounds (tests/eigen/_eigen_bounds.py; the rounding depends on the code path)
    X = raw.vectors
    bound = residual_bounds(K, M, X[:, r:nev], lam[r:nev]) + dense_bounds(K, M, ref[r:nev])
    assert np.all(np.abs(lam[r:nev] - ref[r:nev]) <= bound), (lam[r:nev] - ref[r:nev], bound)
    assert np.all(np.abs(lam[:r]) < 1e-6 * ref[r])
    np.testing.assert_allclose(X.T @ (M @ X), np.eye(len(lam)), atol=1e-10)
    assert raw.orthonormality_error < 1e-10
    # ARPACK runs to machine precision; the block solver stops at the certificate's own bound,
    # FLOOR_FACTOR x the roundoff floor of the pairs (certify.build_certificate)
    floor = np.asarray(raw.info["residual_floor"])[r:nev].max()
    assert np.all(raw.residuals[:nev] < (1e-9 if method == "arpack" else max(1e-9, 10 * floor)))
    # Sylvester count equals the dense count below the chosen shift, which sits in a clear gap
    assert raw.inertia_count == int(np.sum(ref < raw.inertia_shift))
    assert lam[nev - 1] < raw.inertia_shift


def test_inertia_count_against_dense(cantilever_km):
    K, M, ref = cantilever_km
    for sigma in (-1e3, 0.5 * (ref[0] + ref[2]), 0.5 * (ref[10] + ref[11]), 0.5 * (ref[30] + ref[31])):
        count, used, method = inertia_count(K, M, sigma)
        assert used == sigma and count == int(np.sum(ref < sigma)), (sigma, method)


def test_inertia_dense_fallback_on_zero_diagonal():
    # [[0, 1], [1, 0]] (+ SPD block) has a zero diagonal: SuperLU must pivot off it -> Bunch-Kaufman path
    A = sp.block_diag([np.array([[0.0, 1.0], [1.0, 0.0]]), sp.identity(3)]).tocsr()
    count, _, method = inertia_count(A, sp.identity(5, format="csr"), 0.0)
    assert (count, method) == (1, "dense-bunch-kaufman")


def test_bad_arguments(cantilever_km):
    K, M, _ = cantilever_km
    with pytest.raises(SolverError, match="negative shift"):
        solve_scipy(K, M, nev=3, shift=1.0)
    with pytest.raises(SolverError, match="nev"):
        solve_scipy(K, M, nev=K.shape[0] + 1, shift=-1.0)


@pytest.mark.parametrize("factor", FACTORS)
def test_indefinite_mass_is_a_solver_error(cantilever_km, factor):
    K, M, _ = cantilever_km
    with pytest.raises(SolverError):
        solve_scipy(K, -M, nev=4, shift=-1e6, factor=factor)


def test_unknown_factor_is_a_solver_error(cantilever_km):
    K, M, _ = cantilever_km
    with pytest.raises(SolverError, match="factor must be"):
        solve_scipy(K, M, nev=4, shift=-1e6, factor="lu")


def test_tiny_problem_uses_dense_path(cube, steel, assemble_km):
    K, M = assemble_km(cube, steel, degree=1)
    raw = solve_scipy(K.tocsr(), M.tocsr(), nev=8, shift=-1e6)
    ref = sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    assert raw.info["method"] == "dense eigh"
    np.testing.assert_allclose(raw.eigenvalues[6:8], ref[6:8], rtol=1e-10)
    assert raw.inertia_count == int(np.sum(ref < raw.inertia_shift))

