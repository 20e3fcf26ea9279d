"""ClothScene composition: opt-in effects, stage (d) smoothing and its re-check, with a stub pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel
from modalfem.cloth.scene import ClothScene
from modalfem.cloth.solver import ImplicitEuler
from modalfem.errors import InputError, SimulationError

MESH = grid((0.4, 0.4), (7, 7))
MAT = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)


class _Stats:
    def __init__(self, touched, unresolved=0):
        self.touched, self.unresolved, self.seconds, self.zone_sizes = touched, unresolved, {}, []


class StubPipeline:
    """Stands in for CollisionPipeline: stops vertex 24 (the middle) from moving down; records calls."""

    class config:
        thickness, friction = 1e-3, 0.0

    def __init__(self, unresolved=0):
        self.calls, self.unresolved = [], unresolved

    def resolve(self, x0, v, masses, dt, *, t=0.0):
        self.calls.append(v.copy())
        out = v.copy()
        out[24, 2] = max(out[24, 2], 0.0)
        touched = np.zeros(len(v), bool)
        touched[24] = out[24, 2] != v[24, 2]
        return out, _Stats(touched, self.unresolved)


def test_smoothing_keeps_momentum_and_spreads_the_change():
    model = ClothModel(MESH, MAT)
    s = ImplicitEuler(model)
    s.stiffness(MESH.points * 1.01)
    dv = np.zeros((MESH.point_count, 3))
    dv[24, 2] = 1.0
    sm = s.smooth(dv, 0.01, strength=0.05)
    assert np.allclose(model.masses @ sm, model.masses @ dv)
    assert sm[24, 2] < 1.0 and np.count_nonzero(np.abs(sm[:, 2]) > 1e-6) > 1
    assert s.smooth(dv, 0.01, strength=0.0) is dv


@pytest.mark.parametrize("linear_solver", ["splu", "cg"])
def test_smoothing_with_fixed_vertices_solves_its_system(linear_solver, monkeypatch):
    from modalfem.cloth import solver as solver_module

    monkeypatch.setattr(solver_module, "SMOOTH_RTOL", 1e-8)  # the system, solved tightly
    model = ClothModel(MESH, MAT)
    s = ImplicitEuler(model, linear_solver=linear_solver, cg_rtol=1e-8)
    K = s.stiffness(MESH.points * 1.01).toarray()
    dv = np.random.default_rng(3).standard_normal((MESH.point_count, 3))
    fixed = np.array([0, 6, 30])
    sm = s.smooth(dv, 0.01, strength=0.05, fixed=fixed)
    free = np.setdiff1d(np.arange(MESH.point_count), fixed)
    f = (3 * free[:, None] + np.arange(3)).reshape(-1)
    m3 = np.repeat(model.masses, 3)
    ref = np.zeros(3 * MESH.point_count)
    ref[f] = np.linalg.solve(np.diag(m3[f]) + 0.01 * 0.05 * K[np.ix_(f, f)], (m3 * dv.reshape(-1))[f])
    tol = 1e-10 if linear_solver == "splu" else 3e-6  # CG to the relative residual 1e-8
    assert np.allclose(sm.reshape(-1), ref, rtol=0, atol=tol * np.abs(ref).max())
    assert np.all(sm[fixed] == 0.0)


def test_smoothing_starts_from_the_last_answer_and_still_solves_its_system(monkeypatch):
    from modalfem.cloth import solver as solver_module

    monkeypatch.setattr(solver_module, "SMOOTH_RTOL", 1e-8)
    model = ClothModel(MESH, MAT)
    s = ImplicitEuler(model, cg_rtol=1e-8)
    K = s.stiffness(MESH.points * 1.01).toarray()
    rng = np.random.default_rng(4)
    dv = rng.standard_normal((MESH.point_count, 3))
    m3 = np.repeat(model.masses, 3)
    A = np.diag(m3) + 0.01 * 0.05 * K
    s.smooth(dv, 0.01, strength=0.05)
    cold = s.smooth_iterations
    assert cold > 0
    s.smooth(dv, 0.01, strength=0.05)  # the same change again: its start is the answer
    assert s.smooth_iterations < cold
    dv2 = dv + 0.1 * rng.standard_normal(dv.shape)  # a nearby change: fewer iterations, the same tolerance
    sm = s.smooth(dv2, 0.01, strength=0.05)
    assert s.smooth_iterations < cold
    ref = np.linalg.solve(A, m3 * dv2.reshape(-1))
    assert np.allclose(sm.reshape(-1), ref, rtol=0, atol=3e-6 * np.abs(ref).max())


def _scene(pipeline, smoothing):
    sc = ClothScene(ClothModel(MESH, MAT), gravity=(0, 0, -9.81), smoothing=smoothing)
    sc.pipeline = pipeline
    sc._pinned_masses = sc.model.masses.copy()
    return sc


def test_smoothed_velocities_go_through_the_pipeline_again():
    stub = StubPipeline()
    sc = _scene(stub, 0.05)
    st = sc.step(0.01)
    assert len(stub.calls) == 2 and st.recheck is not None and st.smooth_iterations > 0
    assert sc.v[24, 2] >= 0.0  # the stub's constraint holds after the re-check
    # neighbours of the stopped vertex were slowed too (smoothing), unlike without smoothing
    stub0 = StubPipeline()
    sc0 = _scene(stub0, 0.0)
    sc0.step(0.01)
    assert len(stub0.calls) == 1
    assert sc.v[23, 2] > sc0.v[23, 2]


def test_unresolved_collisions_raise():
    sc = _scene(StubPipeline(unresolved=3), 0.0)
    with pytest.raises(SimulationError, match="3 colliding pairs"):
        sc.step(0.01)


def test_only_requested_effects_act():
    sc = ClothScene(ClothModel(MESH, MAT))
    sc.step(0.01)
    assert np.abs(sc.v).max() < 1e-12 and sc.pipeline is None  # rest state, no forces
    with pytest.raises(InputError, match="gravity"):
        ClothScene(ClothModel(MESH, MAT), gravity=(0, -9.81))
    with pytest.raises(InputError, match="smoothing"):
        ClothScene(ClothModel(MESH, MAT), smoothing=-1.0)
    with pytest.raises(InputError, match="wind"):
        ClothScene(ClothModel(MESH, MAT), wind=(1, 0, 0))


class FlakyRecheck(StubPipeline):
    """Resolves the first call; reports an unresolved pair on the second (the re-check)."""

    def resolve(self, x0, v, masses, dt, *, t=0.0):
        out, st = super().resolve(x0, v, masses, dt, t=t)
        st.unresolved = int(len(self.calls) % 2 == 0)
        return out, st


def test_a_failed_recheck_keeps_the_unsmoothed_collision_free_answer():
    stub = FlakyRecheck()
    sc = _scene(stub, 0.05)
    sc.step(0.01)
    assert len(stub.calls) == 2
    first = stub.calls[0].copy()
    first[24, 2] = max(first[24, 2], 0.0)
    assert np.array_equal(sc.v, first)
