"""Physics of the assembled K and M, checked against analytic values (not against the code)."""

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from backend_testing import BACKEND_PARAMS, load_backend
from meshgen import box_mesh

from modalfem.material import Material

MAT = Material(E=70e9, nu=0.28, rho=2650.0, name="test")


@pytest.fixture(scope="module")
def mesh():
    return box_mesh(3, 3, 2, size=(0.3, 0.25, 0.2), jitter=0.4, shuffle=True, seed=11)


def nodal_field(mesh, degree, f):
    """Canonical DOF vector of the vector field f(x) (x: (N, 3)) at the Lagrange nodes."""
    return f(mesh.dof_points(degree)).ravel()


def rigid_modes(mesh, degree):
    x = mesh.dof_points(degree) - mesh.points.mean(axis=0)
    modes = [np.tile(np.eye(3)[c], (len(x), 1)) for c in range(3)]
    modes += [np.cross(np.eye(3)[c], x) for c in range(3)]
    return [m.ravel() for m in modes]


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("lumped", [False, True])
def test_total_mass(backend, degree, lumped, mesh):
    _, M = load_backend(backend).assemble(mesh, MAT, degree=degree, lumped=lumped)
    for c in range(3):
        e = np.zeros(M.shape[0])
        e[c::3] = 1.0
        assert e @ (M @ e) == pytest.approx(MAT.rho * mesh.volume, rel=1e-12)
        e2 = np.zeros_like(e)
        e2[(c + 1) % 3 :: 3] = 1.0
        assert abs(e2 @ (M @ e)) < 1e-12 * MAT.rho * mesh.volume  # components do not couple


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("degree", [1, 2])
def test_rigid_body_modes_in_kernel(backend, degree, mesh):
    K, _ = load_backend(backend).assemble(mesh, MAT, degree=degree)
    knorm = spla.norm(K)
    for r in rigid_modes(mesh, degree):
        assert np.linalg.norm(K @ r) / (knorm * np.linalg.norm(r)) < 1e-12


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("degree", [1, 2])
def test_uniform_strain_energy(backend, degree, mesh):
    """u = A x (A with a skew part too) stores 0.5 * V * sigma(eps0) : eps0, eps0 = sym(A)."""
    K, _ = load_backend(backend).assemble(mesh, MAT, degree=degree)
    A = np.array([[1.0, 0.3, -0.2], [0.5, -0.7, 0.4], [0.1, 0.6, 0.25]]) * 1e-3
    eps = 0.5 * (A + A.T)
    sigma = 2 * MAT.shear_modulus * eps + MAT.lame_lambda * np.trace(eps) * np.eye(3)
    u = nodal_field(mesh, degree, lambda x: x @ A.T)
    assert 0.5 * u @ (K @ u) == pytest.approx(0.5 * mesh.volume * np.sum(sigma * eps), rel=1e-11)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("degree", [1, 2])
def test_symmetric_and_positive(backend, degree, mesh):
    K, M = load_backend(backend).assemble(mesh, MAT, degree=degree)
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()
    assert abs(M - M.T).max() <= 1e-12 * abs(M).max()
    rng = np.random.default_rng(0)
    for _ in range(5):
        v = rng.standard_normal(K.shape[0])
        assert v @ (M @ v) > 0 and v @ (K @ v) > 0


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("degree", [1, 2])
def test_lumped_mass_diagonal_positive(backend, degree, mesh):
    _, M = load_backend(backend).assemble(mesh, MAT, degree=degree, lumped=True)
    d = M.diagonal()
    assert M.nnz == M.shape[0] and abs(M - np.diag(d)).max() == 0.0
    assert d.min() > 0
    assert d.sum() == pytest.approx(3 * MAT.rho * mesh.volume, rel=1e-12)
    # HRZ weights on an affine tetrahedron: vertex |T|/36, edge midpoint 4|T|/27 (P1: |T|/4)
    vols = mesh.volumes
    expect = np.zeros(mesh.node_count(degree))
    if degree == 1:
        np.add.at(expect, mesh.cells, np.repeat(vols[:, None] / 4, 4, axis=1))
    else:
        np.add.at(expect, mesh.cells, np.repeat(vols[:, None] / 36, 4, axis=1))
        np.add.at(expect, mesh.point_count + mesh.cell_edges, np.repeat(4 * vols[:, None] / 27, 6, axis=1))
    assert np.allclose(d, MAT.rho * np.repeat(expect, 3), rtol=1e-12, atol=0)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_p2_row_sum_would_be_negative(backend, mesh):
    """Why HRZ: the consistent P2 mass has negative vertex row sums."""
    _, M = load_backend(backend).assemble(mesh, MAT, degree=2)
    row_sums = np.asarray(M.sum(axis=1)).ravel()
    assert row_sums[: 3 * mesh.point_count].min() < 0
