"""UFL forms of 3D isotropic linear elasticity: stiffness, consistent mass and lumped mass.

Physics (SI units): displacement ``u`` [m], small strain ``eps(u) = sym(grad u)`` [-], stress
``sigma(u) = 2 mu eps(u) + lambda tr(eps(u)) I`` [Pa], stiffness ``a(u, v) = int sigma(u) : eps(v) dx``
(K [N/m]) and mass ``m(u, v) = int rho u . v dx`` (M [kg]).

The point-wise densities (``elastic_energy_density``, ``kinetic_density``) are small named functions
of trial/test functions (or any UFL vector expressions) so that Rayleigh-Ritz bases can reuse them.

Quadrature is exact and minimal on affine tetrahedra: degree ``2 (p - 1)`` for the stiffness and
``2 p`` for the mass of Lagrange degree ``p`` (FFCx's estimate is higher and costs time).

Lumped mass: a nodal quadrature (points at the Lagrange nodes) makes the mass matrix diagonal.
  * P1: the vertex rule (weights ``|T| / 4``) = row-sum lumping.
  * P2: row-sum lumping gives negative vertex masses, so the HRZ (Hinton-Rock-Zienkiewicz)
    lumping is used instead: each node gets its consistent diagonal entry scaled so that the cell
    keeps its mass. On an affine tetrahedron that is vertex ``|T| / 36`` and edge-midpoint
    ``4 |T| / 27`` (all positive, summing to ``|T|``), realised exactly by a custom nodal rule.

Material constants enter as ``dolfinx.fem.Constant`` when the function space lives on a dolfinx
mesh, so one compiled kernel (JIT-cached) serves every material.
"""

from __future__ import annotations

import numpy as np
import ufl

from modalfem.errors import InputError

__all__ = [
    "strain",
    "stress",
    "elastic_energy_density",
    "kinetic_density",
    "stiffness_quadrature_degree",
    "mass_quadrature_degree",
    "nodal_quadrature",
    "stiffness_form",
    "mass_form",
    "lumped_mass_form",
]

#: Reference-tetrahedron vertices and basix's edge order (edge k joins these two local vertices).
_REF_VERTICES = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
BASIX_TET_EDGES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]], dtype=np.int64)


def strain(u):
    """Small-strain tensor ``sym(grad u)`` [-] of a UFL vector field ``u`` [m]."""
    return ufl.sym(ufl.grad(u))


def stress(u, mu, lam):
    """Cauchy stress [Pa] ``2 mu eps(u) + lam tr(eps(u)) I``.

    Args:
        u: UFL vector field (3,) [m].
        mu: shear modulus [Pa] (float or UFL scalar).
        lam: first Lame parameter [Pa] (float or UFL scalar).
    """
    eps = strain(u)
    return 2.0 * mu * eps + lam * ufl.tr(eps) * ufl.Identity(3)


def elastic_energy_density(u, v, mu, lam):
    """Bilinear strain-energy density ``sigma(u) : eps(v)`` [J/m^3 per m^2 of u, v].

    ``0.5 * elastic_energy_density(u, u, ...)`` is the stored energy density [J/m^3].
    """
    return ufl.inner(stress(u, mu, lam), strain(v))


def kinetic_density(u, v, rho):
    """Mass density form ``rho u . v`` [kg/m^3 times m^2]."""
    return rho * ufl.inner(u, v)


def _degree(V) -> int:
    p = V.ufl_element().degree()
    if p not in (1, 2):
        raise InputError(f"elasticity forms support Lagrange degree 1 or 2, got {p!r}")
    return int(p)


def stiffness_quadrature_degree(degree: int) -> int:
    """Exact quadrature degree ``2 (p - 1)`` of the stiffness integrand on affine tetrahedra."""
    return 2 * (degree - 1)


def mass_quadrature_degree(degree: int) -> int:
    """Exact quadrature degree ``2 p`` of the mass integrand on affine tetrahedra."""
    return 2 * degree


def nodal_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodal rule on the reference tetrahedron (volume 1/6) for the lumped mass.

    Args:
        degree: Lagrange degree 1 or 2.

    Returns:
        points (q, 3) in basix node order (vertices, then edge midpoints in basix edge order) and
        weights (q,) summing to 1/6: P1 vertex rule (1/24 each); P2 HRZ weights (1/216 per vertex,
        2/81 per edge midpoint).
    """
    if degree == 1:
        return _REF_VERTICES.copy(), np.full(4, 1.0 / 24.0)
    if degree == 2:
        mids = 0.5 * (_REF_VERTICES[BASIX_TET_EDGES[:, 0]] + _REF_VERTICES[BASIX_TET_EDGES[:, 1]])
        w = np.concatenate([np.full(4, 1.0 / 36.0), np.full(6, 4.0 / 27.0)]) / 6.0
        return np.vstack([_REF_VERTICES, mids]), w
    raise InputError(f"elasticity forms support Lagrange degree 1 or 2, got {degree!r}")


def _constant(V, value: float):
    """A dolfinx Constant on V's mesh when there is one (keeps kernels material-independent)."""
    msh = getattr(V, "mesh", None)
    if msh is None:
        return float(value)
    from dolfinx.fem import Constant
    from petsc4py import PETSc

    return Constant(msh, PETSc.ScalarType(value))


def stiffness_form(V, material) -> ufl.Form:
    """Stiffness bilinear form ``int sigma(u) : eps(v) dx`` (K [N/m]).

    Args:
        V: vector Lagrange function space (P1 or P2) on tetrahedra (dolfinx or UFL).
        material: ``modalfem.Material`` (E [Pa], nu [-]).

    Returns:
        UFL bilinear form with quadrature degree ``2 (p - 1)``.

    Raises:
        InputError: the space is not of degree 1 or 2.
    """
    p = _degree(V)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    mu, lam = _constant(V, material.shear_modulus), _constant(V, material.lame_lambda)
    dx = ufl.dx(metadata={"quadrature_degree": stiffness_quadrature_degree(p)})
    return elastic_energy_density(u, v, mu, lam) * dx


def mass_form(V, material) -> ufl.Form:
    """Consistent mass bilinear form ``int rho u . v dx`` (M [kg]).

    Args:
        V: Lagrange function space (P1 or P2; vector, or scalar for one component block).
        material: ``modalfem.Material`` (rho [kg/m^3]).

    Returns:
        UFL bilinear form with quadrature degree ``2 p``.

    Raises:
        InputError: the space is not of degree 1 or 2.
    """
    p = _degree(V)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    dx = ufl.dx(metadata={"quadrature_degree": mass_quadrature_degree(p)})
    return kinetic_density(u, v, _constant(V, material.rho)) * dx


def lumped_mass_form(V, material) -> ufl.Form:
    """Lumped (diagonal) mass bilinear form: ``rho u . v`` under the nodal rule (M [kg]).

    P1 gives row-sum lumping; P2 gives HRZ lumping (positive; see module docstring). The assembled
    matrix is diagonal in value (its sparsity pattern may still be the full one).

    Args:
        V: Lagrange function space (P1 or P2) on affine tetrahedra.
        material: ``modalfem.Material`` (rho [kg/m^3]).

    Raises:
        InputError: the space is not of degree 1 or 2.
    """
    p = _degree(V)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    points, weights = nodal_quadrature(p)
    md = {
        "quadrature_rule": "custom",
        "quadrature_degree": mass_quadrature_degree(p),
        # nested tuples of floats: UFL canonicalises them into the form signature without warnings
        "quadrature_points": tuple(tuple(x) for x in points.tolist()),
        "quadrature_weights": tuple(weights.tolist()),
    }
    return kinetic_density(u, v, _constant(V, material.rho)) * ufl.dx(metadata=md)
