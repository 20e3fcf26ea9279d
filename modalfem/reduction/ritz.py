"""Rayleigh-Ritz modes from smooth polynomial trial fields (affine: 12, affine + quadratic: 30).

The low-frequency modes of a compact body barely depend on fine geometry, so a handful of smooth
fields (``modalfem.forms.ritz``) already give useful frequencies. ``ritz_modes`` assembles the
reduced stiffness K_r [N/m] and mass M_r [kg] of the fields directly from the elasticity forms
(FEniCSx/UFL or scikit-fem quadrature), solves the small dense generalized eigenproblem
``K_r c = lambda M_r c`` and returns the modes.

* Rank deficiency: on a degenerate body (e.g. a thin plate, where quadratic terms through the
  thickness are numerically indistinguishable from lower ones) M_r is (nearly) singular. Directions
  whose M_r eigenvalue is below ``rank_rtol`` times the largest are dropped with a ``RuntimeWarning``
  naming how many and why, instead of failing in the eigen solve.
* Rigid modes: for a free body the 6 rigid motions lie in the affine span; their Ritz eigenvalues
  are zero to roundoff (tested). ``ritz_modes`` deflates them exactly (``rigid_coefficients``) and
  solves for the deformation modes in their mass-orthogonal complement: on very thin bodies the
  genuine bending eigenvalues can be ~1e-16 of the largest, where roundoff could not tell them apart.
* Min-max: Ritz eigenvalues are upper bounds of the exact ones, and of the FEM ones when the fields
  lie in the FE space (affine in P1, quadratic in P2).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError, SolverError

__all__ = ["RitzModes", "field_matrix", "ritz_modes", "solve_reduced"]

#: M_r eigenvalues below this fraction of the largest are null directions (dropped)
RANK_RTOL = 1e-10


def solve_reduced(K_r: np.ndarray, M_r: np.ndarray, *, rigid: np.ndarray | None = None,
                  rank_rtol: float = RANK_RTOL, what: str = "Ritz basis"):
    """Solve ``K_r c = lambda M_r c`` after removing the null directions of M_r.

    Args:
        K_r: reduced stiffness (F, F) [N/m], symmetric.
        M_r: reduced mass (F, F) [kg], symmetric positive semi-definite.
        rigid: optional coefficient vectors (F, r) of known zero-energy motions (the rigid modes of a
            free body): they are deflated exactly, returned first with eigenvalue 0, and the rest is
            solved in their M_r-orthogonal complement (so tiny but genuine eigenvalues of very thin
            bodies are not confused with roundoff of the rigid ones).
        rank_rtol: relative threshold on M_r's eigenvalues for a direction to be kept.
        what: name used in the warning.

    Returns:
        ``(lam, C, dropped)``: eigenvalues (m,) [rad^2/s^2] ascending (the r deflated ones first, 0),
        M_r-orthonormal coefficient vectors (F, m) and the number of dropped directions F - m.

    Raises:
        InputError: the matrices are not square of equal size or not finite.
        SolverError: M_r has no positive direction.
    """
    K = np.asarray(K_r, dtype=np.float64)
    M = np.asarray(M_r, dtype=np.float64)
    if K.ndim != 2 or K.shape[0] != K.shape[1] or K.shape != M.shape:
        raise InputError(f"K_r and M_r must be square and of equal size, got {K.shape} and {M.shape}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(M))):
        raise InputError("K_r and M_r must be finite")
    K, M = 0.5 * (K + K.T), 0.5 * (M + M.T)
    s, V = np.linalg.eigh(M)
    if s[-1] <= 0:
        raise SolverError(f"{what}: the reduced mass matrix has no positive direction")
    keep = s > rank_rtol * s[-1]
    dropped = int(np.sum(~keep))
    if dropped:
        warnings.warn(
            f"{what} is rank-deficient on this body: dropped {dropped} of {len(s)} directions whose reduced "
            f"mass is below {rank_rtol:g} x the largest (fields indistinguishable on the body, e.g. quadratic "
            "terms through the thickness of a thin plate)",
            RuntimeWarning,
            stacklevel=3,
        )
    T = V[:, keep] / np.sqrt(s[keep])  # T^T M T = I
    r = 0 if rigid is None else int(np.asarray(rigid).shape[1])
    if r:
        Q, _ = np.linalg.qr(T.T @ M @ np.asarray(rigid, dtype=np.float64), mode="complete")
        rig, T = T @ Q[:, :r], T @ Q[:, r:]  # rigid span and its M-orthogonal complement
    A = T.T @ K @ T
    lam, Y = np.linalg.eigh(0.5 * (A + A.T))
    if r:
        return np.concatenate([np.zeros(r), lam]), np.hstack([rig, T @ Y]), dropped
    return lam, T @ Y, dropped


@dataclass(frozen=True)
class RitzModes:
    """Rayleigh-Ritz modes of a body.

    Attributes:
        kind: ``"affine"`` or ``"quadratic"``.
        frame: ``modalfem.forms.ritz.RitzFrame`` of the fields (centre, scale, clamp).
        omega: deformation angular frequencies (k,) [rad/s], ascending.
        coefficients: field coefficients of the deformation modes (F, k): mode ``j`` is
            ``sum_I coefficients[I, j] B_I(x)`` [1/sqrt(kg)], mass-normalised (the fields ``B_I`` are
            dimensionless), i.e. ``coefficients.T @ M_r @ coefficients = I``.
        rigid_coefficients: the same for the zero-frequency modes (F, r).
        dropped: null directions removed from the basis (rank deficiency).
        K_r: reduced stiffness (F, F) [N/m]; M_r: reduced mass (F, F) [kg].
        backend: ``"fenicsx"`` (UFL) or ``"skfem"``.
    """

    kind: str
    frame: object
    omega: np.ndarray
    coefficients: np.ndarray
    rigid_coefficients: np.ndarray
    dropped: int
    K_r: np.ndarray
    M_r: np.ndarray
    backend: str

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Deformation frequencies (k,) [Hz]."""
        return self.omega / (2.0 * np.pi)

    @property
    def rigid_mode_count(self) -> int:
        return int(self.rigid_coefficients.shape[1])

    def shapes_at(self, points: np.ndarray) -> np.ndarray:
        """Deformation mode shapes [1/sqrt(kg)] at points (n, 3) [m], node-major DOFs (3 n, k)."""
        return field_matrix(self.kind, self.frame, points) @ self.coefficients


def field_matrix(kind: str, frame, points: np.ndarray) -> np.ndarray:
    """Values of the Ritz fields at points (n, 3) [m] as a node-major matrix (3 n, F) [-]."""
    from modalfem.forms.ritz import evaluate_fields

    p = np.asarray(points, dtype=np.float64)
    vals, _ = evaluate_fields(kind, frame, p.T)  # (F, 3, n)
    return vals.transpose(2, 1, 0).reshape(3 * len(p), -1)


def ritz_modes(
    mesh,
    material,
    *,
    kind: str = "quadratic",
    clamp: tuple[int, float] | None = None,
    backend: str = "auto",
    rank_rtol: float = RANK_RTOL,
) -> RitzModes:
    """Rayleigh-Ritz modes of a body from affine or affine + quadratic fields.

    Args:
        mesh: ``modalfem.mesh.Mesh`` [m] (the integration domain; any resolution works).
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        kind: ``"affine"`` (12 fields) or ``"quadratic"`` (30 fields).
        clamp: None for a free body, or ``(axis, coordinate [m])`` of a clamped plane (the fields are
            multiplied by the distance to it, so they vanish there).
        backend: ``"auto"`` (FEniCSx/UFL if installed, else scikit-fem), ``"fenicsx"`` or ``"skfem"``.
        rank_rtol: relative M_r eigenvalue below which a direction is dropped (with a warning).

    Returns:
        ``RitzModes`` (deformation modes ascending, rigid modes split off).

    Raises:
        InputError: unknown kind or backend, bad clamp. BackendUnavailableError: fenicsx requested
        but not installed.
    """
    from modalfem.backends import resolve_backend
    from modalfem.forms.ritz import frame_for, monomials, rigid_coefficients

    monomials(kind)  # validates kind
    backend = resolve_backend(backend)
    frame = frame_for(mesh.points, clamp=clamp)
    if backend == "fenicsx":
        from modalfem.forms.ritz import reduced_matrices_ufl

        K_r, M_r = reduced_matrices_ufl(mesh, material, kind, frame=frame)
    else:
        from modalfem.forms.skfem_ritz import reduced_matrices_skfem

        K_r, M_r = reduced_matrices_skfem(mesh, material, kind, frame=frame)
    R = None if clamp is not None else rigid_coefficients(kind, frame)
    lam, C, dropped = solve_reduced(K_r, M_r, rigid=R, rank_rtol=rank_rtol, what=f"Ritz basis {kind!r}")
    rigid = np.zeros(len(lam), dtype=bool)
    rigid[: 0 if R is None else R.shape[1]] = True
    if np.any(lam[~rigid] <= 0):
        raise SolverError(
            f"Ritz basis {kind!r}: {int(np.sum(lam[~rigid] <= 0))} deformation eigenvalue(s) <= 0 besides the "
            "rigid modes (roundoff on an extremely degenerate body)"
        )
    return RitzModes(
        kind=kind, frame=frame, omega=np.sqrt(lam[~rigid]), coefficients=C[:, ~rigid],
        rigid_coefficients=C[:, rigid], dropped=dropped, K_r=K_r, M_r=M_r, backend=backend,
    )
