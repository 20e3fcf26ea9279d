"""A modal body touching a tet body meets a moving box's edges inside the tet step (issue 17), found where the body
is relative to the box at the step start and carried by the box's travel (``_tet_contacts._modal_planes``). Before,
only the box's vertex rows were in the tet step and its edges acted after it: the 7.85 kg steel bar (conftest's)
lying across a soft tet cube and a box turned 45 degrees about y (its top an edge along y, between two rows of the
bar's vertices) rising at 0.5 m/s, 20 ms steps, was tipped into the cube: a cube vertex 2.5 mm inside the bar at
step 0; after, 0.19 mm at most (margin 1 mm). Measured independently: the cube's surface vertices inside the bar's
closed surface (winding number), as deep as their distance to it (tests/world/test_tet_box_edges.py's sampling)."""

from __future__ import annotations

import numpy as np
import pytest
from test_tet_box_edges import _depth_inside

from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.mesh import box


@pytest.fixture(scope="module")
def cube():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))


def _ridge_world(bar_model, cube, speed, effects=()):
    """The steel bar lying across the soft cube, a box ridge turned 45 degrees about y under its end rising at
    ``speed`` [m/s] (its top edge along y at x = 0.165, z = 0.06 at t = 0)."""
    contact = Contact(restitution=0.0, friction=0.5)
    bar = mw.Modal(bar_model, name="bar", position=(0.09, 0.03, 0.06 + 0.025 + 1.5 * contact.margin))
    c = np.cos(np.pi / 4)
    R = np.array([[c, 0.0, c], [0.0, 1.0, 0.0], [-c, 0.0, c]])
    h = 0.03
    ridge = mw.Box((0.165, 0.03, 0.06 - h * np.sqrt(2.0)), (h, h, h), rotation=R,
                   path=lambda t: (0.0, 0.0, speed * t))
    return mw.World(bodies=[bar, mw.Tet(cube, name="cube")], obstacles=[mw.Ground(0.0), ridge],
                    effects=[Gravity(), contact, *effects]), contact


@pytest.mark.parametrize(("speed", "dt"), [(0.5, 2e-2), (1.0, 2e-2)])
def test_a_rising_ridge_tips_a_bar_off_a_tet_cube_without_pressing_the_cube_into_it(bar_model, cube, speed, dt):
    """At 1 m/s the bar, at rest at the step start (so the step was not divided by its start velocities), turned
    0.14 rad in the first 20 ms step, and the tet step's contacts, linearised at its predicted end, left 4 cube
    vertices 0.77 mm inside it: 20 crossing triangle pairs at step 0, 4 at step 1 (1.5 mm). A step is now taken
    again in sub-steps when the travel it took asks for them (``substeps.taken_count``)."""
    w, contact = _ridge_world(bar_model, cube, speed)
    s = w.state()
    z0 = w.surface(s, "bar")[0][:, 2].max()
    for i in range(int(round(0.3 / dt))):
        w.step(s, s, None, dt)
        X, F = w.surface(s, "bar")
        depth = _depth_inside(w.surface(s, "cube")[0], X, F)
        assert depth <= contact.margin, f"step {i}: a cube vertex {depth * 1e3:.2f} mm inside the bar"
        assert w.penetrations(s, tolerance=contact.margin) == [], f"step {i}"
        assert w.intersections(s) == [], f"step {i}"
    assert w.surface(s, "bar")[0][:, 2].max() > z0 + 0.05  # (the ridge did lift it)


def test_a_step_taken_again_in_substeps_keeps_only_the_substeps_sounds(bar_model, cube):
    """The first 20 ms step of the 1 m/s ridge, the bar tapped in it, is taken again in sub-steps (the bar was at
    rest at its start): the dropped pass's impacts leave the bar's sound, so it holds what the sub-steps taken one
    by one, as their own steps, give (the same times and amplitudes; the tap heard once, not twice)."""
    from modalfem.effects import Sound

    def tap(world):
        return world.control().add_impulse("bar", 0, (0.0, 0.0, -1e-3))  # 1 mN s on a 7.85 kg bar

    w, _ = _ridge_world(bar_model, cube, 1.0, effects=[Sound(bodies=("bar",))])
    s = w.state()
    r = w.step(s, s, tap(w), 2e-2)
    assert r.substeps > 1
    v, _ = _ridge_world(bar_model, cube, 1.0, effects=[Sound(bodies=("bar",))])
    t = v.state()
    for k in range(r.substeps):
        assert v.step(t, t, tap(v) if k == 0 else None, 2e-2 / r.substeps).substeps == 1
    a, b = w.sound("bar"), v.sound("bar")
    assert a.impact_count == b.impact_count > 0
    assert np.array_equal(a._times, b._times)
    np.testing.assert_array_equal(np.array(a._amps), np.array(b._amps))
    # the same motion, up to the tet solves' warm starts (the dropped pass left the tet solver's caches warm): far
    # below the 1 mm contact margin
    np.testing.assert_allclose(s.bodies["bar"].position, t.bodies["bar"].position, rtol=0, atol=1e-9)


def test_a_bar_across_a_tet_cube_and_a_static_ridge_never_crosses_the_cube(bar_model, cube):
    """The static obstacles a tet step has solved with a modal body are left out of the solid stage for that body
    (``ctx.tet_obstacles``): solved there again, without the cube in that solve, the ridge's push turned the bar
    into the cube after the tet step had placed it: 16-26 crossing triangle pairs (cube vertices 0.3-0.84 mm inside
    the bar) at every 20 ms step. Also the bar stays out of the ridge (within the contact margin)."""
    contact = Contact(restitution=0.0, friction=0.5)
    bar = mw.Modal(bar_model, name="bar", position=(0.09, 0.03, 0.06 + 0.025 + 1.5 * contact.margin))
    c = np.cos(np.pi / 4)
    R = np.array([[c, 0.0, c], [0.0, 1.0, 0.0], [-c, 0.0, c]])
    h = 0.03
    ridge = mw.Box((0.165, 0.03, 0.06 - h * np.sqrt(2.0)), (h, h, h), rotation=R)
    w = mw.World(bodies=[bar, mw.Tet(cube, name="cube")], obstacles=[mw.Ground(0.0), ridge],
                 effects=[Gravity(), contact])
    s = w.state()
    for step in range(8):
        w.step(s, s, None, 2e-2)
        assert w.intersections(s) == [], step
        X, F = w.surface(s, "bar")
        Xc, _ = w.surface(s, "cube")
        assert _depth_inside(Xc, X, F) <= 1e-9, step
        assert ridge.signed_distance(X, s.time)[0].min() >= -contact.margin, step
