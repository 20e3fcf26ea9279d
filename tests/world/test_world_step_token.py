"""A ``World`` step marks the state it writes with a token (``WorldState.token``: that step and a CRC-32 of the
state's time and arrays) instead of keeping a copy of every body's arrays to compare with the next step's start
(issue 17): the tet solvers' caches are kept only when a step starts from the state the last step wrote, unedited.
A state edited in place since (its arrays' bytes changed) fails the checksum, and the step starts afresh: a run from
it on the used World equals a new World's run from it, bit for bit (as tests/world/test_world_rerun.py for
``w.state()`` and older states)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.mesh import box


def _scene(bar_model):
    from modalfem import tet
    from modalfem.material import Material

    cube = tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))
    bar = mw.Modal(bar_model, name="bar", position=(0.09, 0.03, 0.11))
    return mw.World(bodies=[bar, mw.Tet(cube, name="cube", position=(0.0, 0.0, 0.0005))], obstacles=[mw.Ground(0.0)],
                    effects=[Gravity(), Contact(restitution=0.2, friction=0.5)])


def _arrays(s):
    b = s.bodies["bar"]
    return [s.bodies["cube"].x, s.bodies["cube"].v, b.q, b.qdot, b.position, b.orientation, b.velocity,
            b.angular_momentum]


def test_a_step_marks_the_state_it_wrote_and_no_other(bar_model):
    w = _scene(bar_model)
    s = w.state()
    assert s.token is None
    w.step(s, s, None, 1e-2)
    assert s.token is not None and s.copy().token == s.token
    t1 = s.token
    w.step(s, s, None, 1e-2)
    assert s.token != t1  # (each step its own)
    assert w.state().token is None


@pytest.mark.parametrize("edit", ["tet velocity", "modal position"])
def test_a_state_edited_in_place_after_a_step_starts_afresh(bar_model, edit):
    w = _scene(bar_model)
    s = w.state()
    for _ in range(6):
        w.step(s, s, None, 1e-2)
    if edit == "tet velocity":  # in place: the same state and array objects, the token unchanged
        s.bodies["cube"].v[5, 2] += 0.01
    else:
        s.bodies["bar"].position[2] -= 1e-4
    edited = s.copy()
    other = _scene(bar_model)
    for _ in range(6):
        w.step(s, s, None, 1e-2)
        other.step(edited, edited, None, 1e-2)
    for x, y in zip(_arrays(s), _arrays(edited)):
        assert np.array_equal(x, y)
