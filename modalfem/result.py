"""Result types of a modal analysis: ``ModalResult`` and its ``Certificate``."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Certificate", "ModalResult"]


@dataclass(frozen=True)
class Certificate:
    """Evidence that the returned eigenpairs are right and that none below the top one was missed.

    Attributes:
        residuals: per deformation mode, ||K x - lambda M x|| / ||K x|| (k,).
        rigid_residuals: per rigid mode, ||K x|| / (||K|| ||x||) (r,).
        orthonormality_error: max |Phi^T M Phi - I| over all returned modes (rigid included).
        inertia_shift: sigma [rad^2/s^2] at which K - sigma M was factorised (LDL^T).
        inertia_count: negative pivots of that factorisation = eigenvalues below sigma (Sylvester).
        computed_below_shift: eigenvalues this solve returned (rigid included) below sigma.
        pairs: index pairs (i, j) of deformation modes forming degenerate pairs.
        tolerance: the residual bound used for ``passed``.
        passed: residuals <= tolerance, orthonormality <= 1e-8, rigid_coupling <= 1e-8 and
            inertia_count == computed_below_shift.
        rigid_coupling: max over deformation modes of ||Z^T M x|| against the M-orthonormal rigid fields
            Z known from the mesh's structure: how far a deformation mode is from the rigid subspace's
            M-orthogonal complement (0 exact). Rigid modes are classified by that subspace, never by
            an eigenvalue threshold.
    """

    residuals: np.ndarray
    rigid_residuals: np.ndarray
    orthonormality_error: float
    inertia_shift: float
    inertia_count: int
    computed_below_shift: int
    pairs: tuple[tuple[int, int], ...]
    tolerance: float
    passed: bool
    rigid_coupling: float = 0.0

    @property
    def max_residual(self) -> float:
        return float(np.max(self.residuals)) if len(self.residuals) else 0.0

    @property
    def missed_count(self) -> int:
        """Eigenvalues below ``inertia_shift`` that the solve did not return (0 when certified)."""
        return self.inertia_count - self.computed_below_shift

    def to_dict(self) -> dict:
        return {
            "passed": bool(self.passed),
            "max_residual": self.max_residual,
            "residuals": [float(r) for r in self.residuals],
            "rigid_residuals": [float(r) for r in self.rigid_residuals],
            "orthonormality_error": float(self.orthonormality_error),
            "inertia_shift": float(self.inertia_shift),
            "inertia_count": int(self.inertia_count),
            "computed_below_shift": int(self.computed_below_shift),
            "pairs": [list(map(int, p)) for p in self.pairs],
            "tolerance": float(self.tolerance),
            "rigid_coupling": float(self.rigid_coupling),
        }


@dataclass(frozen=True)
class ModalResult:
    """Lowest vibration modes of a body.

    Attributes:
        omega: deformation-mode angular frequencies (k,) [rad/s], ascending.
        shapes: mass-normalised deformation mode shapes (N_dof, k), node-major DOF order (see
            ``modalfem.mesh.core``), zeros on fixed DOFs. ``shapes.T @ M @ shapes = I``.
        rigid_shapes: mass-normalised rigid-body modes (N_dof, r) found by the solve.
        rigid_mode_count: r, checked against the count expected from pieces and constraints.
        labels: one label per deformation mode, e.g. ``"bending-y 1"``, ``"torsion 1"``, ``"axial 1"``.
        certificate: residuals, orthonormality, inertia count, degenerate pairs.
        timings: wall seconds per stage (``assembly``, ``eigen``, ``certificate``, ``total``, ...).
        degree: Lagrange degree (1 or 2).
        dof_points: node coordinates (N_dof / 3, 3) [m] in the DOF order.
        fixed_dofs: boolean mask (N_dof,) of eliminated DOFs.
        backend: assembly backend used (``"fenicsx"`` or ``"skfem"``).
        solver: eigen solver used (``"slepc"`` or ``"scipy"``).
        info: free-form provenance (versions, shift, sizes).
    """

    omega: np.ndarray
    shapes: np.ndarray
    rigid_shapes: np.ndarray
    rigid_mode_count: int
    labels: tuple[str, ...]
    certificate: Certificate
    timings: dict[str, float]
    degree: int
    dof_points: np.ndarray
    fixed_dofs: np.ndarray
    backend: str
    solver: str
    info: dict = field(default_factory=dict)

    @property
    def frequencies_hz(self) -> np.ndarray:
        """Deformation-mode frequencies (k,) [Hz], ascending."""
        return self.omega / (2.0 * np.pi)

    @property
    def eigenvalues(self) -> np.ndarray:
        """lambda = omega^2 (k,) [rad^2/s^2]."""
        return self.omega**2

    def shape(self, i: int) -> np.ndarray:
        """Displacement field of deformation mode ``i`` at the nodes, (N_dof / 3, 3)."""
        return self.shapes[:, i].reshape(-1, 3)
