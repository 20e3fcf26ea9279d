"""Weak forms of 3D isotropic linear elasticity, installed as ``modalfem.forms``.

* ``modalfem.forms.ufl_elasticity``: UFL forms (stiffness, consistent mass, lumped mass) compiled by
  dolfinx for the FEniCSx backend.
* ``modalfem.forms.skfem_elasticity``: the same physics as scikit-fem forms.
* ``modalfem.forms.ritz``: Rayleigh-Ritz fields (affine, affine + quadratic) over the spatial
  coordinate and their reduced K_r, M_r in UFL (dolfinx imported lazily).
* ``modalfem.forms.skfem_ritz``: the same reduced matrices with scikit-fem quadrature.
"""
