"""Two tet bodies closing on each other: a World step in which they would travel more than ``TRAVEL_SHARE`` of
their smallest rest surface edge relative to each other is divided (``modalfem.world.substeps``), and the soft
foam stays within its contact margin of the ground (issue 17).

The scene is test_tet_squeeze.py's stack without the bar: the stiff cube (2 cm cells) dropped 1.2 mm onto the soft
damped foam on the ground. Before: in the first 50 ms step the cube fell 12.3 mm, its contacts with the foam found
and linearised at the step start, and the two crossed; the foam dipped 1.97 mm under the ground in the first 20 ms
step (1.43 mm at 50 ms): the "too deep" retry that held it was dropped for ending with more energy than the attempt
it redid (+1.0 mJ: the foam held higher, its weight's potential), now the work of lifting the over-deep contacts is
allowed for."""

from __future__ import annotations

import math

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Damping, Gravity
from modalfem.mesh import box
from modalfem.world.substeps import TRAVEL_SHARE

G = 9.81
CELL = 0.02  # [m] the cube's cells: the smaller body's smallest rest surface edge


def _stack():
    from modalfem import tet
    from modalfem.material import Material

    foam = tet.tet_model(box(size=(0.16, 0.16, 0.05), cells=(4, 4, 2)), Material(E=3e4, nu=0.3, rho=60.0))
    cube = tet.tet_model(box(size=(3 * CELL, 3 * CELL, 3 * CELL), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))
    w = mw.World(bodies=[mw.Tet(cube, name="cube", position=(0.09, 0.01, 0.0512)), mw.Tet(foam, name="block")],
                 obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(restitution=0.2, friction=0.5), Damping(alpha=1.0, bodies=["block"])])
    return w, w.state(), cube, foam


@pytest.mark.parametrize("dt", [2e-3, 5e-3, 1e-2, 2e-2, 5e-2])
def test_a_tet_cube_dropped_on_tet_foam_never_crosses_it_nor_sinks_the_foam_into_the_ground(dt):
    w, s, cube, foam = _stack()
    names = ("cube", "block")

    def energy():
        return sum(w.energy(s, n)["total"] for n in names)

    e0 = energy()
    steps = round(0.4 / dt)
    # as test_tet_squeeze.py: each implicit step stops at vertex updates below tol * size, against the weight
    weight = (cube.masses.sum() + foam.masses.sum()) * G
    allow = steps * weight * w._tet["block"]["solver"].tol * max(foam.size, cube.size)
    margin = w._tet["block"]["contact"].margin
    peak = -np.inf
    for i in range(steps):
        w.step(s, s, None, dt)
        assert w.intersections(s) == [], f"surfaces cross at step {i}"
        assert w.penetrations(s, tolerance=margin) == [], f"in the ground beyond the margin at step {i}"
        peak = max(peak, energy() - e0)
    assert peak <= allow, (peak, allow)
    assert s["cube"].x[:, 2].min() > 0.04  # [m] (it rests on the 5 cm foam)


def test_a_divided_tet_tet_step_is_its_sub_steps_taken_one_by_one():
    """The cube at rest over the foam, 50 ms: it would fall g dt^2 / 2 = 12.3 mm, more than half a 2 cm cell, so
    the step is two 25 ms sub-steps (each 3.1 mm: not divided again), the same states bit for bit."""
    dt = 5e-2
    n = math.ceil(0.5 * G * dt * dt / (TRAVEL_SHARE * CELL))
    a, sa, _, _ = _stack()
    b, sb, _, _ = _stack()
    assert a.step(sa, sa, None, dt).substeps == n == 2
    for _ in range(n):
        assert b.step(sb, sb, None, dt / n).substeps == 1
    for name in ("cube", "block"):
        assert np.array_equal(sa[name].x, sb[name].x) and np.array_equal(sa[name].v, sb[name].v)
    assert sa.time == pytest.approx(dt, abs=1e-15)


def test_tet_bodies_far_apart_are_not_divided():
    w, s, _, _ = _stack()
    s["cube"].x[:, 2] += 1.0  # 1 m over the foam: out of reach within 50 ms
    assert w.step(s, s, None, 5e-2).substeps == 1
