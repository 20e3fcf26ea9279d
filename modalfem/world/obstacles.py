"""Static and scripted obstacles of a ``World``: ground, plane, sphere, box, triangle mesh.

Every obstacle can move on a ``path`` (a translation over time): a callable ``t [s] -> offset (3,) [m]`` or
key frames ``[(t0, (x, y, z)), (t1, ...), ...]`` interpolated linearly (held before the first and after the
last). Obstacles are kinematic: bodies push on them, never the other way round.

Each obstacle answers the world's questions in one place: ``signed_distance(x, t)`` (gap [m], negative
inside, and the outward normal), ``velocity(x, t)`` [m/s] of its surface, and ``surface(t)`` (a triangle
mesh for the cloth's collision pipeline and for pictures).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from modalfem.effects import vec3
from modalfem.errors import InputError

__all__ = ["Box", "Ground", "Path", "Plane", "Sphere", "TriangleMesh"]


_vec = vec3


class Path:
    """A translation over time: ``offset(t)`` (3,) [m] and its velocity (3,) [m/s].

    Args:
        motion: a callable ``t [s] -> (3,) [m]``, or key frames ``[(t, (x, y, z)), ...]`` with increasing
            times [s] (linear in between, held outside).
    """

    def __init__(self, motion) -> None:
        self._fn: Callable | None = None
        if callable(motion):
            self._fn = motion
            self.offset(0.0)
            return
        try:
            frames = [(float(t), _vec("path key frame", p, "m")) for t, p in motion]
        except (TypeError, ValueError):
            raise InputError("a path is a callable t -> (x, y, z) [m] or key frames [(t [s], (x, y, z) [m]), ...]"
                             ) from None
        if not frames:
            raise InputError("a path needs at least one key frame")
        times = np.array([f[0] for f in frames])
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
            raise InputError(f"path key frame times must be finite and increasing [s], got {times.tolist()}")
        self.times = times
        self.points = np.stack([f[1] for f in frames])

    def offset(self, t: float) -> np.ndarray:
        """Translation (3,) [m] at time ``t`` [s]."""
        if self._fn is not None:
            p = np.asarray(self._fn(float(t)), dtype=np.float64).reshape(-1)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise InputError(f"the obstacle path must return 3 finite numbers [m] at t = {t:g} s, got {p!r}")
            return p
        return np.array([np.interp(t, self.times, self.points[:, c]) for c in range(3)])

    def velocity(self, t: float, dt: float) -> np.ndarray:
        """Mean velocity (3,) [m/s] over ``[t, t + dt]``."""
        return (self.offset(t + dt) - self.offset(t)) / dt


def _path(path) -> Path | None:
    if path is None or isinstance(path, Path):
        return path
    return Path(path)


class _Obstacle:
    path: Path | None = None
    kind = "obstacle"

    @property
    def moving(self) -> bool:
        return self.path is not None

    def offset(self, t: float) -> np.ndarray:
        return np.zeros(3) if self.path is None else self.path.offset(t)

    def velocity(self, x: np.ndarray, t: float, dt: float) -> np.ndarray:
        """Velocity (k, 3) [m/s] of the obstacle's surface at points ``x`` over ``[t, t + dt]``."""
        v = np.zeros(3) if self.path is None else self.path.velocity(t, dt)
        return np.broadcast_to(v, np.shape(x))

    def _local(self, x: np.ndarray, t: float) -> np.ndarray:
        return np.asarray(x, dtype=np.float64) - self.offset(t)


class Plane(_Obstacle):
    """The half-space ``(x - point) . normal >= 0`` is free.

    Args:
        normal: (3,) normal towards the free side (normalised here).
        point: (3,) a point of the plane [m] at t = 0.
        path: optional translation over time (``Path`` or its arguments).
        size: half-width [m] of the square drawn for it in pictures and given to the cloth pipeline.
    """

    kind = "plane"

    def __init__(self, normal=(0.0, 0.0, 1.0), point=(0.0, 0.0, 0.0), *, path=None, size: float = 5.0) -> None:
        n = _vec("plane normal", normal, "-")
        if not np.linalg.norm(n) > 0:
            raise InputError("plane normal must not be zero")
        self.normal = n / np.linalg.norm(n)
        self.point = _vec("plane point", point, "m")
        self.path = _path(path)
        self.size = float(size)

    def signed_distance(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Gap (k,) [m] (negative inside) and outward normal (k, 3) at points ``x`` (k, 3) [m], time ``t``."""
        g = self._local(x, t) @ self.normal - float(self.point @ self.normal)
        return g, np.broadcast_to(self.normal, np.shape(x))

    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        a = np.cross(self.normal, [1.0, 0.0, 0.0] if abs(self.normal[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(self.normal, a)
        c = self.point + self.offset(t)
        s = self.size
        v = np.array([c - s * a - s * b, c + s * a - s * b, c + s * a + s * b, c - s * a + s * b])
        return v, np.array([[0, 1, 2], [0, 2, 3]])


class Ground(Plane):
    """The horizontal ground ``z = height`` [m] (free above)."""

    kind = "ground"

    def __init__(self, height: float = 0.0, *, size: float = 5.0) -> None:
        h = float(height)
        if not math.isfinite(h):
            raise InputError(f"ground height must be finite [m], got {height!r}")
        super().__init__((0.0, 0.0, 1.0), (0.0, 0.0, h), size=size)
        self.height = h


def _midpoint(verts: list, cache: dict, i: int, j: int) -> int:
    key = (min(i, j), max(i, j))
    if key not in cache:
        m = verts[i] + verts[j]
        verts.append(m / np.linalg.norm(m))
        cache[key] = len(verts) - 1
    return cache[key]


def _icosphere(level: int = 2) -> tuple[np.ndarray, np.ndarray]:
    t = (1.0 + 5.0**0.5) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
         (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
         (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, dtype=float) / np.linalg.norm(p) for p in v]
    faces = [tuple(x) for x in f]
    for _ in range(level):
        cache: dict = {}
        nf = []
        for a, b, c in faces:
            ab, bc, ca = (_midpoint(verts, cache, i, j) for i, j in ((a, b), (b, c), (c, a)))
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = nf
    return np.array(verts), np.array(faces, dtype=np.int64)


class Sphere(_Obstacle):
    """A solid ball.

    Args:
        center: (3,) centre [m] at t = 0.
        radius: radius [m], > 0.
        path: optional translation over time.
    """

    kind = "sphere"

    def __init__(self, center, radius: float, *, path=None) -> None:
        self.center = _vec("sphere center", center, "m")
        try:
            self.radius = float(radius)
        except (TypeError, ValueError):
            raise InputError(f"sphere radius must be a number [m], got {radius!r}") from None
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise InputError(f"sphere radius must be > 0 [m], got {radius!r}")
        self.path = _path(path)

    def signed_distance(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        d = self._local(x, t) - self.center
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        n = d / np.where(r > 0, r, 1.0)[:, None]
        n[r == 0] = (0.0, 0.0, 1.0)
        return r - self.radius, n

    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        v, f = _icosphere(3)
        return self.center + self.offset(t) + self.radius * v, f


class Box(_Obstacle):
    """A solid box.

    Args:
        center: (3,) centre [m] at t = 0.
        half_extents: (3,) half sizes [m], > 0.
        rotation: (3, 3) box axes -> world (default identity).
        path: optional translation over time.
    """

    kind = "box"

    def __init__(self, center, half_extents, *, rotation=None, path=None) -> None:
        self.center = _vec("box center", center, "m")
        self.half = _vec("box half extents", half_extents, "m")
        if np.any(self.half <= 0):
            raise InputError(f"box half extents must be > 0 [m], got {self.half.tolist()}")
        R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) <= 0:
            raise InputError("box rotation must be a proper 3x3 rotation matrix")
        self.rotation = R
        self.path = _path(path)
        self._rt = None

    def signed_distance(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        from modalfem.runtime.obstacles import (
            Box as _RuntimeBox,  # one box distance for the whole package
        )

        if self._rt is None:
            self._rt = _RuntimeBox(self.center, self.half, self.rotation)
        return self._rt.signed_distance(np.ascontiguousarray(self._local(x, t)))

    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        c = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
        f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
        return self.center + self.offset(t) + (c * self.half) @ self.rotation.T, f


class TriangleMesh(_Obstacle):
    """A triangle mesh (closed: a solid, outward triangles; open: a one-sided sheet whose free side is the
    one its triangle normals point to).

    Args:
        vertices: (k, 3) positions [m] at t = 0.
        triangles: (f, 3) vertex indices.
        path: optional translation over time.
    """

    kind = "mesh"

    def __init__(self, vertices, triangles, *, path=None) -> None:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(triangles)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.all(np.isfinite(v)):
            raise InputError(f"obstacle mesh vertices must be a finite (k, 3) array [m], got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.size == 0 or not np.issubdtype(f.dtype, np.integer) \
                or f.min() < 0 or f.max() >= len(v):
            raise InputError("obstacle mesh triangles must be an (f, 3) integer array of indices into its vertices")
        self.vertices = v
        self.triangles = f.astype(np.int64)
        self.path = _path(path)
        self._proximity = None

    def surface(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices + self.offset(t), self.triangles

    def signed_distance(self, x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Gap and normal of every point against the closest triangle (an exhaustive search: for the few
        points of a check; the world's contact search uses the BVH)."""
        from modalfem.world.proximity import SurfaceProximity

        if self._proximity is None:
            self._proximity = SurfaceProximity(self.triangles, self.vertices)
        V = self.vertices + self.offset(t)
        x = np.asarray(x, dtype=np.float64)
        ext = float(np.ptp(np.concatenate([V, x]), axis=0).max()) + 1.0
        hit = self._proximity.query(x, V, ext)
        gap = np.full(len(x), np.inf)
        n = np.zeros((len(x), 3))
        gap[hit.point] = hit.gap
        n[hit.point] = hit.normal
        return gap, n
