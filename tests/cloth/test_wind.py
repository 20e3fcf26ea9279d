"""Wind: zero force with the wind or in-plane wind, exact velocity Jacobian, a flag streams out."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.cloth.energies import assemble_blocks
from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel, Handle
from modalfem.cloth.scene import ClothScene
from modalfem.cloth.wind import Wind
from modalfem.errors import InputError

RNG = np.random.default_rng(2)
MESH = grid((0.4, 0.3), (5, 4))
X = MESH.points + 0.05 * RNG.standard_normal(MESH.points.shape)


def test_no_force_when_the_cloth_moves_with_the_wind():
    w = np.array([3.0, -1.0, 2.0])
    f, _ = Wind(w, drag=2.0).forces(X, np.tile(w, (MESH.point_count, 1)), MESH.triangles)
    assert np.abs(f).max() < 1e-14


def test_no_force_when_the_wind_blows_in_the_plane():
    flat = MESH.points  # plane z = 0
    f, _ = Wind([4.0, 1.0, 0.0], drag=2.0).forces(flat, np.zeros_like(flat), MESH.triangles)
    assert np.abs(f).max() < 1e-14


def test_normal_wind_on_a_still_sheet_gives_drag_times_area_times_speed():
    f, _ = Wind([0.0, 0.0, 5.0], drag=1.5).forces(MESH.points, np.zeros_like(MESH.points), MESH.triangles)
    assert np.allclose(f[:, :2], 0.0)
    assert np.isclose(f[:, 2].sum(), 1.5 * 5.0 * 0.4 * 0.3)


def test_velocity_jacobian_is_exact_and_field_wind_is_evaluated_at_centroids():
    wind = Wind(lambda x, t: np.stack([x[:, 1], np.full(len(x), t), x[:, 0]], 1), drag=0.7)
    v = RNG.standard_normal(X.shape)
    f, C = wind.forces(X, v, MESH.triangles, t=0.3)
    J = assemble_blocks(C, MESH.triangles, MESH.point_count).toarray()
    dv = RNG.standard_normal(X.shape)
    f2, _ = wind.forces(X, v + dv, MESH.triangles, t=0.3)
    assert np.allclose((f2 - f).reshape(-1), -J @ dv.reshape(-1), atol=1e-12)  # linear in v
    assert np.linalg.eigvalsh(J).min() > -1e-12


def test_bad_wind_parameters():
    with pytest.raises(InputError, match="drag"):
        Wind([1, 0, 0], drag=0.0)
    with pytest.raises(InputError, match="velocity"):
        Wind([1, 0], drag=1.0)


def test_a_pinned_flag_streams_out_in_the_wind():
    # flag in the yz plane, pole along z at y = 0; wind along +x, across the flag
    nu, nv, w = 9, 6, 0.4
    m = grid((w, 0.25), (nu, nv), plane="yz")
    pole = np.flatnonzero(np.isclose(m.points[:, 1], 0.0))
    tip = np.flatnonzero(np.isclose(m.points[:, 1], w))
    mat = ClothMaterial(areal_density=0.15, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)
    model = ClothModel(m, mat, handles=(Handle.pin(m.points, pole),), mass_damping=0.5)
    scene = ClothScene(model, gravity=(0, 0, -9.81), wind=Wind([6.0, 0.0, 0.0], drag=1.0))
    e_max = 0.0
    for _ in range(150):
        scene.step(0.01)
        assert np.all(np.isfinite(scene.x))
        e_max = max(e_max, scene.energy()["kinetic"])
    tip_x = scene.x[tip, 0].mean()
    # downwind (x) reach of the free edge: the flag points mostly along the wind now
    assert tip_x > 0.6 * w
    # the flag keeps its length (stiff membrane) and does not blow up
    assert np.linalg.norm(scene.x[tip] - scene.x[pole], axis=1).mean() < 1.05 * w
    assert e_max < 10.0
