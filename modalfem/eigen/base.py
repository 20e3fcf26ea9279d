"""What every eigen solver returns, and the shift convention.

Solvers work on the constrained (free-DOF) matrices K_ff [N/m], M_ff [kg] of the generalized
problem K x = lambda M x, lambda = omega^2 [rad^2/s^2]. They use shift-and-invert at a NEGATIVE
shift ``shift = -alpha`` (so K - shift M is positive definite even for a free body and a Cholesky /
LDL^T factorisation applies), return the lowest ``nev`` eigenpairs (rigid ones included, lambda ~ 0),
and compute the certificate numbers with their own linear algebra (serial or distributed), so the
shared logic in ``modalfem.eigen.certify`` only sees numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["RawModes"]


@dataclass
class RawModes:
    """Output of one eigen solve on the free DOFs.

    Attributes:
        eigenvalues: lambda (m,) [rad^2/s^2], ascending, m >= nev requested (rigid included).
        vectors: (n_free, m) in the canonical order of the free DOFs, M-orthonormal
            (X^T M X = I); on every MPI rank.
        residuals: (m,) ||K x - lambda M x|| / ||K x|| for each pair (for lambda ~ 0 the
            solver divides by ||K||_inf ||x|| instead, since K x ~ 0).
        orthonormality_error: max |X^T M X - I|.
        inertia_shift: sigma [rad^2/s^2] where K - sigma M was factorised for the Sylvester count.
        inertia_count: number of negative pivots of that LDL^T = eigenvalues below sigma.
        timings: wall seconds: ``factor``, ``solve``, ``certificate`` (and others the solver adds).
        info: solver name, shift, iterations, options, versions.
    """

    eigenvalues: np.ndarray
    vectors: np.ndarray
    residuals: np.ndarray
    orthonormality_error: float
    inertia_shift: float
    inertia_count: int
    timings: dict[str, float] = field(default_factory=dict)
    info: dict = field(default_factory=dict)
