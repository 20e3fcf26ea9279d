"""Coarse physics, fine render surface: modes of a coarse tet mesh carried to a fine triangle surface.

A fine surface (an OBJ/STL/PLY/OFF scan or CAD tessellation, tens of thousands of vertices) is
rendered with the modes of a coarse tetrahedral mesh of the same body:

* ``read_surface(path, unit_scale=...)`` reads the triangles (meshio; anything else is refused
  with one line);
* ``transfer_modes(result, mesh, vertices)`` evaluates the coarse finite-element mode shapes at
  the fine vertices with the shape functions (P1 or P2, the result's degree) of the coarse
  tetrahedron that contains each vertex (``modalfem.reduction.embed``). **Extrapolation rule**: a
  vertex outside the coarse mesh (a fine surface of a curved body lies outside the coarse one's
  chords) takes the nearest tetrahedron, the one owning the nearest coarse boundary triangle, and
  that tetrahedron's polynomial is continued to it (its barycentric coordinates, some negative, are
  used as they are), so affine fields (and, at P2, quadratic ones) are reproduced exactly outside
  too. A vertex farther than ``max_distance`` [m] from the coarse boundary (default: half the
  median coarse boundary edge) is refused, inside or outside: the surface is not the same body
  (wrong units, wrong file);
* ``render_surface_model(result, mesh, material, surface)`` builds the ``ModalModel`` on the fine
  surface. The mass properties (mass, centre of mass, inertia) and the rotation coupling
  (``rotation_T``, ``rotation_S``, so ``runtime.PseudoForces`` works) come from the volume mesh, not
  from the surface; the provenance records which surface the model carries (file, SHA-256 of the
  vertices and triangles, counts) and the transfer's accuracy (``TransferReport``);
* ``check_transfer(...)`` measures the transferred shapes against a finer solve: a given reference
  tet mesh (e.g. a mesh of the fine surface) or the coarse mesh refined once (each tetrahedron
  split into 8, ``refine_mesh``). Frequencies are compared after matching modes by MAC; the MAC is
  taken on the fine surface vertices, weighted by vertex area (a third of the adjacent triangles'
  areas, per component), between the transferred coarse modes and the reference modes carried to
  the same vertices; each coarse mode is matched one to one to a reference mode (the reference
  solve has a few more modes, so a mode that changed place in the order is still found). Nearly
  degenerate modes (reference frequencies within ``cluster_tol`` of each other) rotate freely within
  their pair, so the MAC is the subspace MAC: the W-norm share of the coarse mode inside the span of
  its reference cluster (the plain MAC for a single mode).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from modalfem.errors import InputError, MeshError

__all__ = [
    "RenderSurface",
    "TransferCheck",
    "TransferReport",
    "check_transfer",
    "orient_outward",
    "read_surface",
    "refine_mesh",
    "surface_distances",
    "render_surface_model",
    "transfer_modes",
]

#: surface formats read by ``read_surface`` (meshio readers)
SURFACE_FORMATS = (".obj", ".stl", ".ply", ".off")
#: boundary triangles (nearest centroids) checked exactly per vertex for the distance to the boundary
_NEAREST = 16


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


@dataclass(frozen=True)
class TransferReport:
    """How far the fine vertices are from the coarse mesh the modes were computed on.

    Attributes:
        vertex_count: fine vertices.
        degree: Lagrange degree of the interpolation (the coarse result's).
        distance_max: largest distance of a fine vertex to the coarse boundary surface [m] (inside or out).
        distance_mean: mean of those distances [m].
        outside_count: fine vertices outside the coarse mesh (values continued from the nearest element).
        outside_distance_max: largest distance outside the coarse mesh [m] (0 when none is outside).
        outside_distance_mean: mean distance of all fine vertices to the coarse mesh [m] (0 inside).
        allowed_distance: the refusal threshold used [m].
        coarse_edge: median coarse boundary edge length [m] (the default threshold is half of it).
    """

    vertex_count: int
    degree: int
    distance_max: float
    distance_mean: float
    outside_count: int
    outside_distance_max: float
    outside_distance_mean: float
    allowed_distance: float
    coarse_edge: float

    def as_dict(self) -> dict:
        """JSON-ready dict (lengths in m) with the extrapolation rule stated."""
        d = {k: (float(v) if isinstance(v, float) else int(v)) for k, v in self.__dict__.items()}
        d["extrapolation"] = "nearest tetrahedron's polynomial continued (barycentric coordinates kept)"
        return d

    def line(self) -> str:
        """One human-readable line."""
        return (f"{self.vertex_count} vertices, P{self.degree}; distance to the coarse boundary max "
                f"{self.distance_max:.3g} m, mean {self.distance_mean:.3g} m (coarse edge {self.coarse_edge:.3g} m); "
                + (f"{self.outside_count} outside (up to {self.outside_distance_max:.3g} m, mean over all "
                   f"{self.outside_distance_mean:.3g} m), continued from the nearest element"
                   if self.outside_count else "none outside"))


def _boundary_distance(mesh, q: np.ndarray, *, candidates: int = _NEAREST) -> np.ndarray:
    """Distance (n,) [m] of points to the boundary triangles of ``mesh``: exact over the ``candidates``
    triangles with the nearest centroids, so never below the true distance (equal to it with all)."""
    from scipy.spatial import cKDTree

    from modalfem.reduction.embed import point_triangle_distance

    pts, facets = mesh.points, mesh.boundary_facets
    tree = cKDTree(pts[facets].mean(axis=1))
    kk = min(int(candidates), len(facets))
    out = np.empty(len(q))
    batch = max(1, 320_000 // kk)
    for s in range(0, len(q), batch):
        qb = q[s : s + batch]
        _, near = tree.query(qb, k=kk)
        f = facets[near.reshape(len(qb), kk).ravel()]
        d = point_triangle_distance(np.repeat(qb, kk, axis=0), pts[f[:, 0]], pts[f[:, 1]], pts[f[:, 2]])
        out[s : s + batch] = d.reshape(len(qb), kk).min(axis=1)
    return out


def _median_boundary_edge(mesh) -> float:
    f = mesh.boundary_facets
    p = mesh.points
    e = np.linalg.norm(p[f] - p[np.roll(f, 1, axis=1)], axis=2)
    return float(np.median(e))


def surface_distances(mesh, vertices: np.ndarray, *, max_distance: float | None = None):
    """Distances of fine vertices to the coarse boundary surface, refusing a surface that is too far.

    Args:
        mesh: the coarse ``Mesh`` [m].
        vertices: fine vertices (n, 3) [m].
        max_distance: largest accepted distance [m]; default half the median coarse boundary edge.

    Returns:
        ``(distances (n,) [m], allowed [m], median coarse boundary edge [m])``.

    Raises:
        InputError: a vertex is farther than allowed (the farthest one, its distance, the threshold
            and how many are too far are named; one line).
    """
    q = np.asarray(vertices, dtype=np.float64)
    edge = _median_boundary_edge(mesh)
    allowed = 0.5 * edge if max_distance is None else float(max_distance)
    if not (np.isfinite(allowed) and allowed > 0):
        raise InputError(f"max_distance must be a finite length > 0 [m], got {max_distance!r}")
    dist = _boundary_distance(mesh, q)
    flagged = np.flatnonzero(dist > allowed)
    if 0 < len(flagged) * len(mesh.boundary_facets) <= 20_000_000:  # exact over every boundary triangle
        dist[flagged] = _boundary_distance(mesh, q[flagged], candidates=len(mesh.boundary_facets))
    far = int(np.argmax(dist))
    if dist[far] > allowed:
        x = ", ".join(f"{c:.4g}" for c in q[far])
        raise InputError(
            f"render surface vertex {far} at ({x}) m is {dist[far]:.3g} m from the coarse mesh's surface, more than "
            f"the allowed {allowed:.3g} m ({int(np.sum(dist > allowed))} vertices are): not the same body? "
            f"check the units (unit_scale, --render-unit-scale) or allow more (max_distance, --max-transfer-distance)")
    return dist, allowed, edge


def transfer_modes(result, mesh, vertices: np.ndarray, *, max_distance: float | None = None):
    """Mode shapes of ``result`` (computed on the coarse ``mesh``) at fine vertices.

    Args:
        result: ``ModalResult`` of ``modalfem.modes`` on ``mesh`` (P1 or P2).
        mesh: the coarse tetrahedral ``Mesh`` [m].
        vertices: fine vertices (n, 3) [m].
        max_distance: largest accepted distance of a vertex to the coarse boundary [m]; default half
            the median coarse boundary edge.

    Returns:
        ``(shapes, report)``: mass-normalised shapes (3 n, k) [m / sqrt(kg)] at the vertices,
        node-major (rows ``3 i + c``), and the ``TransferReport``.

    Raises:
        InputError: a vertex is farther than ``max_distance`` from the coarse mesh (the vertex, its
            distance and the threshold are named), or ``result`` does not belong to ``mesh``.
    """
    from modalfem.reduction.embed import embed_points

    degree = int(result.degree)
    if np.asarray(result.shapes).shape[0] != 3 * mesh.node_count(degree):
        raise InputError(f"result has {np.asarray(result.shapes).shape[0]} DOFs but the coarse mesh has "
                         f"{3 * mesh.node_count(degree)} at degree {degree}: the result was not computed on it")
    q = np.asarray(vertices, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 3 or not np.all(np.isfinite(q)):
        raise InputError(f"fine vertices must be a finite (n, 3) array [m], got shape {q.shape}")
    dist, allowed, edge = surface_distances(mesh, q, max_distance=max_distance)
    emb = embed_points(mesh, q)
    shapes = emb.transfer(result.shapes, degree=degree)
    report = TransferReport(
        vertex_count=len(q), degree=degree, distance_max=float(dist.max()), distance_mean=float(dist.mean()),
        outside_count=int(emb.outside.sum()),
        outside_distance_max=float(emb.distance.max()), outside_distance_mean=float(emb.distance.mean()),
        allowed_distance=allowed, coarse_edge=edge)
    return shapes, report


def render_surface_model(result, mesh, material, surface: RenderSurface, *, max_distance: float | None = None,
                         damping=(0.0, 1e-6), provenance: dict | None = None, mass_matrix=None):
    """A ``ModalModel`` whose surface is ``surface``, with modes, mass properties and rotation coupling of ``mesh``.

    The model is ``ModalModel.from_modes(result, mesh, material, ...)`` (mass, centre of mass,
    inertia and ``rotation_T`` / ``rotation_S`` integrated over the coarse volume) with its coarse
    boundary surface and boundary modes replaced by ``surface`` and ``transfer_modes`` at its vertices.

    Args:
        result: ``ModalResult`` on ``mesh``.
        mesh: the coarse ``Mesh`` [m].
        material: its ``Material`` (E [Pa], nu, rho [kg/m^3]) or dict.
        surface: the fine ``RenderSurface`` [m].
        max_distance: see ``transfer_modes`` [m].
        damping: Rayleigh (alpha [1/s], beta [s]).
        provenance: extra JSON-able entries (merged over the generated ones).
        mass_matrix: the coarse mass matrix [kg], if at hand (see ``ModalModel.from_modes``).

    Returns:
        ``(model, report)``: the ``ModalModel`` and the ``TransferReport`` (also stored in
        ``model.provenance["render_surface"]["transfer"]``).
    """
    from modalfem.model import ModalModel

    if not isinstance(surface, RenderSurface):
        raise InputError(f"surface must be a RenderSurface (see read_surface), got {type(surface).__name__}")
    shapes, report = transfer_modes(result, mesh, surface.vertices, max_distance=max_distance)
    coarse = ModalModel.from_modes(result, mesh, material, damping=damping, provenance=provenance,
                                   mass_matrix=mass_matrix)
    prov = dict(coarse.provenance)
    prov["render_surface"] = {
        "source": surface.source, "sha256": surface.fingerprint, "vertex_count": surface.vertex_count,
        "triangle_count": len(surface.triangles), "coarse_surface_vertex_count": coarse.vertex_count,
        "transfer": report.as_dict(),
    }
    model = replace(coarse, vertices=surface.vertices, triangles=surface.triangles, shapes=shapes, provenance=prov)
    return model, report


def refine_mesh(mesh):
    """``mesh`` with every tetrahedron split into 8 at its edge midpoints (tags split into 4 likewise).

    The points are ``mesh.dof_points(2)`` (vertices, then edge midpoints); the geometry is unchanged,
    the element size halves.

    Args:
        mesh: a ``Mesh`` [m].

    Returns:
        The refined ``Mesh``, all cells positively oriented.
    """
    from modalfem.mesh.core import Mesh

    n = mesh.point_count
    c = mesh.cell_nodes(2)  # 0..3 vertices, 4..9 midpoints of edges 01 02 03 12 13 23
    v0, v1, v2, v3, m01, m02, m03, m12, m13, m23 = c.T
    children = [
        (v0, m01, m02, m03), (m01, v1, m12, m13), (m02, m12, v2, m23), (m03, m13, m23, v3),
        (m02, m13, m01, m03), (m02, m13, m03, m23), (m02, m13, m23, m12), (m02, m13, m12, m01),
    ]
    cells = np.vstack([np.column_stack(ch) for ch in children])
    pts = mesh.dof_points(2)
    d = pts[cells]
    vol = np.einsum("ij,ij->i", d[:, 1] - d[:, 0], np.cross(d[:, 2] - d[:, 0], d[:, 3] - d[:, 0]))
    neg = vol < 0
    cells[neg] = cells[neg][:, [0, 2, 1, 3]]
    ekeys = mesh.edges[:, 0].astype(np.int64) * n + mesh.edges[:, 1]

    def mid(a, b):
        lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
        return n + np.searchsorted(ekeys, lo * n + hi)

    tags = {}
    for name, f in mesh.tags.items():
        if len(f) == 0:
            tags[name] = f
            continue
        a, b, cc = f.T
        ab, bc, ca = mid(a, b), mid(b, cc), mid(cc, a)
        tags[name] = np.vstack([np.column_stack(t) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, cc), (ab, bc, ca))])
    return Mesh(pts, cells, tags)


@dataclass(frozen=True)
class TransferCheck:
    """Transferred coarse modes against a finer solve, on the fine surface.

    Attributes:
        reference: ``"refined coarse mesh"`` or the reference mesh's description.
        reference_dof_count: DOFs of the reference solve.
        frequencies_hz: coarse frequencies (k,) [Hz].
        reference_frequencies_hz: frequencies of the matched reference modes (k,) [Hz].
        frequency_error: (coarse - reference) / reference (k,) [-].
        mac: area-weighted MAC on the fine surface vertices (k,) [-] (subspace MAC inside clusters).
        matched: index of the reference mode matched to each coarse mode (k,) (the reference solve
            computes k + max(2, k // 2) modes, so a coarse mode whose place in the order changed is found).
        reference_spectrum_hz: all frequencies of the reference solve (k_r,) [Hz].
        clusters: groups of reference mode indices treated as one (nearly) degenerate subspace.
        report: the ``TransferReport`` of the coarse transfer.
        seconds: wall time of the reference solve [s].
    """

    reference: str
    reference_dof_count: int
    frequencies_hz: np.ndarray
    reference_frequencies_hz: np.ndarray
    frequency_error: np.ndarray
    mac: np.ndarray
    matched: np.ndarray
    reference_spectrum_hz: np.ndarray
    clusters: tuple
    report: TransferReport
    seconds: float

    @property
    def max_frequency_error(self) -> float:
        """Largest |relative frequency error| [-]."""
        return float(np.max(np.abs(self.frequency_error)))

    @property
    def min_mac(self) -> float:
        """Smallest MAC [-]."""
        return float(np.min(self.mac))

    def as_dict(self) -> dict:
        """JSON-ready dict (frequencies in Hz)."""
        return {
            "reference": self.reference, "reference_dof_count": int(self.reference_dof_count),
            "frequencies_hz": [float(x) for x in self.frequencies_hz],
            "reference_frequencies_hz": [float(x) for x in self.reference_frequencies_hz],
            "frequency_error": [float(x) for x in self.frequency_error],
            "mac": [float(x) for x in self.mac], "matched": [int(x) for x in self.matched],
            "reference_spectrum_hz": [float(x) for x in self.reference_spectrum_hz], "clusters": [list(map(int, c)) for c in self.clusters],
            "max_frequency_error": self.max_frequency_error, "min_mac": self.min_mac,
            "mac_weighting": "fine-surface vertex areas; subspace MAC within clusters", "seconds": float(self.seconds),
        }


def _clusters(f: np.ndarray, tol: float) -> list[list[int]]:
    out: list[list[int]] = [[0]]
    for i in range(1, len(f)):
        if f[i] - f[i - 1] <= tol * f[i]:
            out[-1].append(i)
        else:
            out.append([i])
    return out


def surface_mac(approx: np.ndarray, ref: np.ndarray, weights: np.ndarray, f_ref: np.ndarray, *,
                cluster_tol: float = 0.01):
    """Match each approximate mode to a reference mode and measure its MAC on surface DOFs.

    Args:
        approx: approximate shapes (3 n, k).
        ref: reference shapes (3 n, k_r), k_r >= k, on the same vertices.
        weights: per-vertex weights (n,) (e.g. areas [m^2]).
        f_ref: reference frequencies (k_r,) [Hz], ascending.
        cluster_tol: reference modes whose frequencies differ by at most this fraction form one cluster.

    Returns:
        ``(matched, mac, clusters)``: the reference mode matched to each approximate mode (k,) (one to
        one, maximising the summed MAC; inside a cluster in frequency order), the MAC of each (k,):
        the W-norm share of the approximate mode inside the span of its reference cluster, and the
        clusters (lists of reference indices).
    """
    from modalfem.reduction.compare import mac_matrix, match_modes

    w = np.repeat(np.asarray(weights, dtype=np.float64), 3)
    s = np.sqrt(w)[:, None]
    A, B = approx * s, ref * s  # W-weighted shapes: plain products are W inner products
    matched = match_modes(mac_matrix(B, A))  # for each approximate mode, its reference mode
    clusters = _clusters(np.asarray(f_ref, dtype=np.float64), cluster_tol)
    cluster_of = np.empty(len(f_ref), dtype=np.int64)
    for c, members in enumerate(clusters):
        cluster_of[members] = c
    mac = np.empty(A.shape[1])
    for i in range(A.shape[1]):
        Q, _ = np.linalg.qr(B[:, clusters[cluster_of[matched[i]]]])
        a = A[:, i]
        mac[i] = min(1.0, float(np.sum((Q.T @ a) ** 2) / (a @ a)))
    for c in np.unique(cluster_of[matched]):  # inside a cluster the shapes may rotate: pair by frequency order
        idx = np.flatnonzero(cluster_of[matched] == c)
        matched[idx] = np.sort(matched[idx])
    return matched, mac, clusters


def check_transfer(result, mesh, material, surface: RenderSurface, *, reference_mesh=None, fixed=None,
                   backend: str = "auto", solver: str = "auto", lumped: bool = False,
                   max_distance: float | None = None, cluster_tol: float = 0.01, progress=None) -> TransferCheck:
    """Frequency error and MAC of the transferred coarse modes against a finer solve.

    Args:
        result: ``ModalResult`` on the coarse ``mesh``.
        mesh: the coarse ``Mesh`` [m].
        material: the ``Material`` of ``result``.
        surface: the fine ``RenderSurface`` [m].
        reference_mesh: a finer ``Mesh`` of the body (e.g. a tet mesh of the fine surface); None for
            ``refine_mesh(mesh)`` (same geometry, half the element size).
        fixed: the constraints ``result`` was computed with (tag names must exist on the reference).
        backend, solver, lumped: as for ``modalfem.modes`` (the reference uses the result's degree).
        max_distance: see ``transfer_modes`` [m].
        cluster_tol: relative frequency spacing below which reference modes form one cluster [-].
        progress: optional callable(str) for stage lines (passed to the reference solve).

    Returns:
        ``TransferCheck``.
    """
    import time

    import modalfem
    from modalfem.reduction.compare import frequency_errors
    from modalfem.reduction.embed import embed_points

    say = progress if callable(progress) else (lambda msg: None)
    shapes, report = transfer_modes(result, mesh, surface.vertices, max_distance=max_distance)
    if reference_mesh is None:
        say("check transfer: refining the coarse mesh (each tetrahedron into 8)")
        ref_mesh, what = refine_mesh(mesh), "refined coarse mesh"
    else:
        ref_mesh, what = reference_mesh, f"reference mesh ({reference_mesh.cell_count} tetrahedra)"
    k = len(result.omega)
    t0 = time.perf_counter()  # a few more reference modes, so that reordered coarse modes find their partner
    ref = modalfem.modes(ref_mesh, material, k=k + max(2, k // 2), degree=int(result.degree), fixed=fixed, backend=backend,
                         solver=solver, lumped=lumped, progress=progress)
    seconds = time.perf_counter() - t0
    say("check transfer: comparing on the fine surface")
    ref_shapes = embed_points(ref_mesh, surface.vertices).transfer(ref.shapes, degree=int(ref.degree))
    f_ref = np.asarray(ref.frequencies_hz)
    matched, mac, clusters = surface_mac(shapes, ref_shapes, surface.vertex_areas(), f_ref, cluster_tol=cluster_tol)
    f = np.asarray(result.frequencies_hz)
    return TransferCheck(reference=what, reference_dof_count=int(ref.shapes.shape[0]), frequencies_hz=f,
                         reference_frequencies_hz=f_ref[matched], frequency_error=frequency_errors(f, f_ref[matched]),
                         mac=mac, matched=matched, reference_spectrum_hz=f_ref,
                         clusters=tuple(tuple(c) for c in clusters), report=report, seconds=seconds)
