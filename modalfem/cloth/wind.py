"""Wind on cloth: a normal traction from the relative air velocity, per triangle.

For a triangle with current unit normal ``n``, area ``A`` and velocity ``v`` (the mean of its three
vertex velocities), the wind force is ``D A ((w - v) . n) n``, split equally among its vertices, with
``w`` the wind velocity at the triangle's centroid and ``D`` the drag coefficient [kg/(m^2 s)] (a
traction [N/m^2] per relative normal speed [m/s]). The force is zero when the cloth moves with the
wind or the wind blows in the cloth's plane. It is linear in ``v``: its velocity Jacobian (a positive
semi-definite damping matrix) is returned for the implicit solve.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = ["PressureWind", "Wind"]


@dataclass(frozen=True, eq=False)
class Wind:
    """A wind field acting on the cloth's triangles.

    Args:
        velocity: constant wind velocity (3,) [m/s], or a callable ``(x, t) -> (k, 3)`` [m/s] taking
            points ``x`` (k, 3) [m] and time ``t`` [s].
        drag: coefficient ``D`` > 0 [kg/(m^2 s)].

    Raises:
        InputError: ``drag`` not finite or <= 0, or a constant velocity that is not 3 finite numbers.
    """

    velocity: np.ndarray | Callable
    drag: float

    def __post_init__(self) -> None:
        d = float(self.drag)
        if not np.isfinite(d) or d <= 0:
            raise InputError(f"wind drag D must be finite and > 0 kg/(m^2 s), got {self.drag!r}")
        if not callable(self.velocity):
            w = np.asarray(self.velocity, dtype=float)
            if w.shape != (3,) or not np.all(np.isfinite(w)):
                raise InputError(
                    f"wind velocity must be 3 finite numbers [m/s] or a callable (x, t), got {self.velocity!r}"
                )
            object.__setattr__(self, "velocity", w)
        object.__setattr__(self, "drag", d)

    def _field(self, c: np.ndarray, t: float) -> np.ndarray:
        if callable(self.velocity):
            w = np.asarray(self.velocity(c, t), dtype=float)
            if w.shape != c.shape or not np.all(np.isfinite(w)):
                raise InputError(f"wind velocity field must return finite values of shape {c.shape}, got {w.shape}")
            return w
        return np.broadcast_to(self.velocity, c.shape)

    def forces(self, x: np.ndarray, v: np.ndarray, triangles: np.ndarray, t: float = 0.0):
        """Vertex forces [N] and the per-triangle velocity Jacobian blocks.

        Args:
            x: positions (n, 3) [m].
            v: velocities (n, 3) [m/s].
            triangles: (m, 3) vertex indices.
            t: time [s] (for a field).

        Returns:
            ``(f, C)``: forces (n, 3) [N] and blocks (m, 9, 9) [kg/s] with ``df/dv = -C`` (assembled
            over ``triangles``).
        """
        q = x[triangles]
        nrm = np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0])
        a2 = np.linalg.norm(nrm, axis=1)
        n = nrm / np.maximum(a2, 1e-300)[:, None]
        area = 0.5 * a2
        w = self._field(q.mean(axis=1), t)
        vt = v[triangles].mean(axis=1)
        s = np.einsum("mi,mi->m", w - vt, n)  # relative normal air speed [m/s]
        traction, stiffness = self._law(s)
        f_tri = (traction * area * s / 3.0)[:, None] * n
        f = np.zeros_like(x, dtype=float)
        np.add.at(f, triangles.reshape(-1), np.repeat(f_tri, 3, axis=0))
        nn = (stiffness * area / 9.0)[:, None, None] * n[:, :, None] * n[:, None, :]
        C = np.tile(nn, (1, 3, 3))
        return f, C

    def _law(self, s: np.ndarray) -> tuple:
        """Per triangle, the traction per relative normal speed [kg/(m^2 s)] (force ``traction A s n``) and its
        derivative ``d(traction s) / ds``: both ``D`` for this linear law."""
        return self.drag, self.drag


class PressureWind(Wind):
    """The quadratic law of ``modalfem.effects.Wind`` on a cloth: ``0.5 rho C A |s| s n`` per triangle (both
    sides of the sheet), its velocity Jacobian ``rho C A |s| n n^T / 9`` per vertex pair implicit in the solve.

    Args:
        air: the ``modalfem.effects.Wind`` (velocity or field, density rho, drag coefficient C).
    """

    def __init__(self, air) -> None:
        object.__setattr__(self, "velocity", np.zeros(3))
        object.__setattr__(self, "drag", 1.0)
        object.__setattr__(self, "air", air)

    def _field(self, c: np.ndarray, t: float) -> np.ndarray:
        return self.air.at(c, t)

    def _law(self, s: np.ndarray) -> tuple:
        k = self.air.density * self.air.drag * np.abs(s)
        return 0.5 * k, k
