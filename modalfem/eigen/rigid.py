"""Rigid-body fields: the null space of K that constraints have not removed.

Every connected piece of a mesh has 6 rigid motions (3 translations, 3 rotations about its
centroid). Linear fields are exactly representable by P1 and P2 Lagrange elements and have zero
strain, so their nodal interpolants lie exactly in the null space of the assembled stiffness K.
A constraint removes the rigid motions that do not vanish on the fixed DOFs; what survives per piece
is the null space of the fixed rows of that piece's 6 fields (an SVD rank), e.g. 6 for a free body,
0 when clamped on a face, 3 for a plate held only in z on its edges (in-plane motions survive).
"""

from __future__ import annotations

import numpy as np

__all__ = ["RANK_RTOL", "expected_rigid_count", "node_pieces", "rigid_basis", "rigid_fields"]

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
    n = len(points)
    c = points.mean(axis=0)
    d = points - c
    scale = float(np.sqrt((d**2).sum(axis=1).mean())) or 1.0  # rotations of O(1) nodal size, like translations
    d = d / scale
    R = np.zeros((n, 3, 6))
    R[:, 0, 0] = R[:, 1, 1] = R[:, 2, 2] = 1.0
    # rotation about axis a: u = e_a x d
    R[:, 1, 3], R[:, 2, 3] = -d[:, 2], d[:, 1]
    R[:, 0, 4], R[:, 2, 4] = d[:, 2], -d[:, 0]
    R[:, 0, 5], R[:, 1, 5] = -d[:, 1], d[:, 0]
    return R.reshape(3 * n, 6)


def rigid_fields(mesh, degree: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per piece: (node indices (n_p,), rigid fields (3 n_p, 6)) at that piece's DOF points.

    The fields are dimensionless displacement patterns; rotations are about the piece centroid and
    divided by the piece's RMS radius [m] so all 6 columns have comparable norms.
    """
    pts = mesh.dof_points(degree)
    labels = node_pieces(mesh, degree)
    out = []
    for p in range(int(labels.max()) + 1):
        nodes = np.flatnonzero(labels == p)
        out.append((nodes, _piece_fields(pts[nodes])))
    return out


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
