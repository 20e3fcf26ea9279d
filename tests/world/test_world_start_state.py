"""``World.state()`` is the start state (every body where its definition places it, t = 0), also after the world
has stepped: a cloth's came from its ``ClothScene``'s current positions, which every cloth step overwrites, so a run
started again from ``w.state()`` began with the cloth where the last run left it (inside the bodies it had fallen
onto: the collision pipeline then failed, "left 65 colliding pairs")."""

from __future__ import annotations

import numpy as np

from modalfem import world as mw
from modalfem.effects import Contact, Gravity


def test_the_start_state_of_a_world_with_a_cloth_is_the_same_after_steps(cloth_model):
    w = mw.World(bodies=[mw.Cloth(cloth_model, name="cloth", x0=cloth_model.mesh.points + (0.0, 0.0, 0.05))],
                 obstacles=[mw.Ground(0.0)], effects=[Gravity(), Contact()])
    s0 = w.state()
    s = w.state()
    for _ in range(5):
        w.step(s, s, None, 1e-3)
    assert not np.array_equal(s.bodies["cloth"].x, s0.bodies["cloth"].x)  # (it did move)
    again = w.state()
    assert again.time == 0.0
    for a, b in ((again.bodies["cloth"].x, s0.bodies["cloth"].x), (again.bodies["cloth"].v, s0.bodies["cloth"].v),
                 (again.bodies["cloth"].released, s0.bodies["cloth"].released)):
        assert np.array_equal(a, b)
    again.bodies["cloth"].x[:] = 1.0  # (a copy: changing it changes no later start state)
    assert np.array_equal(w.state().bodies["cloth"].x, s0.bodies["cloth"].x)
