"""The solid solve's no-gain rule is lifted only for the islands a moving obstacle touches (issue 17): a moving
obstacle may do work on the bodies it pushes, so their island is exempt, but the other islands keep the rule.

Before, one moving obstacle in contact with any body switched the rule off for the whole solve: with a box pushing a
floating bar 1 m away, a bar dropped 1 cm onto the ground tumbling rose 4.5e-6 J above its lowest energy at dt = 1 ms
(step 57), 2.0e-5 J at 10 ms (step 8), and a bar dropped 2 cm at e = 0.5 gained 0.36 J at 0.1 s (step 2); after, at
most 2e-14 J.
Tolerance as tests/world/test_world_islands.py (the rule admits 1e-12 of its quadratic term; the free rotation keeps
1e-9 of m g r)."""

from __future__ import annotations

import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Gravity

G = 9.81  # [m/s^2]


@pytest.mark.parametrize(("dt", "restitution", "height", "spin"),
                         [(1e-3, 0.0, 0.01, (0.5, 0.2, 0.0)), (1e-2, 0.0, 0.01, (0.5, 0.2, 0.0)),
                          (0.1, 0.5, 0.02, (0.3, 0.0, 0.0))])
def test_a_bar_far_from_a_moving_box_keeps_the_no_gain_rule(bar_model, dt, restitution, height, spin):
    contact = Contact(restitution=restitution, friction=0.3)
    skin = 0.5 * contact.margin
    w0 = mw.World(bodies=[mw.Modal(bar_model, name="b")], effects=[])
    s0 = w0.state()
    zmin = w0.surface(s0, "b")[0][:, 2].min() - s0.bodies["b"].position[2]
    xmin = w0.surface(s0, "b")[0][:, 0].min() - s0.bodies["b"].position[0]
    # a box sweeping at 0.2 m/s into a floating bar's -x end, 1 m away (that bar has no gravity: it is only pushed)
    speed = 0.2
    box = mw.Box((xmin - 0.05 - skin, 1.0, 1.0), (0.05, 0.1, 0.1), path=lambda t: (speed * t, 0.0, 0.0))
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0.0, 0.0, skin - zmin + height),
                                  angular_velocity=spin),
                         mw.Modal(bar_model, name="pushed", position=(0.0, 1.0, 1.0))],
                 obstacles=[mw.Ground(), box], effects=[Gravity(bodies=["bar"]), contact])
    s = w.state()
    low = w.energy(s, "bar")["total"]  # the lowest energy so far: no step may rise above it
    tol_e = 1e-9 * w._modal["bar"]["body"].mass * G * 0.1
    for i in range(max(20, int(round(0.3 / dt)))):
        w.step(s, s, None, dt)
        e = w.energy(s, "bar")["total"]
        assert e <= low + tol_e, f"step {i}: the bar gained {e - low:.3e} J (allowed {tol_e:.1e})"
        low = min(low, e)
    assert w.penetrations(s, tolerance=0.0) == []
    assert s.bodies["pushed"].velocity[0] > 0.5 * speed  # the box did push the other bar (its island is exempt)
