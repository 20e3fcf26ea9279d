"""Implicit backward Euler: free fall, momentum, dissipation, handles, statics, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from modalfem.cloth.mesh import grid
from modalfem.cloth.model import COTTON, ClothMaterial, ClothModel, Handle
from modalfem.cloth.scene import ClothScene
from modalfem.cloth.solver import ImplicitEuler, pcg_constrained
from modalfem.errors import InputError, MaterialError, SimulationError, SolverError

MESH = grid((0.4, 0.4), (6, 6))
SOFT = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)


def test_free_fall_is_exact():
    scene = ClothScene(ClothModel(MESH, COTTON), gravity=(0, 0, -9.81))
    scene.solver.cg_rtol = 1e-12  # exact up to the linear solve's residual: make that negligible
    dt, n = 0.02, 10
    for _ in range(n):
        scene.step(dt)
    assert np.allclose(scene.v, [0, 0, -9.81 * n * dt], atol=1e-9)
    # backward Euler positions: x_k = x_0 + dt^2 g k (k + 1) / 2
    assert np.allclose(scene.x - MESH.points, [0, 0, -9.81 * dt * dt * n * (n + 1) / 2], atol=1e-9)


@pytest.mark.parametrize("linear_solver", ["splu", "cg"])
def test_linear_momentum_is_conserved_and_energy_decays(linear_solver):
    rng = np.random.default_rng(0)
    x0 = MESH.points * np.array([1.2, 0.9, 1.0]) + 0.01 * rng.standard_normal(MESH.points.shape)
    v0 = 0.3 * rng.standard_normal(x0.shape)
    model = ClothModel(MESH, SOFT)
    scene = ClothScene(model, x0=x0, v0=v0, linear_solver=linear_solver)
    scene.solver.cg_rtol = 1e-10
    p0 = model.masses @ v0
    e = [scene.energy()["total"]]
    for _ in range(20):
        scene.step(0.01)
        e.append(scene.energy()["total"])
    assert np.allclose(model.masses @ scene.v, p0, atol=1e-9 * np.abs(p0).max())
    assert e[-1] < 0.5 * e[0] and max(e) <= e[0] * (1 + 1e-9)


def test_cg_and_splu_agree_and_cg_reports_iterations():
    model = ClothModel(MESH, SOFT, handles=(Handle.pin(MESH.points, [0, 5]),))
    x = MESH.points + 0.02 * np.random.default_rng(1).standard_normal(MESH.points.shape)
    f = np.tile([0.0, 0.0, -0.1], (MESH.point_count, 1))
    vs = []
    for ls in ("splu", "cg"):
        s = ImplicitEuler(model, linear_solver=ls, cg_rtol=1e-12)
        v, info = s.step_velocity(x, np.zeros_like(x), f, 0.01, fixed=[0, 5], fixed_velocity=np.zeros((2, 3)))
        vs.append(v)
        assert (info.iterations > 0) == (ls == "cg")
    assert np.allclose(vs[0], vs[1], atol=1e-9 * np.abs(vs[0]).max())
    assert np.allclose(vs[0][[0, 5]], 0.0)
    with pytest.raises(InputError, match="linear_solver"):
        ImplicitEuler(model, linear_solver="amg")


def test_pcg_solves_an_spd_system():
    A = sp.diags([-1.0, 2.5, -1.0], [-1, 0, 1], shape=(48, 48)).tocsr()
    b = np.arange(48.0)
    x, it = pcg_constrained(A, b, rtol=1e-12)
    assert np.allclose(A @ x, b) and 0 < it <= 48
    with pytest.raises(SolverError, match="did not reach"):
        pcg_constrained(A, b, rtol=1e-12, maxiter=3)
    with pytest.raises(InputError, match="3n"):
        pcg_constrained(sp.identity(5).tocsr(), np.ones(5))


def test_hanging_cloth_pins_carry_its_weight():
    m = grid((0.3, 0.3), (6, 6), plane="xz")
    top = np.flatnonzero(np.isclose(m.points[:, 2], 0.3))
    model = ClothModel(m, SOFT, handles=(Handle.pin(m.points, top),), mass_damping=2.0)
    scene = ClothScene(model, gravity=(0, 0, -9.81), linear_solver="splu")
    for _ in range(300):
        scene.step(0.01)
    free = np.setdiff1d(np.arange(m.point_count), top)
    f_el = -(model.membrane.gradient(scene.x) + model.bending.gradient(scene.x))
    weight = 9.81 * model.masses[free].sum()
    # free vertices in equilibrium; the pins' elastic forces carry the free part's weight
    assert np.abs(f_el[free] + model.masses[free, None] * [0, 0, -9.81]).max() < 1e-3 * weight
    assert np.isclose(-f_el[top, 2].sum(), weight, rtol=1e-3)


def test_twist_handles_follow_their_path_exactly():
    m = grid((0.2, 0.2), (5, 5))
    left = np.flatnonzero(np.isclose(m.points[:, 0], 0.0))
    right = np.flatnonzero(np.isclose(m.points[:, 0], 0.2))
    c = np.array([0.1, 0.1, 0.0])
    h = (Handle.pin(m.points, left), Handle.rotating(m.points, right, center=c, axis=(1, 0, 0), rate=2 * np.pi))
    scene = ClothScene(ClothModel(m, SOFT, handles=h))
    for _ in range(25):
        scene.step(0.02)
    assert np.allclose(scene.x[left], m.points[left])
    turned = m.points[right] - c
    assert np.allclose(scene.x[right, 1:] - c[1:], -turned[:, 1:], atol=1e-12)  # half a turn at t = 0.5 s
    assert np.all(np.isfinite(scene.x))


def test_bad_materials_and_steps():
    with pytest.raises(MaterialError, match="thickness"):
        ClothMaterial(areal_density=0.2, young=1e6, poisson=0.3, thickness=0.0)
    with pytest.raises(MaterialError, match="thickness"):
        ClothMaterial(areal_density=0.2, young=1e6, poisson=0.3, thickness=-1e-3)
    with pytest.raises(MaterialError, match="areal density"):
        ClothMaterial(areal_density=0.0, young=1e6, poisson=0.3, thickness=1e-3)
    with pytest.raises(MaterialError, match="Poisson"):
        ClothMaterial(areal_density=0.2, young=1e6, poisson=0.5, thickness=1e-3)
    scene = ClothScene(ClothModel(MESH, SOFT))
    with pytest.raises(SimulationError, match="time step"):
        scene.step(0.0)
    with pytest.raises(InputError, match="overlap"):
        ClothModel(MESH, SOFT, handles=(Handle.pin(MESH.points, [1, 2]), Handle.pin(MESH.points, [2])))
    with pytest.raises(InputError, match="collision config"):
        ClothScene(ClothModel(MESH, SOFT), obstacles=(object(),))


def test_contact_constraints_prescribe_normal_velocity_in_both_solvers():
    model = ClothModel(MESH, SOFT, handles=(Handle.pin(MESH.points, [0]),))
    rng = np.random.default_rng(4)
    x = MESH.points + 0.02 * rng.standard_normal(MESH.points.shape)
    v = 0.1 * rng.standard_normal(x.shape)
    f = np.tile([0.0, 0.0, -0.1], (MESH.point_count, 1))
    idx = np.array([7, 8, 20])
    nrm = rng.standard_normal((3, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    un = np.array([0.0, 0.2, -0.1])
    out = []
    for ls in ("splu", "cg"):
        s = ImplicitEuler(model, linear_solver=ls, cg_rtol=1e-12)
        vn, info = s.step_velocity(x, v, f, 0.01, fixed=[0], fixed_velocity=np.zeros((1, 3)), contacts=(idx, nrm, un))
        assert np.allclose(np.sum(vn[idx] * nrm, axis=1), un, atol=1e-12)
        assert np.allclose(vn[0], 0.0) and info.contact_impulses.shape == (3,)
        out.append((vn, info.contact_impulses))
    assert np.allclose(out[0][0], out[1][0], atol=1e-8)
    assert np.allclose(out[0][1], out[1][1], atol=1e-8 * np.abs(out[0][1]).max())


def _cloth_system(n=10, seed=5):
    """A cloth implicit-step matrix ``M + dt^2 K`` (3n, 3n) at a deformed state, with its solver."""
    m = grid((0.4, 0.4), (n, n))
    model = ClothModel(m, SOFT)
    rng = np.random.default_rng(seed)
    x = m.points * np.array([1.1, 0.95, 1.0]) + 0.005 * rng.standard_normal(m.points.shape)
    s = ImplicitEuler(model)
    K = s.stiffness(x)
    return s, (sp.diags(np.repeat(model.masses, 3)) + 1e-4 * K).tocsr(), model, x, rng


def test_stiffness_pattern_holds_the_energies_hessians_and_the_diagonal_blocks():
    s, _, model, x, _ = _cloth_system()
    K = s.stiffness(x).toarray()
    ref = (model.membrane.hessian(x) + model.bending.hessian(x)).toarray()
    assert np.allclose(K, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    n = model.mesh.point_count
    blocks = s._Kdata[s._pattern.diag]
    for i in (0, 7, n - 1):
        assert np.array_equal(blocks[i], K[3 * i:3 * i + 3, 3 * i:3 * i + 3])
    u = np.random.default_rng(2).standard_normal((n, 3))
    assert np.allclose(s._matvec(s._Kdata, u).reshape(-1), K @ u.reshape(-1), rtol=0, atol=1e-12 * np.abs(K).sum())


@pytest.mark.parametrize("threads", [1, 2])
def test_gathered_stiffness_and_gradients_are_the_serial_scatter_bit_for_bit(threads):
    # the parallel per-block gather adds the same element sub-blocks in the same order (triangles, then
    # hinges, each in element order) as a serial scatter over the elements: the same bits on any thread count
    from modalfem._threads import thread_count
    from modalfem.cloth import _energy_kernels, _kernels

    s, _, model, x, _ = _cloth_system(n=24)  # 576 vertices: the gather runs in 2 chunks
    pat = s._pattern
    ref = pat.zeros()
    _kernels.scatter_blocks(ref, pat.maps[0], model.membrane.hessian_blocks(x), 1.0)
    w, g = model.bending.gauss_newton_factors(x)
    _energy_kernels.scatter_outer(ref, pat.maps[1], w, g)
    with thread_count(threads):
        K = s._stiffness_data(x)
        A = s._scale_plus_diagonal(K, 0.37, s._m3 * 1.5)
    assert np.abs(ref).max() > 0 and np.array_equal(K, ref)
    with thread_count(threads):  # the gradients from the same pass, gathered per vertex: the serial scatter's bits
        grad_m = s._gather_rows(0, s._mgrads, s._m_ones)
        wg, _, gb = model.bending.angle_factors(x)
        grad_b = s._gather_rows(1, gb, wg)
    assert np.array_equal(grad_m, model.membrane.gradient(x)) and np.array_equal(grad_b, model.bending.gradient(x))
    ref_a = ref * 0.37
    pat.add_diagonal(ref_a, s._m3 * 1.5)
    assert np.array_equal(A, ref_a)


def test_filtered_cg_matches_a_direct_solve_with_handles_and_contacts():
    _, A, model, _, rng = _cloth_system()
    n = model.mesh.point_count
    b = rng.standard_normal(A.shape[0])
    ref = spla.spsolve(A.tocsc(), b)
    x, it = pcg_constrained(A, b, rtol=1e-10, maxiter=2000)
    assert np.allclose(x, ref, rtol=0, atol=1e-8 * np.abs(ref).max()) and it > 0
    # constraints: 3 fixed vertices with given values, 12 contacts with a prescribed normal component
    perm = rng.permutation(n)
    fixed, idx = perm[:3], perm[3:15]
    fval = rng.standard_normal((3, 3))
    nrm = rng.standard_normal((12, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    un = rng.standard_normal(12)
    # reference: eliminate the constrained components with an explicit basis of the free ones
    z = np.zeros((n, 3))
    z[fixed] = fval
    z[idx] = nrm * un[:, None]
    basis = []
    for i in range(n):
        if i in fixed:
            continue
        e = np.eye(3)
        if i in idx:
            nv = nrm[list(idx).index(i)]
            e = np.linalg.svd(np.eye(3) - np.outer(nv, nv))[0][:, :2]
        for c in range(e.shape[1]):
            col = np.zeros(3 * n)
            col[3 * i:3 * i + 3] = e[:, c]
            basis.append(col)
    Q = np.array(basis).T
    Ad = A.toarray()
    ref = z.reshape(-1) + Q @ np.linalg.solve(Q.T @ Ad @ Q, Q.T @ (b - Ad @ z.reshape(-1)))
    y, it = pcg_constrained(A, b, fixed=fixed, fixed_values=fval, contacts=(idx, nrm, un), rtol=1e-10,
                            maxiter=2000, x0=rng.standard_normal(3 * n))
    assert np.allclose(y, ref, rtol=0, atol=1e-8 * np.abs(ref).max()) and it > 0
    assert np.allclose(y.reshape(n, 3)[fixed], fval) and np.allclose(np.sum(y.reshape(n, 3)[idx] * nrm, 1), un)


def test_filtered_cg_with_whole_aggregates_constrained():
    # a fixed edge row and a patch of contacts sharing one normal make aggregation blocks singular (only
    # the prescribed components there): the multilevel preconditioner must still give the direct solution
    from modalfem.cloth.solver import _Levels

    s, A, model, _, rng = _cloth_system(n=20)
    n = model.mesh.point_count
    pts = model.mesh.points
    fixed = np.flatnonzero(np.isclose(pts[:, 1], 0.0))
    idx = np.flatnonzero((pts[:, 1] > 0.15) & (pts[:, 1] < 0.3) & (pts[:, 0] < 0.2))
    nrm = np.tile([0.0, 0.0, 1.0], (len(idx), 1))
    un = rng.standard_normal(len(idx))
    fval = rng.standard_normal((len(fixed), 3))
    lv = _Levels(s._pattern.indptr, s._pattern.indices)
    assert len(lv.off) > 2 and np.all(np.diff(lv.off) > 0)  # several levels, none empty
    b = rng.standard_normal(3 * n)
    y, it = pcg_constrained(A, b, fixed=fixed, fixed_values=fval, contacts=(idx, nrm, un), rtol=1e-10, maxiter=2000)
    free = np.ones((n, 3), bool)
    free[fixed] = False
    free[idx, 2] = False
    z = np.zeros((n, 3))
    z[fixed] = fval
    z[idx, 2] = un
    f, Ad = free.reshape(-1), A.toarray()
    ref = z.reshape(-1).copy()
    ref[f] += np.linalg.solve(Ad[np.ix_(f, f)], (b - Ad @ z.reshape(-1))[f])
    assert np.allclose(y, ref, rtol=0, atol=1e-8 * np.abs(ref).max()) and 0 < it < 100


def test_level_matrices_are_the_galerkin_products_on_any_thread_count():
    # the coarsest level's matrix P^T S A S P (P: piecewise-constant translations of the aggregates) and the
    # finer levels' diagonal blocks, summed in parallel chunks: the same bits on 1 and 2 threads
    from modalfem._threads import thread_count
    from modalfem.cloth import _kernels
    from modalfem.cloth.solver import _Levels

    s, A, model, _, rng = _cloth_system(n=24)  # 576 vertices: 2 chunks
    n = model.mesh.point_count
    pat = s._pattern
    data = np.ascontiguousarray(sp.bsr_matrix(A, blocksize=(3, 3)).data)
    kind = np.zeros(n, np.int8)
    normal = np.zeros((n, 3))
    kind[:24] = 2  # a fixed edge
    kind[100:140] = 1  # contacts
    normal[100:140] = rng.standard_normal((40, 3))
    normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    lv = _Levels(pat.indptr, pat.indices)
    B = sp.bsr_matrix(A, blocksize=(3, 3))
    assert np.array_equal(B.indptr, pat.indptr) and np.array_equal(B.indices, pat.indices)
    out = []
    for threads in (1, 2):
        with thread_count(threads):
            out.append(_kernels.level_matrices(pat.indptr, pat.indices, data, kind, normal, lv.agg, lv.up, lv.off))
    assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    S = np.zeros((n, 3, 3))
    S[kind == 0] = np.eye(3)
    c = kind == 1
    S[c] = np.eye(3) - normal[c][:, :, None] * normal[c][:, None, :]
    Sd = sp.block_diag(list(S)).toarray()
    g = lv.agg.copy()
    nd = lv.off[-2]
    while np.any(g < nd):
        g = np.where(g < nd, lv.up[np.minimum(g, nd - 1)], g)
    P = np.kron(np.eye(lv.off[-1] - nd)[g - nd], np.eye(3))
    ref = P.T @ Sd @ A.toarray() @ Sd @ P
    assert np.allclose(out[0][1], ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_cg_on_many_separate_pieces_uses_one_global_aggregate():
    # 200 separate two-vertex pieces: aggregation stalls at one aggregate per piece (more than COARSEST),
    # so the coarsest level becomes one aggregate of everything instead of a 600x600 dense solve
    from modalfem.cloth.solver import COARSEST, _Levels

    rng = np.random.default_rng(8)
    blocks = []
    for _ in range(200):
        Q = rng.standard_normal((6, 6))
        blocks.append(Q @ Q.T + 6 * np.eye(6))
    A = sp.block_diag(blocks, format="csr")
    B = sp.bsr_matrix(A, blocksize=(3, 3))
    lv = _Levels(B.indptr.astype(np.int64), B.indices.astype(np.int64))
    assert np.diff(lv.off)[-1] == 1 and np.diff(lv.off)[0] > COARSEST
    b = rng.standard_normal(A.shape[0])
    x, _ = pcg_constrained(A, b, rtol=1e-10, maxiter=500)
    assert np.allclose(x, spla.spsolve(A.tocsc(), b), rtol=0, atol=1e-8 * np.abs(x).max())
