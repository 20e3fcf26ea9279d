"""Static obstacles of the modal runtime's contact: plane (ground), sphere, box, and the ``Obstacles`` effect.

Each obstacle gives signed distances in numpy (``signed_distance``) and an encoding ``(kind, params)`` that
the compiled contact kernels (``modalfem.runtime._contact_kernels``) evaluate. Obstacles are static: their
geometry is read when the ``Obstacles`` effect is made. numba is imported only when a contact is computed
(its version check loads the top-level ``scipy`` package, so ``import modalfem.runtime`` does not).
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import InputError

__all__ = ["Box", "Ground", "Obstacles", "Plane", "Sphere"]

#: obstacle kinds of the compiled kernels, and floats per encoded obstacle
PLANE, SPHERE, BOX = 0, 1, 2
PARAMS = 15


def _vec(name, v, n=3) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be a finite {n}-vector, got {v!r}")
    return a


class Plane:
    """Half-space ``n . x >= offset`` is free; the body must stay on the side ``n`` points to.

    Args:
        normal: (3,) outward normal of the obstacle surface (normalised here).
        point: (3,) a point of the plane [m].
    """

    def __init__(self, normal=(0.0, 0.0, 1.0), point=(0.0, 0.0, 0.0)) -> None:
        n = _vec("plane normal", normal)
        if not np.linalg.norm(n) > 0:
            raise InputError("plane normal must be non-zero")
        self.normal = n / np.linalg.norm(n)
        self.offset = float(self.normal @ _vec("plane point", point))

    def signed_distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gap (n,) [m] (negative inside) and outward normal (n, 3) at points x (n, 3) [m]."""
        return x @ self.normal - self.offset, np.broadcast_to(self.normal, x.shape)

    def encode(self) -> tuple[int, np.ndarray]:
        """``(kind, params)`` of the compiled kernels: normal (3), offset [m]."""
        p = np.zeros(PARAMS)
        p[0:3], p[3] = self.normal, self.offset
        return PLANE, p


class Ground(Plane):
    """Horizontal ground plane z = height [m] (normal +z)."""

    def __init__(self, height: float = 0.0) -> None:
        super().__init__((0.0, 0.0, 1.0), (0.0, 0.0, float(height)))


class Sphere:
    """Solid sphere obstacle: center (3,) [m], radius [m] > 0."""

    def __init__(self, center, radius: float) -> None:
        self.center = _vec("sphere center", center)
        self.radius = float(radius)
        if not self.radius > 0:
            raise InputError(f"sphere radius must be > 0 [m], got {radius!r}")

    def signed_distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = x - self.center
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        n = d / np.where(r > 0, r, 1.0)[:, None]
        n[r == 0] = (0.0, 0.0, 1.0)
        return r - self.radius, n

    def encode(self) -> tuple[int, np.ndarray]:
        """``(kind, params)`` of the compiled kernels: center (3) [m], radius [m]."""
        p = np.zeros(PARAMS)
        p[0:3], p[3] = self.center, self.radius
        return SPHERE, p


class Box:
    """Solid box obstacle: center (3,) [m], half extents (3,) [m] > 0, rotation (3, 3) box -> world."""

    def __init__(self, center, half_extents, rotation=None) -> None:
        self.center = _vec("box center", center)
        self.half = _vec("box half extents", half_extents)
        if np.any(self.half <= 0):
            raise InputError(f"box half extents must be > 0 [m], got {self.half.tolist()}")
        self.rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64).reshape(3, 3)

    def signed_distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = (x - self.center) @ self.rotation  # box axes
        q = np.abs(p) - self.half
        sign = np.where(p < 0, -1.0, 1.0)
        outside = np.maximum(q, 0.0)
        dout = np.sqrt(np.einsum("ij,ij->i", outside, outside))
        inside = dout == 0
        gap = np.where(inside, q.max(axis=1), dout)
        n_local = np.where(inside[:, None], 0.0, sign * outside / np.where(dout > 0, dout, 1.0)[:, None])
        k = np.argmax(q, axis=1)
        rows = np.flatnonzero(inside)
        n_local[rows, k[rows]] = sign[rows, k[rows]]
        return gap, n_local @ self.rotation.T

    def encode(self) -> tuple[int, np.ndarray]:
        """``(kind, params)`` of the compiled kernels: center (3), half extents (3) [m], rotation (9, row-major)."""
        p = np.zeros(PARAMS)
        p[0:3], p[3:6], p[6:15] = self.center, self.half, self.rotation.reshape(-1)
        return BOX, p


class Obstacles:
    """Opt-in contact effect: static obstacles touched by the surface vertices.

    Args:
        obstacles: list of ``Plane`` / ``Ground`` / ``Sphere`` / ``Box``.
        restitution: coefficient of restitution e in [0, 1].
        friction: Coulomb coefficient >= 0.
        iterations: sequential-impulse sweeps over the simultaneous contacts.
        margin: contacts are gathered within this distance [m] (plus what the body travels in dt).
        bounce_threshold: impacts slower than this [m/s] do not bounce (resting contact).
        modal: include the modes in the contact response (impacts excite vibration).

    The effect is fixed once made: its obstacles and coefficients are read into the contact kernels' plan on
    first use (make a new ``Obstacles`` to change them).
    """

    def __init__(self, obstacles, *, restitution: float = 0.3, friction: float = 0.5, iterations: int = 10,
                 margin: float = 1e-3, bounce_threshold: float = 0.05, modal: bool = True) -> None:
        self.obstacles = list(obstacles)
        if not self.obstacles or not all(hasattr(o, "encode") for o in self.obstacles):
            raise InputError("Obstacles needs a non-empty list of Plane/Ground/Sphere/Box")
        if not 0.0 <= restitution <= 1.0:
            raise InputError(f"restitution must be in [0, 1], got {restitution!r}")
        if not friction >= 0.0:
            raise InputError(f"friction must be >= 0, got {friction!r}")
        if int(iterations) < 1:
            raise InputError(f"iterations must be >= 1, got {iterations!r}")
        if not (np.isfinite(margin) and margin > 0.0):
            raise InputError(f"margin must be finite and > 0 [m], got {margin!r}")
        if not (np.isfinite(bounce_threshold) and bounce_threshold >= 0.0):
            raise InputError(f"bounce_threshold must be finite and >= 0 [m/s], got {bounce_threshold!r}")
        if not np.isfinite(friction):
            raise InputError(f"friction must be finite, got {friction!r}")
        self.restitution, self.friction = float(restitution), float(friction)
        self.iterations, self.margin = int(iterations), float(margin)
        self.bounce_threshold, self.modal = float(bounce_threshold), bool(modal)
        codes = [o.encode() for o in self.obstacles]
        self.kinds = np.array([c[0] for c in codes], dtype=np.int64)  # what the compiled kernels read
        self.params = np.array([c[1] for c in codes], dtype=np.float64).reshape(-1, PARAMS)
