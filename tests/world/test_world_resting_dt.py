"""A modal body resting on the ground in a ``World`` whose solid solve holds it (a second body in the world, so the
ground's contacts are the compiled modal contacts' and the one solve's, not the body's own runtime contacts) stays
where it rests at any dt, with no energy gained (issue 17).

The solve's contacts hold a body at the skin, half the contact margin above the ground. Before the translation's
velocity change acted at the step's middle (``_solid_stage._solve``), it acted at the step start and the no-gain rule
stopped the impulse that would hold a body at rest (lifting it at the start costs ``m (g dt)^2 / 2``): the body fell
``g dt^2 / 2`` within the step before the next one held it. With these tests on 7217f04: the bottom went 16 um below
the ground at dt = 10 ms, 49 mm at 0.1 s and 4.9 m at 1 s (fell through), and 6.5 um below the skin at 1 ms.

Tolerance: the sequential-impulse solve stops once a sweep changes no contact's velocity by more than
``VELOCITY_STOP`` of the velocity that closes the skin in one step (``skin / dt``), which leaves an end gap within
``VELOCITY_STOP * skin`` of its target in that step; so the bottom must stay within that of the skin (5 um here),
never below the ground (``World.penetrations`` at tolerance 0), and the total energy never above its start.

Restitution 0 here; e > 0: tests/world/test_world_restitution_dt.py."""

from __future__ import annotations

import numpy as np
import pytest
from _world import assert_stays_resting, resting_bar

from modalfem.effects import Contact
from modalfem.world._solid_stage import VELOCITY_STOP

G = 9.81  # [m/s^2]


@pytest.mark.parametrize("dt", [1e-3, 1e-2, 0.1, 1.0])
def test_a_modal_body_resting_on_the_ground_in_a_world_stays_at_any_dt(bar_model, dt):
    contact = Contact(restitution=0.0)  # e > 0: test_world_restitution_dt.py
    w, skin = resting_bar(bar_model, contact)
    s = assert_stays_resting(w, skin, dt, VELOCITY_STOP * skin, G)
    assert np.linalg.norm(s.bodies["bar"].velocity) < 1e-2 * G * dt  # at rest, not holding a step's g dt
