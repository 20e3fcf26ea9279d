"""Reduced Ritz matrices with scikit-fem quadrature (the pip-only twin of ``ritz.reduced_matrices_ufl``).

The Ritz fields of ``modalfem.forms.ritz`` (component x monomial of the scaled coordinate, optional
clamp weight) are evaluated in closed form at the global quadrature points of a scikit-fem basis and
wrapped as ``skfem.DiscreteField`` objects, so the energy densities are exactly the ones of the full
FEM forms (``modalfem.forms.skfem_elasticity.elastic_energy_density`` and ``kinetic_density``).
Quadrature of degree ``2 p + 1`` (p = polynomial degree of the fields) is exact on affine tetrahedra
(one order above the needed ``2 p``: scikit-fem's degree-6 tetrahedron rule was measured ~6e-6 off
on the clamped quadratic fields, its degree-7 rule agrees with basix to 1e-14).
The densities are bilinear and pointwise: probing them once with unit gradients (unit values) gives
their exact 9 x 9 (3 x 3) matrices, and the integrals over all field pairs become BLAS products,
over chunks of cells so memory stays bounded on large meshes.
"""

from __future__ import annotations

import numpy as np
from modalfem.forms.ritz import (
    RitzFrame,
    evaluate_fields,
    field_count,
    field_degree,
    frame_for,
)

__all__ = ["reduced_matrices_skfem"]

#: quadrature points per chunk (bounds the (F, 9, points) work arrays to ~25 MB)
_CHUNK_POINTS = 10_000


def reduced_matrices_skfem(mesh, material, kind: str, *, frame: RitzFrame | None = None):
    """Reduced stiffness and mass of the Ritz fields, integrated with scikit-fem quadrature.

    Args:
        mesh: ``modalfem.mesh.Mesh`` of the body [m].
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        kind: ``"affine"`` or ``"quadratic"``.
        frame: the ``RitzFrame`` (default ``frame_for(mesh.points)``, no clamp).

    Returns:
        ``(K_r, M_r)``: dense symmetric (F, F) arrays, K_r [N/m], M_r [kg].

    Raises:
        InputError: unknown kind.
    """
    from modalfem.forms import skfem_elasticity as forms
    from skfem.element import DiscreteField

    from modalfem.backends.skfem import create_basis

    frame = frame_for(mesh.points) if frame is None else frame
    n = field_count(kind)
    basis = create_basis(mesh, degree=1, vector=False, intorder=2 * field_degree(kind, frame) + 1)
    X = np.asarray(basis.global_coordinates())  # (3, E, Q) [m]
    dx = np.asarray(basis.dx)  # (E, Q) [m^3]
    # The densities are bilinear and pointwise, so probing them with the 9 unit gradients (and the 3
    # unit values) gives their exact matrices C [Pa] (9, 9) and R [kg/m^3] (3, 3); the integrals are
    # then BLAS products over all quadrature points.
    unit = np.eye(9).reshape(3, 3, 9)
    C = forms.elastic_energy_density(DiscreteField(value=np.zeros((3, 1, 9)), grad=unit[:, :, None, :]),
                                     DiscreteField(value=np.zeros((3, 9, 1)), grad=unit[:, :, :, None]),
                                     material.shear_modulus, material.lame_lambda)  # C[b, a] = sigma(e_a) : e_b
    R = forms.kinetic_density(DiscreteField(value=np.eye(3)[:, None, :]), DiscreteField(value=np.eye(3)[:, :, None]),
                              material.rho)
    K = np.zeros((n, n))
    M = np.zeros((n, n))
    step = max(1, _CHUNK_POINTS // max(1, X.shape[2]))
    for start in range(0, X.shape[1], step):
        c = slice(start, start + step)
        vals, grads = evaluate_fields(kind, frame, X[:, c])  # (F, 3, e, q), (F, 3, 3, e, q)
        w = dx[c].ravel()
        G = grads.reshape(n, 9, -1)
        V = vals.reshape(n, 3, -1)
        K += (C @ G).reshape(n, -1) @ (G * w).reshape(n, -1).T  # K[J, I] = sum_p w sigma(B_I) : eps(B_J)
        M += (R @ V).reshape(n, -1) @ (V * w).reshape(n, -1).T
    K = 0.5 * (K + K.T)
    M = 0.5 * (M + M.T)
    return K, M
