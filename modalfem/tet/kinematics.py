"""Kinematics of linear tetrahedra: shape-function gradients, the deformation gradient F, dF/dx,
area-weighted face normals, and the rotation-variant SVD / polar decomposition of F.

Conventions: a tetrahedron's vertices are ``x_0..x_3`` (local order of ``Mesh.cells``, positively
oriented at rest). ``Ds = [x_1 - x_0, x_2 - x_0, x_3 - x_0]`` (columns), ``Dm`` the same at rest,
``F = Ds Dm^-1 = sum_a x_a (grad N_a)^T`` with ``grad N_a`` the (constant) rest gradient of vertex
``a``'s linear shape function. Arrays are vectorised over elements: ``F`` is (m, 3, 3).
"""

from __future__ import annotations

import numpy as np

from modalfem.mesh.core import TET_FACES

__all__ = [
    "area_weighted_normals",
    "dF_dx",
    "deformation_gradient",
    "deformation_gradient_t",
    "polar",
    "scatter_vertices",
    "shape_gradients",
    "svd_rv",
    "svd_rv_of_positions",
    "svd_rv_t",
]


def shape_gradients(points: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rest gradients of the 4 linear shape functions and rest volumes.

    Args:
        points: rest vertex positions (n, 3) [m].
        cells: tetrahedra (m, 4) (positively oriented).

    Returns:
        ``(grad, volumes)``: ``grad`` (m, 4, 3) [1/m] with ``grad[:, a] = grad N_a`` (rows of
        ``Dm^-1`` for a = 1..3, minus their sum for a = 0); ``volumes`` (m,) signed rest volumes [m^3].
    """
    p = points[cells]
    Dm = np.swapaxes(p[:, 1:] - p[:, :1], 1, 2)  # columns are edge vectors
    vol = np.linalg.det(Dm) / 6.0
    Dm_inv = np.linalg.inv(Dm)
    grad = np.empty((len(cells), 4, 3))
    grad[:, 1:] = Dm_inv
    grad[:, 0] = -Dm_inv.sum(axis=1)
    return grad, vol


def deformation_gradient(x: np.ndarray, cells: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """Deformation gradient ``F = sum_a x_a grad N_a^T`` (m, 3, 3) [-] of positions ``x`` (n, 3) [m]."""
    return np.matmul(np.swapaxes(x[cells], 1, 2), grad)


def deformation_gradient_t(x: np.ndarray, cells: np.ndarray, grad_t: np.ndarray) -> np.ndarray:
    """``deformation_gradient`` with the element index last: F (3, 3, m) [-] from positions ``x`` (n, 3) [m]
    and the shape-function gradients ``grad_t`` (4, 3, m) [1/m] (``np.moveaxis(grad, 0, -1)``).

    Formed as 36 long vector products (several times faster than a batched 3x4 @ 4x3 ``matmul``);
    what ``svd_rv(..., element_last=True)`` takes.
    """
    xt = np.asarray(x, dtype=float).T
    F = np.empty((3, 3, len(cells)))
    for i in range(3):
        xi = [xt[i][cells[:, a]] for a in range(4)]
        for j in range(3):
            o = F[i, j]
            np.multiply(xi[0], grad_t[0, j], out=o)
            for a in range(1, 4):
                o += xi[a] * grad_t[a, j]
    return F


def dF_dx(grad: np.ndarray) -> np.ndarray:
    """Jacobian of vec(F) (row-major, index ``3 i + j``) w.r.t. the 12 vertex coordinates.

    Args:
        grad: shape-function gradients (m, 4, 3) [1/m].

    Returns:
        B (m, 9, 12) [1/m] with ``B[e, 3 i + j, 3 a + k] = delta_ik grad[e, a, j]``.
    """
    m = len(grad)
    B = np.zeros((m, 3, 3, 4, 3))
    for i in range(3):
        B[:, i, :, :, i] = np.swapaxes(grad, 1, 2)
    return B.reshape(m, 9, 12)


def area_weighted_normals(x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Outward normal times area of the face opposite each vertex (m, 4, 3) [m^2].

    For a positively oriented tetrahedron face ``a`` of ``TET_FACES`` is opposite vertex ``a``;
    ``V grad N_a = -A_a n_a / 3`` (so the four vectors sum to zero).
    """
    p = x[cells]
    f = p[:, TET_FACES]  # (m, 4, 3 vertices, 3)
    return 0.5 * np.cross(f[:, :, 1] - f[:, :, 0], f[:, :, 2] - f[:, :, 0])


def svd_rv(F: np.ndarray, V0: np.ndarray | None = None, *, element_last: bool = False
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation-variant SVD ``F = U diag(s) V^T`` with ``det U = det V = +1``.

    A reflection is moved onto the smallest singular value, so an inverted element has ``s[2] < 0``
    (and ``s[0] >= s[1] >= |s[2]|``): the energies then see the inversion and push back.
    Computed per element by one-sided (Hestenes) Jacobi rotations on the columns of F (a few sweeps to
    full precision; compiled, elements in parallel: ``modalfem.tet._kernels.svd_rv``), which is several
    times faster than a loop of LAPACK calls for 3x3 matrices and well defined for repeated or zero
    singular values.

    Args:
        F: deformation gradients (m, 3, 3).
        V0: optional starting rotations (m, 3, 3), e.g. the ``V`` of the previous call on nearby F: the
            sweeps then start almost converged (the result is the same up to roundoff).
        element_last: ``F`` is given as (3, 3, m) (``deformation_gradient_t``); the outputs are the same.

    Returns:
        ``(U, s, V)``: rotations (m, 3, 3), signed singular values (m, 3), rotations (m, 3, 3).
    """
    F = np.asarray(F, dtype=float)
    Ft = F if element_last else np.moveaxis(F, 0, -1)
    U, s, V = svd_rv_t(Ft, None if V0 is None else np.moveaxis(np.asarray(V0, dtype=float), 0, -1))
    return np.moveaxis(U, -1, 0).copy(), s, np.moveaxis(V, -1, 0).copy()


def svd_rv_t(Ft: np.ndarray, V0t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`svd_rv` with the element index last for the rotations: ``Ft`` (3, 3, m) [-] (as from
    ``deformation_gradient_t``), optional warm start ``V0t`` (3, 3, m); returns ``U`` (3, 3, m), ``s``
    (m, 3), ``V`` (3, 3, m) (what ``element_forces_and_hessians(..., element_last=True)`` takes).
    """
    from modalfem.tet import _kernels

    Ft = np.ascontiguousarray(Ft, dtype=float)  # (3, 3, m): Ft[i, j] = F_ij
    m = Ft.shape[-1]
    U, V, s = np.empty((3, 3, m)), np.empty((3, 3, m)), np.empty((m, 3))
    warm = V0t is not None
    _kernels.svd_rv(Ft, np.ascontiguousarray(V0t, dtype=float) if warm else Ft, warm, U, s, V)
    return U, s, V


def svd_rv_of_positions(x: np.ndarray, cells: np.ndarray, grad_t: np.ndarray, V0t: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``svd_rv_t(deformation_gradient_t(x, cells, grad_t), V0t)`` in one compiled pass (the same numbers;
    F formed per element, elements in parallel): positions ``x`` (n, 3) [m], ``cells`` (m, 4), ``grad_t``
    (4, 3, m) [1/m]; returns ``U`` (3, 3, m), ``s`` (m, 3), ``V`` (3, 3, m)."""
    from modalfem.tet import _kernels

    m = len(cells)
    U, V, s = np.empty((3, 3, m)), np.empty((3, 3, m)), np.empty((m, 3))
    warm = V0t is not None
    _kernels.svd_of_positions(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(cells),
                              np.ascontiguousarray(grad_t, dtype=float),
                              np.ascontiguousarray(V0t, dtype=float) if warm else U, warm, U, s, V)
    return U, s, V


def polar(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar decomposition ``F = R S`` with ``R`` a rotation (det +1) and ``S`` symmetric (m, 3, 3).

    Built from :func:`svd_rv`: ``R = U V^T``, ``S = V diag(s) V^T``; for an inverted element ``S``
    has one negative eigenvalue instead of ``R`` being a reflection.
    """
    U, s, V = svd_rv(F)
    R = U @ np.swapaxes(V, 1, 2)
    S = np.einsum("mik,mk,mjk->mij", V, s, V)
    return R, S


def scatter_vertices(values: np.ndarray, cells: np.ndarray, n: int) -> np.ndarray:
    """Sum per-element vertex vectors ``values`` (m, 4, 3) into vertices (n, 3)."""
    idx = (3 * cells[:, :, None] + np.arange(3)).ravel()
    return np.bincount(idx, weights=values.ravel(), minlength=3 * n).reshape(n, 3)
