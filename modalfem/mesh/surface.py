"""Boundary surface of a tetrahedral mesh and its exact rigid-body mass properties.

* ``boundary_surface(mesh)``: the outward triangles of the mesh boundary over renumbered boundary
  vertices, with the mesh vertex index of every surface vertex (to restrict mode shapes).
* ``mass_properties(mesh, rho)``: mass [kg], centre of mass [m] and inertia tensor about the centre
  of mass [kg m^2] of the mesh filled with uniform density, in closed form per tetrahedron:
  ``int_T x dV = V (p0 + p1 + p2 + p3) / 4`` and
  ``int_T x x^T dV = V / 20 (sum_a p_a p_a^T + s s^T)`` with ``s = sum_a p_a`` (exact for affine
  tetrahedra), accumulated about a reference point near the body to avoid cancellation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modalfem.errors import MaterialError
from modalfem.mesh.core import Mesh

__all__ = ["BoundarySurface", "MassProperties", "boundary_surface", "mass_properties"]


@dataclass(frozen=True, eq=False)
class BoundarySurface:
    """Boundary triangles of a tetrahedral mesh over their own vertex numbering.

    Attributes:
        vertices: surface vertex coordinates (nv, 3) [m].
        triangles: outward-oriented triangles (nt, 3), indices into ``vertices``.
        mesh_vertices: mesh vertex index of each surface vertex (nv,), ascending, so that
            ``vertices == mesh.points[mesh_vertices]`` and the DOFs of surface vertex i are
            ``3 * mesh_vertices[i] + (0, 1, 2)`` in the canonical order.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    mesh_vertices: np.ndarray

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)

    def enclosed_volume(self) -> float:
        """Volume [m^3] enclosed by the triangles (divergence theorem); > 0 for outward orientation."""
        p = self.vertices[self.triangles]
        return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


@dataclass(frozen=True, eq=False)
class MassProperties:
    """Rigid-body mass properties of a body of uniform density.

    Attributes:
        mass: total mass [kg].
        center_of_mass: (3,) [m].
        inertia: inertia tensor about the centre of mass (3, 3) [kg m^2], symmetric.
        volume: total volume [m^3].
    """

    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    volume: float

    @property
    def principal_moments(self) -> np.ndarray:
        """Principal moments of inertia (3,) [kg m^2], ascending."""
        return np.linalg.eigvalsh(self.inertia)


def boundary_surface(mesh: Mesh) -> BoundarySurface:
    """Extract the boundary surface of ``mesh`` with renumbered vertices.

    Args:
        mesh: a validated ``Mesh`` (positively oriented cells, so ``mesh.boundary_facets`` is outward).

    Returns:
        ``BoundarySurface`` with vertices (nv, 3) [m], outward triangles (nt, 3) and the mesh vertex
        index of each surface vertex (nv,).
    """
    facets = np.asarray(mesh.boundary_facets, dtype=np.int64)
    ids = np.unique(facets)
    tris = np.searchsorted(ids, facets).astype(np.int64)
    vertices = np.array(mesh.points[ids], dtype=np.float64)
    for a in (vertices, tris, ids):
        a.setflags(write=False)
    return BoundarySurface(vertices=vertices, triangles=tris, mesh_vertices=ids)


def mass_properties(mesh: Mesh, rho: float) -> MassProperties:
    """Exact mass, centre of mass and inertia about the centre of mass of ``mesh`` at density ``rho``.

    Args:
        mesh: tetrahedral ``Mesh`` (coordinates [m]).
        rho: uniform density [kg/m^3], > 0.

    Returns:
        ``MassProperties`` (mass [kg], centre of mass (3,) [m], inertia (3, 3) [kg m^2], volume [m^3]).

    Raises:
        MaterialError: ``rho`` is not a finite positive number.
    """
    try:
        rho = float(rho)
    except (TypeError, ValueError):
        raise MaterialError(f"density rho must be a number, got {rho!r}") from None
    if not math.isfinite(rho) or rho <= 0:
        raise MaterialError(f"density rho must be > 0 kg/m^3, got {rho!r}")
    points = np.asarray(mesh.points, dtype=np.float64)
    ref = 0.5 * (points.min(axis=0) + points.max(axis=0))
    p = points[mesh.cells] - ref  # (m, 4, 3) about the bounding-box centre
    vol = np.asarray(mesh.volumes, dtype=np.float64)
    s = p.sum(axis=1)
    volume = float(vol.sum())
    first = vol @ s / 4.0  # int x dV about ref (3,)
    second = (np.einsum("m,mai,maj->ij", vol, p, p) + np.einsum("m,mi,mj->ij", vol, s, s)) / 20.0
    c = first / volume
    second_c = second - volume * np.outer(c, c)  # int (x - c)(x - c)^T dV
    second_c = 0.5 * (second_c + second_c.T)
    inertia = rho * (np.trace(second_c) * np.eye(3) - second_c)
    return MassProperties(mass=rho * volume, center_of_mass=c + ref, inertia=inertia, volume=volume)
