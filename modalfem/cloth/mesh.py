"""The cloth ``ClothMesh``: a validated triangle surface (points [m], triangles), grid generator, reader.

Validation rejects what the cloth energies cannot handle, each with one line naming the first
offender: wrong shapes, non-finite coordinates, missing vertices, repeated vertices in a triangle,
degenerate (zero-area) triangles, duplicate triangles and non-manifold edges (shared by more than two
triangles). Unused points are kept (they would have no mass: the solver rejects them).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from modalfem.errors import InputError, MeshError
from modalfem.mesh.core import check_simplices

__all__ = ["ClothMesh", "Hinges", "grid", "read_cloth"]

#: a triangle is degenerate when its area is below this fraction of its longest edge squared
DEGENERATE_RATIO = 1e-10


@dataclass(frozen=True)
class Hinges:
    """Interior edges with their two opposite vertices (the bending stencils).

    Attributes:
        vertices: (h, 4) vertex indices ``(e0, e1, a, b)``: shared edge ``e0 -> e1``, ``a`` opposite in
            the triangle where the edge runs ``e0 -> e1``, ``b`` opposite in the other one.
    """

    vertices: np.ndarray


@dataclass(frozen=True, eq=False)
class ClothMesh:
    """A manifold (possibly open) triangle mesh for cloth.

    Args:
        points: vertex coordinates (n, 3) [m]; the rest shape of the cloth.
        triangles: (m, 3) vertex indices.

    Raises:
        MeshError: malformed arrays, non-finite points, bad indices, repeated vertices in a triangle,
            degenerate or duplicate triangles, non-manifold edges.
    """

    points: np.ndarray
    triangles: np.ndarray

    def __post_init__(self) -> None:
        p, t = check_simplices(self.points, self.triangles, corners=3, noun="cloth", cell="triangle",
                               cells_name="triangles")
        rep = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 0] == t[:, 2])
        if rep.any():
            c = int(np.flatnonzero(rep)[0])
            raise MeshError(f"triangle {c} repeats a vertex: {t[c].tolist()} ({int(rep.sum())} such triangles)")
        q = p[t]
        area2 = np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1)
        longest2 = np.max(np.sum((q - np.roll(q, 1, axis=1)) ** 2, axis=2), axis=1)
        deg = area2 <= 2.0 * DEGENERATE_RATIO * longest2
        if deg.any():
            c = int(np.flatnonzero(deg)[0])
            raise MeshError(
                f"triangle {c} is degenerate (area {0.5 * area2[c]:.3g} m^2 for longest edge "
                f"{np.sqrt(longest2[c]):.3g} m; {int(deg.sum())} such triangles)"
            )
        key = np.sort(t, axis=1)
        _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
        if (counts > 1).any():
            c = int(first[np.flatnonzero(counts > 1)[0]])
            raise MeshError(f"triangle {c} appears more than once: {t[c].tolist()}")
        e = np.sort(t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        ue, ecount = np.unique(e, axis=0, return_counts=True)
        if (ecount > 2).any():
            k = int(np.flatnonzero(ecount > 2)[0])
            raise MeshError(
                f"cloth mesh is non-manifold: edge {ue[k].tolist()} is shared by {int(ecount[k])} triangles "
                f"({int((ecount > 2).sum())} such edges)"
            )
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "triangles", t)

    @property
    def point_count(self) -> int:
        """Number of vertices n."""
        return len(self.points)

    @property
    def triangle_count(self) -> int:
        """Number of triangles m."""
        return len(self.triangles)

    @cached_property
    def areas(self) -> np.ndarray:
        """Rest areas (m,) [m^2]."""
        q = self.points[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1)

    @cached_property
    def edges(self) -> np.ndarray:
        """Unique edges (k, 2), ``i < j``, sorted lexicographically."""
        e = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        return np.unique(e, axis=0)

    @cached_property
    def hinges(self) -> Hinges:
        """Interior edges and their opposite vertices (see ``Hinges``)."""
        t = self.triangles
        # directed half-edges (a -> b) with the opposite vertex c
        a = t.reshape(-1)
        b = t[:, [1, 2, 0]].reshape(-1)
        c = t[:, [2, 0, 1]].reshape(-1)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        key = lo * np.int64(len(self.points)) + hi
        order = np.argsort(key, kind="stable")
        ks = key[order]
        same = np.flatnonzero(ks[1:] == ks[:-1])
        h1, h2 = order[same], order[same + 1]
        verts = np.stack([a[h1], b[h1], c[h1], c[h2]], axis=1)
        return Hinges(vertices=verts)

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """Indices of vertices on open boundary edges (sorted)."""
        e = np.sort(self.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        ue, cnt = np.unique(e, axis=0, return_counts=True)
        return np.unique(ue[cnt == 1])

    def lumped_masses(self, areal_density: float) -> np.ndarray:
        """Vertex masses (n,) [kg]: a third of each adjacent triangle's rest area times ``areal_density``.

        Args:
            areal_density: mass per unit area [kg/m^2], finite and > 0.

        Raises:
            InputError: ``areal_density`` not finite or <= 0.
        """
        rho = float(areal_density)
        if not np.isfinite(rho) or rho <= 0:
            raise InputError(f"areal density must be finite and > 0 kg/m^2, got {areal_density!r}")
        m = np.zeros(self.point_count)
        np.add.at(m, self.triangles.reshape(-1), np.repeat(self.areas * rho / 3.0, 3))
        return m


def grid(size=(1.0, 1.0), vertices=(32, 32), *, origin=(0.0, 0.0, 0.0), plane: str = "xy") -> ClothMesh:
    """A rectangular cloth of ``vertices[0] x vertices[1]`` vertices, quads split along alternating diagonals.

    Args:
        size: side lengths (a, b) [m] along the plane's first and second axis.
        vertices: vertex counts (nu, nv) along those axes, each >= 2.
        origin: corner of the cloth [m].
        plane: ``"xy"`` (horizontal, normal +z), ``"xz"`` (vertical, normal -y) or ``"yz"``.

    Returns:
        ClothMesh with vertex ``i + nu * j`` at ``origin + i * a/(nu-1) e_u + j * b/(nv-1) e_v``.

    Raises:
        InputError: non-positive sizes, fewer than 2 vertices per side, unknown plane.
    """
    axes = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    if plane not in axes:
        raise InputError(f"plane must be one of {sorted(axes)}, got {plane!r}")
    a, b = (float(s) for s in size)
    if not (np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0):
        raise InputError(f"cloth size must be two finite lengths > 0 m, got {size!r}")
    nu, nv = (int(k) for k in vertices)
    if nu < 2 or nv < 2 or nu != vertices[0] or nv != vertices[1]:
        raise InputError(f"cloth vertex counts must be integers >= 2, got {vertices!r}")
    u, v = np.meshgrid(np.linspace(0.0, a, nu), np.linspace(0.0, b, nv), indexing="xy")
    pts = np.zeros((nu * nv, 3))
    iu, iv = axes[plane]
    pts[:, iu] = u.reshape(-1)
    pts[:, iv] = v.reshape(-1)
    pts += np.asarray(origin, dtype=float)
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="xy")
    i, j = i.reshape(-1), j.reshape(-1)
    v00, v10, v01, v11 = i + nu * j, i + 1 + nu * j, i + nu * (j + 1), i + 1 + nu * (j + 1)
    alt = (i + j) % 2 == 0
    t1 = np.where(alt[:, None], np.stack([v00, v10, v11], 1), np.stack([v00, v10, v01], 1))
    t2 = np.where(alt[:, None], np.stack([v00, v11, v01], 1), np.stack([v10, v11, v01], 1))
    return ClothMesh(pts, np.vstack([t1, t2]))


def read_cloth(path, *, unit_scale: float = 1.0) -> ClothMesh:
    """Read the triangles of any meshio-readable file as a cloth (other cell types are ignored).

    Args:
        path: file name (``.msh``, ``.obj``, ``.ply``, ``.stl``, ``.vtk``, ...).
        unit_scale: factor from file units to metres (e.g. 1e-3 for millimetres), > 0.

    Returns:
        ClothMesh (points the triangles do not use are dropped, triangles renumbered).

    Raises:
        InputError: missing file or bad ``unit_scale``.
        MeshError: unreadable file, no triangles, or a triangle mesh failing validation.
    """
    import meshio

    p = Path(path)
    if not p.is_file():
        raise InputError(f"cloth mesh file not found: {p}")
    s = float(unit_scale)
    if not np.isfinite(s) or s <= 0:
        raise InputError(f"unit_scale must be finite and > 0, got {unit_scale!r}")
    try:
        m = meshio.read(p)
    except Exception as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeshError(f"cannot read cloth mesh {p}: {msg}") from exc
    tris = [np.asarray(c.data) for c in m.cells if c.type == "triangle"]
    if not tris:
        raise MeshError(f"{p} holds no triangles (cell types: {sorted({c.type for c in m.cells})})")
    t = np.vstack(tris).astype(np.int64)
    used, inv = np.unique(t, return_inverse=True)
    pts = np.asarray(m.points, dtype=float)
    if pts.shape[1] == 2:
        pts = np.hstack([pts, np.zeros((len(pts), 1))])
    return ClothMesh(pts[used] * s, inv.reshape(-1, 3))
