"""scikit-fem backend: pip-only assembly of elasticity stiffness and mass (no dolfinx needed).

The weak forms live in ``modalfem.forms.skfem_elasticity``. scikit-fem's DOF numbering is mapped to
the canonical node-major order of ``modalfem.mesh.core`` exactly (not by coordinates): vertex DOFs
through ``basis.nodal_dofs`` (points keep their indices) and P2 edge DOFs through
``basis.edge_dofs`` and scikit-fem's edge list, matched by vertex pair to ``Mesh.edges``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from modalfem.backends._sparse import expand_components
from modalfem.errors import InputError

__all__ = ["assemble", "canonical_permutation", "create_basis"]


def _check_degree(degree: int) -> int:
    if degree not in (1, 2):
        raise InputError(f"degree must be 1 or 2, got {degree!r}")
    return int(degree)


def create_basis(mesh, *, degree: int = 2, vector: bool = True, intorder: int = 2):
    """scikit-fem Lagrange basis on a ``modalfem`` Mesh.

    Args:
        mesh: ``modalfem.mesh.Mesh`` [m].
        degree: Lagrange degree 1 or 2.
        vector: ``ElementVector`` (3 components) when True, scalar element otherwise.
        intorder: quadrature order (exact for polynomials of this degree).

    Returns:
        ``skfem.CellBasis`` on ``skfem.MeshTet(points.T, cells.T)``.

    Raises:
        InputError: degree is not 1 or 2.
    """
    from skfem import Basis, ElementTetP1, ElementTetP2, ElementVector, MeshTet

    degree = _check_degree(degree)
    m = MeshTet(np.ascontiguousarray(mesh.points.T), np.ascontiguousarray(mesh.cells.T))
    elem = ElementTetP1() if degree == 1 else ElementTetP2()
    return Basis(m, ElementVector(elem) if vector else elem, intorder=intorder)


def canonical_permutation(basis, mesh) -> np.ndarray:
    """Canonical DOF index of every scikit-fem DOF of ``basis`` (built by ``create_basis``).

    Args:
        basis: scalar or 3-component vector P1/P2 basis.
        mesh: the ``modalfem.mesh.Mesh`` it was made from.

    Returns:
        int64 array (basis.N,): ``perm[skfem_dof] = bs * node + component`` (bs = 1 or 3).
    """
    nodal = np.asarray(basis.nodal_dofs)
    bs = nodal.shape[0]
    perm = np.full(basis.N, -1, dtype=np.int64)
    comp = np.arange(bs)[:, None]
    perm[nodal] = bs * np.arange(nodal.shape[1])[None, :] + comp
    if basis.edge_dofs.size:
        n = np.int64(mesh.point_count)
        se = np.sort(np.asarray(basis.mesh.edges, dtype=np.int64), axis=0)
        ekeys = mesh.edges[:, 0] * n + mesh.edges[:, 1]
        edge = np.searchsorted(ekeys, se[0] * n + se[1])
        perm[np.asarray(basis.edge_dofs)] = bs * (n + edge)[None, :] + comp
    return perm


def _assemble_canonical(form, basis, perm, **params) -> sp.csr_matrix:
    """scikit-fem's generic assembly of ``form``, renumbered to the canonical order."""
    coo = form.coo_data(basis, **params)
    n = basis.N
    A = sp.coo_matrix((coo.data, (perm[coo.indices[0]], perm[coo.indices[1]])), shape=(n, n)).tocsr()
    A.sum_duplicates()
    return A


def _node_pattern(nodes: np.ndarray, node_count: int):
    """Node-pair sparsity of cells with node lists ``nodes`` (nloc, n_cells).

    Returns:
        ``(indptr, cols, inv)``: CSR structure (sorted columns) of the node graph and, for every
        ``(i, j, cell)``, the index of its non-zero (array (nloc, nloc, n_cells)).
    """
    nloc, nt = nodes.shape
    n = np.int64(node_count)
    keys = (nodes[:, None, :] * n + nodes[None, :, :]).ravel()
    ukeys, inv = np.unique(keys, return_inverse=True)
    rows = ukeys // n
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=node_count))])
    return indptr, ukeys - rows * n, inv.reshape(nloc, nloc, nt)


#: cells per chunk of element-stiffness evaluation (bounds peak memory to ~200 MB at P2)
_CHUNK = 16384


def _assemble_blocks(mesh, material, degree: int, lumped: bool):
    from modalfem.forms import skfem_elasticity as forms

    kb = create_basis(mesh, degree=degree, vector=False, intorder=forms.stiffness_intorder(degree))
    mb = create_basis(mesh, degree=degree, vector=False, intorder=forms.mass_intorder(degree))
    n_nodes = mesh.node_count(degree)
    nodes = canonical_permutation(kb, mesh)[np.asarray(kb.element_dofs)]
    indptr, cols, inv = _node_pattern(nodes, n_nodes)
    nnzb = len(cols)
    mu, lam = material.shear_modulus, material.lame_lambda
    blocks = np.zeros((nnzb, 3, 3))
    ms = np.zeros(nnzb)
    for start in range(0, nodes.shape[1], _CHUNK):
        c = slice(start, start + _CHUNK)
        idx = inv[:, :, c].ravel()
        Ke = forms.element_stiffness(kb, mu, lam, cells=c)
        for a in range(3):
            for b in range(3):
                blocks[:, a, b] += np.bincount(idx, weights=Ke[a, b].ravel(), minlength=nnzb)
        ms += np.bincount(idx, weights=forms.element_mass(mb, material.rho, cells=c).ravel(), minlength=nnzb)
    N = 3 * n_nodes
    K = sp.bsr_matrix((blocks, cols, indptr), shape=(N, N)).tocsr()
    Ms = sp.csr_matrix((ms, cols, indptr), shape=(n_nodes, n_nodes))
    return K, Ms


def assemble(mesh, material, *, degree: int = 2, lumped: bool = False, method: str = "blocks"):
    """Assemble stiffness and mass over all DOFs in the canonical order.

    The mass is component-diagonal: it is assembled for one component and expanded with
    ``kron(M, I3)``, storing only its structural non-zeros.

    Args:
        mesh: ``modalfem.mesh.Mesh`` with n points [m].
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        degree: Lagrange degree 1 or 2.
        lumped: diagonal mass (P1 row-sum, P2 HRZ; see ``modalfem.forms.skfem_elasticity``).
        method: ``"blocks"`` (default: vectorised element kernels on a scalar basis, 3x3 node
            blocks) or ``"forms"`` (scikit-fem's generic ``BilinearForm`` assembly over an
            ``ElementVector`` basis; ~10x slower, kept as an independent reference).

    Returns:
        ``(K, M)``: ``scipy.sparse.csr_matrix`` (N, N), N = 3 * ``mesh.node_count(degree)``;
        K [N/m], M [kg].

    Raises:
        InputError: degree is not 1 or 2, or an unknown method.
    """
    from modalfem.forms import skfem_elasticity as forms

    degree = _check_degree(degree)
    if method == "blocks":
        K, Ms = _assemble_blocks(mesh, material, degree, lumped)
    elif method == "forms":
        params = forms.form_parameters(material)
        vb = create_basis(mesh, degree=degree, vector=True, intorder=forms.stiffness_intorder(degree))
        K = _assemble_canonical(
            forms.stiffness, vb, canonical_permutation(vb, mesh), mu=params["mu"], lam=params["lam"]
        )
        sb = create_basis(mesh, degree=degree, vector=False, intorder=forms.mass_intorder(degree))
        Ms = _assemble_canonical(forms.scalar_mass, sb, canonical_permutation(sb, mesh), rho=params["rho"])
    else:
        raise InputError(f"unknown skfem assembly method {method!r}; choose 'blocks' or 'forms'")
    if lumped:
        d = np.repeat(forms.lumped_mass_diagonal(Ms.diagonal(), degree), 3)
        n = len(d)
        M = sp.csr_matrix((d, np.arange(n), np.arange(n + 1)), shape=(n, n))
    else:
        M = expand_components(Ms)
    return K, M
