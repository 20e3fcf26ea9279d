"""Opt-in terms of a tetrahedral simulation: gravity, ground contact, Rayleigh damping, pinned vertices,
volume springs and a volume barrier. A ``TetSolver`` evaluates only the effects it is given.

Every potential is written as an energy with its gradient and (diagonal or element) Hessian so it
enters the incremental potential of backward Euler (``modalfem.tet.solver``) directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError
from modalfem.tet.energies import VolumeBarrierDensity, VolumeSpringDensity

__all__ = ["Gravity", "Ground", "Pins", "RayleighDamping", "VolumeBarrier", "VolumeSprings"]


def _nonneg(what: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0:
        raise InputError(f"{what} must be finite and >= 0, got {value!r}")
    return v


@dataclass(frozen=True)
class Gravity:
    """Uniform gravity: energy ``-sum_i m_i g . x_i`` [J].

    Args:
        g: acceleration (3,) [m/s^2], default (0, 0, -9.81).
    """

    g: tuple = (0.0, 0.0, -9.81)
    kind = "vertex"

    def __post_init__(self) -> None:
        g = np.asarray(self.g, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity g must be 3 finite numbers [m/s^2], got {self.g!r}")
        object.__setattr__(self, "g", tuple(g.tolist()))

    def energy(self, x: np.ndarray, masses: np.ndarray) -> float:
        """Potential energy [J] of positions ``x`` (n, 3) [m], masses (n,) [kg]."""
        return -float(masses @ (x @ np.asarray(self.g)))

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        """Energy gradient (n, 3) [N]."""
        return -masses[:, None] * np.asarray(self.g)[None, :]

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray | None:
        """Diagonal of the energy Hessian (n, 3) [N/m]; None (zero)."""
        return None


@dataclass(frozen=True)
class Ground:
    """Penalty ground plane ``z >= height``: energy ``stiffness/2 sum_i min(0, z_i - height)^2`` [J].

    Args:
        height: ground level [m] (the plane z = height; z is up).
        stiffness: penalty stiffness per vertex [N/m], > 0.
    """

    height: float = 0.0
    stiffness: float = 1e5
    kind = "vertex"

    def __post_init__(self) -> None:
        if not math.isfinite(float(self.height)):
            raise InputError(f"ground height must be finite, got {self.height!r}")
        if _nonneg("ground stiffness [N/m]", self.stiffness) == 0:
            raise InputError("ground stiffness must be > 0 N/m")

    def _pen(self, x: np.ndarray) -> np.ndarray:
        return np.minimum(x[:, 2] - float(self.height), 0.0)

    def energy(self, x: np.ndarray, masses: np.ndarray) -> float:
        """Penalty energy [J]."""
        d = self._pen(x)
        return 0.5 * float(self.stiffness) * float(d @ d)

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        """Energy gradient (n, 3) [N]."""
        g = np.zeros_like(x)
        g[:, 2] = float(self.stiffness) * self._pen(x)
        return g

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        """Diagonal of the energy Hessian (n, 3) [N/m]."""
        h = np.zeros_like(x)
        h[:, 2] = np.where(x[:, 2] < float(self.height), float(self.stiffness), 0.0)
        return h


@dataclass(frozen=True)
class RayleighDamping:
    """Rayleigh damping force ``-(alpha M + beta K(x_n)) v`` [N], K the projected elastic Hessian.

    Args:
        alpha: mass-proportional coefficient [1/s], >= 0.
        beta: stiffness-proportional coefficient [s], >= 0.
    """

    alpha: float = 0.0
    beta: float = 0.0
    kind = "damping"

    def __post_init__(self) -> None:
        _nonneg("Rayleigh alpha [1/s]", self.alpha)
        _nonneg("Rayleigh beta [s]", self.beta)


@dataclass(frozen=True, eq=False)
class Pins:
    """Vertices held at fixed positions (their DOFs are eliminated).

    Args:
        vertices: vertex indices (k,).
        positions: held positions (k, 3) [m]; None holds them at their rest positions.
    """

    vertices: np.ndarray
    positions: np.ndarray | None = None
    kind = "pins"

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices)
        if v.ndim != 1 or (v.size and not np.issubdtype(v.dtype, np.integer)):
            raise InputError(f"pinned vertices must be a 1-D array of indices, got shape {v.shape}")
        object.__setattr__(self, "vertices", v.astype(np.int64))
        if self.positions is not None:
            p = np.asarray(self.positions, dtype=float)
            if p.shape != (len(v), 3) or not np.all(np.isfinite(p)):
                raise InputError(f"pin positions must be finite with shape ({len(v)}, 3), got {p.shape}")
            object.__setattr__(self, "positions", p)


@dataclass(frozen=True)
class VolumeSprings:
    """Per-element volume springs ``K/2 (V - V0)^2`` [J] with ``K = stiffness / V0`` [N/m^5].

    The forces are along the area-weighted normals of each vertex's opposite face.

    Args:
        stiffness: volumetric stiffness [Pa], >= 0.
    """

    stiffness: float
    kind = "element"

    def __post_init__(self) -> None:
        _nonneg("volume spring stiffness [Pa]", self.stiffness)

    def density(self) -> VolumeSpringDensity:
        """The energy density term."""
        return VolumeSpringDensity(float(self.stiffness))


@dataclass(frozen=True)
class VolumeBarrier:
    """Volume barrier ``stiffness V0 (J - 1 - log J)`` [J] per element: infinite as V -> 0.

    Steps with this term require every element to have positive volume at the start.

    Args:
        stiffness: barrier stiffness [Pa] (its curvature at rest volume), > 0.
    """

    stiffness: float
    kind = "element"

    def __post_init__(self) -> None:
        if _nonneg("volume barrier stiffness [Pa]", self.stiffness) == 0:
            raise InputError("volume barrier stiffness must be > 0 Pa")

    def density(self) -> VolumeBarrierDensity:
        """The energy density term."""
        return VolumeBarrierDensity(float(self.stiffness))
