"""Shared test fixtures: small box meshes built with numpy, STEEL, and an ``assemble`` helper.

``box_mesh`` splits every hexahedron into 6 positive tetrahedra (Kuhn split along a main diagonal),
mirrored in every other cell along each axis. With even cell counts the mesh is then symmetric under
the reflections about the mid-planes and (for equal sizes) under axis swaps, so a square-section
beam along x has exactly degenerate bending pairs (up to roundoff). A plain (unmirrored) Kuhn mesh
is only symmetric about the diagonal plane and splits the pairs by 2e-3 (P2, 8x2x2).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from modalfem.material import STEEL as _STEEL
from modalfem.mesh.core import Mesh


def box_mesh(size=(1.0, 1.0, 1.0), cells=(2, 2, 2), *, origin=(0.0, 0.0, 0.0)) -> Mesh:
    """Box [origin, origin + size] [m] with ``cells`` hexahedra per axis, 6 tets each, tags x0..z1."""
    n = np.asarray(cells, dtype=np.int64)
    axes = [np.linspace(o, o + s, k + 1) for o, s, k in zip(origin, size, n)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    vid = np.arange(len(points)).reshape(n + 1)
    i, j, k = (a.ravel() for a in np.meshgrid(*(np.arange(m) for m in n), indexing="ij"))
    ijk = np.column_stack([i, j, k])
    flip = ijk % 2  # mirror the split in odd cells: start the diagonal at the opposite corner
    tets = []
    for perm in itertools.permutations(range(3)):
        corner = flip.copy()
        path = [vid[tuple((ijk + corner).T)]]
        for axis in perm:
            corner[:, axis] = 1 - corner[:, axis]
            path.append(vid[tuple((ijk + corner).T)])
        tets.append(np.column_stack(path))
    tets = np.vstack(tets)
    p = points[tets]
    d = p[:, 1:] - p[:, :1]
    neg = np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    bare = Mesh(points, tets)
    f = bare.boundary_facets
    c = bare.points[f]  # (b, 3 vertices, 3 coords)
    lo, hi = np.asarray(origin, float), np.asarray(origin, float) + np.asarray(size, float)
    tags = {}
    for a, name in enumerate("xyz"):
        tags[f"{name}0"] = f[np.all(np.isclose(c[:, :, a], lo[a]), axis=1)]
        tags[f"{name}1"] = f[np.all(np.isclose(c[:, :, a], hi[a]), axis=1)]
    return Mesh(points, tets, tags)


def merge_meshes(*meshes: Mesh) -> Mesh:
    """Disjoint union of meshes (tags dropped): one Mesh with several pieces."""
    pts, cells, off = [], [], 0
    for m in meshes:
        pts.append(m.points)
        cells.append(m.cells + off)
        off += m.point_count
    return Mesh(np.vstack(pts), np.vstack(cells))


def _skfem_assemble(mesh: Mesh, material, *, degree: int = 2, lumped: bool = False):
    """Small scikit-fem assembly in the canonical DOF order (fallback until the backend lands)."""
    import skfem
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    m = skfem.MeshTet(np.ascontiguousarray(mesh.points.T), np.ascontiguousarray(mesh.cells.T))
    elem = skfem.ElementVector(skfem.ElementTetP2() if degree == 2 else skfem.ElementTetP1())
    basis = skfem.Basis(m, elem, intorder=2 * degree)
    K = skfem.asm(linear_elasticity(*lame_parameters(material.E, material.nu)), basis)
    rho = material.rho

    @skfem.BilinearForm
    def mass(u, v, w):
        return rho * dot(u, v)

    M = skfem.asm(mass, basis)
    perm = np.empty(3 * mesh.node_count(degree), dtype=np.int64)
    nd = basis.nodal_dofs  # (3, n_points)
    perm[: 3 * mesh.point_count] = nd.T.ravel()
    if degree == 2:
        npts = np.int64(mesh.point_count)
        e_sk = np.sort(m.edges.T, axis=1)
        keys = mesh.edges[:, 0] * npts + mesh.edges[:, 1]
        pos = np.searchsorted(keys, e_sk[:, 0] * npts + e_sk[:, 1])  # canonical edge of each skfem edge
        ed = np.empty((len(keys), 3), dtype=np.int64)
        ed[pos] = basis.edge_dofs.T
        perm[3 * mesh.point_count :] = ed.ravel()
    K = K.tocsr()[perm][:, perm].tocsr()
    M = M.tocsr()[perm][:, perm].tocsr()
    if lumped:
        import scipy.sparse as sp

        M = sp.diags(np.asarray(M.sum(axis=1)).ravel()).tocsr()
    return K, M


def assemble(mesh: Mesh, material, *, degree: int = 2):
    """(K, M) over all DOFs: the skfem backend when it imports, else the local fallback."""
    try:
        from modalfem.backends.skfem import assemble as backend_assemble
    except ImportError:
        return _skfem_assemble(mesh, material, degree=degree)
    return backend_assemble(mesh, material, degree=degree)


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
