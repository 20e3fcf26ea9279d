"""The tet solver on 1 and 2 threads: element Hessians and forces, assembly, CG products and whole Newton
steps give the same bits (elements and rows in chunks fixed by the problem size; each value summed by
one thread in a fixed order)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet.effects import Gravity, Pins, RayleighDamping
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetSolver, TetState
from modalfem._threads import thread_count

pytestmark = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")


def _run(threads: int, steps: int = 6, effects=(), **options):
    mesh = box(size=(0.8, 0.3, 0.2), cells=(16, 6, 4))  # 2304 tets: 18 element chunks, 13 row chunks
    model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    with thread_count(threads):
        solver = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0")), *effects], **options)
        state = TetState.at_rest(model)
        infos = [solver.step(state, state, 1.0 / 30.0) for _ in range(steps)]
    return model, state, infos


def test_newton_steps_are_bit_identical_on_one_and_two_threads():
    model, s1, i1 = _run(1)
    _, s2, i2 = _run(2)
    assert [(i.newton_iterations, i.linear_iterations) for i in i1] == [
        (i.newton_iterations, i.linear_iterations) for i in i2]
    assert sum(i.newton_iterations for i in i1) > len(i1)  # real Newton iterations, not one linear solve
    np.testing.assert_array_equal(s1.x, s2.x)
    np.testing.assert_array_equal(s1.v, s2.v)
    sag = model.rest_points[:, 2] - s1.x[:, 2]
    assert sag.max() > 1e-3  # the bar sagged under gravity: the steps did work


@pytest.mark.parametrize("options", [
    {"preconditioner": "jacobi"},  # the CG's Jacobi-only passes
    {"projection": "always", "coarse_lag": 1},  # projected Hessians, a coarse space rebuilt every solve
    {"effects": (RayleighDamping(alpha=0.5, beta=0.01),), "newton_max": 1},  # damping matrix K(x_n)
], ids=["jacobi", "projected", "damped-linearised"])
def test_other_solver_paths_are_bit_identical_on_one_and_two_threads(options):
    _, s1, i1 = _run(1, 4, **options)
    _, s2, i2 = _run(2, 4, **options)
    assert [i.linear_iterations for i in i1] == [i.linear_iterations for i in i2]
    np.testing.assert_array_equal(s1.x, s2.x)
    np.testing.assert_array_equal(s1.v, s2.v)


def test_svd_of_positions_is_the_svd_of_the_deformation_gradients():
    from modalfem.tet import kinematics as kin

    mesh = box(size=(0.8, 0.3, 0.2), cells=(16, 6, 4))
    model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    rng = np.random.default_rng(2)
    x = model.rest_points + 0.02 * rng.standard_normal(model.rest_points.shape)
    x[:40] = x[40]  # some degenerate (collapsed) elements too
    gt = np.ascontiguousarray(np.moveaxis(model.grad, 0, -1))
    F = kin.deformation_gradient_t(x, model.cells, gt)
    for V0 in (None, kin.svd_rv_t(F)[2]):
        ref = kin.svd_rv_t(F, V0)
        for t in (1, 2):
            with thread_count(t):
                got = kin.svd_rv_of_positions(x, model.cells, gt, V0)
            for a, b in zip(got, ref):
                np.testing.assert_array_equal(a, b)
