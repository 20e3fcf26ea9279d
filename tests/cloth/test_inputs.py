"""Cloth scene inputs: handles, vertex indices, paths (at t = 0 and at every step), start arrays, fully
held cloth. Every bad input is one error line naming the problem; a failed step changes nothing."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel, Handle
from modalfem.cloth.scene import ClothScene
from modalfem.errors import InputError, SimulationError

MESH = grid((0.4, 0.4), (7, 7))  # 49 vertices
MAT = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)
N = MESH.point_count


def _one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize("indices, message", [
    ([0, 49], r"pin vertex 49 out of range \[0, 49\)"),
    ([-1], r"pin vertex -1 out of range"),
    ([0.5], r"must be integers"),
])
def test_pin_with_a_bad_vertex_is_refused(indices, message):
    with pytest.raises(InputError, match=message) as info:
        Handle.pin(MESH.points, indices)
    _one_line(info)


def test_rotating_handle_with_bad_arguments_is_refused():
    with pytest.raises(InputError, match="out of range"):
        Handle.rotating(MESH.points, [70], center=(0, 0, 0), axis=(0, 0, 1), rate=1.0)
    with pytest.raises(InputError, match="axis"):
        Handle.rotating(MESH.points, [0], center=(0, 0, 0), axis=(0, 0, 0), rate=1.0)
    with pytest.raises(InputError, match="rate"):
        Handle.rotating(MESH.points, [0], center=(0, 0, 0), axis=(0, 0, 1), rate=float("nan"))


def test_handle_out_of_range_in_the_model_is_named():
    with pytest.raises(InputError, match=r"handle 1 vertex 99 out of range \[0, 49\)"):
        ClothModel(MESH, MAT, handles=(Handle.pin(MESH.points, [0]), Handle(np.array([99]), lambda t: np.zeros((1, 3)))))
    with pytest.raises(InputError, match="vertex 3 is driven by two handles"):
        ClothModel(MESH, MAT, handles=(Handle.pin(MESH.points, [3]), Handle.pin(MESH.points, [3, 4])))


@pytest.mark.parametrize("path, message", [
    (lambda t: np.full((2, 3), np.nan), r"handle 0 path at t = 0 s returned 6 non-finite values, first at vertex 0"),
    (lambda t: np.zeros((3, 3)), r"handle 0 path at t = 0 s must return \(2, 3\) positions.*got shape \(3, 3\)"),
    (lambda t: "up", r"handle 0 path at t = 0 s failed"),
])
def test_a_bad_path_at_t0_is_refused_when_the_model_is_built(path, message):
    with pytest.raises(InputError, match=message) as info:
        ClothModel(MESH, MAT, handles=(Handle(np.array([0, 7]), path),))
    _one_line(info)


def test_a_path_that_turns_non_finite_later_names_the_handle_and_the_time_and_changes_nothing():
    """NaN from a handle path at t = 0.03 s: the step to it raises one line naming handle 1 and the time
    (before: 'CG did not reach ... (reached nan)'), and the scene is left as it was."""
    def path(t):
        p = MESH.points[[42, 48]] + [0.0, 0.0, t]
        return p if t < 0.025 else p * np.nan

    model = ClothModel(MESH, MAT, handles=(Handle.pin(MESH.points, [0, 7]), Handle(np.array([42, 48]), path)))
    scene = ClothScene(model, gravity=(0, 0, -9.81))
    dt = 0.01
    scene.step(dt)
    scene.step(dt)
    x, v, t = scene.x.copy(), scene.v.copy(), scene.t
    with pytest.raises(SimulationError, match=r"handle 1 path at t = 0.03 s returned 6 non-finite values") as info:
        scene.step(dt)
    _one_line(info)
    assert np.array_equal(scene.x, x) and np.array_equal(scene.v, v) and scene.t == t


@pytest.mark.parametrize("name", ["x0", "v0"])
def test_non_finite_start_arrays_say_which_vertex(name):
    a = MESH.points.copy() if name == "x0" else np.zeros((N, 3))
    a[12, 1] = np.nan
    a[12, 2] = np.inf
    a[30, 0] = np.nan
    model = ClothModel(MESH, MAT)
    with pytest.raises(InputError, match=rf"{name} has 3 non-finite values, first at vertex 12") as info:
        ClothScene(model, **{name: a})
    _one_line(info)
    with pytest.raises(InputError, match=rf"{name} must have shape \(49, 3\).*got \(48, 3\)"):
        ClothScene(model, **{name: a[:-1]})


def test_a_fully_held_cloth_follows_its_handles():
    """Every vertex a handle: nothing free, the step is valid and moves the cloth with its handles."""
    model = ClothModel(MESH, MAT, handles=(Handle(np.arange(N), lambda t: MESH.points + [0.0, 0.0, 0.5 * t]),))
    for solver in ("cg", "splu"):
        scene = ClothScene(model, gravity=(0, 0, -9.81), linear_solver=solver)
        for _ in range(3):
            scene.step(0.01)
        np.testing.assert_allclose(scene.x, MESH.points + [0.0, 0.0, 0.015], rtol=0, atol=1e-12)
        np.testing.assert_allclose(scene.v[:, 2], 0.5, rtol=1e-9)
