"""Names the world's step stages share (SI units): contact thresholds, the key of the tet reaction records in
``WorldState.contacts`` and the check of a strike's vertex index."""

from __future__ import annotations

import numpy as np

from modalfem.errors import SimulationError

#: impacts slower than this [m/s] do not bounce and are not heard (resting contact)
BOUNCE_THRESHOLD = 0.05
#: fraction of a penetration depth [m] undone per step by the solid contact solve (its push-out speed is
#: ``PUSH_OUT * depth / dt``)
PUSH_OUT = 0.2
#: modes with omega dt above this take no part in the velocity-level contact between modal bodies
SLOW = 0.5
#: ``WorldState.contacts[(_REACTION_KEY, tet body)]``: the energy [J] stored in the tet body's penalty contacts at
#: the end of the last step (``World.energy``'s ``contact``); ``[(_REACTION_KEY, tet body, "force")]``: the normal
#: force [N] its contacts bore from each modal body (the next step's stiffness is sized to hold it), ``[(...,
#: "obstacle force")]`` its vertices' from the obstacles (n,) [N];
#: ``[(_REACTION_KEY, tet body, "impact", modal body)]``: an impact in progress (``_tet_restitution``)
_REACTION_KEY = "tet reaction"


def pack_states(bodies: dict, names: list) -> tuple:
    """The modal states ``bodies[n]`` (``runtime.State``) of the bodies ``names``, packed: ``(position, velocity,
    angular_momentum, orientation)`` (m, 3), (m, 3), (m, 3), (m, 4) and every body's ``q``, ``qdot`` one after
    another (float64, new arrays)."""
    sts = [bodies[n] for n in names]
    return (np.array([s.position for s in sts], dtype=np.float64).reshape(-1, 3),
            np.array([s.velocity for s in sts], dtype=np.float64).reshape(-1, 3),
            np.array([s.angular_momentum for s in sts], dtype=np.float64).reshape(-1, 3),
            np.array([s.orientation for s in sts], dtype=np.float64).reshape(-1, 4),
            np.concatenate([np.zeros(0)] + [s.q for s in sts]),
            np.concatenate([np.zeros(0)] + [s.qdot for s in sts]))


def packed_states(ctx, names: list) -> tuple:
    """``pack_states`` of the pass's start states (``ctx.state_in``), made once per pass (``ctx.packed``) for its
    stages: the solid contact stage and the batched modal step read the same bodies. Shared: callers must not change
    the arrays."""
    p = ctx.packed
    if p is not None and p[0] == names:
        return p[1]
    arrays = pack_states(ctx.state_in.bodies, names)
    ctx.packed = (names, arrays)
    return arrays


def _vertex(name: str, p, n: int) -> int:
    if isinstance(p, (int, np.integer)) and 0 <= int(p) < n:
        return int(p)
    raise SimulationError(f"control impulse on {name!r}: the point must be a vertex index in [0, {n}), got {p!r}")
