"""The tet solver's fused kernels against plain references: the blocked CG product gives the bits of the
row-by-row one, the fused CG solves its systems like the unfused formulas, the element-major assembly and
the force gather give the bits of the layouts and scatters they replace, the compiled coarse matrix is
SciPy's ``P^T A P``; each on 1 and 2 threads."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import scipy.sparse as sp

from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet import _kernels as K
from modalfem.tet.assembly import HessianPattern
from modalfem.tet.effects import Gravity, Pins
from modalfem.tet.model import tet_model
from modalfem.tet.precond import TwoLevel
from modalfem.tet.solver import TetSolver, TetState, _pcg
from modalfem._threads import thread_count

THREADS = (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,)
MAT = Material(E=1e6, nu=0.3, rho=1000.0)


@pytest.fixture(scope="module")
def bar():
    """A bent bar's step matrix (the solver's own, Dirichlet rows included) and its two-level preconditioner."""
    mesh = box(size=(0.8, 0.3, 0.2), cells=(16, 6, 4))  # 2304 tets, 1785 DOFs: several row chunks
    model = tet_model(mesh, MAT)
    solver = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))])
    state = TetState.at_rest(model)
    for _ in range(3):
        solver.step(state, state, 1.0 / 30.0)
    A, prec = solver._system
    return mesh, model, solver, A, prec


def test_blocked_product_has_the_bits_of_the_row_product(bar):
    _, _, solver, A, _ = bar
    assert solver.pattern.blocked and K.is_blocked3(A.indptr, A.indices)
    n = A.shape[0]
    rng = np.random.default_rng(0)
    z, p0, Ap0 = rng.standard_normal(n), rng.standard_normal(n), rng.standard_normal(n)
    ind = K.unsigned(A.indices)
    part = np.empty(64)
    ref_p, ref_Ap = p0.copy(), Ap0.copy()
    ref = K._search(A.indptr, ind, A.data, z, ref_p, ref_Ap, 0.7, part)
    # the definition: p = z + beta p, Ap = A z + beta Ap, and p . Ap
    np.testing.assert_allclose(ref_Ap, A @ z + 0.7 * Ap0, rtol=1e-13, atol=1e-13 * np.abs(A @ z).max())
    np.testing.assert_array_equal(ref_p, z + 0.7 * p0)
    for t in THREADS:
        with thread_count(t):
            p, Ap = p0.copy(), Ap0.copy()
            got = K._search3(A.indptr, ind, A.data, z, p, Ap, 0.7, part)
        np.testing.assert_array_equal(p, ref_p)
        np.testing.assert_array_equal(Ap, ref_Ap)
        # p . Ap: the same products, summed over vertex chunks instead of row chunks
        assert abs(got - ref) <= len(p) * np.finfo(float).eps * float(np.abs(p * Ap).sum())
        p, Ap = p0.copy(), Ap0.copy()
        K._search3(A.indptr, ind, A.data, z, p, Ap, 0.0, part)  # beta = 0 starts: p = z, Ap = A z
        np.testing.assert_array_equal(p, z)
        y = np.empty(n)
        K.csr_matvec(A.indptr, ind, A.data, z, y)
        np.testing.assert_array_equal(Ap, y)


def test_block_structure_is_recognised():
    mesh = box(size=(0.2, 0.1, 0.1), cells=(2, 1, 1))
    pat = HessianPattern(mesh.cells, mesh.point_count)
    assert pat.blocked
    A = pat.matrix(np.arange(pat.nnz, dtype=float) + 1.0).tolil()
    A[0, 4] = 0.0
    B = A.tocsr()
    B.eliminate_zeros()  # one entry of a block missing
    assert not K.is_blocked3(B.indptr, B.indices)
    L = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(9, 9), format="csr")  # a scalar chain: no blocks
    assert not K.is_blocked3(L.indptr, L.indices)
    assert not K.is_blocked3(sp.identity(9, format="csr").indptr, sp.identity(9, format="csr").indices)


def test_fused_cg_solves_to_its_tolerance_with_the_same_bits_on_any_thread_count(bar):
    _, _, _, A, prec = bar
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    for blocked in (True, False):
        runs = []
        for t in THREADS:
            with thread_count(t):
                runs.append(_pcg(A, b, prec, 1e-10, 10 * len(b), blocked=blocked))
        x, it, definite = runs[0]
        assert definite and 0 < it < len(b)
        # the residual reached is the one asked for (A p by linearity drifts only at roundoff level)
        assert np.linalg.norm(b - A @ x) <= 1e-10 * np.linalg.norm(b) * (1 + 1e-6)
        for xr, itr, dr in runs[1:]:
            np.testing.assert_array_equal(xr, x)
            assert (itr, dr) == (it, definite)


def test_element_major_hessians_assemble_to_the_bits_of_the_c_layout():
    mesh = box(size=(0.2, 0.1, 0.1), cells=(3, 2, 2))
    pat = HessianPattern(mesh.cells, mesh.point_count)
    rng = np.random.default_rng(2)
    em = rng.standard_normal((mesh.cell_count, 78))  # what the kernel writes, (m, 78)
    diag = rng.standard_normal(3 * mesh.point_count)
    for t in THREADS:
        with thread_count(t):
            a = pat.assemble(em.T, diag, upper=True)  # the transposed view: element-major gather
            b = pat.assemble(np.ascontiguousarray(em.T), diag, upper=True)
        np.testing.assert_array_equal(a, b)
    iu = np.triu_indices(12)
    full = np.zeros((mesh.cell_count, 12, 12))
    full[:, iu[0], iu[1]] = em
    full[:, iu[1], iu[0]] = em
    np.testing.assert_allclose(a, pat.assemble(full, diag), rtol=1e-13, atol=1e-13)


def test_force_gather_has_the_bits_of_bincount(bar):
    _, model, solver, _, _ = bar
    f = np.random.default_rng(3).standard_normal((4, 3, model.cell_count))
    index = np.moveaxis(3 * model.cells[:, :, None] + np.arange(3), 0, -1).ravel()
    ref = np.bincount(index, weights=f.ravel(), minlength=3 * model.point_count)
    for t in THREADS:
        out = np.empty(3 * model.point_count)
        with thread_count(t):
            K.gather_sum(solver._force_ptr, solver._force_order, f.ravel(), out)
        np.testing.assert_array_equal(out, ref)


def test_compiled_coarse_matrix_is_scipys_galerkin_product(bar):
    mesh, model, _, A, _ = bar
    free = np.ones(A.shape[0], dtype=bool)
    free[:30] = False  # held DOFs: zero rows of P
    tl = TwoLevel(model.rest_points)
    x = model.rest_points + 0.01 * np.random.default_rng(4).standard_normal(model.rest_points.shape)
    P = tl.prolongation(x, free)
    ref = (P.T @ (A @ P)).toarray()
    got = []
    for t in THREADS:
        Ac = np.zeros_like(ref)
        with thread_count(t):
            K.galerkin(A.indptr, K.unsigned(A.indices), A.data, P.indptr, K.unsigned(P.indices), P.data,
                       tl._group_ptr, tl._group_rows, Ac)
        got.append(Ac)
    # sums of the same products in another order: roundoff of the row sums of |P^T| |A| |P|
    bound = 64 * np.finfo(float).eps * (abs(P).T @ (abs(A) @ abs(P))).toarray()
    assert np.all(np.abs(got[0] - ref) <= bound)
    for Ac in got[1:]:
        np.testing.assert_array_equal(Ac, got[0])


def test_compiled_stable_corotated_is_its_numpy_form():
    """Scalar moduli take the compiled pass; per-element moduli (the same values) the NumPy sums of the
    ARAP and volumetric terms: equal to roundoff (a few ulps of the largest term), on any thread count."""
    from modalfem.tet.energies import StableCorotated

    rng = np.random.default_rng(5)
    m = 3000
    s = 1.0 + 0.3 * rng.standard_normal((m, 3))
    s[:10, 2] *= -1.0  # inverted elements
    s[10:20, 1:] = 0.0  # degenerate ones: the pair sum clamped
    mu, lam = 3.8e5, 5.8e5
    ref = StableCorotated(np.full(m, mu), np.full(m, lam))
    for order in (0, 1, 2):
        want = ref.derivs(s, order)
        for t in THREADS:
            with thread_count(t):
                got = StableCorotated(mu, lam).derivs(s, order)
            fields = ("psi", "d1", "d2", "twist", "flip")[:(1, 2, 5)[order]]
            for name in fields:
                a, b = getattr(got, name), getattr(want, name)
                # the same operations in another grouping: a few ulps of the largest value
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-13 * np.abs(b).max(), err_msg=name)


def test_compiled_preconditioner_is_the_two_level_operator(bar):
    """The CG's restriction (group by group, TwoLevel's layout of P), coarse product and prolongation give
    ``inv * r + P Ac_inv P^T r`` (the preconditioner's SciPy form) to roundoff, on 1 and 2 threads alike."""
    _, _, _, A, prec = bar
    inv, Pp, Pi, Pd, Ac_inv, gptr, grows = prec.arrays()
    n, nc = A.shape[0], Ac_inv.shape[0]
    assert nc > 0
    r0 = np.random.default_rng(6).standard_normal(n)
    want = prec(r0)
    outs = []
    for t in THREADS:
        r, x, zero = r0.copy(), np.zeros(n), np.zeros(n)
        cr, cz, z, part = np.empty(nc), np.empty(nc), np.empty(n), np.empty(128)
        with thread_count(t):
            rr = K._update(x, r, zero, zero, 0.0, Pp, Pi, Pd, Ac_inv, gptr, grows, cr, cz, part)
            rz = K._precondition(r, inv, Pp, Pi, Pd, cz, z, part)
        np.testing.assert_array_equal(r, r0)  # alpha = 0: the residual untouched
        np.testing.assert_allclose(cr, prec.Pt @ r0, rtol=1e-12, atol=1e-13 * np.abs(prec.Pt @ r0).max())
        np.testing.assert_allclose(z, want, rtol=1e-10, atol=1e-12 * np.abs(want).max())
        assert abs(rr - r0 @ r0) <= 1e-12 * (r0 @ r0) and abs(rz - r0 @ want) <= 1e-10 * abs(r0) @ abs(want)
        outs.append(z)
    for z in outs[1:]:
        np.testing.assert_array_equal(z, outs[0])


def test_a_coarse_part_without_its_groups_is_refused(bar):
    from modalfem.errors import InputError
    from modalfem.tet.precond import Preconditioner

    _, _, _, _, prec = bar
    with pytest.raises(InputError, match="groups of TwoLevel's P"):
        Preconditioner(prec.inv, prec.P, prec.Ac_inv)
