"""Concurrent Sylvester count (second PARDISO handle) and diagonal pivoting with its fallbacks."""

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp

from modalfem.eigen import inertia_thread, pardiso, scipy_solver
from modalfem.eigen.inertia_thread import ConcurrentInertia, pardiso_inertia
from modalfem.eigen.pardiso import PardisoLDLT, have_pardiso
from modalfem.errors import SolverError

pytestmark = pytest.mark.skipif(not have_pardiso(), reason="MKL PARDISO not loadable here")


def pencil(n: int = 400, seed: int = 0):
    """A sparse SPD pencil (K, M) with known dense eigenvalues."""
    rng = np.random.default_rng(seed)
    t = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    K = (t @ t + sp.diags(rng.uniform(0.0, 0.01, n))).tocsr() * 1e3
    M = sp.diags(rng.uniform(0.5, 2.0, n)).tocsr() + 0.1 * sp.diags([np.ones(n - 1), np.ones(n - 1)], [-1, 1])
    K, M = K.tocsr(), M.tocsr()
    K.sort_indices()
    M.sort_indices()
    return K, M, sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)


def test_twin_solves_like_the_original_and_refuses_another_pattern():
    K, M, _ = pencil()
    A = (K + M).tocsr()
    A.sort_indices()
    with PardisoLDLT(A, pivoting="diagonal") as f:
        f.refactor()
        g = f.twin()
        try:
            g.refactor()
            b = np.random.default_rng(1).standard_normal((A.shape[0], 3))
            np.testing.assert_allclose(g.solve(b), f.solve(b), rtol=1e-10, atol=1e-14)
            assert g.threads == 1 and g.pivoting == "diagonal"
        finally:
            g.close()
        with pytest.raises(SolverError, match="pattern"):
            f.twin(sp.identity(A.shape[0], format="csr"))


def test_diagonal_pivoting_counts_like_dense_and_falls_back_on_a_zero_diagonal():
    K, M, w = pencil()
    A = (K - 0.0 * M).tocsr()
    A.sort_indices()
    with PardisoLDLT(A, pivoting="diagonal") as f:
        for sigma in (0.5 * (w[4] + w[5]), 0.5 * (w[30] + w[31])):
            assert pardiso_inertia(f, K, M, sigma) == int(np.sum(w < sigma))
    # [[0, 1], [1, 0]] blocks: no 1x1 diagonal pivot exists, so the factor is redone with 2x2 pivots
    J = sp.block_diag([np.array([[0.0, 1.0], [1.0, 0.0]])] * 50, format="csr")
    with PardisoLDLT(J, pivoting="diagonal") as f:
        f.refactor()
        assert f.pivoting_used == "bunch-kaufman"
        assert f.perturbed_pivots == 0 and f.inertia == (50, 0, 50)


def test_unknown_pivoting_is_refused():
    with pytest.raises(SolverError, match="pivoting"):
        PardisoLDLT(sp.identity(3, format="csr"), pivoting="rook")


def _factor(K, M, shift):
    A = (K - shift * M).tocsr()
    A.sort_indices()
    return PardisoLDLT(A, pivoting="diagonal").refactor()


def test_early_sigma_is_used_when_the_converged_eigenvalues_agree():
    K, M, w = pencil()
    shift, nev = -1.0, 6
    f = _factor(K, M, shift)
    c = ConcurrentInertia(f, K, M, nev=nev, shift=shift)
    try:
        lam = w[:10]
        theta = 1.0 / (lam * (1 + 1e-6) - shift)  # Ritz values slightly above, as Rayleigh-Ritz gives
        c.monitor(theta[:nev], np.full(nev, 1e-3))  # too few pairs to place sigma above nev: waits
        assert c.early_sigma is None
        c.monitor(theta, np.full(10, 0.5))  # estimates not yet good enough: waits
        assert c.early_sigma is None
        c.monitor(theta, np.full(10, 1e-3))
        assert c.early_sigma is not None and lam[nev - 1] < c.early_sigma < lam[-1]
        count, sigma = c.count(lam)
        assert sigma == c.early_sigma
        assert count == int(np.sum(w < sigma))
        assert f.threads == c._main_threads  # the main handle gets its threads back
    finally:
        c.close()
        f.close()


def test_a_misplaced_early_sigma_is_replaced_by_the_converged_one():
    K, M, w = pencil(seed=3)
    shift, nev = -1.0, 6
    f = _factor(K, M, shift)
    c = ConcurrentInertia(f, K, M, nev=nev, shift=shift)
    try:
        lam = w[:10]
        wrong = np.concatenate([lam[:nev], lam[nev:] * 3.0])  # early estimates far off above nev
        c.monitor(1.0 / (wrong - shift), np.full(10, 1e-3))
        early = c.early_sigma
        assert early is not None
        count, sigma = c.count(lam)
        assert sigma != early and lam[nev - 1] < sigma < lam[-1]
        assert count == int(np.sum(w < sigma))
    finally:
        c.close()
        f.close()


def test_worker_errors_reach_the_caller_as_solver_errors(monkeypatch):
    K, M, _ = pencil()
    f = _factor(K, M, -1.0)

    def broken(*args, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr(inertia_thread, "pardiso_inertia", broken)
    c = ConcurrentInertia(f, K, M, nev=3, shift=-1.0)
    try:
        with pytest.raises(SolverError, match="boom"):
            c.count(np.linspace(1.0, 2.0, 8) ** 2)
    finally:
        c.close()
        f.close()


def test_the_count_runs_concurrently_only_on_large_problems_and_free_cores(monkeypatch):
    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 0.0)
    assert scipy_solver._cores_free(scipy_solver.CONCURRENT_MIN_ROWS)
    assert not scipy_solver._cores_free(scipy_solver.CONCURRENT_MIN_ROWS - 1)
    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 1.0)
    assert not scipy_solver._cores_free(scipy_solver.CONCURRENT_MIN_ROWS)


@pytest.mark.parametrize("trigger", [inertia_thread.TRIGGER_RTOL, np.inf])
def test_block_solver_with_the_concurrent_count_matches_dense(monkeypatch, trigger):
    """solve_scipy's block path with the concurrent count on (threshold lowered to this size): the count
    equals the dense count below its shift, whether the early shift (even from the first, rough Ritz
    values: trigger inf) is kept or replaced."""
    K, M, w = pencil(n=600, seed=5)
    monkeypatch.setattr(scipy_solver, "CONCURRENT_MIN_ROWS", 0)
    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 0.0)  # as on a quiet machine
    monkeypatch.setattr(inertia_thread, "TRIGGER_RTOL", trigger)
    raw = scipy_solver.solve_scipy(K, M, nev=8, shift=-0.5 * w[0], tol=1e-10, method="block")
    assert raw.info["inertia_method"].endswith("(concurrent)")
    assert raw.inertia_count == int(np.sum(w < raw.inertia_shift))
    np.testing.assert_allclose(raw.eigenvalues[:8], w[:8], rtol=1e-9)


def test_background_analysis_gives_the_same_factor_and_reports_errors():
    K, M, _ = pencil()
    A = (K + M).tocsr()
    A.sort_indices()
    bg = pardiso.BackgroundAnalysis(lambda: A, pivoting="diagonal")
    f = bg.result()
    try:
        f.refactor()
        b = np.random.default_rng(2).standard_normal(A.shape[0])
        np.testing.assert_allclose(A @ f.solve(b), b, rtol=1e-9, atol=1e-12)
    finally:
        f.close()
        bg.close()

    def broken():
        raise ValueError("no pattern")

    bad = pardiso.BackgroundAnalysis(broken)
    with pytest.raises(SolverError, match="no pattern"):
        bad.result()
    bad.close()
    unused = pardiso.BackgroundAnalysis(lambda: A)
    unused.close()  # releases the handle nobody took
    assert unused._factor is None


def test_modes_with_background_analysis_and_concurrent_count_match_the_plain_path(monkeypatch):
    """The whole pipeline with both overlaps forced on a small cantilever: same frequencies, certified,
    and the solver says it used the background analysis and the concurrent count."""
    import sys

    import modalfem
    from modalfem.mesh import box

    modes_module = sys.modules["modalfem.modes"]
    mesh = box(size=(0.4, 0.04, 0.04), cells=(10, 2, 2))
    plain = modalfem.modes(mesh, modalfem.STEEL, k=6, degree=2, fixed="x0", backend="skfem", solver="block")
    monkeypatch.setattr(modes_module, "BACKGROUND_ANALYSIS_MIN", 0)
    monkeypatch.setattr(scipy_solver, "CONCURRENT_MIN_ROWS", 0)
    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 0.0)
    both = modalfem.modes(mesh, modalfem.STEEL, k=6, degree=2, fixed="x0", backend="skfem", solver="block")
    info = both.info["solver_info"]
    assert info["analysis"] == "in background"
    assert info["inertia_method"].endswith("(concurrent)")
    assert "analysis" not in plain.info["solver_info"]
    assert both.certificate.passed and plain.certificate.passed
    np.testing.assert_allclose(both.frequencies_hz, plain.frequencies_hz, rtol=1e-9)
