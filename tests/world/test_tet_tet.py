"""Tet with tet in contact (issue 17, part 2/3: contact never adds energy at any dt).

A 6 cm tet cube (E = 1 MPa, 0.22 kg) dropped 2 cm onto a soft tet foam block (E = 30 kPa, test_tet_modal.py's foam)
on the ground, Gravity and Contact(friction=0.5), 0.3 s.

Known failure, kept as a strict xfail until it is fixed: tet-tet contact goes through the velocity-level solid solve
(``World._stage_contacts``) after each tet's implicit step, which changes the velocities of the touching surface
vertices alone and moves them alone by ``dt dv``. That strains the elements under them; the solve's no-gain rule
counts kinetic energy only, so the strain energy is never checked. Measured per stage (Intel Xeon, 3 ms steps): the
contact stage adds +0.3 to +1.3 J of elastic energy per step while the kinetic energy changes by -0.01 J, the next
implicit step dissipates most of it, and the scene's energy peaks +2.6 J above its start (+0.16 J at 1 ms, +51 J
and crossings from step 9 at 10 ms). Neither the push-out (PUSH_OUT = 0) nor friction (0) changes this. Counting
the strain energy in the no-gain rule is no fix: it scales the impulses to ~0 and the cube crosses the foam at every
dt (from step 63 / 20 / 5 at 1 / 3 / 10 ms); so does giving the solve's velocity changes at the step start and
redoing the implicit step (the impulse spreads through the soft body and no longer stops the touching vertices).
The fix is the other tet's surface as a moving penalty obstacle inside each tet's implicit step (as tet-modal
contact does, ``World._tet_contacts``)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.mesh import box

G = 9.81


@pytest.fixture(scope="module")
def foam_model():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(0.16, 0.16, 0.05), cells=(4, 4, 2)), Material(E=3e4, nu=0.3, rho=60.0))


@pytest.fixture(scope="module")
def cube_model():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))


@pytest.mark.xfail(strict=True, reason="issue 17: tet-tet contact stores strain energy the no-gain rule does not "
                   "count (the solid solve moves touching surface vertices alone); see the module docstring")
@pytest.mark.parametrize("dt", [1e-3, 3e-3])
def test_a_tet_cube_landing_on_a_tet_foam_block_never_gains_energy_nor_crosses_it(cube_model, foam_model, dt):
    w = mw.World(bodies=[mw.Tet(cube_model, name="cube", position=(0.05, 0.05, 0.07)), mw.Tet(foam_model, name="block")],
                 obstacles=[mw.Ground(0.0)], effects=[Gravity(), Contact(friction=0.5)])
    s = w.state()

    def energy():
        return sum(w.energy(s, n)["total"] for n in ("cube", "block"))

    e0 = energy()
    steps = round(0.3 / dt)
    # nothing but gravity (held in the energy) does work: the total may not rise. Derived allowance (as
    # test_tet_modal.py): each implicit step stops at vertex updates below tol * size, against both bodies' weight
    tol = max(w._tet[n]["solver"].tol for n in ("cube", "block"))
    weight = (cube_model.masses.sum() + foam_model.masses.sum()) * G
    allow = steps * weight * tol * max(cube_model.size, foam_model.size)
    peak, touched = -np.inf, 0
    for i in range(steps):
        r = w.step(s, s, None, dt)
        touched += r.contacts.get("solid", 0) > 0
        assert w.intersections(s) == [], f"surfaces cross at step {i} (t = {s.time:.3f} s)"
        peak = max(peak, energy() - e0)
    assert touched > 0  # the cube reached the foam
    assert peak <= allow, f"energy rose {peak:.3g} J above the start (allowed {allow:.2g} J)"
