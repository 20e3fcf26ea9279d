"""Rigid-body fields: the null space of K that constraints have not removed.

Every connected piece of a mesh has 6 rigid motions (3 translations, 3 rotations about its
centroid). Linear fields are exactly representable by P1 and P2 Lagrange elements and have zero
strain, so their nodal interpolants lie exactly in the null space of the assembled stiffness K.
A constraint removes the rigid motions that do not vanish on the fixed DOFs; what survives per piece
is the null space of the fixed rows of that piece's 6 fields (an SVD rank), e.g. 6 for a free body,
0 when clamped on a face, 3 for a plate held only in z on its edges (in-plane motions survive).

Mechanisms come from structure too. Tetrahedra that share a face form a rigid *part* (two tets
sharing three non-collinear vertices cannot move rigidly with respect to each other), so the
zero-energy fields of a piece are exactly the fields that are rigid on each part and continuous at
the nodes parts share. A piece whose parts touch only at a vertex or along an edge has more of
them than its 6 - (constrained) rigid motions: a hinge. ``analyse_rigid`` counts both and names
the hinge, with no eigenvalue and no threshold tied to a shift.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from modalfem.eigen.spmm import spmm

__all__ = ["RANK_RTOL", "Deflation", "RigidStructure", "analyse_rigid", "cell_parts", "expected_rigid_count", "node_pieces",
           "rigid_basis", "rigid_fields"]

#: singular values of the fixed rows below RANK_RTOL * sqrt(nodes in the piece) count as zero. The
#: columns are scaled to norm ~sqrt(nodes), so this is a relative test far above roundoff (1e-16) and
#: far below any geometric constraint (a single fixed node already gives O(1) singular values).
RANK_RTOL = 1e-9


def node_pieces(mesh, degree: int) -> np.ndarray:
    """Connected-piece label (N_nodes,) of every Lagrange node (edge midpoints take their edge's)."""
    piece = mesh.point_piece
    if degree == 1:
        return piece
    return np.concatenate([piece, piece[mesh.edges[:, 0]]])


def _piece_fields(points: np.ndarray) -> np.ndarray:
    """6 rigid fields (3n, 6) of one piece: translations, then rotations about the centroid / size."""
    c = points.mean(axis=0)
    scale = float(np.sqrt(((points - c) ** 2).sum(axis=1).mean())) or 1.0  # rotations of O(1) nodal size
    return _frame_fields(points, c, scale)


def rigid_fields(mesh, degree: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per piece: (node indices (n_p,), rigid fields (3 n_p, 6)) at that piece's DOF points.

    The fields are dimensionless displacement patterns; rotations are about the piece centroid and
    divided by the piece's RMS radius [m] so all 6 columns have comparable norms.
    """
    pts = mesh.dof_points(degree)
    return [(nodes, _piece_fields(pts[nodes])) for nodes in _groups(node_pieces(mesh, degree))]


def _groups(labels: np.ndarray) -> list[np.ndarray]:
    """Indices of each label 0..max, in one sort (not one scan per label: scans have thousands of pieces)."""
    order = np.argsort(labels, kind="stable")
    return np.split(order, np.cumsum(np.bincount(labels, minlength=int(labels.max()) + 1))[:-1])


def _piece_null(R: np.ndarray, fixed_rows: np.ndarray, n_nodes: int) -> np.ndarray:
    """Coefficients (6, r) of the rigid fields of one piece vanishing on its fixed rows."""
    if not fixed_rows.any():
        return np.eye(6)
    _, s, vt = np.linalg.svd(R[fixed_rows], full_matrices=True)
    rank = int(np.sum(s > RANK_RTOL * np.sqrt(n_nodes)))
    return vt[rank:].T


def _piece_dofs(nodes: np.ndarray) -> np.ndarray:
    return (3 * nodes[:, None] + np.arange(3)).ravel()


def expected_rigid_count(mesh, degree: int, fixed_mask: np.ndarray) -> int:
    """Dimension of the rigid motions that vanish on all fixed DOFs, summed over pieces.

    Args:
        mesh: the ``Mesh``.
        degree: Lagrange degree (1 or 2).
        fixed_mask: bool (3 * N_nodes,) from ``modalfem.constraints.fixed_mask``.

    Returns:
        The number of zero-frequency modes the eigen solve must find (6 per free piece).
    """
    fixed = np.asarray(fixed_mask, dtype=bool)
    count = 0
    for nodes, R in rigid_fields(mesh, degree):
        count += _piece_null(R, fixed[_piece_dofs(nodes)], len(nodes)).shape[1]
    return count


def rigid_basis(mesh, degree: int, fixed_mask: np.ndarray, M_ff=None) -> np.ndarray:
    """Basis (n_free, r) of the surviving rigid motions, restricted to the free DOFs.

    Args:
        mesh: the ``Mesh``.
        degree: Lagrange degree (1 or 2).
        fixed_mask: bool (3 * N_nodes,) of fixed DOFs.
        M_ff: optional mass matrix [kg] on the free DOFs; when given the basis is M-orthonormal
            (B^T M_ff B = I), otherwise Euclidean-orthonormal.

    Returns:
        B (n_free, r) with r = ``expected_rigid_count(mesh, degree, fixed_mask)``.
    """
    fixed = np.asarray(fixed_mask, dtype=bool)
    n_dof = fixed.size
    cols = []
    for nodes, R in rigid_fields(mesh, degree):
        dofs = _piece_dofs(nodes)
        V = _piece_null(R, fixed[dofs], len(nodes))
        if V.shape[1]:
            full = np.zeros((n_dof, V.shape[1]))
            full[dofs] = R @ V
            cols.append(full)
    free = ~fixed
    if not cols:
        return np.zeros((int(free.sum()), 0))
    B = np.hstack(cols)[free]
    if M_ff is None:
        q, _ = np.linalg.qr(B)
        return q
    G = B.T @ (M_ff @ B)
    L = np.linalg.cholesky(0.5 * (G + G.T))
    return np.linalg.solve(L, B.T).T


def cell_parts(mesh) -> np.ndarray:
    """Face-connected part label (m,) of every cell: cells sharing a triangle face are in one part."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from modalfem.mesh.core import TET_FACES, unique_rows

    m = mesh.cell_count
    faces = np.sort(mesh.cells[:, TET_FACES].reshape(-1, 3), axis=1)
    _, inv = unique_rows(faces, mesh.point_count, return_inverse=True)
    inv = np.asarray(inv).ravel()
    cells = np.repeat(np.arange(m), 4)
    n = m + int(inv.max()) + 1  # bipartite graph: cells, then faces
    g = coo_matrix((np.ones(len(cells)), (cells, m + inv)), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    _, parts = np.unique(labels[:m], return_inverse=True)
    return parts.astype(np.int64)


@dataclass(frozen=True)
class RigidStructure:
    """Zero-energy motions of a constrained mesh, read from its structure.

    Attributes:
        rigid_count: rigid motions that survive the constraints, summed over pieces (6 per free piece).
        zero_energy_count: dimension of all zero-strain fields (rigid motions plus mechanisms).
        mechanisms: one line per piece with a mechanism, naming the piece and where it hinges.
        fields: a basis (N_dof, zero_energy_count) of the zero-energy fields over all DOFs (zero on
            fixed DOFs), dimensionless; ``basis`` turns it into an M-orthonormal one on the free DOFs.
    """

    rigid_count: int
    zero_energy_count: int
    mechanisms: tuple[str, ...]
    fields: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))

    def basis(self, free: np.ndarray, M_ff, *, rows=None, comm=None) -> np.ndarray:
        """M-orthonormal basis Z (n_free, zero_energy_count) of the zero-energy fields: Z^T M_ff Z = I.

        Args:
            free: bool mask (N_dof,) of the free DOFs.
            M_ff: mass matrix [kg] on the free DOFs: scipy sparse, or a distributed PETSc matrix with
                ``rows`` (this rank's canonical free indices) and ``comm`` (mpi4py); Z is then on every rank.
        """
        B = self.fields[np.asarray(free, dtype=bool)]
        if not B.shape[1]:
            return B
        if rows is None:
            def gram(Y):
                return Y.T @ spmm(M_ff, Y)
        else:
            from mpi4py import MPI

            from modalfem.eigen.shift import petsc_products

            def gram(Y):
                return comm.allreduce(Y[rows].T @ petsc_products(M_ff, Y, rows), op=MPI.SUM)

        G = gram(B)
        s, U = np.linalg.eigh(0.5 * (G + G.T))
        Z = B @ (U / np.sqrt(s))  # the fields are independent by construction (an SVD null space): s > 0
        for _ in range(2):  # Cholesky QR twice against rounding in the first pass
            G = gram(Z)
            Z = Z @ np.linalg.inv(np.linalg.cholesky(0.5 * (G + G.T))).T
        return Z

    @property
    def mechanism_count(self) -> int:
        return self.zero_energy_count - self.rigid_count


def _describe_hinge(mesh, piece: int, shared: np.ndarray, parts: int, extra: int) -> str:
    v = np.unique(shared[shared < mesh.point_count])
    where = ", ".join(f"{int(i)} ({', '.join(f'{c:.4g}' for c in mesh.points[i])})" for i in v[:4])
    x = mesh.points[v]
    sv = np.linalg.svd(x - x.mean(axis=0), compute_uv=False) if len(v) > 1 else np.zeros(1)
    line = len(v) > 1 and sv[1] <= 1e-9 * max(float(sv[0]), np.finfo(float).tiny)
    kind = "vertex" if len(v) == 1 else (f"a line of edges (an edge hinge) through {len(v)} vertices" if line
                                         else f"{len(v)} vertices")
    more = ", ..." if len(v) > 4 else ""
    return (f"piece {piece} is {parts} parts joined only at {kind} {where}{more} [m], a hinge with {extra} "
            "free motion(s): join the parts through a face or mesh them apart")


def analyse_rigid(mesh, degree: int, fixed_mask: np.ndarray) -> RigidStructure:
    """Rigid-motion and mechanism counts of a mesh under its constraints, from its structure.

    Args:
        mesh: the ``Mesh``.
        degree: Lagrange degree (1 or 2).
        fixed_mask: bool (3 * N_nodes,) from ``modalfem.constraints.fixed_mask``.

    Returns:
        ``RigidStructure``: per piece, the rigid count is 6 minus the rank the constraints remove from
        the piece's 6 rigid fields; the zero-energy count is the null space of "rigid on every
        face-connected part, continuous at shared nodes, zero on fixed DOFs" (an SVD rank at
        ``RANK_RTOL``, relative, like the rigid count).
    """
    fixed = np.asarray(fixed_mask, dtype=bool)
    parts = cell_parts(mesh)
    cells_of_piece = _groups(mesh.point_piece[mesh.cells[:, 0]])
    pts = mesh.dof_points(degree)
    cell_nodes = mesh.cell_nodes(degree)
    rigid, zero, notes, cols = 0, 0, [], []
    n_dof = fixed.size
    for piece, (nodes_p, R_p) in enumerate(rigid_fields(mesh, degree)):
        cells = cells_of_piece[piece]
        plabels = np.unique(parts[cells])
        null = _piece_null(R_p, fixed[_piece_dofs(nodes_p)], len(nodes_p))
        held = null.shape[1]  # the piece's rigid motions left by the constraints
        rigid += held
        if len(plabels) == 1:
            zero += held
            if held:
                full = np.zeros((n_dof, held))
                full[_piece_dofs(nodes_p)] = R_p @ null
                full[fixed] = 0.0
                cols.append(full)
            continue
        # several parts: unknowns are 6 rigid coefficients per part
        blocks, owner_nodes = [], []
        for a in plabels:
            nodes = np.unique(cell_nodes[cells[parts[cells] == a]])
            owner_nodes.append(nodes)
        all_nodes = np.concatenate(owner_nodes)
        owner = np.concatenate([np.full(len(n), j) for j, n in enumerate(owner_nodes)])
        P = len(plabels)
        c = pts[nodes_p].mean(axis=0)
        scale = float(np.sqrt(((pts[nodes_p] - c) ** 2).sum(axis=1).mean())) or 1.0

        def fields_at(nodes):  # the piece's 6 rigid fields (one frame for every part) at these nodes
            return _frame_fields(pts[nodes], c, scale)

        for j, nodes in enumerate(owner_nodes):
            F = fields_at(nodes)
            rows = fixed[_piece_dofs(nodes)]
            if rows.any():
                G = F[rows].T @ F[rows]
                s, V = np.linalg.eigh(0.5 * (G + G.T))
                blk = np.zeros((6, 6 * P))
                blk[:, 6 * j : 6 * j + 6] = (np.sqrt(np.maximum(s, 0.0))[:, None] * V.T)
                blocks.append(blk)
        order = np.argsort(all_nodes, kind="stable")
        sn, so = all_nodes[order], owner[order]
        dup = np.flatnonzero(sn[1:] == sn[:-1]) + 1
        shared = np.unique(sn[dup])
        run_start = np.maximum.accumulate(np.where(np.r_[True, sn[1:] != sn[:-1]], np.arange(len(sn)), 0))
        for i in dup:  # a node of several parts: the same displacement in the part listed first and this one
            node, a, b = int(sn[i]), int(so[run_start[i]]), int(so[i])
            if a == b:
                continue
            F = fields_at(np.array([node]))
            blk = np.zeros((3, 6 * P))
            blk[:, 6 * a : 6 * a + 6] = F
            blk[:, 6 * b : 6 * b + 6] = -F
            blocks.append(blk)
        C = np.vstack(blocks) if blocks else np.zeros((0, 6 * P))
        if len(C):
            _, s, vt = np.linalg.svd(C, full_matrices=True)
        else:
            s, vt = np.zeros(0), np.eye(6 * P)
        rank = int(np.sum(s > RANK_RTOL * max(1.0, float(s.max()) if len(s) else 1.0)))
        z = 6 * P - rank
        zero += z
        if z:
            N = vt[rank:].T  # (6 P, z): rigid coefficients of every part
            full = np.zeros((n_dof, z))
            for j, nodes in enumerate(owner_nodes):
                full[_piece_dofs(nodes)] = fields_at(nodes) @ N[6 * j : 6 * j + 6]
            full[fixed] = 0.0
            cols.append(full)
        if z > held:
            notes.append(_describe_hinge(mesh, piece, shared, P, z - held))
    fields = np.hstack(cols) if cols else np.zeros((n_dof, 0))
    return RigidStructure(rigid_count=int(rigid), zero_energy_count=int(zero), mechanisms=tuple(notes), fields=fields)


def _frame_fields(points: np.ndarray, c: np.ndarray, scale: float) -> np.ndarray:
    """6 rigid fields (3n, 6) at ``points`` about the centre ``c`` [m], rotations divided by ``scale`` [m]."""
    d = (points - c) / scale
    n = len(points)
    R = np.zeros((n, 3, 6))
    R[:, 0, 0] = R[:, 1, 1] = R[:, 2, 2] = 1.0
    R[:, 1, 3], R[:, 2, 3] = -d[:, 2], d[:, 1]
    R[:, 0, 4], R[:, 2, 4] = d[:, 2], -d[:, 0]
    R[:, 0, 5], R[:, 1, 5] = -d[:, 1], d[:, 0]
    return R.reshape(3 * n, 6)


class Deflation:
    """The rigid (zero-energy) subspace, handled exactly: an M-orthonormal basis Z (n, r) of fields with
    K Z = 0 up to roundoff, known from the mesh's structure (``modalfem.eigen.rigid``).

    Solvers keep their Krylov spaces M-orthogonal to Z (``project``), so they compute the elastic pairs
    only; the rigid pairs are Z itself. Z is invariant under (K - shift M)^-1 M (eigenvalue -1/shift),
    so the projection only removes what roundoff lets in."""

    def __init__(self, Z: np.ndarray | None, M) -> None:
        n = M.shape[0]
        self.Z = np.zeros((n, 0)) if Z is None else np.ascontiguousarray(Z, dtype=np.float64)
        self.MZ = spmm(M, self.Z) if self.Z.shape[1] else np.zeros((n, 0))

    @property
    def count(self) -> int:
        return int(self.Z.shape[1])

    def project(self, Y: np.ndarray) -> np.ndarray:
        """Y minus its M-projection on span(Z), twice ("twice is enough")."""
        if not self.count:
            return Y
        for _ in range(2):
            Y = Y - self.Z @ (self.MZ.T @ Y)
        return Y

    def complement(self) -> np.ndarray:
        """Euclidean-orthonormal basis (n, n - r) of the M-orthogonal complement of Z (dense problems)."""
        n = self.Z.shape[0]
        if not self.count:
            return np.eye(n)
        q, _ = np.linalg.qr(self.MZ, mode="complete")
        return q[:, self.count :]
