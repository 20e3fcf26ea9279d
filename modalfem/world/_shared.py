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


def _vertex(name: str, p, n: int) -> int:
    if isinstance(p, (int, np.integer)) and 0 <= int(p) < n:
        return int(p)
    raise SimulationError(f"control impulse on {name!r}: the point must be a vertex index in [0, {n}), got {p!r}")
