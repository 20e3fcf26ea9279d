"""scikit-fem forms of 3D isotropic linear elasticity (same physics as ``ufl_elasticity``).

Displacement ``u`` [m], strain ``eps(u) = sym(grad u)``, stress ``sigma = 2 mu eps + lam tr(eps) I``
[Pa]; stiffness ``int sigma(u) : eps(v)`` (K [N/m]); mass ``int rho u . v`` (M [kg]).

Material constants are passed at assembly time as the form parameters ``mu``, ``lam`` [Pa] and
``rho`` [kg/m^3] (see ``form_parameters``), so the forms are module-level constants.

Quadrature orders (exact, minimal on affine tetrahedra): stiffness ``2 (p - 1)``, mass ``2 p``
(``stiffness_intorder`` / ``mass_intorder``). Lumped mass is computed from the consistent one by
``lumped_mass_diagonal`` (P1 row-sum; P2 HRZ, positive, see ``modalfem.forms.ufl_elasticity``).

Two equivalent ways to use them: the ``BilinearForm`` objects (``stiffness``, ``mass``,
``scalar_mass``) for scikit-fem's generic assembly, and the vectorised element kernels
``element_stiffness`` / ``element_mass`` on a SCALAR basis (one einsum over all cells, 3x3 blocks per
node pair), which the backend uses because it is ~10x faster at 140k DOFs. Tests check the two agree.

Only numpy and scikit-fem are imported (no dolfinx), so this works in a pip-only environment.
"""

from __future__ import annotations

import numpy as np
from skfem import BilinearForm
from skfem.helpers import ddot, dot, eye, sym_grad, trace

from modalfem.errors import InputError

__all__ = [
    "strain",
    "stress",
    "elastic_energy_density",
    "kinetic_density",
    "stiffness",
    "mass",
    "scalar_mass",
    "form_parameters",
    "stiffness_intorder",
    "mass_intorder",
    "lumped_mass_diagonal",
    "element_stiffness",
    "element_mass",
]

#: forms are assembled with scikit-fem's threaded path using one thread: measured ~4x faster than
#: the default loop (less memory-allocation churn; see /work/shared/ENVIRONMENT.md)
NTHREADS = 1


def strain(u):
    """Small-strain tensor ``sym(grad u)`` [-] of a vector field (skfem ``DiscreteField``)."""
    return sym_grad(u)


def stress(eps, mu, lam):
    """Stress [Pa] ``2 mu eps + lam tr(eps) I`` from a strain field ``eps`` (3, 3, ...)."""
    return 2.0 * mu * eps + lam * eye(trace(eps), eps.shape[0])


def elastic_energy_density(u, v, mu, lam):
    """Bilinear strain-energy density ``sigma(u) : eps(v)`` (per unit volume)."""
    return ddot(stress(strain(u), mu, lam), strain(v))


def kinetic_density(u, v, rho):
    """Mass density form ``rho u . v`` for vector fields."""
    return rho * dot(u, v)


def _stiffness(u, v, w):
    return elastic_energy_density(u, v, w.mu, w.lam)


def _mass(u, v, w):
    return kinetic_density(u, v, w.rho)


def _scalar_mass(u, v, w):
    return w.rho * u * v


#: Stiffness form over ``ElementVector`` bases; parameters ``mu``, ``lam`` [Pa].
stiffness = BilinearForm(_stiffness, nthreads=NTHREADS)
#: Consistent mass form over ``ElementVector`` bases; parameter ``rho`` [kg/m^3].
mass = BilinearForm(_mass, nthreads=NTHREADS)
#: Consistent mass of one displacement component (scalar basis); ``M = kron(M_scalar, I3)``.
scalar_mass = BilinearForm(_scalar_mass, nthreads=NTHREADS)


def form_parameters(material) -> dict[str, float]:
    """Keyword parameters ``mu``, ``lam`` [Pa] and ``rho`` [kg/m^3] for the forms above."""
    return {"mu": material.shear_modulus, "lam": material.lame_lambda, "rho": material.rho}


def _check(degree: int) -> int:
    if degree not in (1, 2):
        raise InputError(f"degree must be 1 or 2, got {degree!r}")
    return int(degree)


def stiffness_intorder(degree: int) -> int:
    """Exact quadrature order ``2 (p - 1)`` of the stiffness on affine tetrahedra (at least 1)."""
    return max(2 * (_check(degree) - 1), 1)


def mass_intorder(degree: int) -> int:
    """Exact quadrature order ``2 p`` of the mass on affine tetrahedra."""
    return 2 * _check(degree)


#: HRZ factor: (cell mass) / (trace of the consistent cell mass) on an affine tetrahedron.
_HRZ_SCALE = {1: 5.0 / 2.0, 2: 35.0 / 18.0}


def lumped_mass_diagonal(consistent_diagonal: np.ndarray, degree: int) -> np.ndarray:
    """Lumped mass [kg] from the diagonal of the consistent mass matrix.

    HRZ lumping scales each cell's consistent diagonal so that the cell keeps its mass. On affine
    tetrahedra the scale is the same for every cell (P1: 5/2, equal to row-sum lumping; P2: 35/18,
    i.e. vertex ``|T| / 36``, edge midpoint ``4 |T| / 27``), so it applies to the global diagonal.

    Args:
        consistent_diagonal: diagonal (N,) of the consistent mass [kg].
        degree: Lagrange degree 1 or 2.

    Returns:
        positive lumped masses (N,) [kg] with the same total.
    """
    return _HRZ_SCALE[_check(degree)] * np.asarray(consistent_diagonal, dtype=np.float64)


def _cells(basis, cells):
    return slice(None) if cells is None else cells


def element_stiffness(basis, mu, lam, *, cells=None) -> np.ndarray:
    """Element stiffness blocks [N/m] from a scalar Lagrange basis (same physics as ``stiffness``).

    With ``phi_i`` the scalar shape functions and ``e_a`` the unit vectors, entry ``[a, b, i, j, e]``
    is ``int_e sigma(phi_j e_b) : eps(phi_i e_a)
    = mu delta_ab grad phi_i . grad phi_j + mu d_b phi_i d_a phi_j + lam d_a phi_i d_b phi_j``.

    Args:
        basis: scalar skfem ``CellBasis`` (P1 or P2) with the stiffness quadrature.
        mu: shear modulus [Pa].
        lam: first Lame parameter [Pa].
        cells: optional index/slice of cells to compute (default all).

    Returns:
        array (3, 3, nloc, nloc, n_cells) [N/m]; ``(i, a)`` is the test (row) DOF.
    """
    c = _cells(basis, cells)
    G = np.stack([basis.basis[i][0].grad[:, c] for i in range(basis.Nbfun)], axis=1)  # (3, nloc, E, q)
    Gw = G * basis.dx[c]
    # T[a, b, i, j, e] = int d_a phi_i d_b phi_j
    T = np.stack([np.stack([np.einsum("ieq,jeq->ije", Gw[a], G[b]) for b in range(3)]) for a in range(3)])
    K = lam * T + mu * T.transpose(1, 0, 2, 3, 4)
    S = mu * (T[0, 0] + T[1, 1] + T[2, 2])
    for a in range(3):
        K[a, a] += S
    return K


def element_mass(basis, rho, *, cells=None) -> np.ndarray:
    """Scalar element mass ``int_e rho phi_i phi_j`` [kg], array (nloc, nloc, n_cells).

    Args:
        basis: scalar skfem ``CellBasis`` with the mass quadrature.
        rho: density [kg/m^3].
        cells: optional index/slice of cells to compute (default all).
    """
    c = _cells(basis, cells)
    P = np.stack([np.asarray(basis.basis[i][0])[c] for i in range(basis.Nbfun)])  # (nloc, E, q)
    return rho * np.einsum("ieq,jeq->ije", P * basis.dx[c], P, optimize=True)
