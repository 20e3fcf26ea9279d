"""The solid solve's no-gain rule acts per island (issue 17): the impulses of bodies that do not touch, directly or
through other bodies (an obstacle links nothing), are scaled each by their own factor, from their own energy balance.

Before (one factor for every impulse of the solve) energy moved between bodies far apart: with a bar resting on the
ground in one place and a bar dropped 7 cm onto another bar 1 m away, the resting bar's island gained 1.07e-6 J at
dt = 1 ms (step 132: the drop island's loss paid for it); at dt = 10 ms the old rule happened to keep both (that
case passes before too). See ``_solid_stage.islands``.

Tolerances: energy as tests/world/test_world_resting_dt.py (the rule admits 1e-12 of its quadratic term; the free
rotation keeps 1e-9 of m g r). Against the island simulated alone: bit for bit, since each island's sweeps stop on
their own (``_kernels.sequential_impulses``'s island labels). Before, the islands shared the solve's stop, so an island
was swept on while another converged and differed from the island alone (the resting bar at 1 ms: 2.5e-6 m/s at step
117; the test then allowed ``VELOCITY_STOP skin / dt`` in velocity and ``VELOCITY_STOP skin`` a step in position)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.world._solid_stage import islands

G = 9.81  # [m/s^2]


def test_islands_are_the_components_linked_by_body_contacts():
    body = np.array([0, 1, 3, 4, 4, 2])
    other = np.array([-1, -1, 4, -1, 3, -1])  # 3-4 touch; 0, 1, 2 touch only obstacles; 5 nothing
    got = islands(body, other, 6)
    assert [g.tolist() for g in got] == [[0], [1], [2], [3, 4]]
    got = islands(np.array([0, 2]), np.array([1, 1]), 4)  # linked through body 1
    assert [g.tolist() for g in got] == [[0, 1, 2]]


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_the_no_gain_rule_keeps_each_island_to_itself(bar_model, dt):
    contact = Contact(restitution=0.0)
    skin = 0.5 * contact.margin
    w0 = mw.World(bodies=[mw.Modal(bar_model, name="b")], effects=[])
    s0 = w0.state()
    zmin = w0.surface(s0, "b")[0][:, 2].min() - s0.bodies["b"].position[2]

    def resting():  # a bar on the ground (and a body far off, so the solid solve holds it: test_world_resting_dt)
        return [mw.Modal(bar_model, name="bar", position=(0.0, 0.0, skin - zmin)),
                mw.Modal(bar_model, name="far", position=(0.0, 1.0, 1.0))]

    def dropped():  # a bar dropped 7 cm onto another resting on the ground 1 m away, tumbling a little
        return [mw.Modal(bar_model, name="base", position=(0.0, -1.0, skin - zmin)),
                mw.Modal(bar_model, name="top", position=(0.0, -1.0, skin - 5 * zmin + 0.02),
                         angular_velocity=(0.3, 0.0, 0.0))]

    def world(bodies):
        return mw.World(bodies=bodies, obstacles=[mw.Ground()],
                        effects=[Gravity(bodies=[b.name for b in bodies if b.name != "far"]), contact])

    groups = {"resting": ["bar", "far"], "dropped": ["base", "top"]}
    alone = {"resting": world(resting()), "dropped": world(dropped())}
    both = world(resting() + dropped())
    s_alone = {k: w.state() for k, w in alone.items()}
    s = both.state()

    def energy(k):
        return sum(both.energy(s, n)["total"] for n in groups[k])

    e0 = {k: energy(k) for k in groups}
    tol_e = 1e-9 * both._modal["bar"]["body"].mass * G * 0.1
    steps = int(round(0.3 / dt))
    for i in range(steps):
        both.step(s, s, None, dt)
        for k, w in alone.items():
            w.step(s_alone[k], s_alone[k], None, dt)
            assert energy(k) <= e0[k] + tol_e, f"step {i}: island {k} gained {energy(k) - e0[k]:.3e} J"
            for n in groups[k]:
                a, b = s_alone[k].bodies[n], s.bodies[n]
                for x, y in ((a.velocity, b.velocity), (a.position, b.position), (a.q, b.q), (a.qdot, b.qdot)):
                    assert np.array_equal(x, y), (i, n, np.abs(x - y).max())
    assert s.contacts and both.penetrations(s, tolerance=0.0) == []
    z0 = both.state().bodies["top"].position[2]
    assert s.bodies["top"].position[2] < z0 - 0.065  # the top bar fell (7 cm to the base, less its skin)
