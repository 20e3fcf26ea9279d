"""FEniCSx backend: UFL elasticity forms compiled by FFCx and assembled by dolfinx (0.5 API).

* ``assemble``: serial, returns scipy CSR K [N/m] and M [kg] over all DOFs in the canonical order of
  ``modalfem.mesh.core`` (node-major ``3 * node + component``).
* ``assemble_petsc``: distributed (``mpirun -n P``), returns PETSc K_ff, M_ff restricted to the free
  DOFs and, per locally owned row, its index in the canonical free-DOF numbering.

DOF mapping is exact (no coordinate matching): a dolfinx cell's geometry nodes lead, through
``geometry.input_global_indices``, to the original point indices; cell DOF ``j < 4`` sits at local
vertex ``j`` and P2 DOF ``4 + k`` at the midpoint of basix edge ``k`` (``BASIX_TET_EDGES``), which is
looked up in ``Mesh.edges``.

Logging: importing FFCx calls ``logging.basicConfig()`` and ``logging.captureWarnings(True)``, so
every later ``warnings.warn`` (modalfem's own RuntimeWarnings included) became a
``WARNING:py.warnings:`` log line that ``warnings.catch_warnings`` and ``pytest.warns`` never saw; and
a cold JIT cache printed pages of ``INFO:root:running build_ext`` / gcc command lines (the cffi
build raises the root logger to INFO). Every entry point here runs inside ``jit_logging()``, which
hands warnings back to the ``warnings`` module afterwards and, unless ``VERBOSE`` (or the environment
variable ``MODALFEM_VERBOSE=1``, or the CLI's ``--verbose``), holds back INFO records while dolfinx
imports and compiles.

This module is imported only when dolfinx/petsc4py are installed (``get_backend``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys

import numpy as np
import scipy.sparse as sp

from modalfem.backends._sparse import expand_components
from modalfem.errors import InputError

__all__ = [
    "VERBOSE",
    "assemble",
    "assemble_free",
    "assemble_petsc",
    "canonical_dofs",
    "create_function_space",
    "jit_logging",
    "node_of_block",
]

#: let the JIT compiler's INFO log (FFCx, cffi/distutils build and gcc command lines) through
VERBOSE = False

# logging.captureWarnings(True) made before FFCx was imported is the program's own choice: keep it
_USER_CAPTURES_WARNINGS = "ffcx" not in sys.modules and logging._warnings_showwarning is not None  # type: ignore[attr-defined]


def _verbose() -> bool:
    return bool(VERBOSE) or os.environ.get("MODALFEM_VERBOSE", "") not in ("", "0")


@contextlib.contextmanager
def jit_logging(verbose: bool | None = None):
    """Run dolfinx/FFCx calls (import, JIT compilation) without their side effects on logging.

    Inside: INFO and DEBUG log records are dropped (``logging.disable``) unless ``verbose``.
    After: the root logger's level is restored (the cffi build sets it to INFO) and warnings go back
    to the ``warnings`` module (FFCx's ``logging.captureWarnings(True)`` is undone, unless the program
    had turned capturing on itself before FFCx was imported). Re-entrant.

    Args:
        verbose: let the compiler log through; default ``VERBOSE`` / ``MODALFEM_VERBOSE``.
    """
    verbose = _verbose() if verbose is None else bool(verbose)
    root = logging.getLogger()
    level = root.level
    disabled = logging.root.manager.disable
    if not verbose:
        logging.disable(max(disabled, logging.INFO))
    try:
        with contextlib.suppress(ImportError):
            import ffcx  # noqa: F401  (its import-time captureWarnings, undone at once below)
        _release_warnings()
        yield
    finally:
        logging.disable(disabled)
        root.setLevel(level)
        _release_warnings()


def _release_warnings() -> None:
    if not _USER_CAPTURES_WARNINGS and logging._warnings_showwarning is not None:  # type: ignore[attr-defined]
        logging.captureWarnings(False)


def _jit_quiet(fun):
    """Run ``fun`` inside ``jit_logging()`` (every entry point imports dolfinx and may JIT-compile)."""
    import functools

    @functools.wraps(fun)
    def wrapper(*args, **kwargs):
        with jit_logging():
            return fun(*args, **kwargs)

    return wrapper


def _check_degree(degree: int) -> int:
    if degree not in (1, 2):
        raise InputError(f"degree must be 1 or 2, got {degree!r}")
    return int(degree)


def _comm(comm):
    from mpi4py import MPI

    return MPI.COMM_WORLD if comm is None else comm


@_jit_quiet
def create_function_space(mesh, *, degree: int = 2, comm=None, shape: int | None = 3):
    """dolfinx mesh and Lagrange space for a ``modalfem`` Mesh.

    Points and cells are given on rank 0 only; dolfinx partitions them over ``comm``.

    Args:
        mesh: ``modalfem.mesh.Mesh`` (identical on every rank).
        degree: Lagrange degree 1 or 2.
        comm: MPI communicator (default ``MPI.COMM_WORLD``).
        shape: 3 for the vector (displacement) space, None for a scalar space.

    Returns:
        ``(V, node_of_block)``: the function space and, for each local DOF block (owned + ghost),
        its canonical node index (int64 array of length ``size_local + num_ghosts``).

    Raises:
        InputError: degree is not 1 or 2.
    """
    import dolfinx.cpp.graph
    import dolfinx.fem
    import dolfinx.mesh
    import ufl
    degree = _check_degree(degree)
    comm = _comm(comm)
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
    if comm.rank == 0:
        cells, x = np.asarray(mesh.cells, dtype=np.int64), np.asarray(mesh.points, dtype=np.float64)
    else:
        cells, x = np.empty((0, 4), dtype=np.int64), np.empty((0, 3), dtype=np.float64)
    # cells as an AdjacencyList: dolfinx 0.5 tries the numpy array first, and the TypeError pybind11 raises
    # for it formats the arrays' reprs (5-10 ms at any size) before create_mesh retries with this
    dmesh = dolfinx.mesh.create_mesh(comm, dolfinx.cpp.graph.AdjacencyList_int64(cells), x, domain)
    element = ("Lagrange", degree) if shape is None else ufl.VectorElement("Lagrange", ufl.tetrahedron, degree)
    V = dolfinx.fem.FunctionSpace(dmesh, element)

    return V, node_of_block(V, mesh)


def node_of_block(V, mesh) -> np.ndarray:
    """Canonical node index of each local DOF block (owned + ghost) of a P1/P2 space ``V``.

    Args:
        V: dolfinx Lagrange space (scalar or vector, degree 1 or 2) on a mesh made by
            ``create_function_space`` from ``mesh``.
        mesh: the ``modalfem.mesh.Mesh`` it was made from.

    Returns:
        int64 array of length ``size_local + num_ghosts``.
    """
    from modalfem.forms.ufl_elasticity import BASIX_TET_EDGES

    degree = _check_degree(V.ufl_element().degree())
    # canonical vertex numbers of every local cell (geometry node order = reference vertex order)
    geo = V.mesh.geometry
    verts = np.asarray(geo.input_global_indices, dtype=np.int64)[geo.dofmap.array.reshape(-1, 4)]
    ndpc = 4 if degree == 1 else 10
    nodes = np.empty((len(verts), ndpc), dtype=np.int64)
    nodes[:, :4] = verts
    if degree == 2:
        n = np.int64(mesh.point_count)
        e = np.sort(verts[:, BASIX_TET_EDGES], axis=2)
        ekeys = mesh.edges[:, 0] * n + mesh.edges[:, 1]
        nodes[:, 4:] = n + np.searchsorted(ekeys, e[..., 0] * n + e[..., 1])
    imap = V.dofmap.index_map
    out = np.full(imap.size_local + imap.num_ghosts, -1, dtype=np.int64)
    out[V.dofmap.list.array] = nodes.ravel()
    return out


def canonical_dofs(node_of_block: np.ndarray, bs: int = 3) -> np.ndarray:
    """Canonical DOF ``bs * node + c`` of each unrolled local DOF ``bs * block + c``."""
    return (bs * node_of_block[:, None] + np.arange(bs)).ravel()


def _compile(forms):
    import dolfinx.fem

    return [dolfinx.fem.form(f) for f in forms]


def _assemble_stiffness_mass(V_k, V_m, material, *, lumped: bool, stiffness_type: str = "aij"):
    """Assembled PETSc stiffness on ``V_k`` [N/m] and (lumped or consistent) mass on ``V_m`` [kg].

    ``stiffness_type="baij"`` stores K by 3 x 3 node blocks: PETSc inserts a block per lookup instead
    of a value per lookup, measured 0.30 s against 1.04 s for the P2 stiffness at 139,587 DOFs. Only
    for callers that take a sub-matrix of it (which comes back as AIJ), not its raw CSR arrays.
    """
    import dolfinx.fem.petsc

    from modalfem.forms import ufl_elasticity as forms

    mass = forms.lumped_mass_form if lumped else forms.mass_form
    a_k, a_m = _compile([forms.stiffness_form(V_k, material), mass(V_m, material)])
    K = dolfinx.fem.petsc.create_matrix(a_k, mat_type=stiffness_type)
    K.zeroEntries()
    dolfinx.fem.petsc.assemble_matrix(K, a_k)
    K.assemble()
    M = dolfinx.fem.petsc.assemble_matrix(a_m)
    M.assemble()
    return K, M


def _petsc_to_csr(A, perm: np.ndarray) -> sp.csr_matrix:
    """Serial PETSc AIJ -> scipy CSR with row/column ``i`` moved to ``perm[i]``."""
    indptr, indices, data = A.getValuesCSR()
    n = A.getSize()[0]
    B = sp.csr_matrix((data, perm[indices], indptr), shape=(n, n))
    inv = np.empty_like(perm)
    inv[perm] = np.arange(n)
    B = B[inv]
    B.sort_indices()
    return B


def _diagonal_csr(d: np.ndarray) -> sp.csr_matrix:
    n = len(d)
    return sp.csr_matrix((d, np.arange(n), np.arange(n + 1)), shape=(n, n))


@_jit_quiet
def assemble(mesh, material, *, degree: int = 2, lumped: bool = False):
    """Assemble stiffness and mass over all DOFs in the canonical order (serial).

    The consistent mass is assembled once on a scalar space and expanded to the three components
    (it is component-diagonal), which is 3-9x cheaper than the vector form and stores only the
    structural non-zeros.

    Args:
        mesh: ``modalfem.mesh.Mesh`` with n points [m].
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        degree: Lagrange degree 1 or 2.
        lumped: diagonal mass (P1 row-sum, P2 HRZ; see ``modalfem.forms.ufl_elasticity``).

    Returns:
        ``(K, M)``: ``scipy.sparse.csr_matrix`` (N, N), N = 3 * ``mesh.node_count(degree)``;
        K [N/m], M [kg].

    Raises:
        InputError: degree is not 1 or 2.
    """
    import dolfinx.fem
    import dolfinx.fem.petsc
    from mpi4py import MPI


    degree = _check_degree(degree)
    V, nodes = create_function_space(mesh, degree=degree, comm=MPI.COMM_SELF)
    Vs = dolfinx.fem.FunctionSpace(V.mesh, ("Lagrange", degree))
    nodes_s = node_of_block(Vs, mesh)
    K, Ms = _assemble_stiffness_mass(V, Vs, material, lumped=lumped)
    Kc = _petsc_to_csr(K, canonical_dofs(nodes))
    if lumped:
        d = np.empty(len(nodes_s))
        d[nodes_s] = Ms.getDiagonal().array
        Mc = _diagonal_csr(np.repeat(d, 3))
    else:
        Mc = expand_components(_petsc_to_csr(Ms, nodes_s))
    K.destroy()
    Ms.destroy()
    return Kc, Mc


@_jit_quiet
def assemble_free(mesh, material, *, degree: int = 2, free, lumped: bool = False):
    """Stiffness and mass restricted to the free DOFs, in the canonical free-DOF order (serial).

    The same matrices as ``restrict(assemble(...), free)``, built with less data movement: the
    stiffness is permuted and restricted by PETSc's sub-matrix extraction (compiled, one pass)
    instead of two scipy passes over the full matrix; the mass is expanded from the scalar
    (component-free) mass, a ninth of the entries.

    Args:
        mesh: ``modalfem.mesh.Mesh`` [m].
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        degree: Lagrange degree 1 or 2.
        free: bool mask (N,) over canonical DOFs, True = free.
        lumped: diagonal mass (P1 row-sum, P2 HRZ).

    Returns:
        ``(K_ff, M_ff)``: ``scipy.sparse.csr_matrix`` (n_free, n_free) with sorted indices,
        K [N/m], M [kg].

    Raises:
        InputError: degree is not 1 or 2, or ``free`` has the wrong shape.
    """
    import dolfinx.fem
    from mpi4py import MPI
    from petsc4py import PETSc

    degree = _check_degree(degree)
    n_dofs = 3 * mesh.node_count(degree)
    free = np.asarray(free)
    if free.dtype != bool or free.shape != (n_dofs,):
        raise InputError(
            f"free must be a bool mask of shape ({n_dofs},) for degree {degree}, got {free.dtype} {free.shape}"
        )
    V, nodes = create_function_space(mesh, degree=degree, comm=MPI.COMM_SELF)
    Vs = dolfinx.fem.FunctionSpace(V.mesh, ("Lagrange", degree))
    nodes_s = node_of_block(Vs, mesh)
    # node blocks when every node is wholly free or wholly held (a block sub-matrix; PETSc refuses a
    # BAIJ sub-matrix that splits a node's block, and a converted copy crashed on it)
    whole_nodes = bool(np.all(free.reshape(-1, 3) == free.reshape(-1, 3)[:, :1]))
    K, Ms = _assemble_stiffness_mass(V, Vs, material, lumped=lumped, stiffness_type="baij" if whole_nodes else "aij")
    canon = canonical_dofs(nodes)  # local DOF -> canonical DOF
    local_of_canon = np.empty_like(canon)
    local_of_canon[canon] = np.arange(len(canon))
    iset = PETSc.IS().createGeneral(local_of_canon[free].astype(PETSc.IntType), comm=MPI.COMM_SELF)
    K_sub = K.createSubMatrix(iset, iset)  # rows and columns in canonical free order
    indptr, indices, data = K_sub.getValuesCSR()
    m = int(free.sum())
    K_ff = sp.csr_matrix((data, indices, indptr), shape=(m, m))
    K_ff.sort_indices()
    if lumped:
        d = np.empty(len(nodes_s))
        d[nodes_s] = Ms.getDiagonal().array
        M_ff = _diagonal_csr(np.repeat(d, 3)[free])
    else:
        M_ff = expand_components(_petsc_to_csr(Ms, nodes_s), free)
    for obj in (K, K_sub, Ms, iset):
        obj.destroy()
    return K_ff, M_ff


@_jit_quiet
def assemble_petsc(mesh, material, *, degree: int = 2, free=None, lumped: bool = False, comm=None):
    """Assemble distributed PETSc stiffness and mass restricted to the free DOFs.

    Collective on ``comm``: every rank passes the same ``mesh``, ``material`` and ``free``.

    Args:
        mesh: ``modalfem.mesh.Mesh`` [m].
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        degree: Lagrange degree 1 or 2.
        free: bool mask (N,) over canonical DOFs, True = free; None keeps all DOFs.
        lumped: diagonal mass (P1 row-sum, P2 HRZ), stored as a diagonal PETSc matrix.
        comm: MPI communicator (default ``MPI.COMM_WORLD``).

    Returns:
        ``(K_ff, M_ff, rows)``: PETSc MPIAIJ/SeqAIJ matrices (n_free, n_free) K [N/m], M [kg]; and
        ``rows`` (int64, one per locally owned row of K_ff, in order, increasing): that row's index
        in the canonical free-DOF numbering (its position in ``np.flatnonzero(free)``). Global
        row/column ``g`` of K_ff is ``concatenate(allgather(rows))[g]`` canonically; on one rank
        ``rows == arange(n_free)``, i.e. K_ff is already in canonical order.

    Raises:
        InputError: degree is not 1 or 2, or ``free`` has the wrong shape.
    """
    from petsc4py import PETSc


    degree = _check_degree(degree)
    comm = _comm(comm)
    n_dofs = 3 * mesh.node_count(degree)
    if free is None:
        free = np.ones(n_dofs, dtype=bool)
    free = np.asarray(free)
    if free.dtype != bool or free.shape != (n_dofs,):
        raise InputError(
            f"free must be a bool mask of shape ({n_dofs},) for degree {degree}, got {free.dtype} {free.shape}"
        )
    V, nodes = create_function_space(mesh, degree=degree, comm=comm)
    K, M = _assemble_stiffness_mass(V, V, material, lumped=lumped)
    if lumped:
        d = M.getDiagonal()
        M.destroy()
        M = PETSc.Mat().createAIJ(K.getSizes(), nnz=(1, 0), comm=comm)
        M.setUp()
        M.setDiagonal(d)
        M.assemble()
        d.destroy()

    imap = V.dofmap.index_map
    n_owned = imap.size_local
    canon = canonical_dofs(nodes[:n_owned])
    sel = free[canon]
    r0 = 3 * imap.local_range[0]
    global_rows = (r0 + np.arange(3 * n_owned, dtype=np.int64))[sel]
    free_pos = np.cumsum(free) - 1
    rows = free_pos[canon[sel]].astype(np.int64)
    # the sub-matrix keeps the IS order: list each rank's rows in canonical order, so that in
    # serial K_ff is exactly the canonical free-DOF matrix (rows == arange)
    order = np.argsort(rows, kind="stable")
    global_rows, rows = global_rows[order], rows[order]
    iset = PETSc.IS().createGeneral(global_rows.astype(PETSc.IntType), comm=comm)
    K_ff = K.createSubMatrix(iset, iset)
    M_ff = M.createSubMatrix(iset, iset)
    for obj in (K, M, iset):
        obj.destroy()
    return K_ff, M_ff, rows

