"""Kinematic obstacles: a plane, a sphere (both with optional rigid motion) and triangle meshes.

Obstacles have infinite mass: collisions change the cloth's velocity only. Planes and spheres act on
cloth vertices (exact for a plane; for a sphere, edges shorter than ``sqrt(8 R h)`` keep their sag
below the thickness ``h``). Triangle meshes join the point-triangle and edge-edge tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from modalfem.errors import InputError

__all__ = ["Plane", "Sphere", "TriangleMeshObstacle"]


def _vec(value, name: str) -> np.ndarray:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise InputError(f"{name} must be 3 finite numbers, got {value!r}")
    return a


@dataclass(frozen=True)
class Plane:
    """The half-space ``(x - point) . normal >= 0`` is free; the plane translates with ``velocity``.

    Attributes:
        point: (3,) a point of the plane at t = 0 [m].
        normal: (3,) normal towards the free side (normalised on construction).
        velocity: (3,) translation velocity [m/s].
    """

    point: np.ndarray
    normal: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        n = _vec(self.normal, "plane normal")
        if np.linalg.norm(n) == 0:
            raise InputError("plane normal must be non-zero")
        object.__setattr__(self, "normal", n / np.linalg.norm(n))
        object.__setattr__(self, "point", _vec(self.point, "plane point"))
        object.__setattr__(self, "velocity", _vec(self.velocity, "plane velocity"))

    def signed_distance(self, x: np.ndarray, t: float) -> np.ndarray:
        """Signed distance [m] of points ``x`` (k, 3) [m] at time ``t`` [s] (> 0 on the free side)."""
        # x . n - p . n: no (k, 3) temporary (the pipeline evaluates all cloth vertices many times a step)
        return np.asarray(x, dtype=float) @ self.normal - float((self.point + t * self.velocity) @ self.normal)

    def normal_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """(k, 3) unit normals [-] at points ``x`` [m], time ``t`` [s]."""
        return np.broadcast_to(self.normal, np.shape(x)).copy()

    def velocity_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """(k, 3) velocity [m/s] of the obstacle's material at points ``x`` [m], time ``t`` [s]."""
        return np.broadcast_to(self.velocity, np.shape(x)).copy()

    def rigid_motion(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(origin [m], linear velocity [m/s], angular velocity [rad/s])`` at time ``t`` [s]."""
        return self.point + t * self.velocity, self.velocity.copy(), np.zeros(3)


@dataclass(frozen=True)
class Sphere:
    """A solid ball of ``radius`` whose centre moves with ``velocity`` and spins with ``angular_velocity``.

    Attributes:
        center: (3,) centre at t = 0 [m].
        radius: radius [m], > 0.
        velocity: (3,) centre velocity [m/s].
        angular_velocity: (3,) spin [rad/s] (moves the surface: friction drags the cloth).
    """

    center: np.ndarray
    radius: float
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _vec(self.center, "sphere center"))
        object.__setattr__(self, "velocity", _vec(self.velocity, "sphere velocity"))
        object.__setattr__(self, "angular_velocity", _vec(self.angular_velocity, "sphere angular_velocity"))
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise InputError(f"sphere radius must be > 0 m, got {self.radius}")

    def center_at(self, t: float) -> np.ndarray:
        """(3,) centre [m] at time ``t`` [s]."""
        return self.center + t * self.velocity

    def signed_distance(self, x: np.ndarray, t: float) -> np.ndarray:
        """Signed distance [m] of points ``x`` (k, 3) [m] to the sphere at time ``t`` [s] (> 0 outside)."""
        return np.linalg.norm(np.asarray(x) - self.center_at(t), axis=-1) - self.radius

    def normal_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """(k, 3) outward unit normals [-] at points ``x`` [m], time ``t`` [s]."""
        r = np.asarray(x) - self.center_at(t)
        nr = np.linalg.norm(r, axis=-1, keepdims=True)
        return np.where(nr > 0, r / np.where(nr > 0, nr, 1.0), np.array([0.0, 0.0, 1.0]))

    def velocity_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """(k, 3) velocity [m/s] of the ball's material at points ``x`` [m], time ``t`` [s]."""
        r = np.asarray(x) - self.center_at(t)
        return self.velocity + np.cross(self.angular_velocity, r)

    def rigid_motion(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(origin [m], linear velocity [m/s], angular velocity [rad/s])`` at time ``t`` [s]."""
        return self.center_at(t), self.velocity.copy(), self.angular_velocity.copy()


@dataclass(frozen=True)
class TriangleMeshObstacle:
    """A closed or open triangle mesh, static or moving (vertices linear in time between key frames).

    Attributes:
        vertices: (k, 3) vertex positions [m] at ``t_start``.
        triangles: (f, 3) int vertex indices.
        vertices_end: (k, 3) positions [m] at ``t_end`` (None: static).
        t_start: time [s] of ``vertices``.
        t_end: time [s] of ``vertices_end``; outside [t_start, t_end] positions are clamped.
        motion: optional callable ``t [s] -> (k, 3) positions [m]`` overriding the key frames
            (the pipeline samples it at the start and end of each step; motion in between is linear).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    vertices_end: np.ndarray | None = None
    t_start: float = 0.0
    t_end: float = 1.0
    motion: Callable[[float], np.ndarray] | None = None

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float)
        f = np.asarray(self.triangles)
        if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
            raise InputError(f"obstacle vertices must be a finite (k, 3) array, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.size == 0 or f.min() < 0 or f.max() >= len(v):
            raise InputError("obstacle triangles must be (f, 3) indices into its vertices")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", f.astype(np.int64))
        if self.vertices_end is not None:
            e = np.asarray(self.vertices_end, dtype=float)
            if e.shape != v.shape or not np.isfinite(e).all():
                raise InputError("obstacle vertices_end must match vertices in shape and be finite")
            if not self.t_end > self.t_start:
                raise InputError("obstacle t_end must be > t_start")
            object.__setattr__(self, "vertices_end", e)

    def positions(self, t: float) -> np.ndarray:
        """(k, 3) vertex positions [m] at time ``t`` [s]."""
        if self.motion is not None:
            p = np.asarray(self.motion(t), dtype=float)
            if p.shape != self.vertices.shape or not np.isfinite(p).all():
                raise InputError("obstacle motion(t) must return finite positions shaped like its vertices")
            return p
        if self.vertices_end is None:
            return self.vertices
        s = min(max((t - self.t_start) / (self.t_end - self.t_start), 0.0), 1.0)
        return (1.0 - s) * self.vertices + s * self.vertices_end
