"""Pictures of a ``World``: every body's surface and the obstacles, offscreen (matplotlib Agg).

``frame_sheet(world, states, path)`` draws states side by side from one fixed camera (the bounding box of every
body over all the states), modal bodies in bronze, tet bodies in green, cloth in blue, obstacles in grey, and
writes a PNG (all-or-nothing: a temporary file renamed into place).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["frame_sheet"]

_COLOURS = {"modal": "#c8963e", "tet": "#5a9e5a", "cloth": "#4f7fc4"}


def frame_sheet(world, states, path, *, titles=None, elev: float = 22.0, azim: float = -60.0, size: float = 3.6,
                dpi: int = 100) -> Path:
    """Draw ``states`` (WorldStates) of ``world`` side by side into the PNG ``path``; returns the path.

    Args:
        world: the ``World``.
        states: the states to draw, left to right.
        titles: one caption per state (default: the time [s]).
        elev, azim: camera angles [degrees].
        size: inches per panel.
        dpi: resolution.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    states = list(states)
    pts = np.concatenate([world.surface(s, b.name)[0] for s in states for b in world.bodies])
    lo, hi = pts.min(0), pts.max(0)
    span = float((hi - lo).max()) * 1.15
    mid = 0.5 * (lo + hi)
    fig = plt.figure(figsize=(size * len(states), size))
    light = np.array([0.3, -0.4, 0.87])
    light /= np.linalg.norm(light)
    for k, s in enumerate(states):
        ax = fig.add_subplot(1, len(states), k + 1, projection="3d")
        for o in world.obstacles:
            V, F = o.surface(s.time)
            tri = V[F]
            keep = np.all(np.abs(tri - mid).max(axis=2) < span, axis=1) | (len(F) <= 2)
            if len(F) <= 2:  # planes: a square around the bodies
                n = o.normal
                a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
                a /= np.linalg.norm(a)
                b = np.cross(n, a)
                c = o.point + o.offset(s.time) + n * 0.0
                c = c + ((mid - c) - n * ((mid - c) @ n))
                r = 0.5 * span
                tri = np.array([[c - r * a - r * b, c + r * a - r * b, c + r * a + r * b],
                                [c - r * a - r * b, c + r * a + r * b, c - r * a + r * b]])
                keep = np.ones(2, dtype=bool)
            ax.add_collection3d(Poly3DCollection(tri[keep], facecolor="#bbbbbb", edgecolor="none", alpha=0.5))
        for b in world.bodies:
            V, F = world.surface(s, b.name)
            tri = V[F]
            nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
            shade = 0.45 + 0.55 * np.abs(nrm @ light)
            base = np.array(matplotlib.colors.to_rgb(_COLOURS[b.kind]))
            col = np.clip(shade[:, None] * base, 0, 1)
            ax.add_collection3d(Poly3DCollection(tri, facecolors=col, edgecolor="none",
                                                 alpha=0.55 if b.kind == "cloth" else 1.0))
        ax.set_xlim(mid[0] - span / 2, mid[0] + span / 2)
        ax.set_ylim(mid[1] - span / 2, mid[1] + span / 2)
        ax.set_zlim(mid[2] - span / 2, mid[2] + span / 2)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev, azim)
        ax.set_axis_off()
        ax.set_title(titles[k] if titles is not None else f"t = {s.time:.3f} s")
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.png")
    try:
        fig.savefig(tmp, dpi=dpi)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
    return path
