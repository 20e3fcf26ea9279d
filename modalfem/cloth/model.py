"""Fixed cloth data: ``ClothMaterial``, scripted ``Handle`` s, and the ``ClothModel`` the solver steps."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from modalfem.cloth.energies import Bending, Membrane
from modalfem.cloth.mesh import ClothMesh
from modalfem.errors import InputError, MaterialError, MeshError

__all__ = ["COTTON", "ClothMaterial", "ClothModel", "Handle"]


def _check(name: str, value, unit: str, *, low: float = 0.0, strict: bool = True) -> float:
    v = float(value)
    if not np.isfinite(v) or (v <= low if strict else v < low):
        rel = ">" if strict else ">="
        raise MaterialError(f"cloth {name} must be finite and {rel} {low:g} {unit}, got {value!r}")
    return v


@dataclass(frozen=True)
class ClothMaterial:
    """A woven sheet: areal density and plane-stress elasticity of a thin layer.

    Args:
        areal_density: mass per area [kg/m^2], > 0.
        young: Young's modulus E [Pa], > 0.
        poisson: Poisson's ratio nu, in [0, 0.5).
        thickness: h [m], > 0.
        bending_stiffness: kb [N m]; default ``E h^3 / (12 (1 - nu^2))``.

    Raises:
        MaterialError: any value out of range or not finite (one line naming it).
    """

    areal_density: float
    young: float
    poisson: float
    thickness: float
    bending_stiffness: float | None = None
    name: str = "cloth"

    def __post_init__(self) -> None:
        _check("areal density", self.areal_density, "kg/m^2")
        _check("Young's modulus", self.young, "Pa")
        _check("thickness", self.thickness, "m")
        nu = float(self.poisson)
        if not np.isfinite(nu) or not 0.0 <= nu < 0.5:
            raise MaterialError(f"cloth Poisson's ratio must be in [0, 0.5), got {self.poisson!r}")
        if self.bending_stiffness is not None:
            _check("bending stiffness", self.bending_stiffness, "N m", strict=False)

    @property
    def mu(self) -> float:
        """2D shear modulus [N/m]: E h / (2 (1 + nu))."""
        return self.young * self.thickness / (2.0 * (1.0 + self.poisson))

    @property
    def lam(self) -> float:
        """2D (plane-stress) Lame modulus [N/m]: E h nu / (1 - nu^2)."""
        return self.young * self.thickness * self.poisson / (1.0 - self.poisson**2)

    @property
    def kb(self) -> float:
        """Bending stiffness [N m]."""
        if self.bending_stiffness is not None:
            return float(self.bending_stiffness)
        return self.young * self.thickness**3 / (12.0 * (1.0 - self.poisson**2))


#: a light cotton-like sheet: 0.2 kg/m^2, E h = 1000 N/m, kb = 2e-5 N m
COTTON = ClothMaterial(areal_density=0.2, young=2.0e6, poisson=0.3, thickness=5e-4, bending_stiffness=2e-5,
                       name="cotton")


@dataclass(frozen=True, eq=False)
class Handle:
    """Vertices driven along a scripted path (a pin is a handle that stays put).

    Args:
        indices: vertex indices (k,).
        path: ``t -> (k, 3)`` prescribed positions [m] at time ``t`` [s].
    """

    indices: np.ndarray
    path: Callable[[float], np.ndarray]

    @staticmethod
    def pin(points: np.ndarray, indices) -> Handle:
        """A handle holding vertices ``indices`` at their positions in ``points`` (n, 3) [m]."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        p = np.asarray(points, dtype=float)[idx].copy()
        return Handle(idx, lambda t: p)

    @staticmethod
    def rotating(points: np.ndarray, indices, *, center, axis, rate: float) -> Handle:
        """Vertices turning rigidly about ``axis`` through ``center`` at ``rate`` [rad/s] from t = 0."""
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        p = np.asarray(points, dtype=float)[idx] - np.asarray(center, dtype=float)
        c0 = np.asarray(center, dtype=float)
        k = np.asarray(axis, dtype=float)
        k = k / np.linalg.norm(k)

        def path(t: float) -> np.ndarray:
            a = rate * t
            # Rodrigues' rotation of the rest offsets
            return c0 + p * np.cos(a) + np.cross(k, p) * np.sin(a) + np.outer(p @ k, k) * (1.0 - np.cos(a))

        return Handle(idx, path)


@dataclass(frozen=True, eq=False)
class ClothModel:
    """The fixed data of one cloth: mesh, material, masses, energies, damping and handles.

    Args:
        mesh: the cloth mesh; its points are the rest shape.
        material: ``ClothMaterial``.
        mass_damping: Rayleigh coefficient alpha [1/s] (damping force ``-alpha M v``), >= 0.
        stiffness_damping: Rayleigh coefficient beta [s] (``-beta K v``), >= 0.
        handles: scripted or pinned vertex groups (disjoint).

    Raises:
        MaterialError: negative damping.
        MeshError: vertices with no triangle (no mass).
        InputError: handles with bad or overlapping indices.
    """

    mesh: ClothMesh
    material: ClothMaterial
    mass_damping: float = 0.0
    stiffness_damping: float = 0.0
    handles: tuple[Handle, ...] = field(default=())

    def __post_init__(self) -> None:
        _check("mass damping", self.mass_damping, "1/s", strict=False)
        _check("stiffness damping", self.stiffness_damping, "s", strict=False)
        m = self.mesh.lumped_masses(self.material.areal_density)
        if np.any(m <= 0):
            i = int(np.flatnonzero(m <= 0)[0])
            raise MeshError(f"cloth vertex {i} belongs to no triangle (no mass); remove unused points")
        object.__setattr__(self, "handles", tuple(self.handles))
        idx = np.concatenate([h.indices for h in self.handles]) if self.handles else np.zeros(0, np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.mesh.point_count):
            raise InputError(f"handle vertex index out of range [0, {self.mesh.point_count})")
        if len(np.unique(idx)) != len(idx):
            raise InputError("handles overlap: a vertex is driven by two handles")
        object.__setattr__(self, "masses", m)
        object.__setattr__(self, "membrane", Membrane(self.mesh, self.material.mu, self.material.lam))
        object.__setattr__(self, "bending", Bending(self.mesh, self.material.kb))
        object.__setattr__(self, "handle_indices", np.sort(idx))

    def handle_targets(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(indices (k,), positions (k, 3) [m]) of all handle vertices at time ``t`` [s]."""
        if not self.handles:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        idx = np.concatenate([h.indices for h in self.handles])
        pos = np.vstack([np.asarray(h.path(t), dtype=float).reshape(-1, 3) for h in self.handles])
        return idx, pos

    def elastic_energy(self, x: np.ndarray) -> float:
        """Membrane + bending energy [J] at positions ``x`` (n, 3) [m]."""
        return self.membrane.energy(x) + self.bending.energy(x)
