"""Coarse physics, fine render surface: modes of a coarse tet mesh carried to a fine triangle surface.

A fine surface (an OBJ/STL/PLY/OFF scan or CAD tessellation, tens of thousands of vertices; read by
``modalfem.reduction.render_surface.read_surface``) is rendered with the modes of a coarse
tetrahedral mesh of the same body:

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
  vertices and triangles, counts) and the transfer's accuracy (``TransferReport``).

``modalfem.reduction.transfer_check.check_transfer`` measures the result against a finer solve.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from modalfem.errors import InputError
from modalfem.reduction.render_surface import RenderSurface

__all__ = ["TransferReport", "render_surface_model", "surface_distances", "transfer_modes"]

#: boundary triangles (nearest centroids) checked exactly per vertex for the distance to the boundary
_NEAREST = 16


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
        extrapolation_max: the most negative barycentric coordinate of an outside vertex in its
            element, negated [-] (0 when none is outside): how far outside, in units of that
            element's height. A P2 shape function there reaches l (2 l - 1) = e (2 e + 1) with
            e = ``extrapolation_max``, which bounds how much the continuation can amplify errors of
            the coarse nodal values (a sliver at the boundary shows up as a large value).
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
    extrapolation_max: float = 0.0

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
                   f"{self.outside_distance_mean:.3g} m), continued from the nearest element (barycentric down to "
                   f"{-self.extrapolation_max:.3g})"
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
        extrapolation_max=float(max(0.0, -emb.bary[emb.outside].min())) if emb.outside.any() else 0.0,
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
