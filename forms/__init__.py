"""Weak forms of 3D isotropic linear elasticity, installed as ``modalfem.forms``.

* ``modalfem.forms.ufl_elasticity``: UFL forms (stiffness, consistent mass, lumped mass) compiled by
  dolfinx for the FEniCSx backend.
* ``modalfem.forms.skfem_elasticity``: the same physics as scikit-fem forms.
"""
