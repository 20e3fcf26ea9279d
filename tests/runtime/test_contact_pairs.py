"""Contact between modal bodies (``runtime.pairs.ContactGroup``): momentum of every exchange, energy,
no interpenetration, obstacles in the same solve, refusals."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.errors import InputError, SimulationError
from modalfem.runtime.pairs import ContactGroup
from modalfem.runtime.rotation import quat_from_axis_angle

SIZE = (0.2, 0.1, 0.05)  # [m] the small_model block (tests/runtime/conftest.py)


def _two_blocks(model, *, gravity=False, spin=0.3, offset=(0.03, 0.02)):
    """Two steel blocks (0.2 x 0.1 x 0.05 m) flying at each other, the upper one turned about z."""
    body = rt.ModalBody(model, dtype=np.float64)
    effects = [rt.Gravity()] if gravity else []
    s1, s2 = rt.ModalSolver(body, effects=effects), rt.ModalSolver(body, effects=effects)
    a = s1.state(position=(0.0, 0.0, 0.0), velocity=(0.0, 0.0, 0.5), angular_velocity=(spin, 0.0, 0.0))
    b = s2.state(position=(offset[0], offset[1], 0.09), orientation=quat_from_axis_angle([0, 0, 1], 0.7),
                 velocity=(0.0, 0.0, -0.5), angular_velocity=(0.0, -spin, 0.0))
    return body, [s1, s2], [a, b]


def _momentum(solvers, states):
    P = sum(s.momentum(st)[0] for s, st in zip(solvers, states))
    L = sum(s.momentum(st)[1] for s, st in zip(solvers, states))
    return P, L


def _depth_inside_block(body, st_point_owner, st_block):
    """Deepest penetration [m] of the vertices of one block into the other, from the box geometry (the other
    block's rest box in its own axes, independent of the contact code): >= 0 inside."""
    x = body.positions(st_point_owner, precise=True)
    local = (x - st_block.position) @ st_block.rotation()  # into the block's axes about its centre of mass
    half = 0.5 * np.asarray(SIZE)
    depth = np.min(half - np.abs(local), axis=1)  # > 0 inside the rest box
    return float(depth.max())


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2])
def test_every_body_body_impulse_conserves_momentum_and_no_step_adds_energy(small_model, monkeypatch, dt):
    """No gravity, no obstacles: between the two blocks only their contact acts, so the total linear
    momentum is the same after every step to rounding, and so is the angular momentum about the origin in
    every step without a position correction (the impulses act on both bodies at one point); the reported
    exchange is what each body received. Kinetic + modal energy never grows in a contact solve (1e-12,
    rounding); over a whole step only by the free rotation's splitting error of these spinning anisotropic
    blocks (runtime.rotation; bounded, not the contact's: 1e-9 here)."""
    body, solvers, states = _two_blocks(small_model)
    group = ContactGroup(solvers, restitution=0.5, friction=0.4)
    solve, rises = group._solve, []

    def checked(states_, *args):
        before = sum(s.energy(st) for s, st in zip(solvers, states_))
        solve(states_, *args)
        rises.append(sum(s.energy(st) for s, st in zip(solvers, states_)) / before - 1.0)

    monkeypatch.setattr(group, "_solve", checked)
    P0, L0 = _momentum(solvers, states)
    scale_p = float(np.linalg.norm(body.mass * states[0].velocity))
    scale_l = scale_p * 0.2
    touched = 0
    for _ in range(int(0.3 / dt)):
        e0 = sum(s.energy(st) for s, st in zip(solvers, states))
        Pa0 = body.mass * states[0].velocity.copy()
        rep = group.step(states, dt)
        e1 = sum(s.energy(st) for s, st in zip(solvers, states))
        assert e1 <= e0 + 1e-9 * e0
        P, L = _momentum(solvers, states)
        assert np.abs(P - P0).max() <= 1e-12 * scale_p
        if not rep.separated:
            assert np.abs(L - L0).max() <= 1e-12 * scale_l
        L0 = L
        if rep.exchanged:
            touched += 1
            (ia, ib, J, _), = rep.exchanged
            assert (ia, ib) == (0, 1)
            assert np.allclose(body.mass * states[0].velocity - Pa0, J, rtol=0, atol=1e-12 * scale_p)
    assert touched > 0 and max(rises) <= 1e-12 and min(rises) < -1e-3  # impacts dissipate (e = 0.5)
    assert states[0].velocity[2] < 0.0 < states[1].velocity[2]  # they bounced apart
    assert body.modal_energy(states[0]) > 0.0  # and ring


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_blocks_dropped_on_each_other_do_not_interpenetrate(small_model, dt):
    """With gravity and the ground in the same solve, the upper block lands on the lower one and both come
    to rest: no vertex of one ends deeper inside the other's box than the tolerance plus its deformation
    bound, none below the ground."""
    body, solvers, states = _two_blocks(small_model, gravity=True, spin=0.0, offset=(0.02, 0.01))
    states[0].position[2] = 0.025
    states[0].velocity[:] = 0.0
    states[1].position[2] = 0.1
    states[1].velocity[:] = 0.0
    ground = rt.Obstacles([rt.Ground(0.0)], restitution=0.2, friction=0.5)
    group = ContactGroup(solvers, obstacles=ground, restitution=0.2, friction=0.5)
    from modalfem.runtime.contact import deformation_bound

    for _ in range(int(0.6 / dt)):
        group.step(states, dt)
        slack = group.tolerance + 2 * max(deformation_bound(body, st.q) for st in states)
        assert _depth_inside_block(body, states[0], states[1]) <= slack
        assert _depth_inside_block(body, states[1], states[0]) <= slack
        for st in states:
            assert body.positions(st, precise=True)[:, 2].min() >= -1e-12
    assert states[1].position[2] > states[0].position[2] + 0.04  # stacked
    assert abs(states[1].velocity[2]) < 0.05


def test_bad_group_input_is_refused(small_model):
    body = rt.ModalBody(small_model)
    s = rt.ModalSolver(body)
    with pytest.raises(InputError, match="at least one"):
        ContactGroup([])
    with pytest.raises(InputError, match="restitution"):
        ContactGroup([s], restitution=2.0)
    with pytest.raises(InputError, match="Obstacles"):
        ContactGroup([s], obstacles=[rt.Ground()])
    group = ContactGroup([s, s])
    st = s.state()
    with pytest.raises(SimulationError, match="2 states"):
        group.step([st], 1e-3)
    keep = st.copy()
    with pytest.raises(SimulationError, match="dt"):
        group.step([st, st.copy()], -1.0)
    assert np.array_equal(st.position, keep.position)
