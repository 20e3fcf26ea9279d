"""Triangle surfaces to render a body with: ``RenderSurface``, ``read_surface`` (OBJ/STL/PLY/OFF) and
``orient_outward`` (consistent, outward triangle orientation).

Used by ``modalfem.reduction.transfer`` (coarse physics, fine render surface). Reading goes through
meshio; a file that is not a triangle surface is refused with one line naming what it holds.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from modalfem.errors import InputError, MeshError

__all__ = ["SURFACE_FORMATS", "RenderSurface", "orient_outward", "read_surface"]

#: surface formats read by ``read_surface`` (meshio readers)
SURFACE_FORMATS = (".obj", ".stl", ".ply", ".off")

@dataclass(frozen=True, eq=False)
class RenderSurface:
    """A triangle surface to render a body with.

    Attributes:
        vertices: (nv, 3) [m].
        triangles: (nt, 3) int64 indices into ``vertices`` (``read_surface`` orients them
            consistently and outwards, ``orient_outward``).
        source: where it came from (``{"file": ..., "unit_scale": ...}`` or ``{}`` for arrays).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    source: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=np.float64)
        t = np.asarray(self.triangles)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise InputError(f"render surface vertices must have shape (nv, 3) with nv >= 3, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise InputError(f"render surface has {int(np.sum(~np.isfinite(v).all(axis=1)))} non-finite vertices")
        if t.ndim != 2 or t.shape[1] != 3 or len(t) < 1 or t.dtype.kind not in "iu":
            raise InputError(f"render surface triangles must be integer indices of shape (nt, 3), got {t.shape}")
        if t.min() < 0 or t.max() >= len(v):
            raise InputError(f"render surface triangles index vertices {int(t.min())}..{int(t.max())}, "
                             f"but there are {len(v)} vertices")
        used = np.zeros(len(v), dtype=bool)
        used[t.ravel()] = True
        if not used.all():  # unused vertices would carry modes nobody renders
            new = np.cumsum(used) - 1
            v, t = v[used], new[t]
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", t.astype(np.int64))

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def fingerprint(self) -> str:
        """SHA-256 of the vertices (float64) and triangles (int64), little-endian."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices, dtype="<f8").tobytes())
        h.update(np.ascontiguousarray(self.triangles, dtype="<i8").tobytes())
        return h.hexdigest()

    def vertex_areas(self) -> np.ndarray:
        """A third of the adjacent triangles' areas per vertex (nv,) [m^2]."""
        p = self.vertices[self.triangles]
        a = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        return np.bincount(self.triangles.ravel(), weights=np.repeat(a / 3.0, 3), minlength=self.vertex_count)


def read_surface(path: str | os.PathLike, *, unit_scale: float = 1.0) -> RenderSurface:
    """Read a triangle surface (.obj, .stl, .ply, .off) with meshio.

    Args:
        path: the file.
        unit_scale: factor turning file coordinates into metres (1e-3 for a file in mm).

    Returns:
        ``RenderSurface`` (unused vertices dropped; triangles oriented consistently and outwards by
        ``orient_outward``; ``source["flipped_triangles"]`` counts the reversed ones).

    Raises:
        MeshError: missing or unreadable file, unknown extension, or no triangles in it (the cell
            types it holds are named). One line.
    """
    import meshio

    p = Path(path)
    name = repr(str(path))
    if not (isinstance(unit_scale, (int, float)) and np.isfinite(unit_scale) and unit_scale > 0):
        raise InputError(f"unit_scale must be a finite number > 0, got {unit_scale!r}")
    if not p.is_file():
        raise MeshError(f"render surface {name} does not exist" if not p.exists() else
                        f"render surface {name} is not a file")
    if p.suffix.lower() not in SURFACE_FORMATS:
        raise MeshError(f"render surface {name}: unknown extension {p.suffix or '(none)'!r}; "
                        f"give a triangle surface: {', '.join(SURFACE_FORMATS)}")
    said = io.StringIO()
    try:  # meshio prints its reader's error and then calls sys.exit(1); the one line below says what went wrong
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            m = meshio.read(p)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - any parse failure is one clear line
        lines = [ln.strip() for ln in said.getvalue().splitlines() if ln.strip()]
        text = str(exc).splitlines()[0] if str(exc) and not isinstance(exc, SystemExit) else (
            lines[0] if lines else type(exc).__name__)
        raise MeshError(f"render surface {name} cannot be read as {p.suffix.lower()[1:].upper()}: {text}") from None
    tris = [np.asarray(c.data) for c in m.cells if c.type == "triangle"]
    others = sorted({f"{c.type} x {len(c.data)}" for c in m.cells if c.type != "triangle" and len(c.data)})
    if not tris or sum(len(t) for t in tris) == 0:
        held = ", ".join(others) if others else "no cells"
        raise MeshError(f"render surface {name} has no triangles ({held}): give a triangle surface")
    if others:
        raise MeshError(f"render surface {name} mixes triangles with {', '.join(others)}: "
                        "give a surface of triangles only (triangulate it first)")
    v = np.asarray(m.points, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] not in (2, 3):
        raise MeshError(f"render surface {name} has points of shape {v.shape}, expected (n, 3)")
    if v.shape[1] == 2:
        raise MeshError(f"render surface {name} is two-dimensional (points have 2 coordinates)")
    t = np.vstack(tris).astype(np.int64)
    if t.min() < 0 or t.max() >= len(v):
        raise MeshError(f"render surface {name} has triangles referencing missing vertices")
    s = RenderSurface(v * float(unit_scale), t)
    tri, flipped = orient_outward(s.vertices, s.triangles)
    return RenderSurface(s.vertices, tri, {"file": str(path), "unit_scale": float(unit_scale),
                                           "flipped_triangles": flipped})


def orient_outward(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, int]:
    """Triangles oriented consistently across shared edges and outwards, piece by piece.

    Two triangles sharing an edge (used by exactly two; vertices at equal coordinates count as one,
    so files that repeat the vertices of every face are handled) agree when they run along it in
    opposite directions. Each edge-connected piece is made to agree by a breadth-first walk; then a
    closed piece (no edge used once) is flipped as a whole when it encloses a negative volume
    (divergence theorem), an open one keeps the orientation most of its triangles had in the file.
    Edges shared by more than two triangles do not link their triangles.

    Args:
        vertices: (nv, 3) [m].
        triangles: (nt, 3) vertex indices.

    Returns:
        ``(triangles, flipped)``: the oriented triangles (nt, 3) int64 and how many were reversed.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    t = np.asarray(triangles, dtype=np.int64)
    nt = len(t)
    _, weld = np.unique(np.asarray(vertices, dtype=np.float64), axis=0, return_inverse=True)
    e = weld.reshape(-1)[t][:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)  # directed edges, 3 per triangle
    lo, hi = e.min(axis=1), e.max(axis=1)
    key = lo * (int(e.max()) + 1) + hi
    order = np.argsort(key, kind="stable")
    k = key[order]
    start = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    count = np.diff(np.r_[start, len(k)])
    two = start[count == 2]  # manifold edges: their two directed uses
    a, b = order[two], order[two + 1]
    ta, tb = a // 3, b // 3
    same = e[a, 0] == e[b, 0]  # both run the same way: one of the two must flip
    g = coo_matrix((np.ones(len(ta)), (ta, tb)), shape=(nt, nt)).tocsr()
    pieces, label = connected_components(g, directed=False)
    parent = np.arange(nt)  # a spanning forest: every triangle's parent in a breadth-first walk of its piece
    for root in np.unique(label, return_index=True)[1]:
        bfs, pred = breadth_first_order(g, root, directed=False, return_predecessors=True)
        parent[bfs[1:]] = pred[bfs[1:]]
    pair_key = np.minimum(ta, tb) * nt + np.maximum(ta, tb)
    o = np.argsort(pair_key)
    child = np.flatnonzero(parent != np.arange(nt))
    pos = o[np.searchsorted(pair_key[o], np.minimum(child, parent[child]) * nt + np.maximum(child, parent[child]))]
    step = np.zeros(nt, dtype=bool)  # flip relative to the parent: the shared edge runs the same way in both
    step[child] = same[pos]
    flip, anc = step.copy(), parent.copy()  # pointer jumping: flip = parity of the path to the piece's root
    while np.any(anc != anc[anc]):
        flip, anc = flip ^ flip[anc], anc[anc]
    out = np.where(flip[:, None], t[:, ::-1], t)
    p = np.asarray(vertices, dtype=np.float64)[out]
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))
    open_piece = np.zeros(pieces, dtype=bool)
    open_piece[label[order[start[count == 1]] // 3]] = True  # an edge used once: a hole or an open sheet
    negative = np.bincount(label, weights=vol, minlength=pieces) < 0
    majority = np.bincount(label, weights=flip, minlength=pieces) > 0.5 * np.bincount(label, minlength=pieces)
    reverse = np.where(open_piece, majority, negative)
    out = np.where(reverse[label][:, None], out[:, ::-1], out)
    return out, int(np.sum(reverse[label] != flip))
