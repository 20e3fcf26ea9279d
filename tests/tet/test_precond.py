"""Two-level preconditioner: its coarse space holds the rigid motions of each aggregate, and CG with it
solves the same systems as Jacobi-PCG and SuperLU, in fewer iterations."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from modalfem.backends.skfem import assemble
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet.effects import Gravity, Pins
from modalfem.tet.model import tet_model
from modalfem.tet.precond import TwoLevel
from modalfem.tet.solver import TetSolver, TetState

MAT = Material(E=1e6, nu=0.3, rho=1000.0)


def test_one_aggregate_spans_the_rigid_motions():
    mesh = box(size=(0.1, 0.1, 0.1), cells=(3, 3, 3))
    K, _ = assemble(mesh, MAT, degree=1)
    tl = TwoLevel(mesh.points, aggregates=1)
    assert tl.count == 1
    x = mesh.points + 0.3  # any placement: rigid modes about the current centroid
    P = tl.prolongation(mesh.points, np.ones(3 * mesh.point_count, dtype=bool)).toarray()
    assert np.linalg.matrix_rank(P) == 6
    assert np.abs(K @ P).max() < 1e-9 * np.abs(K).max()
    P2 = tl.prolongation(x, np.ones(3 * mesh.point_count, dtype=bool)).toarray()
    np.testing.assert_allclose(P2, P, atol=1e-12)  # translation invariant
    held = np.zeros(3 * mesh.point_count, dtype=bool)
    held[:6] = True
    assert not tl.prolongation(mesh.points, ~held).toarray()[held].any()


def test_preconditioners_agree_and_twolevel_needs_fewer_iterations():
    mesh = box(size=(0.8, 0.1, 0.1), cells=(16, 2, 2))
    model = tet_model(mesh, MAT)
    out, its = {}, {}
    for name, kw in {"twolevel": {}, "jacobi": {"preconditioner": "jacobi"}, "splu": {"linear_solver": "splu"}}.items():
        solver = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))], newton_max=1, cg_rtol=1e-10, **kw)
        s = TetState.at_rest(model)
        info = solver.step(s, s, 1 / 30)
        out[name], its[name] = s.x, info.linear_iterations
    np.testing.assert_allclose(out["twolevel"], out["splu"], atol=1e-9)
    np.testing.assert_allclose(out["jacobi"], out["splu"], atol=1e-9)
    assert its["twolevel"] < 0.5 * its["jacobi"]


def test_lagged_coarse_space_reaches_the_same_solutions():
    """coarse_lag > 1 reuses the coarse factorisation across steps: the steps match rebuilding it every
    solve and a direct solve; a change of the held DOFs forces a rebuild."""
    mesh = box(size=(0.8, 0.1, 0.1), cells=(16, 2, 2))
    model = tet_model(mesh, MAT)
    runs = {}
    for name, kw in {"lag1": {"coarse_lag": 1}, "lag4": {"coarse_lag": 4}, "splu": {"linear_solver": "splu"}}.items():
        solver = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))], newton_max=1, cg_rtol=1e-10,
                           **kw)
        s = TetState.at_rest(model)
        rebuilt = []
        for _ in range(5):
            solver.step(s, s, 1 / 30)
            rebuilt.append(solver.twolevel.rebuilt if solver.twolevel else None)
        runs[name] = (s.x, rebuilt)
    np.testing.assert_allclose(runs["lag4"][0], runs["splu"][0], atol=1e-9)
    np.testing.assert_allclose(runs["lag1"][0], runs["splu"][0], atol=1e-9)
    assert runs["lag1"][1] == [True] * 5
    assert runs["lag4"][1][0] and not all(runs["lag4"][1])  # reused at least once
    tl = TwoLevel(mesh.points)
    A = sp.identity(3 * mesh.point_count, format="csr")
    free = np.ones(3 * mesh.point_count, dtype=bool)
    tl.setup(A, np.ones(3 * mesh.point_count), mesh.points, free, reuse=True)
    tl.setup(A, np.ones(3 * mesh.point_count), mesh.points, free, reuse=True)
    assert not tl.rebuilt
    free[:3] = False
    tl.setup(A, np.ones(3 * mesh.point_count), mesh.points, free, reuse=True)
    assert tl.rebuilt


def test_preconditioner_is_jacobi_plus_the_galerkin_coarse_solve():
    """``M^-1 r = D^-1 r + P (P^T A P)^-1 P^T r`` (the coarse matrix is inverted explicitly): compared with a
    dense solve; M^-1 is symmetric positive definite."""
    mesh = box(size=(0.4, 0.1, 0.1), cells=(8, 2, 2))
    K, M = assemble(mesh, MAT, degree=1)
    A = (K + 900.0 * M).tocsr()  # a step matrix M / h^2 + K
    n3 = 3 * mesh.point_count
    free = np.ones(n3, dtype=bool)
    free[:12] = False  # some held DOFs (their rows of P are zero)
    tl = TwoLevel(mesh.points, aggregates=6)
    diag = A.diagonal()
    prec = tl.setup(A, diag, mesh.points, free)
    P = tl.prolongation(mesh.points, free).toarray()
    Ac = P.T @ (A @ P)
    dmax = np.diag(Ac).max()
    empty = np.diag(Ac) <= 1e-14 * dmax
    Ac[empty, empty] = 1.0  # as TwoLevel: groups without free DOFs, and a 1e-10 relative diagonal shift
    Ac[np.diag_indices_from(Ac)] += 1e-10 * dmax
    rng = np.random.default_rng(7)
    R = rng.standard_normal((n3, 4))
    Z = np.stack([prec(r) for r in R.T], axis=1)
    ref = R / diag[:, None] + P @ np.linalg.solve(Ac, P.T @ R)
    np.testing.assert_allclose(Z, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    G = R.T @ Z
    np.testing.assert_allclose(G, G.T, rtol=1e-9, atol=1e-12 * np.abs(G).max())
    assert np.all(np.linalg.eigvalsh(0.5 * (G + G.T)) > 0)


def test_compiled_cg_solves_to_its_tolerance_and_flags_negative_curvature():
    """``solver._pcg`` (the compiled two-level CG): the residual it reports as reached is reached, the
    callable and the compiled preconditioner are the same operator, and an indefinite matrix is flagged."""
    from modalfem.tet.precond import Preconditioner
    from modalfem.tet.solver import _pcg

    mesh = box(size=(0.4, 0.1, 0.1), cells=(8, 2, 2))
    K, M = assemble(mesh, MAT, degree=1)
    A = (K + 1e4 * M).tocsr()
    free = np.ones(A.shape[0], dtype=bool)
    tl = TwoLevel(mesh.points, aggregates=4)
    prec = tl.setup(A, A.diagonal(), mesh.points, free)
    r = np.random.default_rng(3).standard_normal(A.shape[0])
    z_ref = r / A.diagonal() + prec.P @ (prec.Ac_inv @ (prec.Pt @ r))
    np.testing.assert_allclose(prec(r), z_ref, rtol=1e-13, atol=0)
    b = np.random.default_rng(4).standard_normal(A.shape[0])
    for p in (prec, Preconditioner(1.0 / A.diagonal())):
        x, it, definite = _pcg(A, b, p, 1e-8, 10 * len(b))
        assert definite and 0 < it < 10 * len(b)
        assert np.linalg.norm(b - A @ x) <= 1e-8 * np.linalg.norm(b)
        x2, it2, _ = _pcg(A, b, p, 1e-8, 10 * len(b), x0=x)  # started at the answer: nothing to do
        assert it2 == 0 and np.array_equal(x2, x)
    B = (K - 1e2 * sp.identity(A.shape[0])).tocsr()  # K's rigid modes make this indefinite
    _, _, definite = _pcg(B, b, Preconditioner(np.ones(len(b))), 1e-12, 10 * len(b))
    assert not definite
