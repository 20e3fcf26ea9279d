"""Stability suite of the tetrahedral soft body (backward Euler, ``energy="stable"`` unless stated).

Every case asserts: no NaN/inf, every element with positive volume at the end, total energy (kinetic +
elastic + potentials) non-increasing step by step where no work is done (relative slack 1e-9 of the
initial energy), and the rest shape recovered up to a rigid motion: RMS vertex distance after optimal
rotation + translation below ``SHAPE_TOL`` of the body's diagonal.
"""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.material import Material
from modalfem.mesh import box
from modalfem.mesh.core import Mesh, signed_volumes
from modalfem.tet.effects import Pins, RayleighDamping
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetControl, TetSolver, TetState

SOFT = Material(E=1e5, nu=0.3, rho=1000.0)
SHAPE_TOL = 1e-3


def shape_error(x: np.ndarray, X: np.ndarray) -> float:
    """RMS distance between ``x`` and the best rigid placement of ``X``, over the diagonal of ``X``."""
    a, b = x - x.mean(axis=0), X - X.mean(axis=0)
    U, _, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return float(np.sqrt(np.mean(np.sum((a - b @ R) ** 2, axis=1))) / np.linalg.norm(X.max(0) - X.min(0)))


def release(model, state, dt, steps, *, effects=(), **kw):
    """Run ``steps`` free steps; check finiteness and energy monotonicity; return the final state."""
    solver = TetSolver(model, effects=effects, **kw)
    E = [solver.energies(state)["total"]]
    for _ in range(steps):
        solver.step(state, state, dt)
        assert np.all(np.isfinite(state.x)) and np.all(np.isfinite(state.v))
        E.append(solver.energies(state)["total"])
    E = np.array(E)
    assert np.all(np.diff(E) <= 1e-9 * E[0]), f"energy increased by {np.diff(E).max():.3g} J"
    assert E[-1] < 1e-3 * E[0]
    return state


def check_recovered(model, state, tol=SHAPE_TOL):
    vol = signed_volumes(state.x, model.cells)
    assert vol.min() > 0, f"{int((vol <= 0).sum())} elements with non-positive volume"
    assert shape_error(state.x, model.rest_points) < tol


@pytest.fixture(scope="module")
def cube():
    return box(size=(0.1, 0.1, 0.1), cells=(3, 3, 3))


@pytest.mark.parametrize("energy", ["stable", "corotated"])
def test_squash_flat_and_release(cube, energy):
    model = tet_model(cube, SOFT, energy=energy)
    state = TetState.at_rest(model)
    state.x[:, 2] = 0.0  # every element flattened to zero volume
    check_recovered(model, release(model, state, 0.01, 60))


def test_random_vertex_positions_recover(cube):
    model = tet_model(cube, SOFT)
    state = TetState.at_rest(model)
    state.x = np.random.default_rng(0).uniform(0.0, 0.1, state.x.shape)
    assert (signed_volumes(state.x, model.cells) < 0).sum() > 0.3 * model.cell_count
    check_recovered(model, release(model, state, 0.01, 100))


def test_large_dt_on_stiff_material(cube):
    model = tet_model(cube, Material(E=1e9, nu=0.3, rho=1000.0))
    state = TetState.at_rest(model)
    state.x = state.x * [1.5, 0.7, 1.0]
    check_recovered(model, release(model, state, 0.1, 10, newton_max=20))


def test_nearly_incompressible(cube):
    model = tet_model(cube, Material(E=1e5, nu=0.49, rho=1000.0))
    state = TetState.at_rest(model)
    state.x[:, 2] *= 0.2
    check_recovered(model, release(model, state, 0.01, 60))


def sliver_mesh(thin=1e-3, seed=0) -> Mesh:
    """A 3x3x4 box whose second layer is ``thin`` times as thick as the others (flat tetrahedra with
    volume/edge^3 ~ 1e-5), interior points jittered sideways."""
    base = box(size=(0.1, 0.1, 0.1), cells=(3, 3, 4))
    p = base.points.copy()
    z = np.array([0.0, 0.03, 0.03 + 0.03 * thin, 0.06, 0.1])
    p[:, 2] = z[np.rint(p[:, 2] / 0.025).astype(int)]
    inner = np.all((p[:, :2] > 1e-9) & (p[:, :2] < 0.1 - 1e-9), axis=1)
    p[inner, :2] += 0.01 * np.random.default_rng(seed).uniform(-0.5, 0.5, (int(inner.sum()), 2))
    return Mesh(p, base.cells)


def test_sliver_mesh():
    mesh = sliver_mesh()
    edge = np.linalg.norm(mesh.points[mesh.cells][:, :, None] - mesh.points[mesh.cells][:, None], axis=3).max((1, 2))
    assert (mesh.volumes / edge**3).min() < 1e-4  # there really are slivers
    model = tet_model(mesh, SOFT)
    state = TetState.at_rest(model)
    state.x[:, 2] *= 0.3
    check_recovered(model, release(model, state, 0.01, 60))


@pytest.mark.slow
def test_twist_two_turns_and_release():
    """Clamp one end of a bar, turn the other end two full turns (scripted), release it: it untwists."""
    bar = box(size=(0.3, 0.04, 0.04), cells=(10, 2, 2))
    model = tet_model(bar, SOFT)
    x0, x1 = bar.tag_points("x0"), bar.tag_points("x1")
    solver = TetSolver(model, effects=[Pins(x0)])
    state = TetState.at_rest(model)
    centre = np.array([0.0, 0.02, 0.02])
    n = 40
    for i in range(n):
        th = 4 * np.pi * (i + 1) / n
        c, s = np.cos(th), np.sin(th)
        R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        solver.step(state, state, 0.01, control=TetControl(x1, (bar.points[x1] - centre) @ R.T + centre))
    assert np.all(np.isfinite(state.x))
    assert np.allclose(state.x[x1], bar.points[x1], atol=1e-12)  # two full turns: the end is back in place
    assert shape_error(state.x, bar.points) > 0.05  # but the bar is twisted
    state = release(model, state, 0.02, 100, effects=[Pins(x0), RayleighDamping(alpha=5.0)])
    check_recovered(model, state, tol=2e-3)
