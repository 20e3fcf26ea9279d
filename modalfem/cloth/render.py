"""Pictures of cloth scenes, drawn by ``modalfem.output.animation`` (offscreen matplotlib, GIF by pillow).

The animation renderer culls back faces (it draws closed bodies); a cloth has two visible sides, so
each cloth triangle is drawn twice, once per orientation. Sphere obstacles are tessellated and drawn
with the cloth (one colour; the painter's order sorts them together).
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import InputError
from modalfem.output import animation

__all__ = ["render_cloth", "sphere_surface", "write_frame_sheet", "write_gif"]

write_gif = animation.write_gif
write_frame_sheet = animation.write_frame_sheet


def sphere_surface(center, radius: float, *, rings: int = 12, segments: int = 24):
    """A UV-sphere triangulation: (points (k, 3) [m], outward triangles (f, 3))."""
    c = np.asarray(center, dtype=float)
    th = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    body = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    pts = np.vstack([[0, 0, 1], body, [0, 0, -1]]) * radius + c
    tris = []
    s = segments
    for j in range(s):
        tris.append([0, 1 + j, 1 + (j + 1) % s])
    for i in range(rings - 2):
        for j in range(s):
            a, b = 1 + i * s + j, 1 + i * s + (j + 1) % s
            tris += [[a, a + s, b], [b, a + s, b + s]]
    last = len(pts) - 1
    base = 1 + (rings - 2) * s
    for j in range(s):
        tris.append([last, base + (j + 1) % s, base + j])
    return pts, np.asarray(tris, dtype=np.int64)


def render_cloth(frames, triangles, *, spheres=None, camera=None, ground_z=0.0, size=(480, 360), labels=None,
                 elev: float = 25.0, azim: float = -60.0):
    """Images (F, h, w, 3) uint8 of cloth frames, two-sided, with optional sphere obstacles.

    Args:
        frames: cloth positions (F, n, 3) [m] (or a list of (n, 3)).
        triangles: cloth triangles (m, 3).
        spheres: None, or one entry per frame: a list of ``(center (3,) [m], radius [m])`` balls.
        camera: ``modalfem.output.animation.Camera``; default fitted to all frames.
        ground_z: ground height [m] (None: no ground).
        size: (width, height) [px].
        labels: one caption per frame.
        elev, azim: view direction [deg] when the camera is fitted.
    """
    X = [np.asarray(f, dtype=float) for f in frames]
    tri = np.asarray(triangles, dtype=np.int64)
    tri2 = np.vstack([tri, tri[:, ::-1]])
    if spheres is not None and len(spheres) != len(X):
        raise InputError(f"spheres must have one entry per frame ({len(X)}), got {len(spheres)}")
    allp, allt = [], None
    for k, x in enumerate(X):
        sph = spheres[k] if spheres is not None else ()
        pts, tris = [x], [tri2]
        off = len(x)
        for c, r in sph:
            sp, st = sphere_surface(c, r)
            pts.append(sp)
            tris.append(st + off)
            off += len(sp)
        allp.append(np.vstack(pts))
        allt = np.vstack(tris)
    cam = camera or animation.fit_camera(np.asarray(allp), elev=elev, azim=azim, ground_z=ground_z,
                                         aspect=size[0] / size[1])
    return animation.render_frames(np.asarray(allp), allt, camera=cam, ground_z=ground_z, size=size, labels=labels,
                                   color=(0.25, 0.45, 0.75))
