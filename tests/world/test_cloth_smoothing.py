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


def _landing(smoothing: float, *, path=None):
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel
    from modalfem.effects import Contact, Gravity

    silk = ClothMaterial(areal_density=0.1, young=1e5, poisson=0.3, thickness=3e-4, bending_stiffness=2e-6)
    model = ClothModel(grid((0.3, 0.3), (16, 16), origin=(-0.15, -0.15, 0.105)), silk)
    n = model.mesh.point_count
    body = mw.Cloth(model, name="sheet", v0=np.tile([0.0, 0.0, -1.0], (n, 1)), smoothing=smoothing)
    w = mw.World(bodies=[body], obstacles=[mw.Box((0.0, 0.0, 0.05), (0.05, 0.05, 0.05), path=path)],
                 effects=[Gravity(), Contact(thickness=2e-3)])
    s = w.state()
    energy = [w.energy(s, "sheet")]
    for _ in range(STEPS):
        w.step(s, s, None, DT)
        energy.append(w.energy(s, "sheet"))
        assert not w.intersections(s)
    return energy


#: the box held still on a path: a moving obstacle is left to the collision pipeline (the cloth's implicit step
#: constrains vertices on static obstacles only), so the landing is the pipeline's work, which smoothing shapes
STILL = [(0.0, (0.0, 0.0, 0.0))]


def test_smoothing_spreads_the_collision_response_over_the_sheet():
    off, on = _landing(0.0, path=STILL), _landing(0.02, path=STILL)
    peak_off = max(e["elastic"] for e in off)
    peak_on = max(e["elastic"] for e in on)
    # the same landing and the same momentum given by the box: smoothing keeps the sum of m dv (tested in
    # tests/cloth) and only spreads it, so the shear the response stores must drop (measured: 4.9x; 3x asked)
    assert peak_on < peak_off / 3.0, (peak_on, peak_off)
    assert max(e["total"] for e in on) < max(e["total"] for e in off)


def test_a_static_box_constrains_the_sheet_in_its_implicit_step():
    # a static box is among the obstacles the cloth's implicit step constrains (as planes and spheres): the
    # vertices resting on its top get their normal velocity held inside the solve, so the sheet above bends
    # around it instead of the pipeline stopping its vertices one by one (measured: the sheet's total energy
    # peaked at 3.3x its start with the box left to the pipeline, 1.07x with it constrained). Without external
    # work energy should only go; what remains is the first step, where the sheet is still beyond the
    # constraints' reach (2 h) and the pipeline stops it, and the linearised step's stretch as the overhang
    # swings down round the box's edges. The bound is a regression bound in units of the kinetic energy of the
    # part of the sheet the box top stops (0.1 x 0.1 m of 0.1 kg/m^2 at 1 m/s: 5e-4 J, ~4 % of the start):
    # the rise may not exceed 4 times it (measured 2.0x with the constraints and their friction, 65x without)
    held = _landing(0.02)
    e0 = held[0]["total"]
    stopped = 0.5 * 0.1 * 0.1 * 0.1 * 1.0**2
    still = _landing(0.02, path=STILL)  # the same box left to the pipeline
    assert max(e["total"] for e in still) > e0 + 4 * stopped  # the case the constraints fix (measured 3.3x)
    assert max(e["total"] for e in held) <= e0 + 4 * stopped, ([e["total"] for e in held], e0)


def test_cloth_smoothing_must_be_finite_and_not_negative():
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel

    model = ClothModel(grid((0.1, 0.1), (3, 3)), ClothMaterial(areal_density=0.1, young=1e5, poisson=0.3,
                                                               thickness=3e-4))
    for bad in (-0.01, float("nan")):
        with pytest.raises(InputError, match="smoothing must be finite and >= 0"):
            mw.Cloth(model, name="c", smoothing=bad)
