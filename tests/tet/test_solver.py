"""Backward Euler solver of the tet module: gravity, ground contact, pins and scripted vertices, Rayleigh
damping, Newton convergence, linear solvers; opt-in terms are never evaluated unless asked for; bad
input fails before stepping with one clear error."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.errors import InputError, MaterialError, MeshError, SimulationError
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.mesh.core import signed_volumes
from modalfem.tet import effects as fx
from modalfem.tet import energies
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetControl, TetSolver, TetState

SOFT = Material(E=1e5, nu=0.3, rho=1000.0)


@pytest.fixture(scope="module")
def model():
    return tet_model(box(size=(0.1, 0.1, 0.1), cells=(2, 2, 2)), SOFT)


def test_free_fall_is_exact_backward_euler(model):
    g = np.array([0.0, 0.0, -9.81])
    solver = TetSolver(model, effects=[fx.Gravity(tuple(g))], cg_rtol=1e-12, tol=1e-12)
    s = TetState.at_rest(model)
    s.v[:] = [0.3, 0.0, 1.0]
    x, v, h = s.x.copy(), s.v.copy(), 0.01
    for _ in range(5):
        solver.step(s, s, h)
        v = v + h * g
        x = x + h * v
    np.testing.assert_allclose(s.v, v, atol=1e-9)
    np.testing.assert_allclose(s.x, x, atol=1e-11)
    assert s.t == pytest.approx(0.05)


@pytest.mark.parametrize("energy", ["stable", "corotated"])
def test_rigid_motions_cost_nothing(energy):
    m = tet_model(box(size=(0.1, 0.1, 0.1), cells=(2, 2, 2)), SOFT, energy=energy)
    solver = TetSolver(m)
    th = 2.5
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1.0]])
    E, g, _ = solver._elastic(m.rest_points @ R.T + 1.0, 1)
    assert abs(E) < 1e-20 and np.abs(g).max() < 1e-9


def test_body_comes_to_rest_on_the_ground(model):
    k = 1e5
    solver = TetSolver(model, effects=[fx.Gravity(), fx.Ground(height=0.0, stiffness=k),
                                       fx.RayleighDamping(alpha=10.0)])
    s = TetState.at_rest(model)
    s.x[:, 2] += 0.05  # 5 cm above the ground
    for _ in range(150):
        solver.step(s, s, 0.01)
    assert np.abs(s.v).max() < 1e-3
    weight = model.masses.sum() * 9.81
    reaction = k * np.sum(np.maximum(-s.x[:, 2], 0.0))
    assert reaction == pytest.approx(weight, rel=1e-3)  # static equilibrium: the ground carries the weight
    assert s.x[:, 2].min() > -2 * weight / k


def test_pins_and_scripted_vertices_are_exact(model):
    mesh = model.mesh
    x0, x1 = mesh.tag_points("x0"), mesh.tag_points("x1")
    solver = TetSolver(model, effects=[fx.Pins(x0), fx.Gravity()])
    s = TetState.at_rest(model)
    for i in range(10):
        target = mesh.points[x1] + [0.002 * (i + 1), 0.0, 0.0]
        solver.step(s, s, 0.01, control=TetControl(x1, target))
        np.testing.assert_array_equal(s.x[x0], mesh.points[x0])
        np.testing.assert_allclose(s.x[x1], target, atol=1e-15)
    free = np.setdiff1d(np.arange(model.point_count), np.union1d(x0, x1))
    assert np.abs(s.x[free] - mesh.points[free]).max() > 1e-4  # the rest of the body followed


def test_newton_solves_the_incremental_potential(model):
    solver = TetSolver(model, effects=[fx.Gravity()], newton_max=30, tol=1e-12, cg_rtol=1e-12)
    s = TetState.at_rest(model)
    s.x[:, 2] *= 0.5
    s.v[:] = np.random.default_rng(0).normal(0, 0.1, s.v.shape)
    xn, vn, h = s.x.copy(), s.v.copy(), 0.02
    info = solver.step(s, s, h)
    assert info.converged and info.newton_iterations > 1
    _, grad, _ = solver._incremental(s.x, xn, xn + h * vn, h, None, 1)
    scale = np.abs(solver._incremental(xn, xn, xn + h * vn, h, None, 1)[1]).max()
    assert np.abs(grad).max() < 1e-8 * scale


@pytest.mark.parametrize("linear_solver", ["splu", "spsolve"])
def test_linear_solvers_agree(model, linear_solver):
    out = []
    for ls in ("cg", linear_solver):
        solver = TetSolver(model, effects=[fx.Gravity()], linear_solver=ls, cg_rtol=1e-12, newton_max=1)
        s = TetState.at_rest(model)
        s.x[:, 0] *= 1.3
        solver.step(s, s, 0.01)
        out.append(s.x)
    np.testing.assert_allclose(out[0], out[1], atol=1e-12)


def test_rayleigh_damping_dissipates(model):
    def energy_after(effects):
        solver = TetSolver(model, effects=effects)
        s = TetState.at_rest(model)
        s.x[:, 0] *= 1.2
        for _ in range(20):
            solver.step(s, s, 0.001)
        return solver.energies(s)["total"]

    free = energy_after([])  # underdamped: both dampings take energy out faster than backward Euler alone
    assert energy_after([fx.RayleighDamping(alpha=20.0)]) < 0.8 * free
    assert energy_after([fx.RayleighDamping(beta=1e-3)]) < 0.5 * free


def test_volume_terms_resist_compression(model):
    def volume_after(effects):
        solver = TetSolver(model, effects=effects)
        s = TetState.at_rest(model)
        top = model.rest_points[:, 2] > 0.1 - 1e-9
        for i in range(5):
            pos = model.rest_points[top] - [0, 0, 0.01 * (i + 1)]
            solver.step(s, s, 0.01, control=TetControl(np.flatnonzero(top), pos))
        return signed_volumes(s.x, model.cells).sum()

    pins = fx.Pins(np.flatnonzero(model.rest_points[:, 2] < 1e-9))
    plain = volume_after([pins])
    assert volume_after([pins, fx.VolumeSprings(1e6)]) > plain
    assert volume_after([pins, fx.VolumeBarrier(1e6)]) > plain


# ---------------------------------------------------------------------- only what is asked for runs
def _spy(monkeypatch, cls, name, calls):
    original = getattr(cls, name)

    def wrapped(self, *a, **k):
        calls.append(cls.__name__)
        return original(self, *a, **k)

    monkeypatch.setattr(cls, name, wrapped)


def test_terms_are_opt_in(model, monkeypatch):
    calls: list[str] = []
    for cls, name in [(energies.VolumeSpringDensity, "derivs"), (energies.VolumeBarrierDensity, "derivs"),
                      (fx.Gravity, "energy"), (fx.Gravity, "gradient"), (fx.Ground, "energy"),
                      (fx.Ground, "gradient")]:
        _spy(monkeypatch, cls, name, calls)
    damping_calls = []
    original = TetSolver._elastic

    def spy_elastic(self, x, order, **kwargs):
        damping_calls.append(order)
        return original(self, x, order, **kwargs)

    monkeypatch.setattr(TetSolver, "_elastic", spy_elastic)
    s = TetState.at_rest(model)
    s.x[:, 0] *= 1.1
    TetSolver(model, newton_max=1).step(s, s.copy(), 0.01)
    assert calls == []
    assert damping_calls.count(2) == 1  # one Hessian (the Newton step), no extra damping Hessian
    for effect, expected in [(fx.VolumeSprings(1e4), "VolumeSpringDensity"),
                             (fx.VolumeBarrier(1e4), "VolumeBarrierDensity"),
                             (fx.Gravity(), "Gravity"), (fx.Ground(height=0.05), "Ground")]:
        calls.clear()
        TetSolver(model, effects=[effect], newton_max=1).step(s, s.copy(), 0.01)
        assert set(calls) == {expected}
    damping_calls.clear()
    TetSolver(model, effects=[fx.RayleighDamping(beta=1e-3)], newton_max=1).step(s, s.copy(), 0.01)
    assert damping_calls.count(2) == 2  # the damping matrix needs the Hessian at x_n


# ---------------------------------------------------------------------- bad input
def test_zero_volume_rest_element_is_rejected():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0], [0, 0, 1.0]])
    with pytest.raises(MeshError, match="zero volume"):
        tet_model((pts, [[0, 1, 2, 4], [0, 1, 2, 3]]), SOFT)


@pytest.mark.parametrize("energy", ["corotated", "stable"])
def test_incompressible_nu_is_rejected(energy):
    mesh = box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1))
    with pytest.raises(MaterialError, match="nu = 0.5 >= 0.5"):
        tet_model(mesh, {"E": 1e5, "nu": 0.5, "rho": 1000.0}, energy=energy)
    with pytest.raises(MaterialError):
        tet_model(mesh, {"E": 1e5, "nu": 0.7, "rho": 1000.0}, energy=energy)


def test_bad_model_arguments():
    mesh = box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1))
    with pytest.raises(InputError, match="unknown tet energy"):
        tet_model(mesh, SOFT, energy="neo")
    with pytest.raises(InputError, match="missing"):
        tet_model(mesh, {"E": 1e5, "nu": 0.3})
    m = tet_model(mesh, SOFT)
    with pytest.raises(InputError, match="linear solver"):
        TetSolver(m, linear_solver="amg")
    with pytest.raises(InputError, match="unknown tet effect"):
        TetSolver(m, effects=["gravity"])
    with pytest.raises(InputError, match="out of range"):
        TetSolver(m, effects=[fx.Pins([0, 99])])
    with pytest.raises(InputError):
        fx.Ground(stiffness=-1.0)
    with pytest.raises(InputError):
        fx.RayleighDamping(alpha=float("nan"))


@pytest.mark.parametrize("what", ["x_nan", "v_inf", "dt_zero", "dt_nan", "dt_negative", "shape", "control"])
def test_bad_state_fails_before_stepping(model, what):
    solver = TetSolver(model)
    s = TetState.at_rest(model)
    dt = 0.01
    control = None
    if what == "x_nan":
        s.x[3, 1] = np.nan
    elif what == "v_inf":
        s.v[0, 0] = np.inf
    elif what == "dt_zero":
        dt = 0.0
    elif what == "dt_nan":
        dt = float("nan")
    elif what == "dt_negative":
        dt = -0.1
    elif what == "shape":
        s.x = s.x[:-1]
    else:
        control = TetControl(np.array([0, 1]), np.array([[0.0, 0.0, np.nan], [0, 0, 0]]))
    before = s.copy() if what != "shape" else None
    out = TetState.at_rest(model)
    with pytest.raises(SimulationError):
        solver.step(s, out, dt, control=control)
    if before is not None:
        np.testing.assert_array_equal(out.x, model.rest_points)  # nothing written


def test_barrier_refuses_inverted_start(model):
    solver = TetSolver(model, effects=[fx.VolumeBarrier(1e4)])
    s = TetState.at_rest(model)
    s.x[:, 2] *= -1.0  # every element inverted
    with pytest.raises(SimulationError, match="VolumeBarrier"):
        solver.step(s, s, 0.01)


def test_step_caches_do_not_change_the_result(model):
    """The SVD kept from the line search, the CG warm start and the lagged coarse space are caches: a
    solver stepping on (caches warm) matches a fresh solver per step (cold), and a state changed between
    steps is not mistaken for the cached one."""
    effects = [fx.Gravity(), fx.Pins(np.flatnonzero(model.rest_points[:, 0] < 1e-9))]
    warm = TetSolver(model, effects=effects, newton_max=1, linear_solver="splu")
    a = TetState.at_rest(model)
    b = TetState.at_rest(model)
    for k in range(6):
        if k == 3:  # an outside change of the positions between steps
            a.x[:, 2] += 1e-3
            b.x[:, 2] += 1e-3
        warm.step(a, a, 0.01)
        TetSolver(model, effects=effects, newton_max=1, linear_solver="splu").step(b, b, 0.01)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    cg = TetSolver(model, effects=effects, newton_max=1, cg_rtol=1e-12)
    c = TetState.at_rest(model)
    for _ in range(6):
        cg.step(c, c, 0.01)
    d = TetState.at_rest(model)
    direct = TetSolver(model, effects=effects, newton_max=1, linear_solver="splu")
    for _ in range(6):
        direct.step(d, d, 0.01)
    np.testing.assert_allclose(c.x, d.x, rtol=0, atol=1e-10)


@pytest.mark.parametrize("linear_solver, preconditioner", [("cg", "twolevel"), ("cg", "jacobi"), ("splu", "jacobi")])
def test_a_fully_pinned_body_follows_its_pins(model, linear_solver, preconditioner):
    """Every vertex held (Pins) or scripted (TetControl): nothing is free, the step is valid and trivial:
    the body is where its pins put it and v = (x_target - x_n) / h (before: ZeroDivisionError in CG)."""
    n = model.point_count
    everything = np.arange(n)
    solver = TetSolver(model, effects=[fx.Gravity(), fx.Pins(everything)], linear_solver=linear_solver,
                       preconditioner=preconditioner)
    s = TetState.at_rest(model)
    info = solver.step(s, s, 0.01)
    assert info.converged and info.newton_iterations == 0
    np.testing.assert_array_equal(s.x, model.rest_points)
    assert not s.v.any()
    # scripted: a rigid translation by (0, 0, 1 mm) per step
    solver = TetSolver(model, effects=[fx.Gravity()], linear_solver=linear_solver, preconditioner=preconditioner)
    s = TetState.at_rest(model)
    for k in range(1, 4):
        target = model.rest_points + [0.0, 0.0, 1e-3 * k]
        solver.step(s, s, 0.01, control=TetControl(everything, target))
        np.testing.assert_allclose(s.x, target, rtol=0, atol=1e-15)
        np.testing.assert_allclose(s.v, np.tile([0.0, 0.0, 0.1], (n, 1)), rtol=1e-12)


def test_a_pinned_body_minus_one_vertex_still_solves(model):
    """The other edge of the class: one free vertex (a 3-DOF system) falls under gravity by the exact
    backward Euler of its spring to the pinned rest: it moves down, no division by an empty set."""
    n = model.point_count
    solver = TetSolver(model, effects=[fx.Gravity(), fx.Pins(np.arange(1, n))])
    s = TetState.at_rest(model)
    solver.step(s, s, 0.01)
    assert s.x[0, 2] < model.rest_points[0, 2] and np.array_equal(s.x[1:], model.rest_points[1:])


@pytest.mark.parametrize("what, message", [
    ("x_nan", r"state positions x has 1 non-finite values, first at vertex 3"),
    ("control_nan", r"control positions have 1 non-finite values, first at row 1"),
    ("control_range", r"control vertex 99 out of range \[0, 27\)"),
    ("control_shape", r"control positions must have shape \(2, 3\).*got \(3, 3\)"),
    ("control_float", r"control vertices must be a 1-D array of integer indices"),
])
def test_bad_step_inputs_say_what_is_wrong(model, what, message):
    solver = TetSolver(model)
    s = TetState.at_rest(model)
    control = None
    if what == "x_nan":
        s.x[3, 1] = np.nan
    elif what == "control_nan":
        control = TetControl(np.array([0, 1]), np.array([[0.0, 0.0, 0.0], [0, np.inf, 0]]))
    elif what == "control_range":
        control = TetControl(np.array([0, 99]), np.zeros((2, 3)))
    elif what == "control_shape":
        control = TetControl(np.array([0, 1]), np.zeros((3, 3)))
    else:
        control = TetControl(np.array([0.5, 1.0]), np.zeros((2, 3)))
    before = s.x.copy()
    with pytest.raises(SimulationError, match=message):
        solver.step(s, s, 0.01, control=control)
    np.testing.assert_array_equal(s.x, before)


def _bent_bar_steps(projection: str, steps: int, tol: float):
    mesh = box(size=(0.6, 0.1, 0.1), cells=(12, 2, 2))
    m = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    solver = TetSolver(m, effects=[fx.Gravity(), fx.Pins(mesh.tag_points("x0"))], projection=projection,
                       tol=tol, cg_rtol=1e-10)
    s = TetState.at_rest(m)
    infos = [solver.step(s, s, 1.0 / 30.0) for _ in range(steps)]
    return m, s, infos


def test_exact_hessians_reach_the_projected_minimiser_in_fewer_newton_iterations():
    """A clamped bar bending under gravity: its compressed side has negative geometric stiffness, which
    projection clamps (linear convergence); the exact Hessians (``on_demand``) converge quadratically to the
    same positions. Each step stops within about ``tol * size`` of its minimiser (less: the last update is
    taken), and an error carried by the velocity grows at most linearly per step, so after k steps the two
    runs differ by at most ~k^2 tol size each."""
    steps, tol = 5, 1e-8
    m, exact, i_exact = _bent_bar_steps("on_demand", steps, tol)
    _, proj, i_proj = _bent_bar_steps("always", steps, tol)
    assert all(i.converged for i in i_exact + i_proj)
    assert not any(i.projected for i in i_exact) and all(i.projected for i in i_proj)
    assert sum(i.newton_iterations for i in i_exact) < sum(i.newton_iterations for i in i_proj)
    sag = m.rest_points[:, 2] - exact.x[:, 2]
    assert sag.max() > 100 * steps**2 * tol * m.size  # the difference bound below is far below the motion
    np.testing.assert_allclose(exact.x, proj.x, rtol=0, atol=2 * steps**2 * tol * m.size)


def test_indefinite_exact_hessians_fall_back_to_projected_ones(model):
    """Strongly compressed and with a long step (little inertia), the exact Hessians are indefinite: the
    step redoes its iteration with projected ones and ends where ``projection="always"`` ends."""
    out = {}
    for projection in ("on_demand", "always"):
        s = TetState.at_rest(model)
        s.x[:, 0] *= 0.4
        s.x[:, 1] *= 0.7
        solver = TetSolver(model, projection=projection, tol=1e-10, cg_rtol=1e-10, newton_max=50)
        info = solver.step(s, s, 1.0)
        assert info.converged and info.projected
        out[projection] = s.x
    np.testing.assert_allclose(out["on_demand"], out["always"], rtol=0, atol=4e-10 * model.size)


def test_reused_matrix_iterations_reach_the_same_positions(model, monkeypatch):
    """Iterations solving with the previous iteration's matrix (``REUSE_BELOW``) end within the Newton
    tolerance of steps that assemble a fresh Hessian every iteration."""
    from modalfem.tet import solver as solver_module

    out = {}
    for below in (solver_module.REUSE_BELOW, 0.0):
        monkeypatch.setattr(solver_module, "REUSE_BELOW", below)
        s = TetState.at_rest(model)
        s.v[:, 2] = np.linspace(-1.0, 1.0, len(s.v))  # a shearing start
        solver = TetSolver(model, effects=[fx.Gravity()], tol=1e-9, cg_rtol=1e-10)
        calls = []

        def counted(*a, calls=calls, orig=solver._resolve):
            calls.append(1)
            return orig(*a)

        monkeypatch.setattr(solver, "_resolve", counted)
        infos = [solver.step(s, s, 0.01) for _ in range(4)]
        assert all(i.converged for i in infos)
        assert (len(calls) > 0) == (below > 0)
        out[below] = s.x
    a, b = out.values()
    np.testing.assert_allclose(a, b, rtol=0, atol=2 * 4**2 * 1e-9 * model.size)


def test_bad_projection_is_refused(model):
    with pytest.raises(InputError, match="projection"):
        TetSolver(model, projection="sometimes")


def test_looser_early_solves_reach_the_same_positions_with_fewer_cg_iterations():
    """Newton iterations that later ones correct solve to ``cg_rtol_far``; the step still ends within its
    tolerance of the steps whose every solve uses ``cg_rtol`` (bound as in the projection test)."""
    mesh = box(size=(0.6, 0.1, 0.1), cells=(12, 2, 2))
    m = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    steps, tol, out = 5, 1e-8, {}
    for far in (None, 1e-6):
        solver = TetSolver(m, effects=[fx.Gravity(), fx.Pins(mesh.tag_points("x0"))], tol=tol, cg_rtol=1e-6,
                           cg_rtol_far=far)
        s = TetState.at_rest(m)
        infos = [solver.step(s, s, 1.0 / 30.0) for _ in range(steps)]
        assert all(i.converged for i in infos)
        out[far] = (s.x, sum(i.linear_iterations for i in infos))
    assert TetSolver(m, cg_rtol=1e-6).cg_rtol_far == pytest.approx(3e-5)
    assert out[None][1] < out[1e-6][1]
    np.testing.assert_allclose(out[None][0], out[1e-6][0], rtol=0, atol=2 * steps**2 * tol * m.size)
    with pytest.raises(InputError, match="cg_rtol_far"):
        TetSolver(m, cg_rtol_far=0.0)
