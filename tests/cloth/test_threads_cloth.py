"""The cloth pile on 1 and 2 threads: the same positions to the last bit (every parallel loop splits its
work in chunks fixed by the problem size and adds partial sums in chunk order), and no intersection."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem.cloth import scenes
from modalfem._threads import thread_count

pytestmark = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")


def _pile(threads: int, n: int, steps: int):
    with thread_count(threads):
        setup = scenes.pile(n)
        cg, zones = [], 0
        for _ in range(steps):
            st = setup.scene.step(setup.dt)
            cg.append(st.linear.iterations)
            zones += len(st.collision.zone_sizes) if st.collision is not None else 0
        return setup, np.array(setup.scene.x), cg, zones


def test_pile_is_bit_identical_on_one_and_two_threads_and_intersection_free():
    # 24 x 24 = 576 vertices: the CG passes run in 2 chunks; the pile's first layers meet by step 30, so
    # the pair expansion, CCD and contact frames see hundreds to thousands of pairs (several chunks)
    one, x1, cg1, zones1 = _pile(1, 24, 40)
    two, x2, cg2, zones2 = _pile(2, 24, 40)
    assert cg1 == cg2 and zones1 == zones2
    np.testing.assert_array_equal(x1, x2)
    assert np.isfinite(x2).all()
    assert x2[:, 2].min() < x1[:, 2].max() - 0.05  # it fell and folded: not a trivial state
    assert scenes.intersections(one) == 0 and scenes.intersections(two) == 0


def test_pile_with_repulsion_sweeps_in_parallel_groups_is_bit_identical(monkeypatch):
    # the 24 x 24 pile has up to ~900 repulsion pairs, one group at the default GROUP_PAIRS: with 64 pairs per
    # group its sweeps run groups of one colour in parallel (checked), and still give the same bits on 1 and 2
    # threads (groups of one colour share no cloth vertex)
    from modalfem.collision import _impulse_kernels, _stages

    monkeypatch.setattr(_impulse_kernels, "GROUP_PAIRS", 64)
    widest = []
    sweeps = _stages.sequential_pair_impulses

    def spy(*args, **kw):
        widest.append(int(np.diff(kw["order"].cptr).max()))
        return sweeps(*args, **kw)

    monkeypatch.setattr(_stages, "sequential_pair_impulses", spy)
    one, x1, cg1, zones1 = _pile(1, 24, 40)
    two, x2, cg2, zones2 = _pile(2, 24, 40)
    assert max(widest) >= 4  # groups of one colour in parallel
    assert cg1 == cg2 and zones1 == zones2
    np.testing.assert_array_equal(x1, x2)
    assert scenes.intersections(one) == 0 and scenes.intersections(two) == 0


def _drape(threads: int, n: int, steps: int, preconditioner: str = "sgs"):
    with thread_count(threads):
        setup = scenes.drape(n)
        setup.scene.solver.cg_preconditioner = preconditioner
        its = []
        for _ in range(steps):
            st = setup.scene.step(setup.dt)
            its.append((st.linear.iterations, st.smooth_iterations))
        return setup, np.array(setup.scene.x), its


@pytest.mark.parametrize("preconditioner", ["sgs", "sgs-blocks", "multilevel"])
def test_drape_solver_is_bit_identical_on_one_and_two_threads(preconditioner):
    # 40 x 40 = 1600 vertices: the stiffness gather and the CG's parallel passes run in 7 chunks, the level
    # matrices in 4 (multilevel; the natural-order SGS sweeps are serial, its residual checks chunked; the block
    # multicolour sweeps run 3 groups per colour in parallel); the sheet lands on the
    # ball (contact constraints with varying normals in the implicit solve, then smoothing of the collision
    # response with its re-check)
    one, x1, its1 = _drape(1, 40, 25, preconditioner)
    two, x2, its2 = _drape(2, 40, 25, preconditioner)
    assert its1 == its2
    assert sum(s for _, s in its1) > 0  # the smoothing solve ran
    np.testing.assert_array_equal(x1, x2)
    assert scenes.intersections(one) == 0 and scenes.intersections(two) == 0


@pytest.mark.parametrize("preconditioner", ["sgs", "sgs-blocks", "sgs-colours"])
def test_multicolour_sgs_solve_is_bit_identical_on_one_and_two_threads(preconditioner):
    # a 64 x 64 sheet (4096 vertices): the block multicolour sweeps run 8 groups per colour in parallel, the vertex
    # multicolour ones 2 chunks of each of their colours; a stiff system with handles and contacts
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothModel
    from modalfem.cloth.solver import ImplicitEuler, _constraints

    m = grid((1.0, 1.0), (64, 64))
    rng = np.random.default_rng(5)
    s = ImplicitEuler(ClothModel(m, scenes.MATERIAL))
    x = m.points * np.array([1.05, 0.97, 1.0]) + 0.003 * rng.standard_normal(m.points.shape)
    s.stiffness(x)
    data = s._scale_plus_diagonal(s._Kdata, 1e-2, np.repeat(s.model.masses, 3))
    n = m.point_count
    idx = rng.permutation(n)[:300]
    nrm = rng.standard_normal((300, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    contacts = (idx[5:], nrm[5:], rng.standard_normal(295))
    kind, normal, z = _constraints(n, idx[:5], rng.standard_normal((5, 3)), contacts)
    b = rng.standard_normal((n, 3))
    setup = s._setup(preconditioner)
    if preconditioner != "sgs":
        assert np.diff(setup.cptr).max() >= 2  # some colour really runs in parallel
    out = []
    for threads in (1, 2):
        with thread_count(threads):
            y, it, _ = s._solve(data, b, kind, normal, z, preconditioner=preconditioner)
            out.append((y, it))
    assert out[0][1] == out[1][1] > 0
    np.testing.assert_array_equal(out[0][0], out[1][0])
