"""Linear modal references for comparisons with the tetrahedral solver.

``runtime_response`` drives the real-time modal runtime (``modalfem.runtime.ModalSolver`` on a
``ModalModel`` built with ``ModalModel.from_modes``) with one point impulse and records the surface
displacements ``Phi q``: the reference the tet module is checked against for small deformations (same
mesh, material and lumped mass; a clamped bar, so neither side has rigid motion to remove).

``modal_response`` is a plain linear superposition integrated exactly, including rigid modes: each
deformation mode is an undamped oscillator ``q(t) = q0 cos(w t) + (qd0 / w) sin(w t)`` and each rigid
mode moves linearly, ``q(t) = q0 + qd0 t``. The latter is exactly what a purely linear model does under
a large rotation: it follows the tangent of the rotation, ``u = t (w x X)``, and the volume grows as
``1 + (w t)^2`` (``linearised_rotation``), while the corotational tet body keeps its volume. (The
runtime integrates rigid motion as a true rotation, so it cannot show this.)
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import InputError
from modalfem.mesh.core import signed_volumes

__all__ = ["linearised_rotation", "modal_response", "rms_difference", "runtime_response", "volume_ratio"]


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


def runtime_response(model, point, impulse, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface displacements of the real-time modal runtime after one point impulse at t = 0.

    Builds ``modalfem.runtime.ModalBody(model, dtype=np.float64)`` (the model's exact shapes: this is
    a comparison, not a render loop) and a bare ``ModalSolver`` (no effects), applies
    ``Control().add_impulse(point, impulse)`` in the first step and steps exactly to each time. The
    returned displacements are the modal part ``Phi q`` in body axes: the runtime's rigid-body state
    (which the impulse also moves) is left out, as it must be for a clamped model.

    Args:
        model: a ``modalfem.model.ModalModel`` (e.g. ``ModalModel.from_modes`` of a clamped bar).
        point: surface vertex index or ``SurfacePoint`` of the runtime body.
        impulse: J (3,) [N s], body axes (the body starts unrotated).
        times: increasing output times (T,) [s], > 0.

    Returns:
        ``(u, qdot0)``: displacements (T, nv, 3) [m] of the model's surface vertices, and the modal
        velocities (r,) [sqrt(kg) m/s] right after the impulse (``Phi^T J`` at the point).

    Raises:
        InputError: times not increasing and positive.
    """
    from modalfem import runtime as rt

    t = np.asarray(times, dtype=float)
    if t.ndim != 1 or not len(t) or t[0] <= 0 or np.any(np.diff(t) <= 0):
        raise InputError("runtime_response needs increasing times > 0 [s]")
    body = rt.ModalBody(model, dtype=np.float64)
    solver = rt.ModalSolver(body)
    state = solver.state()
    J = np.asarray(impulse, dtype=float)
    qdot0 = body.point_shapes(point).T @ J  # what the impulse gives the modes (the body starts unrotated)
    control = rt.Control().add_impulse(point, J)
    u, t_prev = np.empty((len(t), body.vertex_count, 3)), 0.0
    for k, tk in enumerate(t):
        solver.step(state, state, control if k == 0 else None, None, tk - t_prev)
        t_prev = tk
        u[k] = body.local_positions(state.q) - body.rest
    return u, qdot0


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
