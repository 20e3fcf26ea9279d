"""Both backends assemble the same K and M in the canonical DOF order (unstructured meshes)."""

import numpy as np
import pytest
import scipy.sparse as sp
from backend_testing import load_backend
from meshgen import box_mesh

from modalfem.errors import InputError
from modalfem.material import ALUMINIUM, STEEL


def rel_diff(A, B) -> float:
    return abs(A - B).max() / abs(A).max()


def jittered(seed=1):
    return box_mesh(4, 2, 3, size=(0.4, 0.2, 0.3), jitter=0.35, shuffle=True, seed=seed)


@pytest.mark.fenicsx
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("lumped", [False, True])
def test_backends_agree(degree, lumped):
    fx, sk = load_backend("fenicsx"), load_backend("skfem")
    mesh = jittered()
    K1, M1 = fx.assemble(mesh, STEEL, degree=degree, lumped=lumped)
    K2, M2 = sk.assemble(mesh, STEEL, degree=degree, lumped=lumped)
    n = 3 * mesh.node_count(degree)
    for A in (K1, M1, K2, M2):
        assert isinstance(A, sp.csr_matrix) and A.shape == (n, n)
    assert rel_diff(K1, K2) < 1e-10
    assert rel_diff(M1, M2) < 1e-10


@pytest.mark.fenicsx
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("lumped", [False, True])
@pytest.mark.parametrize("whole_nodes", [False, True])
def test_fenicsx_assemble_free_is_the_restricted_scikit_fem_matrix(degree, lumped, whole_nodes):
    """The fast free-DOF path (PETSc sub-matrix) gives the restricted matrices of the other backend."""
    from modalfem.modes import restrict

    fx, sk = load_backend("fenicsx"), load_backend("skfem")
    mesh = jittered(seed=3)
    n = 3 * mesh.node_count(degree)
    free = np.random.default_rng(degree).random(n) > 0.3  # scattered held DOFs, not just a face
    if whole_nodes:  # every node wholly free or wholly held: K is assembled by 3 x 3 blocks (BAIJ)
        free = np.repeat(np.random.default_rng(degree).random(n // 3) > 0.3, 3)
    K_ff, M_ff = fx.assemble_free(mesh, STEEL, degree=degree, free=free, lumped=lumped)
    K, M = sk.assemble(mesh, STEEL, degree=degree, lumped=lumped)
    m = int(free.sum())
    for A in (K_ff, M_ff):
        assert isinstance(A, sp.csr_matrix) and A.shape == (m, m) and A.has_sorted_indices
    assert rel_diff(restrict(K, free), K_ff) < 1e-10
    assert rel_diff(restrict(M, free), M_ff) < 1e-10
    with pytest.raises(InputError, match="free must be a bool mask"):
        fx.assemble_free(mesh, STEEL, degree=degree, free=free[:-1])


@pytest.mark.fenicsx
def test_fenicsx_second_material():
    """Material constants are runtime dolfinx Constants: a second material must not reuse the first."""
    fx = load_backend("fenicsx")
    mesh = jittered(seed=2)
    _, M1 = fx.assemble(mesh, STEEL, degree=1)
    K2, M2 = fx.assemble(mesh, ALUMINIUM, degree=1)
    sk = load_backend("skfem")
    K3, M3 = sk.assemble(mesh, ALUMINIUM, degree=1)
    assert rel_diff(K2, K3) < 1e-10 and rel_diff(M2, M3) < 1e-10
    assert rel_diff(M2, M1 * (ALUMINIUM.rho / STEEL.rho)) < 1e-12


@pytest.mark.fenicsx
@pytest.mark.parametrize("degree", [1, 2])
def test_fenicsx_dof_map_matches_coordinates(degree):
    """The exact topological DOF map agrees with dolfinx's tabulated DOF coordinates."""
    pytest.importorskip("dolfinx")
    from mpi4py import MPI

    from modalfem.backends import fenicsx

    mesh = jittered(seed=4)
    V, nodes = fenicsx.create_function_space(mesh, degree=degree, comm=MPI.COMM_SELF)
    assert np.array_equal(np.sort(nodes), np.arange(mesh.node_count(degree)))
    X = V.tabulate_dof_coordinates()
    assert np.abs(X - mesh.dof_points(degree)[nodes]).max() < 1e-14


@pytest.mark.parametrize("degree", [1, 2])
def test_skfem_dof_map_matches_coordinates(degree):
    from modalfem.backends import skfem as sk

    mesh = jittered(seed=5)
    basis = sk.create_basis(mesh, degree=degree)
    perm = sk.canonical_permutation(basis, mesh)
    assert np.array_equal(np.sort(perm), np.arange(3 * mesh.node_count(degree)))
    expected = np.repeat(mesh.dof_points(degree), 3, axis=0)[perm]
    assert np.abs(basis.doflocs.T - expected).max() < 1e-14


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("lumped", [False, True])
def test_skfem_fast_kernels_match_generic_forms(degree, lumped, monkeypatch):
    """Vectorised element kernels (chunked) == scikit-fem's BilinearForm assembly of the helper forms."""
    from modalfem.backends import skfem as sk

    monkeypatch.setattr(sk, "_CHUNK", 7)  # several uneven chunks
    mesh = jittered(seed=6)
    K1, M1 = sk.assemble(mesh, STEEL, degree=degree, lumped=lumped, method="blocks")
    K2, M2 = sk.assemble(mesh, STEEL, degree=degree, lumped=lumped, method="forms")
    assert rel_diff(K1, K2) < 1e-12 and rel_diff(M1, M2) < 1e-12
    assert K1.has_sorted_indices


@pytest.mark.parametrize("backend", ["skfem", pytest.param("fenicsx", marks=pytest.mark.fenicsx)])
def test_bad_degree_is_input_error(backend):
    mod = load_backend(backend)
    with pytest.raises(InputError, match="degree"):
        mod.assemble(jittered(), STEEL, degree=3)


def test_skfem_unknown_method():
    from modalfem.backends import skfem as sk

    with pytest.raises(InputError, match="method"):
        sk.assemble(jittered(), STEEL, degree=1, method="magic")


@pytest.mark.parametrize("degree", [1, 2])
def test_skfem_vector_mass_form_equals_expanded_scalar_mass(degree):
    """The vector ``mass`` form (kept for Ritz use) equals kron(scalar mass, I3) used by the backend."""
    from modalfem.forms import skfem_elasticity as forms

    from modalfem.backends import skfem as sk

    mesh = jittered(seed=7)
    basis = sk.create_basis(mesh, degree=degree, intorder=forms.mass_intorder(degree))
    M_vec = sk._assemble_canonical(forms.mass, basis, sk.canonical_permutation(basis, mesh), rho=STEEL.rho)
    _, M = sk.assemble(mesh, STEEL, degree=degree)
    assert rel_diff(M, M_vec) < 1e-12
