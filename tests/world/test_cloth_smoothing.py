"""The World's cloth collision stage smooths the collision pipeline's velocity change over each sheet
(``Cloth(smoothing=s)``: ``(M + dt s K) dv_s = M dv``, then the pipeline again), as ``ClothScene`` stage (d) does.

Without it (the World ignored ``smoothing``), the pipeline's impulses acted on single vertices: a sheet falling
at 1 m/s onto a box narrower than it has its middle stopped and its overhang moving on, dt |dv| ~ 1 cm of shear
between neighbours per step, all stored as elastic energy (the sheet's energy rose to ~14 times its start)."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.world as mw
from modalfem.errors import InputError

DT = 0.01  # [s]
STEPS = 6  # the landing: the box top is reached in the first step


def _landing(smoothing: float):
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel
    from modalfem.effects import Contact, Gravity

    silk = ClothMaterial(areal_density=0.1, young=1e5, poisson=0.3, thickness=3e-4, bending_stiffness=2e-6)
    model = ClothModel(grid((0.3, 0.3), (16, 16), origin=(-0.15, -0.15, 0.105)), silk)
    n = model.mesh.point_count
    body = mw.Cloth(model, name="sheet", v0=np.tile([0.0, 0.0, -1.0], (n, 1)), smoothing=smoothing)
    w = mw.World(bodies=[body], obstacles=[mw.Box((0.0, 0.0, 0.05), (0.05, 0.05, 0.05))],
                 effects=[Gravity(), Contact(thickness=2e-3)])
    s = w.state()
    energy = [w.energy(s, "sheet")]
    for _ in range(STEPS):
        w.step(s, s, None, DT)
        energy.append(w.energy(s, "sheet"))
        assert not w.intersections(s)
    return energy


def test_smoothing_spreads_the_collision_response_over_the_sheet():
    off, on = _landing(0.0), _landing(0.02)
    peak_off = max(e["elastic"] for e in off)
    peak_on = max(e["elastic"] for e in on)
    # the same landing and the same momentum given by the box: smoothing keeps the sum of m dv (tested in
    # tests/cloth) and only spreads it, so the shear the response stores must drop (measured: 4.9x; 3x asked)
    assert peak_on < peak_off / 3.0, (peak_on, peak_off)
    assert max(e["total"] for e in on) < max(e["total"] for e in off)


def test_cloth_smoothing_must_be_finite_and_not_negative():
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel

    model = ClothModel(grid((0.1, 0.1), (3, 3)), ClothMaterial(areal_density=0.1, young=1e5, poisson=0.3,
                                                               thickness=3e-4))
    for bad in (-0.01, float("nan")):
        with pytest.raises(InputError, match="smoothing must be finite and >= 0"):
            mw.Cloth(model, name="c", smoothing=bad)
