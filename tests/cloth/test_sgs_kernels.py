"""The symmetric block Gauss-Seidel CG of ``modalfem.cloth._sgs_kernels``: Eisenstat's product against dense
matrices, the stopping rule on the true residual, handles and contacts, fewer iterations than the multilevel CG."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from modalfem.cloth import _kernels, _sgs_kernels
from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel
from modalfem.cloth.solver import ImplicitEuler, _constraints, pcg_constrained
from modalfem.errors import InputError, SolverError

SOFT = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)


def _system(n: int, stiffness: float, seed: int = 3):
    """Block data of ``M + stiffness K`` on an n x n cloth at a deformed state, its pattern and an rng."""
    m = grid((0.4, 0.4), (n, n))
    model = ClothModel(m, SOFT)
    rng = np.random.default_rng(seed)
    x = m.points * np.array([1.1, 0.95, 1.0]) + 0.005 * rng.standard_normal(m.points.shape)
    s = ImplicitEuler(model)
    s.stiffness(x)
    data = s._scale_plus_diagonal(s._Kdata, stiffness, np.repeat(model.masses, 3))
    return s._pattern, data, rng


def _constraint_set(n_vertices: int, rng):
    perm = rng.permutation(n_vertices)
    fixed, idx = perm[:4], perm[4:30]
    nrm = rng.standard_normal((len(idx), 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    return fixed, rng.standard_normal((len(fixed), 3)), (idx, nrm, rng.standard_normal(len(idx)))


def _dense_projector(kind, normal):
    S = np.zeros((len(kind), 3, 3))
    S[kind == 0] = np.eye(3)
    c = kind == 1
    S[c] = np.eye(3) - normal[c][:, :, None] * normal[c][:, None, :]
    return sp.block_diag(list(S)).toarray()


def _ordered(pat, data, kind, normal, order: str):
    """The pattern, data and constraints in the sweep order ``order`` (new vertex i = old ``perm[i]``)."""
    o = _sgs_kernels.SweepOrder(pat.indptr, pat.indices, pat.diag, order)
    if o.perm is None:
        return o, np.arange(pat.n), data, kind, normal
    pdata = np.empty_like(data)
    _sgs_kernels._gather_blocks(data, o.src, pdata)
    return o, o.perm, pdata, kind[o.perm], np.ascontiguousarray(normal[o.perm])


@pytest.mark.parametrize("order", _sgs_kernels.ORDERS)
def test_sweep_orders_are_colourings_and_permute_the_matrix(order):
    pat, data, rng = _system(40, 1e-3)  # 1600 vertices: several groups and colour chunks
    n = pat.n
    kind, normal, _ = _constraints(n, None, None, None)
    o, perm, pdata, _, _ = _ordered(pat, data, kind, normal, order)
    assert np.array_equal(np.sort(perm), np.arange(n))
    A = sp.bsr_matrix((data, pat.indices, pat.indptr), shape=(3 * n, 3 * n)).toarray()
    B = sp.bsr_matrix((pdata, o.indices, o.indptr), shape=(3 * n, 3 * n)).toarray()
    dof = (3 * perm[:, None] + np.arange(3)).reshape(-1)
    assert np.array_equal(B, A[np.ix_(dof, dof)])  # exactly P A P^T
    assert np.array_equal(o.indices[o.diag], np.arange(n))
    # tasks of one colour share no block (so they may run in parallel), and cover the rows in order
    task = np.repeat(np.arange(len(o.tptr) - 1), np.diff(o.tptr))
    colour = np.repeat(np.arange(len(o.cptr) - 1), np.diff(o.cptr))[task]
    assert o.tptr[0] == 0 and o.tptr[-1] == n and np.all(np.diff(o.tptr) > 0)
    rows = np.repeat(np.arange(n), np.diff(o.indptr))
    cols = o.indices
    same = (colour[rows] == colour[cols]) & (task[rows] != task[cols])
    assert not same.any()
    if order == "colours":  # no block inside a colour at all; a triangle mesh with its hinges: 7 colours here
        assert not np.any((colour[rows] == colour[cols]) & (rows != cols))
        assert 5 <= o.colours <= 12
    if order == "blocks":  # groups of consecutive rows of the grid: stripes, two colours
        assert o.colours == 2 and len(o.tptr) - 1 == n // _sgs_kernels.GROUP


@pytest.mark.parametrize("order", _sgs_kernels.ORDERS)
def test_eisenstat_product_is_the_sgs_preconditioned_operator(order):
    pat, data, rng = _system(8 if order == "natural" else 24, 1e-3)
    n = pat.n
    fixed, fval, con = _constraint_set(n, rng)
    kind, normal, _ = _constraints(n, fixed, fval, con)
    o, perm, data, kind, normal = _ordered(pat, data, kind, normal, order)
    A = sp.bsr_matrix((data, o.indices, o.indptr), shape=(3 * n, 3 * n)).toarray()
    S = _dense_projector(kind, normal)
    As = S @ A @ S
    blk = np.arange(3 * n) // 3
    D = np.where(blk[:, None] == blk[None, :], As, 0.0)
    L = np.where(blk[:, None] > blk[None, :], As, 0.0)
    # on range(S): (D + L)^-1 as the pseudo-inverse restricted to range(S) (constrained components zero)
    Q = np.linalg.svd(S)[0][:, : int(round(np.trace(S)))]  # orthonormal basis of range(S)
    inv_lower = Q @ np.linalg.inv(Q.T @ (D + L) @ Q) @ Q.T
    inv_upper = Q @ np.linalg.inv(Q.T @ (D + L.T) @ Q) @ Q.T
    rb = (S @ rng.standard_normal(3 * n)).reshape(n, 3)
    P = _kernels._preconditioner(data, o.diag, kind, normal)
    # one iteration in the sweeps (_cg_sweeps, the first colour's tasks doing both sweeps) without the update step:
    # c = D rbar (projected), then q = Abar c by the same row operations as the backward and the forward sweep
    c, t2, f2, q2 = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    p0, v0, xb = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    rc, rr, cq2 = _sgs_kernels._cg_sweeps(o.indptr, o.indices, data, o.diag, P, kind, normal, c, t2, f2, q2, p0, v0, xb,
                                          rb, 0.0, 0.0, False, o.cptr, o.tptr)
    assert np.allclose(c.reshape(-1), D @ rb.reshape(-1), rtol=0, atol=1e-12 * np.abs(D @ rb.reshape(-1)).max())
    assert np.isclose(rc, rb.reshape(-1) @ c.reshape(-1), rtol=1e-12) and np.isclose(rr, np.sum(rb**2), rtol=1e-12)
    assert not (p0.any() or v0.any() or xb.any())
    t, u, q = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    _sgs_kernels._backward(o.indptr, o.indices, data, o.diag, P, c, t, c, 0.0, False, o.cptr, o.tptr)
    cq = _sgs_kernels._forward(o.indptr, o.indices, data, o.diag, P, c, t, u, q, True, o.cptr, o.tptr)
    assert cq2 == cq and np.array_equal(q2, q) and np.array_equal(t2, t)
    # with the update step: each row's p = c + beta p, v = q + beta v, xbar += alpha p, rbar -= alpha v first
    alpha, beta = 0.7, 0.3
    p1, v1, xb1, rb1 = (rng.standard_normal((n, 3)) * (kind == 0)[:, None] for _ in range(4))
    p, v, xb, rb2 = p1.copy(), v1.copy(), xb1.copy(), rb1.copy()
    c1, q1 = c.copy(), q.copy()
    _sgs_kernels._cg_sweeps(o.indptr, o.indices, data, o.diag, P, kind, normal, c1, t2, f2, q1, p, v, xb, rb2, alpha,
                            beta, True, o.cptr, o.tptr)
    for got, want in ((p, c + beta * p1), (v, q + beta * v1)):
        assert np.allclose(got, want, rtol=1e-14, atol=1e-14 * np.abs(want).max())
    for got, want in ((xb, xb1 + alpha * p), (rb2, rb1 - alpha * v)):
        assert np.allclose(got, want, rtol=1e-14, atol=1e-14 * np.abs(want).max())
    assert np.allclose(c1.reshape(-1), D @ rb2.reshape(-1), rtol=0, atol=1e-12 * np.abs(D @ rb2.reshape(-1)).max())
    tref = inv_upper @ c.reshape(-1)
    ref = inv_lower @ As @ tref
    scale = np.abs(ref).max()
    assert np.allclose(t.reshape(-1), tref, rtol=0, atol=1e-10 * np.abs(tref).max())
    assert np.allclose(q.reshape(-1), ref, rtol=0, atol=1e-10 * scale)
    assert np.isclose(cq, c.reshape(-1) @ ref, rtol=1e-10)
    Abar = inv_lower @ As @ inv_upper  # symmetric on range(S): what makes CG on it valid
    assert np.allclose(Q.T @ Abar @ Q, (Q.T @ Abar @ Q).T, rtol=0, atol=1e-10 * np.abs(Q.T @ Abar @ Q).max())


@pytest.mark.parametrize("rtol", [1e-2, 1e-6])
def test_sgs_cg_stops_on_the_true_residual_with_handles_and_contacts(rtol):
    pat, data, rng = _system(16, 1e-2)
    n = pat.n
    fixed, fval, con = _constraint_set(n, rng)
    kind, normal, z = _constraints(n, fixed, fval, con)
    A = sp.bsr_matrix((data, pat.indices, pat.indptr), shape=(3 * n, 3 * n)).tocsr()
    b = rng.standard_normal((n, 3))
    y = z.copy()
    y += 0.1 * rng.standard_normal((n, 3)) * (kind == 0)[:, None]  # a start: free vertices only moved
    it, res = _sgs_kernels.pcg_sgs(pat.indptr, pat.indices, data, pat.diag, kind, normal, b, y, rtol, 1000)
    assert it > 0
    S = sp.csr_matrix(_dense_projector(kind, normal))
    r = S @ (b.reshape(-1) - A @ y.reshape(-1))
    rhs = S @ (b.reshape(-1) - A @ z.reshape(-1))
    nb = np.sqrt(rhs @ rhs + np.sum(z[kind == 2] ** 2))
    assert np.linalg.norm(r) <= rtol * nb and np.isclose(np.linalg.norm(r) / nb, res, rtol=1e-6)
    assert np.array_equal(y[fixed], fval)  # the prescribed components are kept exactly
    assert np.allclose(np.sum(y[con[0]] * con[1], axis=1), con[2], rtol=0, atol=1e-12)


@pytest.mark.parametrize("pre", ["sgs", "sgs-blocks", "sgs-colours"])
def test_sgs_and_multilevel_cg_agree_within_their_residuals(pre):
    pat, data, rng = _system(24, 1e-1)
    n = pat.n
    A = sp.bsr_matrix((data, pat.indices, pat.indptr), shape=(3 * n, 3 * n)).tocsr()
    fixed, fval, con = _constraint_set(n, rng)
    b = rng.standard_normal(3 * n)
    out = {p: pcg_constrained(A, b, fixed=fixed, fixed_values=fval, contacts=con, rtol=1e-8, maxiter=5000,
                              preconditioner=p) for p in (pre, "multilevel")}
    (ys, its), (ym, itm) = out[pre], out["multilevel"]
    # both to 1e-8 of the right-hand side: their difference is bounded by the two residuals through A^-1
    # (same constrained components, so S A S (ys - ym) = r_m - r_s on range(S): |ys - ym| <= 2 rtol |b'| / lam_min)
    kind, normal, z = _constraints(n, fixed, fval, con)
    S = _dense_projector(kind, normal)
    lam_min = np.linalg.eigvalsh(S @ A.toarray() @ S + np.eye(3 * n) - S).min()
    nb = np.sqrt(np.sum((S @ (b - A @ z.reshape(-1))) ** 2) + np.sum(fval**2))
    assert np.linalg.norm(ys - ym) <= 2e-8 * nb / lam_min and its > 0 and itm > 0


def test_sgs_takes_fewer_iterations_than_multilevel_in_a_pile():
    # the sheets resting on each other and the ground (contact constraints, stiffness-dominated systems): measured
    # 18.8 against 30.7 implicit iterations per step (24 x 24, 40 steps) and 38.0 against 53.3 on the 64 x 64 pile
    # (the smoothing solve, ``solver.SMOOTH_PRECONDITIONER``, is the same in both runs).
    # (Not everywhere: a free-floating stiff sheet with a random right-hand side takes more with SGS, whose sweeps
    # do not reach the global modes the aggregation levels solve; e.g. 49 against 35 at M + 1e-4 K, 24 x 24.)
    from modalfem.cloth import scenes

    totals = {}
    for pre in ("multilevel", "sgs"):
        setup = scenes.pile(24)
        setup.scene.solver.cg_preconditioner = pre
        totals[pre] = [0, 0]
        for _ in range(20):
            st = setup.scene.step(setup.dt)
            totals[pre][0] += st.linear.iterations
            totals[pre][1] += st.smooth_iterations
        assert scenes.intersections(setup) == 0
    assert totals["sgs"][0] < 0.8 * totals["multilevel"][0], totals  # (measured 413 against 617)


def test_bad_preconditioner_and_too_few_iterations():
    pat, data, rng = _system(6, 1e-2)
    A = sp.bsr_matrix((data, pat.indices, pat.indptr)).tocsr()
    with pytest.raises(InputError, match="preconditioner"):
        pcg_constrained(A, np.ones(A.shape[0]), preconditioner="amg")
    with pytest.raises(InputError, match="preconditioner"):
        ImplicitEuler(ClothModel(grid((0.4, 0.4), (4, 4)), SOFT), cg_preconditioner="jacobi")
    with pytest.raises(InputError, match="sweep order"):
        _sgs_kernels.SweepOrder(pat.indptr, pat.indices, pat.diag, "red-black")
    with pytest.raises(SolverError, match="did not reach"):
        pcg_constrained(A, rng.standard_normal(A.shape[0]), rtol=1e-14, maxiter=2)


def test_a_start_worse_than_none_is_dropped():
    # the smoothing's warm start (the last step's answer) against a right-hand side of rounding size (a collision
    # change of 1e-22 m/s in a World's cloth-pile): from that start the residual cannot fall below the start's
    # rounding, 1e17 times the right-hand side; the solve starts from the prescribed part instead
    pat, data, rng = _system(12, 1e-2)
    n = pat.n
    kind, normal, z = _constraints(n, None, None, None)
    b = 1e-22 * rng.standard_normal((n, 3))
    y = rng.standard_normal((n, 3))
    it, res = _sgs_kernels.pcg_sgs(pat.indptr, pat.indices, data, pat.diag, kind, normal, b, y, 0.1, 200)
    A = sp.bsr_matrix((data, pat.indices, pat.indptr), shape=(3 * n, 3 * n)).tocsr()
    assert 0 < it < 200 and np.linalg.norm(b.reshape(-1) - A @ y.reshape(-1)) <= 0.1 * np.linalg.norm(b)


@pytest.mark.parametrize("order", _sgs_kernels.ORDERS)
def test_shifted_solve_forms_the_matrix_in_the_sweep_order_to_the_last_bit(order):
    """``SweepOrder.solve_shifted`` (the smoothing solve: ``scale K + diag(d)`` formed directly in the sweep order)
    gives the bits of ``solve`` on the matrix formed first (``_kernels.scale_plus_diagonal``), with handles and
    contacts, on 1 and 2 threads."""
    from modalfem._threads import thread_count

    m = grid((0.4, 0.4), (40, 40))  # 1600 vertices: several groups and colour chunks
    model = ClothModel(m, SOFT)
    rng = np.random.default_rng(5)
    s = ImplicitEuler(model)
    s.stiffness(m.points * np.array([1.1, 0.95, 1.0]) + 0.005 * rng.standard_normal(m.points.shape))
    pat, K = s._pattern, s._Kdata
    d = np.repeat(model.masses, 3).reshape(-1, 3) * rng.uniform(0.5, 2.0, (pat.n, 3))
    scale = 3e-4
    data = np.empty_like(K)
    _kernels.scale_plus_diagonal(K, pat.indptr, pat.diag, scale, d, data)
    o = _sgs_kernels.SweepOrder(pat.indptr, pat.indices, pat.diag, order)
    fixed, values, contacts = _constraint_set(pat.n, rng)
    kind, normal, z = _constraints(pat.n, fixed, values, contacts)
    b = rng.standard_normal((pat.n, 3))
    runs = []
    for threads in (1, 2):
        with thread_count(threads):
            y1, y2 = z.copy(), z.copy()
            r1 = o.solve(data, kind, normal, b, y1, 1e-8, 2000)
            r2 = o.solve_shifted(K, scale, d, kind, normal, b, y2, 1e-8, 2000)
        assert r1 == r2 and r1[0] > 5
        np.testing.assert_array_equal(y1, y2)
        runs.append(y2)
    np.testing.assert_array_equal(runs[0], runs[1])
