"""A PNG sheet of mode shapes: each panel the deformed boundary surface coloured by |u|.

Each mode is scaled so that its largest displacement is ``amplitude`` (default 10 %) of the largest
extent of the body. For P2 results every boundary triangle is split into four at the edge nodes,
so the picture shows the quadratic field rather than its vertex interpolation.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from modalfem.errors import InputError
from modalfem.mesh.core import Mesh
from modalfem.result import ModalResult

__all__ = ["surface_triangles", "plot_mode_sheet"]

#: above this many boundary triangles the P2 sheet is drawn on the vertex triangles only
_MAX_SPLIT_TRIANGLES = 20000


def surface_triangles(mesh: Mesh, degree: int) -> np.ndarray:
    """Boundary triangles (t, 3) as node indices of the degree-``degree`` DOF order.

    Degree 1: ``mesh.boundary_facets``. Degree 2: each boundary triangle split into 4 at its edge nodes.
    """
    f = mesh.boundary_facets
    if degree == 1:
        return f
    n = np.int64(mesh.point_count)
    ekeys = mesh.edges[:, 0] * n + mesh.edges[:, 1]

    def mid(a, b):
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        return mesh.point_count + np.searchsorted(ekeys, lo * n + hi)

    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
    return np.concatenate(
        [np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))]
    )


def _view_vector(elev: float, azim: float) -> np.ndarray:
    e, a = np.radians(elev), np.radians(azim)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def _draw_triad(ax, origin: np.ndarray, length: float) -> None:
    for d, name in enumerate("xyz"):
        tip = origin.copy()
        tip[d] += length
        ax.plot(*np.stack([origin, tip], axis=1), color="0.25", lw=1.0)
        ax.text(*(origin + (tip - origin) * 1.25), name, color="0.25", fontsize=7, ha="center", va="center")


def plot_mode_sheet(
    path: str | os.PathLike,
    mesh: Mesh,
    result: ModalResult,
    *,
    count: int = 8,
    amplitude: float = 0.1,
    title: str | None = None,
    elev: float = 22.0,
    azim: float = -58.0,
    dpi: int = 110,
) -> Path:
    """Draw the first ``count`` deformation modes of ``result`` into a PNG.

    Args:
        path: PNG file to write.
        mesh: the mesh the modes were computed on.
        result: its modal analysis.
        count: number of modes shown (at most 4 per row).
        amplitude: largest displacement of each drawn mode as a fraction of the largest body extent.
        title: sheet title (e.g. body, material and constraints).
        elev: view elevation [degrees].
        azim: view azimuth [degrees].
        dpi: resolution [dots per inch].

    Returns:
        The path written.

    Raises:
        InputError: the result has no deformation modes, or the file cannot be written.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    k = min(int(count), result.shapes.shape[1])
    if k < 1:
        raise InputError("no deformation modes to draw")
    degree = result.degree
    if degree == 2 and len(mesh.boundary_facets) > _MAX_SPLIT_TRIANGLES:
        degree = 1
    tri = surface_triangles(mesh, degree)
    nodes = result.dof_points
    lo, hi = mesh.bounds
    size = float(np.max(hi - lo))
    cmap = matplotlib.colormaps["viridis"]
    light = _view_vector(elev + 25.0, azim - 35.0)

    ncols = k if k <= 4 else math.ceil(k / 2) if k <= 8 else 4
    nrows = math.ceil(k / ncols)
    fig = Figure(figsize=(3.9 * ncols, 3.5 * nrows + (0.5 if title else 0.2)))
    FigureCanvasAgg(fig)
    for i in range(k):
        u = result.shape(i)
        mag = np.linalg.norm(u, axis=1)
        umax = float(mag.max())
        s = amplitude * size / umax if umax > 0 else 0.0
        x = nodes + s * u
        p = x[tri]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        shade = 0.55 + 0.45 * np.abs(n @ light)
        rel = mag[tri].mean(axis=1) / umax if umax > 0 else np.zeros(len(tri))
        colours = cmap(rel)
        colours[:, :3] *= shade[:, None]

        ax = fig.add_subplot(nrows, ncols, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(p, facecolors=colours, edgecolors="none", linewidths=0))
        xl, xh = np.minimum(lo, x.min(axis=0)), np.maximum(hi, x.max(axis=0))
        pad = 0.02 * size
        xl, xh = xl - pad, xh + pad
        ax.set_xlim(xl[0], xh[0])
        ax.set_ylim(xl[1], xh[1])
        ax.set_zlim(xl[2], xh[2])
        ax.set_box_aspect(xh - xl, zoom=1.15)
        ax.set_proj_type("ortho")
        ax.view_init(elev=elev, azim=azim)
        ax.set_axis_off()
        _draw_triad(ax, xl.copy(), 0.12 * size)
        label = result.labels[i] if i < len(result.labels) else ""
        ax.set_title(f"{i + 1}. {label}\n{result.frequencies_hz[i]:.5g} Hz", fontsize=10)

    sm = ScalarMappable(cmap=cmap, norm=Normalize(0.0, 1.0))
    cax = fig.add_axes([0.935, 0.25, 0.012, 0.5])
    fig.colorbar(sm, cax=cax).set_label("|u| / max |u|", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0.0, right=0.92, bottom=0.0, top=0.9 if title else 0.95, wspace=0.0, hspace=0.08)
    path = Path(path)
    try:
        fig.savefig(path, dpi=dpi, format="png", facecolor="white")
    except OSError as exc:
        raise InputError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    return path
