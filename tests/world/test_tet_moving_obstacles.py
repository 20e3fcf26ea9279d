"""Tet bodies against moving obstacles inside the tet step (issue 17): a moving obstacle's tangent planes are found
where the vertices are relative to it at the step start and carried by its travel in the step. Read at the step end
(before), a box rising 1 m/s put a 6 cm tet cube resting on it under the box's middle at 50 ms steps (half the box's
height a step): its bottom face was the closest and the cube fell through (45 mm inside, ending 0.42 m below the
platform); a box sweeping sideways at 1 m/s passed through a tet cube at 50 ms (13 mm inside, the cube left behind)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.mesh import box

G = 9.81
U = 1.0  # the obstacles' speed [m/s]


@pytest.fixture(scope="module")
def cube():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))


@pytest.mark.parametrize("dt", [1e-3, 1e-2, 5e-2])
def test_a_tet_cube_rides_a_rising_platform_at_any_dt(cube, dt):
    contact = Contact(friction=0.5)
    plat = mw.Box((0.03, 0.03, -0.05), (0.1, 0.1, 0.05), path=lambda t: (0.0, 0.0, U * t))
    w = mw.World(bodies=[mw.Tet(cube, name="cube", position=(0.0, 0.0, 0.5 * contact.margin))], obstacles=[plat],
                 effects=[Gravity(), contact])
    s = w.state()
    for i in range(int(round(0.15 / dt))):
        w.step(s, s, None, dt)
        assert w.penetrations(s, tolerance=contact.margin) == [], f"cube in the platform at step {i}"
    top = U * s.time
    bottom = s.bodies["cube"].x[:, 2].min()
    assert abs(bottom - top) < contact.margin, (bottom, top)  # (on it, not left behind nor thrown off)
    vz = float(cube.masses @ s.bodies["cube"].v[:, 2] / cube.masses.sum())
    assert abs(vz - U) < G * dt + 1e-3 * U, vz  # (moving with it: one step's gravity, the implicit step's tolerance)


@pytest.mark.parametrize("dt", [1e-3, 1e-2, 5e-2])
def test_a_box_sweeping_into_a_tet_cube_pushes_it_and_gives_no_more_energy_than_its_work(cube, dt):
    """Frictionless, so the box's force is along its face normal (x) and the ground's vertical: the box's impulse
    is the cube's x momentum p_x, its work U p_x (its velocity constant); the cube's energy (kinetic, elastic,
    gravity's, stored in its contacts) may gain at most that, and p_x <= 2 m U (in the box's frame nothing does
    work, so the cube leaves it at most at U). Allowance: each implicit step stops at vertex updates below
    tol * size, against the cube's weight (as test_tet_box_landing.py's)."""
    contact = Contact(friction=0.0)
    wall = mw.Box((-0.021, 0.03, 0.03), (0.02, 0.05, 0.025), path=lambda t: (U * t, 0.0, 0.0))
    w = mw.World(bodies=[mw.Tet(cube, name="cube", position=(0.0, 0.0, 0.5 * contact.margin))],
                 obstacles=[mw.Ground(0.0), wall], effects=[Gravity(), contact])
    s = w.state()
    m = float(cube.masses.sum())
    e0 = w.energy(s, "cube")["total"]
    steps = int(round(0.15 / dt))
    allow = steps * m * G * w._tet["cube"]["solver"].tol * cube.size
    for i in range(steps):
        w.step(s, s, None, dt)
        assert w.penetrations(s, tolerance=contact.margin) == [], f"cube in the box or ground at step {i}"
        px = float(cube.masses @ s.bodies["cube"].v[:, 0])
        gain = w.energy(s, "cube")["total"] - e0
        assert gain <= U * px + allow, (i, gain, U * px)
        assert px <= 2.0 * m * U * (1.0 + 1e-9), (i, px)
    face = U * s.time - 0.001  # the box's +x face
    assert s.bodies["cube"].x[:, 0].min() > face - contact.margin  # (pushed ahead of it, not passed through)
    assert float(cube.masses @ s.bodies["cube"].v[:, 0]) > 0.5 * m * U


@pytest.mark.parametrize(("speed", "dt"), [(0.2, 2e-2), (0.2, 5e-2), (0.5, 5e-2)])
def test_a_bar_across_a_tet_cube_and_a_rising_box_never_crosses_the_cube(bar_model, cube, speed, dt):
    """The 7.85 kg steel bar (conftest's) lies across the tet cube and a box beside it whose top rises at ``speed``
    [m/s]: the box lifts the bar's end and tips it over the cube's edge. The bar touches the tet cube, so its
    contacts with the box are in the tet step too (``_modal_planes``; before, they acted after it: bar and cube
    crossed in 2, 1, 1 steps of these three cases, first at steps 1, 0, 0)."""
    contact = Contact(restitution=0.0, friction=0.5)
    bar = mw.Modal(bar_model, name="bar", position=(0.09, 0.03, 0.06 + 0.025 + 1.5 * contact.margin))
    wall = mw.Box((0.17, 0.03, 0.03), (0.03, 0.03, 0.03), path=lambda t: (0.0, 0.0, speed * t))
    w = mw.World(bodies=[bar, mw.Tet(cube, name="cube")], obstacles=[mw.Ground(0.0), wall],
                 effects=[Gravity(), contact])
    s = w.state()
    z0 = w.surface(s, "bar")[0][:, 2].max()
    for i in range(int(round(0.3 / dt))):
        w.step(s, s, None, dt)
        assert w.intersections(s) == [], f"surfaces cross at step {i}"
        assert [p for p in w.penetrations(s, tolerance=contact.margin) if p.obstacle == 1] == [], f"in the box, step {i}"
    assert w.surface(s, "bar")[0][:, 2].max() > z0 + 0.05  # (the box did lift it)
