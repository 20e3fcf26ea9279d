"""``TetModel``: the fixed data of a soft tetrahedral body (rest shape, shape gradients, lumped masses,
material and elastic energy). Changing data lives in ``TetState`` (``modalfem.tet.solver``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from modalfem.errors import InputError, MaterialError
from modalfem.material import Material
from modalfem.mesh.core import Mesh
from modalfem.tet.energies import Corotated, StableCorotated
from modalfem.tet.kinematics import area_weighted_normals, shape_gradients

__all__ = ["ENERGIES", "TetModel", "tet_model"]

#: elastic energies by name: "corotated" (linear elasticity in the rotated frame), "stable" (fixed corotated)
ENERGIES = {"corotated": Corotated, "stable": StableCorotated}


@dataclass(frozen=True, eq=False)
class TetModel:
    """Fixed data of a tetrahedral soft body (build it with :func:`tet_model`).

    Attributes:
        mesh: the rest mesh (points [m], positively oriented cells).
        material: ``Material`` (E [Pa], nu [-], rho [kg/m^3]).
        energy: elastic energy name (a key of ``ENERGIES``).
        grad: rest shape-function gradients (m, 4, 3) [1/m] (``F = sum_a x_a grad_a^T``).
        rest_volumes: rest volumes (m,) [m^3].
        masses: lumped vertex masses (n,) [kg] (a quarter of each adjacent tetrahedron's mass).
    """

    mesh: Mesh
    material: Material
    energy: str
    grad: np.ndarray
    rest_volumes: np.ndarray
    masses: np.ndarray

    @property
    def cells(self) -> np.ndarray:
        """Tetrahedra (m, 4)."""
        return self.mesh.cells

    @property
    def rest_points(self) -> np.ndarray:
        """Rest vertex positions (n, 3) [m]."""
        return self.mesh.points

    @property
    def point_count(self) -> int:
        return self.mesh.point_count

    @property
    def cell_count(self) -> int:
        return self.mesh.cell_count

    @property
    def mu(self) -> float:
        """Shear modulus [Pa]."""
        return self.material.shear_modulus

    @property
    def lam(self) -> float:
        """First Lame parameter [Pa]."""
        return self.material.lame_lambda

    @cached_property
    def density(self):
        """The elastic energy density object (``Corotated`` or ``StableCorotated``)."""
        return ENERGIES[self.energy](self.mu, self.lam)

    @cached_property
    def rest_normals(self) -> np.ndarray:
        """Outward area-weighted normals of the face opposite each vertex at rest (m, 4, 3) [m^2]."""
        return area_weighted_normals(self.mesh.points, self.mesh.cells)

    @cached_property
    def size(self) -> float:
        """Diagonal of the rest bounding box [m] (the length scale of tolerances)."""
        lo, hi = self.mesh.bounds
        return float(np.linalg.norm(hi - lo))


def _material(material) -> Material:
    if isinstance(material, Material):
        return material
    if isinstance(material, Mapping):
        try:
            E, nu, rho = (float(material[k]) for k in ("E", "nu", "rho"))
        except KeyError as e:
            raise InputError(f"material mapping needs keys E, nu, rho; missing {e}") from None
        except (TypeError, ValueError):
            raise MaterialError(f"material values must be numbers, got {dict(material)}") from None
        if math.isfinite(nu) and nu >= 0.5:
            raise MaterialError(
                f"Poisson's ratio nu = {nu:g} >= 0.5 makes lambda infinite: the linear / corotated elastic "
                "models need nu < 0.5 (use e.g. nu = 0.49 with energy='stable', plus VolumeSprings)")
        return Material(E, nu, rho, str(material.get("name", "")))
    raise InputError(f"material must be a Material or a mapping with E, nu, rho, got {type(material).__name__}")


def tet_model(mesh, material, *, energy: str = "stable") -> TetModel:
    """Build the fixed data of a tetrahedral soft body.

    Args:
        mesh: a ``Mesh`` or a pair ``(points (n, 3) [m], cells (m, 4))``; validated by ``Mesh``
            (zero-volume or inverted rest tetrahedra are rejected).
        material: ``Material`` or a mapping ``{"E": Pa, "nu": -, "rho": kg/m^3}``.
        energy: ``"stable"`` (inversion-robust fixed corotated, default) or ``"corotated"``
            (corotational linear elasticity).

    Returns:
        ``TetModel``.

    Raises:
        MeshError: malformed mesh, zero-volume or inverted rest elements.
        MaterialError: impossible material, including nu >= 0.5 (lambda = inf).
        InputError: unknown energy name.
    """
    if not isinstance(mesh, Mesh):
        try:
            points, cells = mesh
        except (TypeError, ValueError):
            raise InputError("mesh must be a Mesh or a (points, cells) pair") from None
        mesh = Mesh(points, cells)
    if energy not in ENERGIES:
        raise InputError(f"unknown tet energy {energy!r}; choose one of {sorted(ENERGIES)}")
    mat = _material(material)
    grad, vol = shape_gradients(mesh.points, mesh.cells)
    masses = np.bincount(mesh.cells.ravel(), weights=np.repeat(mat.rho * vol / 4.0, 4),
                         minlength=mesh.point_count)
    for a in (grad, vol, masses):
        a.setflags(write=False)
    return TetModel(mesh, mat, energy, grad, vol, masses)
