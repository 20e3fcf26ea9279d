"""A PNG frame sheet of a tetrahedral body in motion: one panel per frame, the boundary surface
coloured by the volume ratio J = V / V0 of the tetrahedron under each face (blue > 1, white = 1,
red < 1, dark red for inverted elements), all panels with the same axes so motion is comparable."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from modalfem.errors import InputError
from modalfem.mesh.core import TET_FACES, Mesh, signed_volumes

__all__ = ["boundary_faces", "plot_frame_sheet"]


def boundary_faces(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Outward boundary triangles (b, 3) and the cell each belongs to (b,)."""
    faces = mesh.cells[:, TET_FACES].reshape(-1, 3)
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    keep = counts[inv.ravel()] == 1
    return faces[keep], np.repeat(np.arange(mesh.cell_count), 4)[keep]


def plot_frame_sheet(path: str | os.PathLike, mesh: Mesh, frames, *, labels=None, ncols: int = 4,
                     title: str | None = None, elev: float = 22.0, azim: float = -58.0, dpi: int = 100,
                     ground: float | None = None) -> Path:
    """Draw positions ``frames`` (each (n, 3) [m]) of ``mesh`` into one PNG, written atomically.

    Args:
        path: PNG file to write.
        mesh: the rest mesh (cells, rest volumes).
        frames: sequence of vertex positions (n, 3) [m].
        labels: one caption per frame (e.g. ``"t = 0.10 s"``).
        ncols: panels per row.
        title: sheet title.
        elev, azim: view angles [degrees].
        dpi: resolution [dots per inch].
        ground: draw the plane z = ground [m] as a grey line of the bounding box floor.

    Returns:
        The path written.

    Raises:
        InputError: no frames, a frame of the wrong shape, or the file cannot be written.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    frames = [np.asarray(f, dtype=float) for f in frames]
    if not frames or any(f.shape != mesh.points.shape for f in frames):
        raise InputError(f"frames must be a non-empty list of ({mesh.point_count}, 3) position arrays")
    tri, cell = boundary_faces(mesh)
    allx = np.concatenate(frames)
    lo, hi = allx.min(axis=0), allx.max(axis=0)
    if ground is not None:
        lo[2] = min(lo[2], ground)
    pad = 0.03 * float(np.max(hi - lo))
    lo, hi = lo - pad, hi + pad
    cmap = matplotlib.colormaps["coolwarm_r"]
    e, a = np.radians(elev + 25.0), np.radians(azim - 35.0)
    light = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    ncols = max(1, min(int(ncols), len(frames)))
    nrows = math.ceil(len(frames) / ncols)
    fig = Figure(figsize=(3.2 * ncols, 3.4 * nrows + (0.5 if title else 0.1)))
    FigureCanvasAgg(fig)
    for i, x in enumerate(frames):
        J = signed_volumes(x, mesh.cells) / mesh.volumes
        p = x[tri]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        colours = cmap(np.clip(0.5 + 0.5 * np.log2(np.clip(J[cell], 0.25, 4.0)) / 2.0, 0.0, 1.0))
        colours[J[cell] <= 0] = (0.45, 0.0, 0.0, 1.0)
        colours[:, :3] *= (0.6 + 0.4 * np.abs(n @ light))[:, None]
        ax = fig.add_subplot(nrows, ncols, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(p, facecolors=colours, edgecolors=(0, 0, 0, 0.15), linewidths=0.2))
        if ground is not None:
            ax.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[1], lo[1], hi[1], hi[1], lo[1]], [ground] * 5,
                    color="0.5", lw=0.8)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(hi - lo, zoom=1.1)
        ax.set_proj_type("ortho")
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()
        caption = labels[i] if labels is not None and i < len(labels) else f"frame {i}"
        ax.set_title(f"{caption}\nmin J = {J.min():.2f}", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=0.9 if title else 0.95, wspace=0.0, hspace=0.2)
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fig.savefig(tmp, dpi=dpi, format="png", facecolor="white")
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    return path
