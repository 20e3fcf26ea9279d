"""A heavy modal bar squeezing a tet stack (issue 17, part 2/3: contact never adds energy at any dt, every step
intersection-free).

The 7.85 kg steel bar (conftest's) dropped from 16 cm onto a stiff tet cube resting on soft damped tet foam on the
ground (test_tet_tet.py's cube and foam). It lands on the cube, rolls off it about its long axis and sinks into the
foam, its side face coming down to ~1 cm above the ground. History: at 2-5 ms steps a foam vertex of the foam's top
edge, dragged under that face, was wedged between the ground (normal +z) and the bar (its face, its edges and a bar
vertex on the foam's face: normals with z from -0.5 to -0.69). The tet step's "too deep" retries stiffened each
over-deep contact in turn (ground to 1.05e6 N/m, bar contacts to 1.3e8) and each retry flung the vertex further
(it ended 8, 20, 32, 37 mm from the bar, 9 cm from where it started a 5 ms step at 1.4 m/s): +22.95 J stored at 5 ms
(step 29; the surfaces crossed the next step), a peak of +5339 J at 2 ms, +199 J and a crossing at 3 ms. Now a
retry is kept only if the step does not end with more energy than the attempt it redoes. At 10 ms (step 15) the bar
took the ground's impulse after the tet step had placed it on the cube (5.7 rad/s: 3.6 degrees, 7.4 mm from the solved
pose) and crossed the cube: its ground contacts are now solved in the tet step with its rigid motion, and the
reaction turns it about its free step end, as solved. At 20 ms the bar, travelling 2.5 cm and turning ~10 degrees per
step, cut the foam with its edge at step 7 (8 pairs; two foam edges 1.1 and 3.6 mm in front of it at the step start
were 20 mm behind it at its predicted end, where the tet step looks for contacts), at 50 ms the cube and the foam
crossed at step 0, and at 10 ms with numpy 2 (.venv-pip) the cube and the foam under the bar crossed at step 19 (4
pairs; none with Debian's numpy 1.24, where the bar ended 0.14 mm in the ground): now a step in which the bar near the
tet bodies would travel more than half the smallest tet surface edge (1 cm) is taken in sub-steps
(``modalfem.world.substeps``). With tet bodies closing on each other divided the same way, the 5 ms squeeze stored
+1.67 J in one sub-step of step 29 (+33 mJ over the start): where the bar's corner met a foam vertex dragged under
it, the bar vertex on the foam face and the bar edge on the foam edge pushed that vertex opposite ways; such a
contradicting pair now keeps only the contact less far behind its plane at the step start
(``_tet_contacts._opposed``)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Damping, Gravity
from modalfem.mesh import box
from modalfem.world._tet_contacts import DEPTH_SHARE

G = 9.81


def _squeeze_scene(bar_model):
    """The bar above the cube on the foam on the ground: (world, state, cube model, foam model)."""
    from modalfem import tet
    from modalfem.material import Material

    foam = tet.tet_model(box(size=(0.16, 0.16, 0.05), cells=(4, 4, 2)), Material(E=3e4, nu=0.3, rho=60.0))
    cube = tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))
    bodies = [mw.Modal(bar_model, name="bar", position=(0.08, 0.08, 0.16)),
              mw.Tet(cube, name="cube", position=(0.09, 0.01, 0.0512)), mw.Tet(foam, name="block")]
    w = mw.World(bodies=bodies, obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(restitution=0.2, friction=0.5), Damping(alpha=1.0, bodies=["block"])])
    return w, w.state(), cube, foam


def test_a_steel_bar_landing_on_a_tet_cube_and_the_ground_in_one_10_ms_step_does_not_cross_the_cube(bar_model):
    """At 10 ms the bar comes down on the cube and the ground within one step (step 15). Before the ground's
    contacts were solved inside the tet step, the solid stage gave the bar the ground's impulse after it (5.7 rad/s
    the tet step never saw): the bar ended 7.4 mm / 3.6 degrees from the pose solved with the cube, and 14 triangle
    pairs crossed. Only the landing is run (18 steps; the whole squeeze at 10 ms is below)."""
    w, s, _, _ = _squeeze_scene(bar_model)
    touched = set()
    for i in range(18):
        r = w.step(s, s, None, 1e-2)
        assert w.intersections(s) == [], f"surfaces cross at step {i}"
        touched |= {frozenset((a, b)) for a, b, _, _ in r.exchanged}
    assert frozenset(("bar", "cube")) in touched  # (it did land on the cube)


@pytest.mark.parametrize("dt", [2e-3, 5e-3, 1e-2, 2e-2, 5e-2])
def test_a_steel_bar_squeezing_a_tet_cube_on_foam_never_gains_energy_nor_crosses(bar_model, dt):
    w, s, cube, foam = _squeeze_scene(bar_model)
    names = ("bar", "cube", "block")

    def energy():
        return sum(w.energy(s, n)["total"] for n in names)

    e0 = energy()
    steps = round(0.4 / dt)  # lands on the cube at ~75 ms, rolls off into the foam by ~0.16 s, settles
    # nothing but gravity (held in the energy) does work; allowance as test_tet_tet.py's: each implicit step stops at
    # vertex updates below tol * size, against the three bodies' weight
    weight = (bar_model.mass + cube.masses.sum() + foam.masses.sum()) * G
    allow = steps * weight * w._tet["block"]["solver"].tol * max(foam.size, cube.size)
    margin = w._tet["block"]["contact"].margin  # [m]
    sink = margin / DEPTH_SHARE  # [m] (the contact skin 1 mm / 4)
    peak, touched = -np.inf, set()
    for i in range(steps):
        r = w.step(s, s, None, dt)
        assert w.intersections(s) == [], f"surfaces cross at step {i}"
        # the bar never inside the ground beyond the depth its in-step ground rows rest at (margin / DEPTH_SHARE:
        # their stiffness holds the load in that part of the skin); no body beyond the margin (the foam dipped 0.5,
        # 0.6, 0.9, 2.0 and 1.4 mm at 2, 5, 10, 20 and 50 ms while a retry that held it could be dropped for the
        # potential energy of holding it higher; now at most 0.41 mm)
        assert [p for p in w.penetrations(s, tolerance=sink) if p.body == "bar"] == [], f"bar in the ground, step {i}"
        assert w.penetrations(s, tolerance=margin) == [], f"in the ground beyond the margin, step {i}"
        peak = max(peak, energy() - e0)
        touched |= {frozenset((a, b)) for a, b, _, _ in r.exchanged}
    assert {frozenset(("bar", "cube")), frozenset(("bar", "block"))} <= touched  # (it did squeeze the stack)
    assert peak <= allow, (peak, allow)
    xb, _ = w.surface(s, "bar")
    assert xb[:, 2].min() < 0.03  # [m]: sunk into the 5 cm foam
