"""Fixed cloth data: ``ClothMaterial``, scripted ``Handle`` s, and the ``ClothModel`` the solver steps."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from modalfem.cloth.energies import Bending, Membrane
from modalfem.cloth.mesh import ClothMesh
from modalfem.errors import InputError, MaterialError, MeshError, SimulationError

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


def non_finite(a: np.ndarray, what: str = "vertex") -> str:
    """"k non-finite values, first at vertex i: [row]" for an (n, 3) array holding NaN/inf."""
    bad = ~np.isfinite(a)
    i = int(np.flatnonzero(bad.reshape(len(a), -1).any(axis=1))[0])
    return f"{int(bad.sum())} non-finite values, first at {what} {i}: {np.asarray(a[i]).tolist()}"


def _points(points) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise InputError("handle points must be an (n, 3) array of numbers [m]") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"handle points must be an (n, 3) array [m], got shape {p.shape}")
    return p


def _indices(what: str, indices, n: int | None = None) -> np.ndarray:
    """Vertex indices as a 1-D int64 array; InputError naming the first bad one."""
    a = np.asarray(indices)
    if a.size == 0:
        return np.zeros(0, np.int64)
    if not (np.issubdtype(a.dtype, np.integer) or (np.issubdtype(a.dtype, np.floating) and np.all(np.isfinite(a))
                                                    and np.all(a == np.round(a)))):
        raise InputError(f"{what} vertex indices must be integers, got {np.asarray(indices).ravel()[:5].tolist()}")
    a = a.astype(np.int64).reshape(-1)
    if n is not None:
        out = (a < 0) | (a >= n)
        if out.any():
            raise InputError(f"{what} vertex {int(a[out][0])} out of range [0, {n}) "
                             f"({int(out.sum())} of {len(a)} out of range)")
    return a


@dataclass(frozen=True, eq=False)
class Handle:
    """Vertices driven along a scripted path (a pin is a handle that stays put).

    Args:
        indices: vertex indices (k,).
        path: ``t -> (k, 3)`` prescribed positions [m] at time ``t`` [s].
    """

    indices: np.ndarray
    path: Callable[[float], np.ndarray]

    def __post_init__(self) -> None:
        object.__setattr__(self, "indices", _indices("handle", self.indices))
        if not callable(self.path):
            raise InputError(f"handle path must be a function t -> (k, 3) positions [m], got "
                             f"{type(self.path).__name__}")

    def positions(self, t: float, *, name: str = "handle") -> np.ndarray:
        """The path at time ``t`` [s] as a finite (k, 3) array [m].

        Raises:
            SimulationError: the path raised, or returned something that is not k finite 3-vectors
                (the message names the handle, the time and what is wrong).
        """
        k = len(self.indices)
        try:
            raw = self.path(t)
            p = np.asarray(raw, dtype=float)
        except (TypeError, ValueError, ArithmeticError, IndexError) as exc:
            raise SimulationError(f"{name} path at t = {t:.6g} s failed: {type(exc).__name__}: {exc}") from None
        if p.size != 3 * k or (p.ndim == 2 and p.shape != (k, 3)) or p.ndim > 2:
            raise SimulationError(f"{name} path at t = {t:.6g} s must return ({k}, 3) positions [m] (one row per "
                                  f"handle vertex), got shape {p.shape}")
        p = p.reshape(k, 3)
        if not np.all(np.isfinite(p)):
            raise SimulationError(f"{name} path at t = {t:.6g} s returned {non_finite(p)}")
        return p

    @staticmethod
    def pin(points: np.ndarray, indices) -> Handle:
        """A handle holding vertices ``indices`` at their positions in ``points`` (n, 3) [m].

        Raises:
            InputError: an index outside ``points``, or non-finite held positions.
        """
        pts = _points(points)
        idx = _indices("pin", indices, len(pts))
        p = pts[idx].copy()
        if not np.all(np.isfinite(p)):
            raise InputError(f"pinned positions have {non_finite(p, 'pinned vertex')}")
        return Handle(idx, lambda t: p)

    @staticmethod
    def rotating(points: np.ndarray, indices, *, center, axis, rate: float) -> Handle:
        """Vertices turning rigidly about ``axis`` through ``center`` at ``rate`` [rad/s] from t = 0.

        Raises:
            InputError: an index outside ``points``, a zero or non-finite axis, non-finite center or rate.
        """
        pts = _points(points)
        idx = _indices("rotating handle", indices, len(pts))
        c0 = np.asarray(center, dtype=float).reshape(-1)
        k = np.asarray(axis, dtype=float).reshape(-1)
        if c0.shape != (3,) or not np.all(np.isfinite(c0)):
            raise InputError(f"rotating handle center must be 3 finite numbers [m], got {center!r}")
        if k.shape != (3,) or not np.all(np.isfinite(k)) or not np.linalg.norm(k) > 0:
            raise InputError(f"rotating handle axis must be 3 finite numbers, not all zero, got {axis!r}")
        if not np.isfinite(float(rate)):
            raise InputError(f"rotating handle rate must be finite [rad/s], got {rate!r}")
        rate = float(rate)
        p = pts[idx] - c0
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
        n = self.mesh.point_count
        for i, h in enumerate(self.handles):
            if not isinstance(h, Handle):
                raise InputError(f"handle {i} must be a modalfem.cloth.model.Handle, got {type(h).__name__}")
            _indices(f"handle {i}", h.indices, n)
            try:
                h.positions(0.0, name=f"handle {i}")  # a bad path fails here, not as a NaN in the solver
            except SimulationError as exc:
                raise InputError(str(exc)) from None
        idx = np.concatenate([h.indices for h in self.handles]) if self.handles else np.zeros(0, np.int64)
        uniq, counts = np.unique(idx, return_counts=True)
        if np.any(counts > 1):
            raise InputError(f"handles overlap: vertex {int(uniq[counts > 1][0])} is driven by two handles")
        object.__setattr__(self, "masses", m)
        object.__setattr__(self, "membrane", Membrane(self.mesh, self.material.mu, self.material.lam))
        object.__setattr__(self, "bending", Bending(self.mesh, self.material.kb))
        object.__setattr__(self, "handle_indices", np.sort(idx))

    def handle_targets(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(indices (k,), positions (k, 3) [m]) of all handle vertices at time ``t`` [s].

        Raises:
            SimulationError: a handle's path is not finite or has the wrong shape at ``t`` (named).
        """
        if not self.handles:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        idx = np.concatenate([h.indices for h in self.handles])
        pos = np.vstack([h.positions(t, name=f"handle {i}") for i, h in enumerate(self.handles)])
        return idx, pos

    def elastic_energy(self, x: np.ndarray) -> float:
        """Membrane + bending energy [J] at positions ``x`` (n, 3) [m]."""
        return self.membrane.energy(x) + self.bending.energy(x)
