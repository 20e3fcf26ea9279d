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
