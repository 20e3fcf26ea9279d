"""``State`` (what changes every step) and ``Control`` (this step's impulses and forces)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from modalfem.errors import SimulationError
from modalfem.runtime.rotation import quat_normalize, quat_to_matrix

__all__ = ["Control", "State"]


@dataclass
class State:
    """Changing state of one modal body.

    Attributes:
        q: modal displacements (r,) [sqrt(kg) m] (surface displacement in body axes = shapes @ q).
        qdot: modal velocities (r,) [sqrt(kg) m/s].
        position: centre of mass c (3,) [m], world.
        orientation: unit quaternion (w, x, y, z) (4,), body (mesh) axes -> world.
        velocity: centre-of-mass velocity v (3,) [m/s], world.
        angular_momentum: L about the centre of mass (3,) [kg m^2/s], world (the angular velocity
            is ``ModalBody.angular_velocity(state)``).
        time: simulated time [s].
    """

    q: np.ndarray
    qdot: np.ndarray
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_momentum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    time: float = 0.0

    def __post_init__(self) -> None:
        for name, n in (("position", 3), ("orientation", 4), ("velocity", 3), ("angular_momentum", 3)):
            a = np.array(getattr(self, name), dtype=np.float64).reshape(-1)
            if a.shape != (n,):
                raise SimulationError(f"state {name} must have {n} components, got {a.shape}")
            setattr(self, name, a)
        self.q = np.array(self.q, dtype=np.float64).reshape(-1)
        self.qdot = np.array(self.qdot, dtype=np.float64).reshape(-1)
        if self.q.shape != self.qdot.shape:
            raise SimulationError(f"state q {self.q.shape} and qdot {self.qdot.shape} differ in size")
        n = float(np.sqrt(self.orientation @ self.orientation))
        if not np.isfinite(n) or n == 0.0:
            raise SimulationError("state orientation must be a non-zero quaternion")
        self.orientation = quat_normalize(self.orientation)
        self.check_finite()

    @classmethod
    def rest(cls, body, *, position=None, orientation=None, velocity=None, angular_velocity=None) -> State:
        """A body at rest (q = qdot = 0), optionally placed and moving.

        Args:
            body: the ``ModalBody``.
            position: centre of mass (3,) [m] (default: where the mesh puts it, ``model.center_of_mass``).
            orientation: quaternion (4,) body -> world (default identity).
            velocity: (3,) [m/s].
            angular_velocity: world (3,) [rad/s]; stored as L = R I R^T omega.
        """
        r = body.mode_count
        st = cls(np.zeros(r), np.zeros(r),
                 position=body.center_of_mass if position is None else position,
                 orientation=[1.0, 0, 0, 0] if orientation is None else orientation,
                 velocity=np.zeros(3) if velocity is None else velocity)
        if angular_velocity is not None:
            R = st.rotation()
            st.angular_momentum = R @ (body.inertia @ (R.T @ np.asarray(angular_velocity, dtype=np.float64)))
        return st

    def rotation(self) -> np.ndarray:
        """Orientation as a rotation matrix R (3, 3), body -> world."""
        return quat_to_matrix(self.orientation)

    def copy(self) -> State:
        """A deep copy."""
        return State(self.q.copy(), self.qdot.copy(), self.position.copy(), self.orientation.copy(),
                     self.velocity.copy(), self.angular_momentum.copy(), self.time)

    def assign(self, other: State) -> None:
        """Copy ``other``'s values into this state's arrays (in place)."""
        self.q[...] = other.q
        self.qdot[...] = other.qdot
        self.position[...] = other.position
        self.orientation[...] = other.orientation
        self.velocity[...] = other.velocity
        self.angular_momentum[...] = other.angular_momentum
        self.time = other.time

    def check_finite(self) -> None:
        """Raise ``SimulationError`` naming the first non-finite field."""
        for name in ("q", "qdot", "position", "orientation", "velocity", "angular_momentum"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise SimulationError(f"state {name} is not finite")


_FIELDS = ("q", "qdot", "position", "orientation", "velocity", "angular_momentum")


def snapshot(s: State) -> tuple:
    """The state's values, bit for bit (no validation, no renormalised quaternion), for ``restore``."""
    return (*(getattr(s, name).copy() for name in _FIELDS), s.time)


def restore(s: State, saved: tuple) -> None:
    """Put a ``snapshot`` back into ``s``'s arrays (in place), bit for bit."""
    for name, value in zip(_FIELDS, saved):
        getattr(s, name)[...] = value
    s.time = saved[-1]


def _vec3(name: str, value) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(3)
    except (TypeError, ValueError):
        raise SimulationError(f"{name} must be a 3-vector, got {value!r}") from None
    if not np.all(np.isfinite(a)):
        raise SimulationError(f"{name} is not finite: {a.tolist()}")
    return a


@dataclass
class Control:
    """Inputs of one step: point impulses (applied at the start) and forces (held over the step).

    Attributes:
        impulses: list of (point, J): point a ``SurfacePoint`` or a vertex index, J (3,) [N s] world.
        forces: list of (point, F): F (3,) [N] world, constant over the step.
        body_force: force at the centre of mass (3,) [N] world (no torque, no deformation), e.g. thrust.
    """

    impulses: list = field(default_factory=list)
    forces: list = field(default_factory=list)
    body_force: np.ndarray | None = None

    def add_impulse(self, point, J) -> Control:
        """Append an impulse J (3,) [N s] at a surface point; NaN/inf -> ``SimulationError``."""
        self.impulses.append((point, _vec3("impulse", J)))
        return self

    def add_force(self, point, F) -> Control:
        """Append a force F (3,) [N] at a surface point, held over the step; NaN/inf -> ``SimulationError``."""
        self.forces.append((point, _vec3("force", F)))
        return self

    def clear(self) -> None:
        """Remove all impulses and forces."""
        self.impulses.clear()
        self.forces.clear()
        self.body_force = None

    @property
    def empty(self) -> bool:
        return not self.impulses and not self.forces and self.body_force is None
