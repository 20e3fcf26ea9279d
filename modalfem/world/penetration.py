"""Bodies' vertices inside the world's obstacles (``World.penetrations``): the check that goes with
``World.intersections`` (which compares bodies with each other only).

Each body's surface vertices (a cloth's every vertex) are measured against the ground, the planes, the spheres and
the boxes at the state's time (``signed_distance``: negative inside); a vertex counts when it is more than
``tolerance`` [m] inside. Triangle-mesh obstacles are not measured (an open mesh has no inside).

What depth the World's contacts allow is stated where they are made: a tet body's penalty contacts redo a step
whose contacts end deeper than ``MAX_DEPTH`` of the contact's margin (0.5 mm with the default 1 mm margin) and rest
about ``margin / DEPTH_SHARE`` deep under a heavy load (``_tet_contacts``); a modal body at rest in the solid solve
(restitution 0) stays within ``VELOCITY_STOP`` times its contact skin of it at any dt (5 um with a 1 mm margin), its lift against gravity acting at the
step's middle (``_solid_stage.gravity_lift``; tests/world/test_world_resting_dt.py), with restitution > 0 too (the
bounce decided on the approach at the step start: tests/world/test_world_restitution_dt.py).
"""

from __future__ import annotations

import math

import numpy as np

from modalfem.errors import InputError
from modalfem.world.obstacles import TriangleMesh

__all__ = ["Penetration", "obstacle_penetrations"]


class Penetration(tuple):
    """``(body, obstacle, count, depth)``: ``count`` vertices of ``body`` (its name) more than the tolerance inside
    ``world.obstacles[obstacle]``, the deepest ``depth`` [m] (> 0) inside."""

    __slots__ = ()

    def __new__(cls, body: str, obstacle: int, count: int, depth: float):
        return super().__new__(cls, (body, obstacle, count, depth))

    body = property(lambda self: self[0])
    obstacle = property(lambda self: self[1])
    count = property(lambda self: self[2])
    depth = property(lambda self: self[3])


def obstacle_penetrations(world, state, tolerance: float) -> list:
    """``Penetration`` per (body, obstacle) with vertices more than ``tolerance`` [m] (>= 0) inside (see the
    module docstring), in the order of the bodies and obstacles; empty when none is."""
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        tol = math.nan
    if not math.isfinite(tol) or tol < 0:
        raise InputError(f"penetration tolerance must be a finite length >= 0 [m], got {tolerance!r}")
    out = []
    for b in world.bodies:
        x, _ = world.surface(state, b.name)
        x = np.asarray(x, dtype=np.float64)
        if not len(x):
            continue
        for i, o in enumerate(world.obstacles):
            if isinstance(o, TriangleMesh):
                continue
            gap = np.asarray(o.signed_distance(x, state.time)[0], dtype=np.float64)
            inside = gap < -tol
            if inside.any():
                out.append(Penetration(b.name, i, int(inside.sum()), float(-gap[inside].min())))
    return out
