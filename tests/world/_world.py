"""Shared numbers and helpers of the world tests."""

from __future__ import annotations

import numpy as np

#: size of the steel bar of the ``bar_model`` fixture [m]
BAR = (0.2, 0.1, 0.05)


def total_momentum(w, s) -> np.ndarray:
    """Sum of the bodies' linear momenta (3,) [kg m/s]."""
    p = np.zeros(3)
    for b in w.bodies:
        p += w.momentum(s, b.name)[0]
    return p


def resting_bar(bar_model, contact, height: float = 0.0):
    """A World with the steel bar ``height`` [m] above resting on the ground (its bottom at the skin, half
    ``contact``'s margin) and a second, far bar, so the ground's contacts are the solid solve's; (world, skin [m])."""
    from modalfem import world as mw
    from modalfem.effects import Gravity

    skin = 0.5 * contact.margin
    w0 = mw.World(bodies=[mw.Modal(bar_model, name="bar")], effects=[])
    s0 = w0.state()
    zmin = w0.surface(s0, "bar")[0][:, 2].min() - s0.bodies["bar"].position[2]
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0.0, 0.0, skin - zmin + height)),
                         mw.Modal(bar_model, name="far", position=(0.0, 1.0, 1.0))],
                 obstacles=[mw.Ground()], effects=[Gravity(bodies=["bar"]), contact])
    assert "bar" in w._fast.names  # the ground's contacts are the solid solve's
    return w, skin


def assert_stays_resting(w, skin: float, dt: float, tol: float, g: float = 9.81):
    """Steps ``resting_bar``'s world for 1 s (at least 20 steps) of ``dt`` [s]: the bar's bottom within ``tol`` [m]
    of the skin, no vertex in the ground, the total energy never above its start (the solve's rule admits 1e-12 of its
    quadratic term; the free rotation keeps 1e-9 of m g r). Returns the end state."""
    s = w.state()
    e0 = w.energy(s, "bar")["total"] + w.energy(s, "far")["total"]
    mass = w._modal["bar"]["body"].mass
    for i in range(max(20, int(round(1.0 / dt)))):
        w.step(s, s, None, dt)
        low = float(w.surface(s, "bar")[0][:, 2].min())
        assert abs(low - skin) <= tol, f"step {i}: bottom {low:.6e} m, skin {skin:.1e} m"
        assert w.penetrations(s, tolerance=0.0) == []
        assert w.energy(s, "bar")["total"] + w.energy(s, "far")["total"] <= e0 + 1e-9 * mass * g * 0.1
    return s
