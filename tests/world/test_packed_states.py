"""The start states a World pass packs once for its stages (``world._shared.packed_states``: read by the solid
contact stage and copied by the batched modal step): packed per list of names, and not changed by the batch."""

from __future__ import annotations

import numpy as np

from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.world import world as world_module
from modalfem.world._modal_step import ModalBatch
from modalfem.world._shared import packed_states

_FIELDS = ("position", "velocity", "angular_momentum", "orientation", "q", "qdot")


def _world(bar_model):
    rng = np.random.default_rng(4)
    bodies = [mw.Modal(bar_model, name=f"b{i}", position=(0.1 * i, 0.0, 0.05 + 0.02 * i),
                       velocity=rng.normal(size=3), angular_velocity=rng.normal(size=3)) for i in range(3)]
    w = mw.World(bodies=bodies, obstacles=[mw.Ground(0.0)], effects=[Gravity(), Contact()])
    s = w.state()
    for i, b in enumerate(bodies):
        s[b.name].q[:] = 1e-6 * (i + 1) * rng.normal(size=len(s[b.name].q))
        s[b.name].qdot[:] = 1e-3 * rng.normal(size=len(s[b.name].q))
    return w, s, [b.name for b in bodies]


def _ctx(s, dt=1e-3):
    return world_module._StepContext(s, world_module.WorldState(s.time, {}), world_module.WorldControl(), dt)


def test_packed_states_are_the_named_bodies_in_order(bar_model):
    """Each call packs the bodies it names, in its order (a second list, here reversed, is not given the first's
    arrays); the same names again get the same arrays."""
    w, s, names = _world(bar_model)
    ctx = _ctx(s)
    for order in (names, names[::-1]):
        got = packed_states(ctx, order)
        for f, a in zip(_FIELDS, got):
            want = np.concatenate([np.asarray(getattr(s[n], f)).reshape(-1) for n in order])
            assert np.array_equal(a.reshape(-1), want), (order, f)
        again = packed_states(ctx, list(order))
        assert all(x is y for x, y in zip(got, again))


def test_the_modal_batch_leaves_the_shared_packed_states_unchanged(bar_model):
    """The batched modal step copies the shared arrays before it applies the lifts and steps: after it they still
    hold the start states, and each body's new position holds its lift (the same step without the lift, plus the
    lift; both steps are the free flight's: the lift is added to the start position, then the same operations)."""
    w, s, names = _world(bar_model)
    batch = ModalBatch(w._modal)
    assert batch.names == names
    lift = {n: np.array([0.0, 0.0, -1e-4 * (i + 1)]) for i, n in enumerate(names)}
    ref = _ctx(s)
    batch.step(ref, set())
    no_lift = {n: ref.out.bodies[n].position.copy() for n in names}
    ctx = _ctx(s)
    ctx.lift = lift
    shared = [a.copy() for a in packed_states(ctx, names)]
    batch.step(ctx, set())
    for f, a, b in zip(_FIELDS, packed_states(ctx, names), shared):
        assert np.array_equal(a, b), f
    for n in names:
        p0 = s[n].position
        # (p0 + lift) + h v ... against p0 + h v ...: they differ by the lift to the rounding of |p| + |lift|
        tol = 8 * np.finfo(float).eps * (np.abs(p0).max() + np.abs(no_lift[n]).max())
        assert np.allclose(ctx.out.bodies[n].position - no_lift[n], lift[n], rtol=0, atol=tol), n
