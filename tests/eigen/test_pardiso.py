"""MKL PARDISO wrapper: solves and inertia against dense references, refactorisation, bad input."""

import platform

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp

from modalfem.eigen.pardiso import AMD_BELOW, SERIAL_BELOW, PardisoLDLT, have_pardiso
from modalfem.eigen.scipy_solver import _pardiso_inertia
from modalfem.errors import SolverError

needs_pardiso = pytest.mark.skipif(not have_pardiso(), reason="MKL PARDISO not loadable here")


def laplacian_3d(n: int, *, shift: float = 0.0) -> sp.csr_matrix:
    """7-point Laplacian on an n^3 grid minus ``shift`` I (eigenvalues known in closed form)."""
    t = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    eye = sp.identity(n)
    A = sp.kron(sp.kron(t, eye), eye) + sp.kron(sp.kron(eye, t), eye) + sp.kron(sp.kron(eye, eye), t)
    return (A - shift * sp.identity(n**3)).tocsr()


def laplacian_eigenvalues(n: int) -> np.ndarray:
    e = 2 - 2 * np.cos(np.pi * np.arange(1, n + 1) / (n + 1))
    return (e[:, None, None] + e[None, :, None] + e[None, None, :]).ravel()


def test_mkl_is_installed_on_x86_64():
    """The project installs the mkl wheel on x86-64: losing it would silently cost 3-5x in speed."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        pytest.skip("the mkl wheel exists for x86-64 only")
    assert have_pardiso()


@needs_pardiso
@pytest.mark.parametrize("shift", [-0.5, 3.0])
def test_solve_and_inertia_match_dense(shift):
    n = 9
    A = laplacian_3d(n, shift=shift)
    with PardisoLDLT(A) as f:
        f.refactor()
        rng = np.random.default_rng(0)
        B = rng.standard_normal((A.shape[0], 5))
        X = f.solve(B)
        np.testing.assert_allclose(A @ X, B, atol=1e-10 * np.abs(B).max())
        x = f.solve(B[:, 0])
        assert x.shape == (A.shape[0],)
        np.testing.assert_allclose(x, X[:, 0], rtol=1e-10, atol=1e-12)  # same factor, other RHS blocking
        neg, zero, pos = f.inertia
        lam = laplacian_eigenvalues(n) - shift
        assert (neg, zero, pos) == (int(np.sum(lam < 0)), 0, int(np.sum(lam > 0)))
        assert f.perturbed_pivots == 0
        info = f.info()
        assert info["pardiso_ordering"] == "amd" and info["pardiso_factor_flops"] > 0  # auto: small -> AMD


@needs_pardiso
def test_refactor_on_the_same_analysis_counts_eigenvalues_of_a_pencil():
    """Sylvester counts of K - sigma M at several sigmas from one analysis equal dense counts."""
    rng = np.random.default_rng(1)
    n = 300
    K = laplacian_3d(7)[:n, :n].tocsr() * 4.0
    M = sp.diags(rng.uniform(0.5, 2.0, n)).tocsr()
    K.sort_indices()
    w = sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    f = PardisoLDLT((K - 0.0 * M).tocsr())
    for sigma in (-1.0, 0.5 * (w[9] + w[10]), 0.5 * (w[40] + w[41])):
        count = _pardiso_inertia(f, K, M, sigma)
        assert count == int(np.sum(w < sigma))
    f.close()
    f.close()  # idempotent


@needs_pardiso
@pytest.mark.parametrize("ordering", ["auto", "amd", "metis", "metis-parallel"])
def test_every_ordering_gives_the_same_solution_and_inertia(ordering):
    """The ordering changes the factor's fill, never the answer: solves agree with the matrix to
    roundoff (bound from the factor's own backward error, n * eps * ||A|| ||x||) and the inertia with
    the closed-form eigenvalues, for the node-grouped (quotient graph) and the plain orderings."""
    n = 13  # 2,197 rows: enough for the node-grouped ordering (SUPERVARIABLE_MIN_ROWS)
    A = laplacian_3d(n, shift=1.5)
    lam = laplacian_eigenvalues(n) - 1.5
    b = np.random.default_rng(3).standard_normal(A.shape[0])
    for groups in (None, np.arange(A.shape[0]) // 2):  # pairs of rows as "nodes"
        with PardisoLDLT(A, ordering=ordering, groups=groups) as f:
            x = f.solve(b)
            bound = A.shape[0] * np.finfo(float).eps * abs(A).sum(axis=1).max() * np.abs(x).max()
            assert np.abs(A @ x - b).max() <= bound
            assert f.inertia == (int(np.sum(lam < 0)), 0, int(np.sum(lam > 0)))
            name = f.info()["pardiso_ordering"]
            assert name.split(" ")[0] == ("amd" if ordering == "auto" else ordering)  # 2,197 rows < AMD_BELOW
            assert ("supervariables" in name) == (groups is not None)


def test_auto_ordering_threshold_is_between_the_measured_sizes():
    """AMD was measured faster at 3,000 and 19,440 rows and METIS at 60,840 and 138,720 (see AMD_BELOW)."""
    assert 19_440 < AMD_BELOW <= 60_840


def test_thread_count_is_one_for_small_matrices_and_on_a_busy_machine(monkeypatch):
    import os

    from modalfem.eigen import pardiso

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 0.0)
    assert pardiso.thread_count(SERIAL_BELOW - 1) == 1 and pardiso.thread_count(SERIAL_BELOW) == 0
    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 1.0)  # another process on one core
    assert pardiso.thread_count(10 * SERIAL_BELOW) == 1
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    assert pardiso.thread_count(10 * SERIAL_BELOW) == 7


def test_busy_elsewhere_sees_another_busy_process_but_not_this_ones_threads():
    import subprocess
    import sys
    import threading

    from modalfem.eigen.pardiso import busy_elsewhere

    stop = threading.Event()
    spin = threading.Thread(target=lambda: [None for _ in iter(stop.is_set, True)], daemon=True)
    spin.start()  # a busy thread of this process is not "elsewhere"
    try:
        quiet = busy_elsewhere(samples=9)
    finally:
        stop.set()
        spin.join()
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        import time

        time.sleep(0.3)
        loaded = busy_elsewhere(samples=9)
    finally:
        busy.kill()
        busy.wait()
    assert loaded >= quiet + 0.5 or loaded >= 1.0


@needs_pardiso
def test_solve_then_refactor_on_a_threaded_size(monkeypatch):
    """analysis -> numeric -> solve -> numeric at another shift, above the one-thread size: this order
    crashed MKL when the solve ran on fewer threads than the factorisation (now one count per handle)."""

    from modalfem.eigen import pardiso

    monkeypatch.setattr(pardiso, "busy_elsewhere", lambda: 0.0)  # threaded even on a busy machine
    n = int(np.ceil(SERIAL_BELOW ** (1 / 3))) + 1
    A = laplacian_3d(n, shift=-0.1)
    B = laplacian_3d(n, shift=1.0)
    with PardisoLDLT(A) as f:
        assert f.threads == 0
        b = np.ones(A.shape[0])
        x = f.solve(b)
        assert np.linalg.norm(A @ x - b) < 1e-10 * np.linalg.norm(b) * 1e3
        assert f.same_pattern(B)
        f.refactor(B.data)
        neg, _, _ = f.inertia
        assert neg == int(np.sum(laplacian_eigenvalues(n) < 1.0))


@needs_pardiso
def test_singular_matrix_count_is_not_trusted():
    """A singular K (free chain, sigma = 0) gives a zero or perturbed pivot: the count is refused."""
    n = 50
    K = sp.diags([-np.ones(n - 1), np.r_[1, 2 * np.ones(n - 2), 1], -np.ones(n - 1)], [-1, 0, 1]).tocsr()
    M = sp.identity(n, format="csr")
    f = PardisoLDLT((K + M).tocsr())
    assert _pardiso_inertia(f, K, M, 0.0) is None
    f.close()


@needs_pardiso
def test_bad_input_is_a_solver_error():
    with pytest.raises(SolverError, match="square"):
        PardisoLDLT(sp.csr_matrix(np.ones((2, 3))))
    with pytest.raises(SolverError, match="ordering"):
        PardisoLDLT(sp.identity(3, format="csr"), ordering="rcm")
    with pytest.raises(SolverError, match="no diagonal or upper entry"):
        PardisoLDLT(sp.csr_matrix(np.array([[1.0, 0.0], [1.0, 0.0]])))
    f = PardisoLDLT(sp.identity(3, format="csr"))
    with pytest.raises(SolverError, match="before a numeric"):
        _ = f.inertia
    with pytest.raises(SolverError, match="rows"):
        f.solve(np.ones(4))
    with pytest.raises(SolverError, match="values"):
        f.refactor(np.ones(5))
    f.close()
    with pytest.raises(SolverError, match="after close"):
        f.refactor()


def _vector_laplacian(n: int, shift: float) -> sp.csr_matrix:
    """kron(Laplacian - shift I, C) with C a 3x3 SPD coupling: three DOFs per grid node, node-major."""
    C = np.array([[2.0, 0.5, 0.2], [0.5, 1.5, 0.3], [0.2, 0.3, 1.0]])
    return sp.kron(laplacian_3d(n, shift=shift), C, format="csr")


@needs_pardiso
@pytest.mark.parametrize("given", [False, True])
def test_supervariable_ordering_solves_and_counts_like_the_dof_ordering(given):
    """The node-graph ordering (detected, or given as groups) gives the same solution and the same
    inertia as ordering the DOF graph; only the fill may differ."""
    import modalfem.eigen.pardiso as pm

    n = 14  # 2744 nodes, 8232 DOFs: above SUPERVARIABLE_MIN_ROWS
    A = _vector_laplacian(n, shift=2.0)
    assert A.shape[0] >= pm.SUPERVARIABLE_MIN_ROWS
    groups = np.arange(A.shape[0]) // 3 if given else None
    assert pm.supervariables_of(A) is not None and pm.supervariables_of(A)[-1] + 1 == A.shape[0] // 3
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    with PardisoLDLT(A, groups=groups) as f, PardisoLDLT(A, supervariables=False) as g:
        assert f.supervariable_ratio == pytest.approx(3.0) and g.supervariable_ratio == 1.0
        assert "supervariables" in f.info()["pardiso_ordering"]
        # a nested dissection of the node graph, not a scrambled one: fill close to the DOF graph's
        assert f.info()["pardiso_factor_entries"] <= 1.3 * g.info()["pardiso_factor_entries"]
        x, y = f.solve(b), g.solve(b)
        np.testing.assert_allclose(A @ x, b, atol=1e-9 * np.abs(b).max())
        np.testing.assert_allclose(x, y, rtol=1e-8, atol=1e-10 * np.abs(y).max())
        assert f.inertia == g.inertia
        lam = np.repeat(laplacian_eigenvalues(n) - 2.0, 3)  # C is SPD: signs of kron = signs of the Laplacian's
        assert f.inertia[0] == int(np.sum(lam < 0))


def test_supervariables_detects_identical_consecutive_patterns_only():
    import modalfem.eigen.pardiso as pm

    A = sp.csr_matrix(np.array([[1, 1, 0, 0], [1, 1, 0, 0], [0, 0, 1, 1], [0, 1, 1, 1]], dtype=float))
    np.testing.assert_array_equal(pm.supervariables_of(A), [0, 0, 1, 2])
    assert pm.supervariables_of(sp.identity(4, format="csr")) is None  # no two rows alike


@needs_pardiso
def test_groups_must_be_consecutive_rows():
    A = _vector_laplacian(14, shift=0.0)
    groups = np.arange(A.shape[0]) % 3  # interleaved: not consecutive
    with pytest.raises(SolverError, match="consecutive"):
        PardisoLDLT(A, groups=groups)


@needs_pardiso
@pytest.mark.parametrize("given", [False, True])
def test_amd_orders_the_dof_graph_from_its_threshold_and_counts_exactly(given):
    """From ``SUPERVARIABLE_AMD_BELOW`` rows on, AMD orders the DOF graph (it left 13-17 % less fill than
    the node graph on P2 bodies of 19k-26k DOFs), below it the node graph; METIS keeps the node graph.
    The certificate's count (``_pardiso_inertia``: a numeric refactorisation of K - sigma M on the solve
    factor's analysis, diagonal pivots) equals the closed-form count of eigenvalues below sigma."""
    import modalfem.eigen.pardiso as pm

    n = 16  # 4,096 nodes, 12,288 DOFs: above the threshold, below AMD_BELOW (auto = AMD)
    K = _vector_laplacian(n, shift=0.0)
    assert pm.SUPERVARIABLE_AMD_BELOW <= K.shape[0] < AMD_BELOW
    groups = np.arange(K.shape[0]) // 3 if given else None
    M = sp.identity(K.shape[0], format="csr")
    with PardisoLDLT(K + 0.5 * M, groups=groups) as f:  # the solve operator K - shift M, shift = -0.5
        assert f.supervariable_ratio == 1.0 and f.info()["pardiso_ordering"] == "amd"
        # eigenvalues of kron(L, C) - sigma I: products of the closed-form Laplacian eigenvalues and C's
        mu = sl.eigvalsh(np.array([[2.0, 0.5, 0.2], [0.5, 1.5, 0.3], [0.2, 0.3, 1.0]]))
        lam = np.sort(np.outer(laplacian_eigenvalues(n), mu).ravel())
        sigma = 0.5 * (lam[40] + lam[41]) if lam[41] > lam[40] else None
        assert sigma is not None
        count = _pardiso_inertia(f, K, M, sigma, groups)
        assert count == int(np.sum(lam < sigma)) == 41
    with PardisoLDLT(K + 0.5 * M, groups=groups, ordering="metis") as g:
        assert g.supervariable_ratio == pytest.approx(3.0)
    small = _vector_laplacian(14, shift=0.0)  # 8,232 DOFs: below the threshold, AMD on the node graph
    assert small.shape[0] < pm.SUPERVARIABLE_AMD_BELOW
    with PardisoLDLT(small + 0.5 * sp.identity(small.shape[0]), groups=None if not given else
                     np.arange(small.shape[0]) // 3) as h:
        assert h.supervariable_ratio == pytest.approx(3.0) and "supervariables" in h.info()["pardiso_ordering"]


@needs_pardiso
def test_amd_threshold_still_checks_given_groups():
    """Groups given to a handle that orders the DOF graph are still validated (one clear error)."""
    import modalfem.eigen.pardiso as pm

    K = _vector_laplacian(16, shift=-0.5)
    bad = np.arange(K.shape[0]) % 5  # rows of a group not consecutive
    assert K.shape[0] >= pm.SUPERVARIABLE_AMD_BELOW
    with pytest.raises(SolverError, match="consecutive"):
        PardisoLDLT(K, groups=bad)
