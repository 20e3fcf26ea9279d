"""Linear modal superposition, integrated exactly, for comparisons with the tetrahedral solver.

``modal_response`` is the reference the tet module is checked against for small deformations (the same
mesh, material and lumped mass): each deformation mode is an undamped oscillator
``q(t) = q0 cos(w t) + (qd0 / w) sin(w t)`` and each rigid mode moves linearly, ``q(t) = q0 + qd0 t``.
The latter is exactly what a purely linear model does under a large rotation: it follows the tangent
of the rotation, ``u = t (w x X)``, and the volume grows as ``1 + (w t)^2`` (``linearised_rotation``),
while the corotational tet body keeps its volume.
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import InputError
from modalfem.mesh.core import signed_volumes

__all__ = ["linearised_rotation", "modal_response", "rms_difference", "volume_ratio"]


def modal_response(shapes: np.ndarray, omega: np.ndarray, masses: np.ndarray, u0: np.ndarray, v0: np.ndarray,
                   times: np.ndarray, *, rigid_shapes: np.ndarray | None = None) -> np.ndarray:
    """Displacements of the linear modal model from initial displacement and velocity, exact in time.

    Args:
        shapes: mass-normalised deformation modes (3n, k) (``Phi^T M Phi = I``).
        omega: their angular frequencies (k,) [rad/s], > 0.
        masses: lumped vertex masses (n,) [kg] (the M of the normalisation).
        u0: initial displacements (n, 3) [m].
        v0: initial velocities (n, 3) [m/s].
        times: output times (T,) [s].
        rigid_shapes: optional mass-normalised rigid modes (3n, r), integrated as free motion.

    Returns:
        Displacements (T, n, 3) [m] of the modes' span (components outside it are dropped).
    """
    shapes = np.asarray(shapes, dtype=float)
    omega = np.asarray(omega, dtype=float)
    if shapes.ndim != 2 or shapes.shape[1] != len(omega) or np.any(omega <= 0):
        raise InputError("modal_response needs shapes (3n, k) and positive omega (k,) [rad/s]")
    m = np.repeat(np.asarray(masses, dtype=float), 3)
    t = np.asarray(times, dtype=float)[:, None]
    u0, v0 = np.ravel(u0), np.ravel(v0)
    q0, qd0 = shapes.T @ (m * u0), shapes.T @ (m * v0)
    q = q0 * np.cos(omega * t) + qd0 / omega * np.sin(omega * t)
    u = q @ shapes.T
    if rigid_shapes is not None and rigid_shapes.shape[1]:
        r0, rd0 = rigid_shapes.T @ (m * u0), rigid_shapes.T @ (m * v0)
        u = u + (r0 + rd0 * t) @ rigid_shapes.T
    return u.reshape(len(t), -1, 3)


def linearised_rotation(points: np.ndarray, angular_velocity, t: float, *, centre=None) -> np.ndarray:
    """Positions of a linear model carried along a rigid rotation: ``X + t w x (X - c)`` (n, 3) [m].

    Args:
        points: rest positions (n, 3) [m].
        angular_velocity: w (3,) [rad/s].
        t: time [s] (the exact body would have turned by ``|w| t`` [rad]).
        centre: rotation centre (3,) [m], default the centroid of ``points``.
    """
    c = points.mean(axis=0) if centre is None else np.asarray(centre, dtype=float)
    return points + t * np.cross(np.asarray(angular_velocity, dtype=float), points - c)


def volume_ratio(x: np.ndarray, cells: np.ndarray, rest_volume: float) -> float:
    """Total signed volume of positions ``x`` (n, 3) [m] over ``rest_volume`` [m^3]."""
    return float(signed_volumes(x, cells).sum() / rest_volume)


def rms_difference(u: np.ndarray, reference: np.ndarray) -> float:
    """RMS of ``u - reference`` over all times, vertices and components, relative to the RMS of ``reference``."""
    return float(np.sqrt(np.mean((u - reference) ** 2) / np.mean(reference**2)))
