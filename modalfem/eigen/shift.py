"""The shift of the shift-and-invert eigen solves: one home, shared by every solver.

Shift-invert at ``shift = -alpha`` with ``alpha = SHIFT_FRACTION * theta`` where ``theta`` is a
Rayleigh-Ritz upper bound of the first deformation eigenvalue, from 30 smooth trial fields (each
displacement component times 1, x, y, z, x^2, ..., zx, multiplied by the distance to the nodes where
that component is held, so the fields are admissible) made M-orthogonal to the rigid fields. By
min-max the lowest Ritz value is >= lambda_1 of the discrete problem; measured it lies within ~1.1-3x
of it for beams, plates and cubes, free or clamped. Why about lambda_1:

* the transformed spectrum 1/(lambda - shift) must separate the wanted modes: alpha much larger than
  lambda_k squeezes them together near 1/alpha (slow Lanczos); alpha much smaller than lambda_1 lets the
  rigid modes (1/alpha) dominate the operator norm, and ARPACK's Ritz vectors of the deformation modes
  then carry errors ~ eps * lambda / alpha (measured: residual 1e-7 at alpha = 1e2, 1e-11 at 1e7 on a
  steel beam with lambda_1 = 1e7);
* K + alpha M stays positive definite with condition ~ lambda_max / alpha, so rigid modes come out
  with lambda ~ 0 to roundoff and a Cholesky-type factorisation applies (ENVIRONMENT.md's -1e4
  rad^2/s^2 for a steel beam is alpha ~ lambda_1 / 25);
* no floor: an earlier floor ``alpha >= 1e-9 max(K_ii / M_ii)`` grew with slivers (large K_ii) and
  thin plates (~1/t^2) until it passed real modes.
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import SolverError

__all__ = ["SHIFT_FRACTION", "estimate_shift", "petsc_products"]

#: alpha = SHIFT_FRACTION * (Ritz upper bound of lambda_1): between lambda_1/6 and lambda_1/2 in practice
SHIFT_FRACTION = 0.5


def petsc_products(A, Y: np.ndarray, rows) -> np.ndarray:
    """A @ Y on this rank's rows (n_local, c) for a distributed PETSc matrix A and a global (n, c) array Y."""
    x, y = A.createVecs()
    out = np.empty((len(rows), Y.shape[1]))
    for j in range(Y.shape[1]):
        x.setArray(Y[rows, j])
        A.mult(x, y)
        out[:, j] = y.getArray()
    return out


def _trial_fields(mesh, degree: int, fixed: np.ndarray) -> np.ndarray:
    """30 admissible smooth fields (n_dof, 30): component x (quadratic polynomial) x distance-to-held."""
    from scipy.spatial import cKDTree

    p = mesh.dof_points(degree)
    lo, hi = mesh.bounds
    L = float(np.max(hi - lo))
    xi = (p - 0.5 * (lo + hi)) / L
    x, y, z = xi.T
    poly = np.column_stack([np.ones(len(p)), x, y, z, x * x, y * y, z * z, x * y, y * z, z * x])
    held = fixed.reshape(-1, 3)
    B = np.zeros((len(p), 3, 3 * poly.shape[1]))
    distance = {}  # held-node set -> distance field: a clamp holds all three components at the same nodes
    for c in range(3):
        w = np.ones(len(p))
        if held[:, c].any():
            key = held[:, c].tobytes()
            if key not in distance:
                distance[key] = cKDTree(p[held[:, c]]).query(p)[0] / L
            w = distance[key]
        B[:, c, c * poly.shape[1] : (c + 1) * poly.shape[1]] = w[:, None] * poly
    return B.reshape(3 * len(p), -1)


def _ritz_products(B: np.ndarray, K, M, rows, comm):
    """(B^T K B, B^T M B, max K_ii / M_ii) for scipy matrices, or PETSc ones with ``rows``."""
    if rows is None:
        from modalfem.eigen.spmm import spmm

        lam_max = float(np.max(K.diagonal() / M.diagonal()))
        return B.T @ spmm(K, B), B.T @ spmm(M, B), lam_max
    Bl = B[rows]
    KB, MB = petsc_products(K, B, rows), petsc_products(M, B, rows)
    dk, dm = K.getDiagonal().getArray(), M.getDiagonal().getArray()
    from mpi4py import MPI

    Kr = comm.allreduce(Bl.T @ KB, op=MPI.SUM)
    Mr = comm.allreduce(Bl.T @ MB, op=MPI.SUM)
    lam_max = comm.allreduce(float(np.max(dk / dm)) if len(dk) else 0.0, op=MPI.MAX)
    return Kr, Mr, lam_max


def estimate_shift(mesh, degree: int, fixed: np.ndarray, K_ff, M_ff, *, rigid_count: int, rows=None, comm=None,
                   deflate: np.ndarray | None = None):
    """Automatic negative shift [rad^2/s^2] for the shift-invert solve (see the module docstring).

    Args:
        mesh: the ``Mesh``; degree: 1 or 2; fixed: bool mask (N_dof,) of held DOFs.
        K_ff, M_ff: free-DOF stiffness [N/m] and mass [kg] (scipy sparse, or PETSc with ``rows``).
        rigid_count: surviving rigid modes r (Ritz value r bounds lambda_1 from above).
        rows, comm: PETSc row map and communicator for distributed matrices.
        deflate: optional M-orthonormal rigid fields Z (n_free, r): the trial fields are then made
            M-orthogonal to them and the lowest Ritz value bounds lambda_1 (sharper than Ritz value r of
            the raw fields when the body has several pieces: global polynomials hold only 6 of their
            6 x pieces rigid motions).

    Returns:
        (shift, theta): shift = -alpha < 0 and theta, the Ritz upper bound of lambda_1 [rad^2/s^2].
    """
    B = _trial_fields(mesh, degree, fixed)[~fixed]
    if deflate is not None and deflate.shape[1]:
        if rows is None:
            from modalfem.eigen.spmm import spmm

            C = spmm(M_ff, deflate).T @ B
        else:
            from mpi4py import MPI

            C = comm.allreduce(petsc_products(M_ff, deflate, rows).T @ B[rows], op=MPI.SUM)
        B = B - deflate @ C
        rigid_count = 0
    Kr, Mr, lam_max = _ritz_products(B, K_ff, M_ff, rows, comm)
    Kr, Mr = 0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T)
    s, V = np.linalg.eigh(Mr)
    keep = s > 1e-10 * s.max()
    T = V[:, keep] / np.sqrt(s[keep])
    theta = np.linalg.eigvalsh(T.T @ Kr @ T)
    theta_1 = float(theta[min(rigid_count, len(theta) - 1)])
    alpha = SHIFT_FRACTION * theta_1
    if not np.isfinite(alpha) or alpha <= np.finfo(float).eps * lam_max:
        raise SolverError(
            f"could not choose a shift: the Ritz bound of the first elastic eigenvalue is {theta_1:.3g} "
            f"rad^2/s^2 against a largest diagonal ratio K_ii / M_ii of {lam_max:.3g} (outside what double "
            "precision resolves: check the material and the mesh's size and units)"
        )
    return -alpha, theta_1
