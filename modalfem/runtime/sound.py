"""Modal sound: impacts ring the vibration modes; the audio is a sum of damped sinusoids.

Physics (numpy and the standard library only; the runtime must not import scipy):

* An impact at time ``t0`` changes the modal velocities by ``dqdot_i = phi_i(p) . J`` (mass-normalised
  modes, impulse J [N s] in body axes). With the Rayleigh modal damping ``mu_i = alpha + beta
  omega_i^2`` [1/s] of the model, mode i then rings as the underdamped impulse response
  ``y_i(t) = dqdot_i / omega_d_i * exp(-mu_i / 2 * (t - t0)) * sin(omega_d_i * (t - t0))`` for
  ``t >= t0``, with ``omega_d_i = sqrt(omega_i^2 - mu_i^2 / 4)``. Modes with ``mu_i / 2 >= omega_i``
  (overdamped, they do not ring) are dropped.
* Radiation (a deliberately simple, documented choice): the pressure at a listener at distance r
  in the unit direction d is that of a compact monopole fed by the volume acceleration of the
  part of the surface that faces the listener,
  ``p(t) = rho_air / (4 pi r) * sum_i w_i * y_i''(t)`` [Pa], with the mode weight
  ``w_i = sum_v max(n_v . d, 0) * (a_v . phi_i(v))`` [m^3 / sqrt(kg)]. Here ``a_v`` is the vertex
  vector area (one third of the area-weighted normals of the triangles around vertex v, so
  ``|a_v|`` is the vertex area [m^2]) and ``n_v = a_v / |a_v|``: the normal velocity of the facing
  surface, cosine-weighted towards the listener so that the weight changes smoothly as the body
  turns (a sphere of radius R moving towards the listener gives ``2 pi R^2 / 3``, a uniform
  expansion ``pi R^2``). It ignores interference between distant surface parts, baffling and the
  listener's distance from each vertex; it gives every mode a plausible, direction-dependent
  loudness and does not radiate modes whose net facing volume change is zero.
* Synthesis, band limit (20 kHz) and contact pulses: ``modalfem.runtime.synthesis``; WAV output:
  ``modalfem.runtime.wav``.
"""

from __future__ import annotations

import math

import numpy as np

from modalfem.errors import InputError, SimulationError
from modalfem.runtime.synthesis import (
    F_MAX_HZ,
    SAMPLE_RATE,
    _positive,
    band_limit,
    synthesize,
)

__all__ = ["AIR_DENSITY", "ModalSound", "listener_weights", "vertex_vector_areas"]

#: density of air [kg/m^3] for the monopole pressure
AIR_DENSITY = 1.2


def vertex_vector_areas(vertices, triangles) -> np.ndarray:
    """Vertex vector areas (nv, 3) [m^2]: a third of the area-weighted outward normals around each vertex.

    Args:
        vertices: surface vertices (nv, 3) [m].
        triangles: outward triangles (nt, 3), indices into ``vertices``.

    Returns:
        ``a`` (nv, 3) with ``a_v = sum_{t ni v} area_t n_t / 3``; ``|a_v|`` is the vertex area for a
        flat neighbourhood and the sum over all vertices of a closed surface is zero.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    p = v[t]
    n2 = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # 2 * area * normal (nt, 3)
    a = np.zeros_like(v)
    for c in range(3):
        np.add.at(a, t[:, c], n2 / 6.0)
    return a


def listener_weights(model, direction) -> np.ndarray:
    """Per-mode radiation weights ``w_i = sum_v max(n_v . d, 0) (a_v . phi_i(v))`` [m^3 / sqrt(kg)].

    Args:
        model: ``ModalModel`` (vertices, triangles, shapes in body axes).
        direction: listener direction d (3,) in body axes (normalised here).

    Returns:
        ``w`` (r,): the facing-surface volume change per unit modal coordinate of every mode.

    Raises:
        InputError: ``direction`` is not a finite non-zero 3-vector.
    """
    d = _unit(direction, "listener direction")
    return _facing_area(vertex_vector_areas(model.vertices, model.triangles), d) @ np.asarray(model.shapes)


def _facing_area(a: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``max(n_v . d, 0) a_v`` flattened to (3 nv,) in the DOF order of the mode shapes."""
    area = np.linalg.norm(a, axis=1)
    facing = np.maximum(a @ d, 0.0) / np.where(area > 0, area, 1.0)
    return (facing[:, None] * a).reshape(-1)


class ModalSound:
    """Collects the impacts on one modal body and renders the sound a listener hears.

    Opt-in: a simulation that wants sound creates one and reports the impulses it applies:
    ``add_contacts`` with a step's ``Contacts`` (the ground hits), ``add_impulses`` at surface
    vertices or points (a strike), or ``add_impact`` with a modal velocity change. Resting contact
    pushes with about ``m g dt`` every step; reporting those too adds a buzz at the step rate, so
    report impacts only (``min_impulse`` of a few ``m g dt``). Forces held over a step (gravity,
    pseudo-forces) deform the body slowly and are not heard. ``render`` returns the pressure.

    Args:
        model: the ``ModalModel`` (vertices, triangles, shapes, omega, damping).
        listener: direction from the body to the listener (3,) in world axes (normalised).
        distance: listener distance r [m], > 0 (pressure ~ 1 / r).
        damping: Rayleigh (alpha [1/s], beta [s]) overriding ``model.damping`` (as ``ModalBody``).
        sample_rate: [1/s], default 44100.
        f_max_hz: band limit [Hz], default 20000; higher modes are dropped (see ``band``).

    Attributes:
        band: ``SoundBand``: the kept modes and the dropped ones with their reasons.
        mu: modal damping of all model modes (r,) [1/s].
        listener: unit direction (3,), world; distance [m]; sample_rate [1/s].

    Raises:
        InputError: bad listener direction, distance, damping, sample rate or band limit.
    """

    def __init__(self, model, *, listener=(1.0, 0.0, 0.0), distance: float = 1.0, damping=None,
                 sample_rate: int = SAMPLE_RATE, f_max_hz: float = F_MAX_HZ) -> None:
        self.model = model
        self.listener = _unit(listener, "listener direction")
        self.distance = _positive("distance", distance, "m")
        self.mu = _modal_damping(model, damping)
        self.band = band_limit(model.omega, self.mu, sample_rate=sample_rate, f_max_hz=f_max_hz)
        self.sample_rate = self.band.sample_rate
        self._area = vertex_vector_areas(model.vertices, model.triangles)
        self._shapes3 = np.asarray(model.shapes, dtype=np.float64).reshape(len(self._area), 3, -1)
        self._shapes_kept = np.asarray(model.shapes)[:, self.band.kept]
        self._times: list[float] = []
        self._amps: list[np.ndarray] = []
        self._contact: list[float] = []

    @property
    def impact_count(self) -> int:
        """Number of impacts recorded so far."""
        return len(self._times)

    @property
    def kept_hz(self) -> np.ndarray:
        """Frequencies (k,) [Hz] of the synthesised modes."""
        return np.asarray(self.model.omega)[self.band.kept] / (2 * math.pi)

    def weights(self, rotation=None) -> np.ndarray:
        """Radiation weights (k,) [m^3 / sqrt(kg)] of the kept modes for a body rotated by ``rotation``.

        Args:
            rotation: body-to-world rotation matrix (3, 3) or None (identity); the world listener
                direction is taken to body axes as ``R^T d``.
        """
        d = self.listener if rotation is None else _rotation(rotation).T @ self.listener
        return _facing_area(self._area, d) @ self._shapes_kept

    def add_impact(self, t: float, dqdot, *, rotation=None, contact_time: float = 0.0) -> None:
        """Record an impact.

        Args:
            t: simulation time of the impact [s], >= 0.
            dqdot: modal velocity change of all model modes (r,) [sqrt(kg) m/s], ``Phi(p)^T J`` with
                the impulse J in body axes.
            rotation: body-to-world rotation (3, 3) at the impact (orients the listener), or None.
            contact_time: duration of the contact [s], >= 0 (0: an ideal impulse). The sound then
                hears the velocity change spread over a half-sine pulse (see ``pulse_factor``):
                hard, short contacts sound bright, soft ones dull. Only the sound is filtered;
                the simulation applied the impulse at once.

        Raises:
            SimulationError: non-finite or negative ``t``, or non-finite ``dqdot``.
            InputError: ``dqdot`` has the wrong shape, or a bad ``contact_time``.
        """
        t = float(t)
        if not math.isfinite(t) or t < 0:
            raise SimulationError(f"impact time must be finite and >= 0 s, got {t!r}")
        dq = np.asarray(dqdot, dtype=np.float64).reshape(-1)
        if dq.shape != (len(self.model.omega),):
            raise InputError(f"dqdot must have one entry per model mode ({len(self.model.omega)}), got {dq.shape}")
        if not np.all(np.isfinite(dq)):
            raise SimulationError("impact modal velocity change dqdot holds NaN/inf")
        tau = float(contact_time)
        if not (math.isfinite(tau) and 0 <= tau < 1):
            raise InputError(f"contact_time must be >= 0 s (and < 1 s), got {contact_time!r}")
        self._times.append(t)
        self._amps.append(self.weights(rotation) * dq[self.band.kept])
        self._contact.append(tau)

    def _forget(self, count: int) -> None:
        """Drop the impacts recorded after the first ``count`` (a world step taken again, or one that failed)."""
        del self._times[count:], self._amps[count:], self._contact[count:]

    def add_impulses(self, t: float, points, impulses, *, rotation=None, contact_time: float = 0.0) -> np.ndarray:
        """Record impulses applied at the same time at surface points; returns the modal velocity change.

        Args:
            t: time [s], >= 0.
            points: one point or a sequence of k points: surface vertex indices, or surface points
                with ``triangle`` and ``barycentric`` attributes (``runtime.SurfacePoint``).
            impulses: J (3,) or (k, 3) [N s] in world axes.
            rotation: body-to-world rotation (3, 3) or None; J is taken to body axes as ``R^T J``.
            contact_time: contact duration [s] heard by the sound (see ``add_impact``).

        Returns:
            dqdot (r,) [sqrt(kg) m/s] of all model modes, ``sum_k Phi(p_k)^T R^T J_k``.

        Raises:
            SimulationError: a point off the surface, non-finite impulses or time, or a count mismatch.
        """
        single = isinstance(points, (int, np.integer)) or hasattr(points, "triangle")
        pts = [points] if single else list(points)
        j = np.asarray(impulses, dtype=np.float64).reshape(-1, 3) if np.size(impulses) % 3 == 0 else None
        if j is None or len(j) != len(pts) or not np.all(np.isfinite(j)):
            raise SimulationError(f"impulses must be {len(pts)} finite 3-vectors [N s], got {impulses!r}")
        if rotation is not None:
            j = j @ _rotation(rotation)  # rows R^T J_k
        phi = np.stack([self._point_shapes(p) for p in pts]) if pts else np.zeros((0, 3, len(self.model.omega)))
        dq = np.einsum("kcr,kc->r", phi, j)
        self.add_impact(t, dq, rotation=rotation, contact_time=contact_time)
        return dq

    def add_contacts(self, t: float, contacts, *, rotation=None, min_impulse: float = 0.0,
                     contact_time: float = 0.0) -> bool:
        """Record the normal contact impulses of one solver step as one impact, if they are one.

        Args:
            t: time of the step's start [s].
            contacts: the step's ``runtime.Contacts`` after ``solver.step`` (uses ``vertex``,
                ``normal`` (k, 3) world and ``impulses`` (k,) [N s]); None or empty: nothing.
            rotation: body-to-world rotation (3, 3) at the start of the step, or None.
            min_impulse: record only if the summed normal impulse exceeds this [N s], e.g. a few
                ``m g dt`` so that resting contact is not heard as a buzz.
            contact_time: contact duration heard by the sound [s] (see ``add_impact``).

        Returns:
            True when an impact was recorded.

        Raises:
            SimulationError: non-finite impulses or time; points off the surface.
        """
        if contacts is None or getattr(contacts, "impulses", None) is None or len(contacts.impulses) == 0:
            return False
        jn = np.asarray(contacts.impulses, dtype=np.float64)
        if not float(jn.sum()) > float(min_impulse):
            return False
        n = np.asarray(contacts.normal, dtype=np.float64).reshape(-1, 3)
        self.add_impulses(t, [int(v) for v in contacts.vertex], jn[:, None] * n, rotation=rotation,
                          contact_time=contact_time)
        return True

    def _point_shapes(self, point) -> np.ndarray:
        nv = len(self._area)
        if isinstance(point, (int, np.integer)) and not isinstance(point, bool):
            if not 0 <= int(point) < nv:
                raise SimulationError(f"point off the surface: vertex {point!r} not in [0, {nv})")
            return self._shapes3[int(point)]
        tris = np.asarray(self.model.triangles)
        try:
            t, b = int(point.triangle), np.asarray(point.barycentric, dtype=np.float64).reshape(3)
        except (AttributeError, TypeError, ValueError):
            raise SimulationError(f"a surface point must be a vertex index or a SurfacePoint, got {point!r}") from None
        if not 0 <= t < len(tris) or not np.all(np.isfinite(b)) or np.any(b < -1e-9) or abs(b.sum() - 1) > 1e-9:
            raise SimulationError(f"point off the surface: triangle {t}, barycentric {b.tolist()}")
        return np.einsum("k,kcr->cr", b, self._shapes3[tris[t]])

    def render(self, duration: float, *, method: str = "recursive") -> np.ndarray:
        """Sound pressure at the listener (n,) [Pa], ``n = round(duration * sample_rate)`` samples.

        Args:
            duration: [s], > 0, counted from t = 0.
            method: ``"recursive"`` or ``"direct"`` (see ``synthesize``).
        """
        kept = self.band.kept
        amps = np.array(self._amps).reshape(len(self._times), len(kept))
        volume_accel = synthesize(np.asarray(self.model.omega)[kept], self.mu[kept], self._times, amps, duration,
                                  contact_times=self._contact, sample_rate=self.sample_rate, derivative=2,
                                  method=method)
        return AIR_DENSITY / (4 * math.pi * self.distance) * volume_accel


# ------------------------------------------------------------------------------ validation
def _modal_damping(model, damping=None) -> np.ndarray:
    try:
        alpha, beta = (float(x) for x in (model.damping if damping is None else damping))
    except (TypeError, ValueError):
        raise InputError(f"damping must be (alpha [1/s], beta [s]), got {damping!r}") from None
    if not (math.isfinite(alpha) and math.isfinite(beta)) or alpha < 0 or beta < 0:
        raise InputError(f"Rayleigh damping (alpha, beta) must be finite and >= 0, got ({alpha!r}, {beta!r})")
    return alpha + beta * np.asarray(model.omega, dtype=np.float64) ** 2


def _unit(v, name: str) -> np.ndarray:
    try:
        d = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a 3-vector, got {v!r}") from None
    n = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
    if d.shape != (3,) or not math.isfinite(n) or n == 0:
        raise InputError(f"{name} must be a finite non-zero 3-vector, got {v!r}")
    return d / n


def _rotation(R) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)) or np.abs(R.T @ R - np.eye(3)).max() > 1e-6:
        raise SimulationError("rotation must be a finite orthonormal (3, 3) matrix")
    return R
