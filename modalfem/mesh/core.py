"""The tetrahedral ``Mesh``: points [m], cells, named boundary tags; validation and DOF points.

DOF ordering contract (used by every backend, constraint and result):
  * degree 1: node ``i`` is ``points[i]``;
  * degree 2: nodes are ``points`` followed by the midpoints of ``mesh.edges`` (unique vertex pairs
    ``(i, j)``, ``i < j``, sorted lexicographically);
  * DOF of node ``a`` and component ``c`` (0=x, 1=y, 2=z) is ``3 * a + c`` (node-major).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from modalfem.errors import MeshError

__all__ = ["TET_EDGES", "Mesh", "signed_volumes", "unique_rows"]

#: local vertex pairs of the 6 edges of a tetrahedron
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
#: local faces of a tetrahedron, ordered so that their normals point outwards for positive cells
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def unique_rows(rows: np.ndarray, n: int, **kwargs):
    """``np.unique(rows, axis=0, **kwargs)`` for integer rows with entries in [0, n): the rows are
    packed into one int64 key each when n ** width fits (10x faster than comparing rows), else
    compared as rows. Same results and order (lexicographic)."""
    rows = np.asarray(rows, dtype=np.int64)
    width = rows.shape[1]
    n = max(int(n), 1)
    if n ** width >= 2**63:
        return np.unique(rows, axis=0, **kwargs)
    key = np.zeros(len(rows), dtype=np.int64)
    for j in range(width):
        key = key * n + rows[:, j]
    out = np.unique(key, **kwargs)
    keys = out[0] if isinstance(out, tuple) else out
    uniq = np.empty((len(keys), width), dtype=np.int64)
    for j in range(width - 1, -1, -1):
        keys, uniq[:, j] = np.divmod(keys, n)
    return (uniq, *out[1:]) if isinstance(out, tuple) else uniq


def signed_volumes(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Signed volumes [m^3] of tetrahedra ``cells`` (m, 4) over ``points`` (n, 3)."""
    p = points[cells]
    d = p[:, 1:] - p[:, :1]
    return np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) / 6.0


def check_simplices(points, cells, *, corners: int, noun: str, cell: str, cells_name: str):
    """Shared checks of a simplex mesh (tetrahedra or cloth triangles): shapes, non-empty, integer
    indices in range, finite coordinates. Returns (points float64 (n, 3) [m], cells int64 (m, corners)).

    Raises:
        MeshError: the first problem found, naming the offending point or cell.
    """
    points = np.asarray(points, dtype=np.float64)
    cells = np.asarray(cells)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeshError(f"{noun} points must have shape (n, 3), got {points.shape}")
    if cells.ndim != 2 or cells.shape[1] != corners:
        raise MeshError(f"{noun} {cells_name} must have shape (m, {corners}), got {cells.shape}")
    if len(points) == 0 or len(cells) == 0:
        raise MeshError(f"{noun} is empty: {len(points)} points, {len(cells)} {cells_name}")
    if not np.issubdtype(cells.dtype, np.integer):
        if not np.all(np.isfinite(cells)) or np.any(cells != np.round(cells)):
            raise MeshError(f"{noun} {cells_name} must hold integer point indices")
    cells = cells.astype(np.int64)
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise MeshError(f"{noun} has {int(bad.sum())} points with NaN/inf coordinates (first: point {i} = {points[i]})")
    out = (cells < 0) | (cells >= len(points))
    if out.any():
        c = int(np.flatnonzero(out.any(axis=1))[0])
        raise MeshError(f"{cell} {c} references a missing point: {cells[c].tolist()} ({noun} has {len(points)} points)")
    return points, cells



@dataclass(frozen=True, eq=False)
class Mesh:
    """A linear tetrahedral mesh with named boundary tags.

    Construction validates the data and drops points no cell uses (renumbering cells and tags).

    Args:
        points: vertex coordinates (n, 3) [m].
        cells: tetrahedra (m, 4), vertex indices, positively oriented.
        tags: name -> boundary triangles (k, 3) of vertex indices (e.g. ``"x0"`` for a clamped end).

    Raises:
        MeshError: empty mesh, non-finite coordinates, cells referencing missing points, inverted or
            zero-volume tetrahedra (the first offending cell is named), malformed tags.
    """

    points: np.ndarray
    cells: np.ndarray
    tags: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        points, cells = check_simplices(self.points, self.cells, corners=4, noun="mesh", cell="cell",
                                        cells_name="tetrahedra")
        vols = signed_volumes(points, cells)
        p = points[cells]
        edge_len = np.linalg.norm(p[:, TET_EDGES[:, 0]] - p[:, TET_EDGES[:, 1]], axis=2).max(axis=1)
        tiny = np.abs(vols) <= 1e-10 * edge_len**3
        if tiny.any():
            c = int(np.flatnonzero(tiny)[0])
            raise MeshError(
                f"{int(tiny.sum())} tetrahedra have zero volume (first: cell {c}, vertices {cells[c].tolist()}, "
                f"volume {vols[c]:.3g} m^3)"
            )
        inv = vols < 0
        if inv.any():
            c = int(np.flatnonzero(inv)[0])
            raise MeshError(
                f"{int(inv.sum())} tetrahedra are inverted (first: cell {c}, vertices {cells[c].tolist()}, "
                f"signed volume {vols[c]:.3g} m^3)"
            )
        tags: dict[str, np.ndarray] = {}
        for name, facets in dict(self.tags).items():
            f = np.asarray(facets)
            if f.size == 0:
                f = f.reshape(0, 3)
            if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
                raise MeshError(f"tag {name!r} must be boundary triangles of shape (k, 3), got {f.shape}")
            if f.size and (f.min() < 0 or f.max() >= len(points)):
                raise MeshError(f"tag {name!r} references a missing point")
            tags[str(name)] = f.astype(np.int64)
        # Drop unused points and renumber.
        used = np.zeros(len(points), dtype=bool)
        used[cells.ravel()] = True
        if not used.all():
            for name, f in tags.items():
                if f.size and not used[f].all():
                    raise MeshError(f"tag {name!r} references points that no tetrahedron uses")
            new = np.full(len(points), -1, dtype=np.int64)
            new[used] = np.arange(int(used.sum()))
            points = points[used]
            cells = new[cells]
            tags = {k: new[f] for k, f in tags.items()}
        points.setflags(write=False)
        cells.setflags(write=False)
        for f in tags.values():
            f.setflags(write=False)
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "cells", cells)
        object.__setattr__(self, "tags", tags)
        object.__setattr__(self, "dropped_point_count", int((~used).sum()))

    # ------------------------------------------------------------------ sizes
    @property
    def point_count(self) -> int:
        return len(self.points)

    @property
    def cell_count(self) -> int:
        return len(self.cells)

    @cached_property
    def volumes(self) -> np.ndarray:
        """Cell volumes (m,) [m^3]."""
        return signed_volumes(self.points, self.cells)

    @property
    def volume(self) -> float:
        """Total volume [m^3]."""
        return float(self.volumes.sum())

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box (lower (3,), upper (3,)) [m]."""
        return self.points.min(axis=0), self.points.max(axis=0)

    # ------------------------------------------------------------------ topology
    @cached_property
    def edges(self) -> np.ndarray:
        """Unique edges (e, 2), ``i < j``, lexicographically sorted."""
        e = np.sort(self.cells[:, TET_EDGES].reshape(-1, 2), axis=1)
        return unique_rows(e, self.point_count).astype(self.cells.dtype, copy=False)

    @cached_property
    def cell_edges(self) -> np.ndarray:
        """Edge index of each local edge of each cell (m, 6), local order ``TET_EDGES``."""
        e = np.sort(self.cells[:, TET_EDGES].reshape(-1, 2), axis=1)
        n = np.int64(self.point_count)
        keys = e[:, 0] * n + e[:, 1]
        ekeys = self.edges[:, 0] * n + self.edges[:, 1]
        return np.searchsorted(ekeys, keys).reshape(-1, 6)

    @cached_property
    def boundary_facets(self) -> np.ndarray:
        """Boundary triangles (b, 3), outward oriented (faces used by exactly one cell)."""
        faces = self.cells[:, TET_FACES].reshape(-1, 3)
        key = np.sort(faces, axis=1)
        _, inv, counts = unique_rows(key, self.point_count, return_inverse=True, return_counts=True)
        return faces[counts[inv.ravel()] == 1]

    @cached_property
    def point_piece(self) -> np.ndarray:
        """Connected-piece label of every point (n,), pieces numbered from 0."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        c = self.cells
        rows = np.concatenate([c[:, 0], c[:, 0], c[:, 0]])
        cols = np.concatenate([c[:, 1], c[:, 2], c[:, 3]])
        g = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(self.point_count,) * 2)
        _, labels = connected_components(g, directed=False)
        return labels.astype(np.int64)

    @property
    def piece_count(self) -> int:
        """Number of disconnected pieces (each is a separate body with its own 6 rigid modes)."""
        return int(self.point_piece.max()) + 1

    # ------------------------------------------------------------------ tags and DOFs
    def tag_points(self, name: str) -> np.ndarray:
        """Sorted unique vertex indices of tag ``name``.

        Raises:
            ConstraintError: unknown tag (the message lists the known ones).
        """
        return np.unique(self.tag_facets(name))

    def tag_facets(self, name: str) -> np.ndarray:
        """Boundary triangles (k, 3) of tag ``name``; unknown names raise ``ConstraintError``."""
        from modalfem.errors import ConstraintError

        if name not in self.tags:
            known = ", ".join(sorted(self.tags)) or "none"
            raise ConstraintError(f"unknown tag {name!r}; this mesh has tags: {known}")
        return self.tags[name]

    def node_count(self, degree: int) -> int:
        """Number of Lagrange nodes for ``degree`` 1 or 2."""
        return self.point_count + (len(self.edges) if degree == 2 else 0)

    def dof_points(self, degree: int) -> np.ndarray:
        """Coordinates (N, 3) [m] of the Lagrange nodes in the canonical order (see module doc)."""
        if degree == 1:
            return self.points
        if degree == 2:
            e = self.edges
            return np.vstack([self.points, 0.5 * (self.points[e[:, 0]] + self.points[e[:, 1]])])
        from modalfem.errors import InputError

        raise InputError(f"degree must be 1 or 2, got {degree!r}")

    def cell_nodes(self, degree: int) -> np.ndarray:
        """Node indices of each cell: (m, 4) for P1; (m, 10) for P2 = 4 vertices + 6 edges (TET_EDGES order)."""
        if degree == 1:
            return self.cells
        return np.hstack([self.cells, self.point_count + self.cell_edges])

    def facet_nodes(self, facets: np.ndarray, degree: int) -> np.ndarray:
        """Unique node indices (vertices, plus edge midpoints for P2) lying on triangles ``facets``."""
        nodes = np.unique(facets)
        if degree == 1:
            return nodes
        e = np.sort(facets[:, [[0, 1], [1, 2], [0, 2]]].reshape(-1, 2), axis=1)
        n = np.int64(self.point_count)
        ekeys = self.edges[:, 0] * n + self.edges[:, 1]
        idx = np.searchsorted(ekeys, np.unique(e[:, 0] * n + e[:, 1]))
        return np.concatenate([nodes, self.point_count + idx])

    @cached_property
    def fingerprint(self) -> str:
        """SHA-256 of points, cells and tags: identifies the mesh in provenance records."""
        import hashlib

        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.points).tobytes())
        h.update(np.ascontiguousarray(self.cells).tobytes())
        for k in sorted(self.tags):
            h.update(k.encode())
            h.update(np.ascontiguousarray(self.tags[k]).tobytes())
        return h.hexdigest()

    def __repr__(self) -> str:
        lo, hi = self.bounds
        return (
            f"Mesh({self.point_count} points, {self.cell_count} tetrahedra, {self.piece_count} piece(s), "
            f"size {np.round(hi - lo, 6).tolist()} m, tags {sorted(self.tags)})"
        )
