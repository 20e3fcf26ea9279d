"""A PNG sheet of mode shapes: each panel the deformed boundary surface coloured by |u|.

Each mode is scaled so that its largest displacement is ``amplitude`` (default 10 %) of the largest
extent of the body. For P2 results every boundary triangle is split into four at the edge nodes,
so the picture shows the quadratic field rather than its vertex interpolation.

Rendering is a 2D orthographic projection done here with numpy (the camera of mplot3d's
``view_init(elev, azim)``): back faces of the closed, outward-oriented boundary are culled, the rest
sorted far to near (painter's algorithm) and drawn by one Gouraud-triangle call per panel. The
48k-DOF, 8-panel sheet took 4.4 s with mplot3d's ``Poly3DCollection`` and takes 0.25-0.6 s now.
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

#: above this many split triangles the P2 sheet is drawn on the vertex triangles only (a panel is
#: ~430 x 380 pixels: more triangles only cost drawing time)
_MAX_SPLIT_TRIANGLES = 24000


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


def _view_basis(elev: float, azim: float) -> np.ndarray:
    """Rows: screen right, screen up, towards the viewer (mplot3d's orthographic camera convention)."""
    e, a = np.radians(elev), np.radians(azim)
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.array([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)])
    return np.stack([right, up, _view_vector(elev, azim)])


def _triangles_artist(xy: np.ndarray, rgba: np.ndarray):
    """A matplotlib artist drawing filled triangles ``xy`` (t, 3, 2) in the given order, each colour
    ``rgba`` (t, 3, 4) interpolated from its corners.

    One ``draw_gouraud_triangles`` call for all of them (one C loop in Agg). A ``PolyCollection``
    builds a ``Path`` object per triangle first, and mplot3d's ``Poly3DCollection`` also re-projects
    and sorts them one by one in Python: 4.4 s for the 8 panels of a 48k-DOF sheet, against 0.25 s.
    """
    from matplotlib.artist import Artist

    class Triangles(Artist):
        def draw(self, renderer):
            if not self.get_visible() or not len(xy):
                return
            gc = renderer.new_gc()
            renderer.draw_gouraud_triangles(gc, xy, rgba, self.axes.transData.frozen())
            gc.restore()

    return Triangles()


def _draw_triad(ax, origin: np.ndarray, length: float, view: np.ndarray) -> None:
    o = view[:2] @ origin
    for d, name in enumerate("xyz"):
        tip = o + length * view[:2, d]
        ax.plot([o[0], tip[0]], [o[1], tip[1]], color="0.25", lw=1.0)
        lab = o + 1.25 * (tip - o)
        ax.text(lab[0], lab[1], name, color="0.25", fontsize=7, ha="center", va="center")


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
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    k = min(int(count), result.shapes.shape[1])
    if k < 1:
        raise InputError("no deformation modes to draw")
    degree = result.degree
    if degree == 2 and 4 * len(mesh.boundary_facets) > _MAX_SPLIT_TRIANGLES:
        degree = 1
    tri = surface_triangles(mesh, degree)
    nodes = result.dof_points
    lo, hi = mesh.bounds
    size = float(np.max(hi - lo))
    cmap = matplotlib.colormaps["viridis"]
    light = _view_vector(elev + 25.0, azim - 35.0)
    view = _view_basis(elev, azim)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

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
        # the surface is closed and outward oriented: triangles facing away are hidden behind the others
        front = n @ view[2] >= 0.0
        q = x @ view.T  # screen x, screen y, depth towards the viewer
        t = tri[front]
        order = np.argsort(q[t, 2].mean(axis=1), kind="stable")  # painter's algorithm: far to near
        t = t[order]
        shade = 0.55 + 0.45 * np.abs(n[front][order] @ light)
        rel = mag[t] / umax if umax > 0 else np.zeros(t.shape)
        colours = cmap(rel)  # (t, 3, 4): |u| at the corners, interpolated across each triangle
        colours[..., :3] *= shade[:, None, None]

        ax = fig.add_subplot(nrows, ncols, i + 1)
        ax.add_artist(_triangles_artist(np.ascontiguousarray(q[t, :2]), np.ascontiguousarray(colours)))
        origin = np.minimum(lo, x.min(axis=0)) - 0.02 * size
        triad = view[:2] @ origin + 1.4 * 0.12 * size * np.vstack([np.zeros(2), view[:2].T])
        box = np.vstack([corners @ view[:2].T, q[:, :2], triad])
        xl, xh = box.min(axis=0), box.max(axis=0)
        pad = 0.03 * size
        ax.update_datalim([xl - pad, xh + pad])
        ax.margins(0.0)
        ax.autoscale_view()
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_axis_off()
        _draw_triad(ax, origin, 0.12 * size, view)
        label = result.labels[i] if i < len(result.labels) else ""
        # a fixed title position: matplotlib then skips measuring the (hidden) tick labels to place it
        ax.set_title(f"{i + 1}. {label}\n{result.frequencies_hz[i]:.5g} Hz", fontsize=10, y=1.0)

    sm = ScalarMappable(cmap=cmap, norm=Normalize(0.0, 1.0))
    cax = fig.add_axes([0.935, 0.25, 0.012, 0.5])
    fig.colorbar(sm, cax=cax).set_label("|u| / max |u|", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.subplots_adjust(left=0.0, right=0.92, bottom=0.0, top=0.9 if title else 0.95, wspace=0.0, hspace=0.08)
    path = Path(path)
    try:
        # zlib level 1: 4x faster to encode than the default 6, the file ~1.3x larger
        fig.savefig(path, dpi=dpi, format="png", facecolor="white", pil_kwargs={"compress_level": 1})
    except OSError as exc:
        raise InputError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    return path
