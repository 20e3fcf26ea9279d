"""Shared test fixtures: small box meshes, STEEL, and an ``assemble`` helper.

``modalfem.mesh.box`` splits every hexahedron into 6 positive tetrahedra (Kuhn split along a main
diagonal), mirrored in every other cell along each axis. With even cell counts the mesh is then symmetric under
the reflections about the mid-planes and (for equal sizes) under axis swaps, so a square-section
beam along x has exactly degenerate bending pairs (up to roundoff). A plain (unmirrored) Kuhn mesh
is only symmetric about the diagonal plane and splits the pairs by 2e-3 (P2, 8x2x2).
"""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.backends.skfem import assemble as skfem_assemble
from modalfem.material import STEEL as _STEEL
from modalfem.mesh import box
from modalfem.mesh.core import Mesh


def box_mesh(size=(1.0, 1.0, 1.0), cells=(2, 2, 2), *, origin=(0.0, 0.0, 0.0)) -> Mesh:
    """Box [origin, origin + size] [m] with ``cells`` hexahedra per axis (``modalfem.mesh.box``)."""
    return box(size=size, cells=cells, origin=origin)


def merge_meshes(*meshes: Mesh) -> Mesh:
    """Disjoint union of meshes (tags dropped): one Mesh with several pieces."""
    pts, cells, off = [], [], 0
    for m in meshes:
        pts.append(m.points)
        cells.append(m.cells + off)
        off += m.point_count
    return Mesh(np.vstack(pts), np.vstack(cells))


def assemble(mesh: Mesh, material, *, degree: int = 2):
    """(K, M) over all DOFs in the canonical order, from the scikit-fem backend (no FEniCSx needed)."""
    return skfem_assemble(mesh, material, degree=degree)


@pytest.fixture(scope="session")
def steel():
    return _STEEL


@pytest.fixture(scope="session")
def cube():
    """Unit-ish cube 0.1 m, 2x2x2 hexahedra (48 tets)."""
    return box_mesh((0.1, 0.1, 0.1), (2, 2, 2))


@pytest.fixture(scope="session")
def beam():
    """Square-section beam 1.0 x 0.1 x 0.1 m, 8x2x2 hexahedra (symmetric under y <-> z)."""
    return box_mesh((1.0, 0.1, 0.1), (8, 2, 2))


@pytest.fixture(scope="session")
def plate():
    """Plate 0.4 x 0.4 x 0.02 m, 4x4x1 hexahedra."""
    return box_mesh((0.4, 0.4, 0.02), (4, 4, 1))


@pytest.fixture(scope="session")
def two_cubes():
    """Two disjoint 0.1 m cubes (2 pieces, 12 rigid modes)."""
    return merge_meshes(box_mesh((0.1, 0.1, 0.1), (1, 1, 1)), box_mesh((0.1, 0.1, 0.1), (1, 1, 1), origin=(0.3, 0, 0)))


@pytest.fixture(scope="session")
def make_box():
    """The ``box_mesh(size, cells, *, origin)`` builder, for tests that need their own sizes."""
    return box_mesh


@pytest.fixture(scope="session")
def assemble_km():
    """``assemble_km(mesh, material, *, degree=2) -> (K, M)`` scipy CSR over all DOFs."""
    return assemble
