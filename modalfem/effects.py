"""The one vocabulary of effects of a ``modalfem.world.World`` (SI units throughout).

Every effect is one public class here; every body kind (modal, tet, cloth) implements the effects it
supports and refuses the rest with one clear line (``InputError``), e.g. self-collision on a modal body.
An effect acts on every body that can take it (``bodies=None``) or on the bodies it names.

==================  =====  ===  =====  ===================================================================
effect              modal  tet  cloth  what it does
==================  =====  ===  =====  ===================================================================
``Gravity``         yes    yes  yes    uniform acceleration ``g`` [m/s^2]
``Wind``            yes    yes  yes    air of velocity ``w`` [m/s] (constant or a field ``(x, t)``) pushing
                                       on the surface: pressure ``0.5 rho C ((w - u) . n)^2`` on the faces
                                       it meets (modal, tet), both sides of a cloth
``Damping``         yes    yes  yes    Rayleigh damping ``alpha M + beta K`` (alpha [1/s], beta [s])
``Contact``         yes    yes  yes    contact with the obstacles and between bodies: restitution,
                                       Coulomb friction
``SelfCollision``   no     yes  yes    the body against itself (cloth pipeline; a tet body's surface)
``PseudoForces``    yes    no   no     Coriolis / centripetal / Euler loads on the modes of a rotating
                                       modal body (needs the rotation coupling stored in the model)
``Sound``           yes    no   no     the modal sound of the body's impacts (``World.sound``)
==================  =====  ===  =====  ===================================================================

Only what is listed runs: a world without ``Wind`` never evaluates wind, a body without contact is
never searched for contacts (``World.plan`` lists the stages; tests count calls).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = [
    "EFFECTS",
    "Contact",
    "Damping",
    "Gravity",
    "PseudoForces",
    "SelfCollision",
    "Sound",
    "Wind",
    "supported",
]


def _bodies(value) -> tuple | None:
    if value is None:
        return None
    if isinstance(value, str):
        return (value,)
    try:
        out = tuple(value)
    except TypeError:
        raise InputError(f"bodies must be None (every body) or a list of body names, got {value!r}") from None
    if not out or not all(isinstance(b, str) and b for b in out):
        raise InputError(f"bodies must be a non-empty list of body names, got {value!r}")
    return out


def _number(name: str, value, unit: str, *, low: float | None = None, high: float | None = None,
            strict_low: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number [{unit}], got {value!r}") from None
    if not math.isfinite(x):
        raise InputError(f"{name} must be finite [{unit}], got {value!r}")
    if low is not None and (x <= low if strict_low else x < low):
        raise InputError(f"{name} must be {'>' if strict_low else '>='} {low:g} [{unit}], got {x:g}")
    if high is not None and x > high:
        raise InputError(f"{name} must be <= {high:g} [{unit}], got {x:g}")
    return x


def vec3(name: str, value, unit: str) -> np.ndarray:
    """``value`` as a finite float64 3-vector, or ``InputError`` naming ``name`` and its unit."""
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 numbers [{unit}], got {value!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be 3 finite numbers [{unit}], got {value!r}")
    return a


def _vec3(name: str, value, unit: str) -> tuple:
    return tuple(float(v) for v in vec3(name, value, unit))


class _Effect:
    """Base: the ``bodies`` selector (None = every body that supports the effect)."""

    name = "effect"

    def applies_to(self, body_name: str) -> bool:
        return self.bodies is None or body_name in self.bodies


@dataclass(frozen=True, eq=False)
class Gravity(_Effect):
    """Uniform gravity.

    Args:
        g: acceleration (3,) [m/s^2], default (0, 0, -9.81).
        bodies: names of the bodies it acts on (None: all).
    """

    g: tuple = (0.0, 0.0, -9.81)
    bodies: tuple | None = None
    name = "gravity"

    def __post_init__(self) -> None:
        object.__setattr__(self, "g", _vec3("gravity g", self.g, "m/s^2"))
        object.__setattr__(self, "bodies", _bodies(self.bodies))


@dataclass(frozen=True, eq=False)
class Wind(_Effect):
    """Air moving at ``velocity`` pushing on the bodies' surfaces.

    The pressure on a face of unit normal n moving at u is ``0.5 rho C s^2`` with
    ``s = (w - u) . n`` the relative normal air speed [m/s]: on the faces the air meets (``s < 0`` for
    an outward normal) of a closed body (modal: force, torque and modal loads; tet: surface vertex
    forces), on both sides of a cloth (force ``0.5 rho C A |s| s n``, implicit in the cloth's velocity).

    Args:
        velocity: wind velocity (3,) [m/s], or a callable ``(x (k, 3) [m], t [s]) -> (k, 3) [m/s]`` (gusts).
        density: air density rho [kg/m^3], >= 0.
        drag: pressure coefficient C [-], >= 0.
        bodies: names of the bodies it acts on (None: all).
    """

    velocity: tuple | Callable = (0.0, 0.0, 0.0)
    density: float = 1.2
    drag: float = 1.0
    bodies: tuple | None = None
    name = "wind"

    def __post_init__(self) -> None:
        if not callable(self.velocity):
            object.__setattr__(self, "velocity", _vec3("wind velocity", self.velocity, "m/s"))
        object.__setattr__(self, "density", _number("wind density", self.density, "kg/m^3", low=0.0))
        object.__setattr__(self, "drag", _number("wind drag coefficient", self.drag, "-", low=0.0))
        object.__setattr__(self, "bodies", _bodies(self.bodies))

    def at(self, x: np.ndarray, t: float) -> np.ndarray:
        """Wind velocity (k, 3) [m/s] at points ``x`` (k, 3) [m] and time ``t`` [s]."""
        x = np.asarray(x, dtype=np.float64)
        if not callable(self.velocity):
            return np.broadcast_to(np.asarray(self.velocity), x.shape)
        w = np.asarray(self.velocity(x, t), dtype=np.float64)
        if w.shape == (3,):
            w = np.broadcast_to(w, x.shape)
        if w.shape != x.shape or not np.all(np.isfinite(w)):
            raise InputError(f"the wind velocity field must return finite values of shape {x.shape} [m/s], "
                             f"got shape {w.shape}")
        return w


@dataclass(frozen=True, eq=False)
class Damping(_Effect):
    """Rayleigh damping ``alpha M + beta K``: modal damping ``mu_i = alpha + beta omega_i^2`` [1/s] of a
    modal body (replacing the model's), ``-(alpha M + beta K) v`` on tet and cloth bodies.

    Args:
        alpha: mass-proportional coefficient [1/s], >= 0.
        beta: stiffness-proportional coefficient [s], >= 0.
        bodies: names of the bodies it acts on (None: all).
    """

    alpha: float = 0.0
    beta: float = 0.0
    bodies: tuple | None = None
    name = "damping"

    def __post_init__(self) -> None:
        object.__setattr__(self, "alpha", _number("damping alpha", self.alpha, "1/s", low=0.0))
        object.__setattr__(self, "beta", _number("damping beta", self.beta, "s", low=0.0))
        object.__setattr__(self, "bodies", _bodies(self.bodies))


@dataclass(frozen=True, eq=False)
class Contact(_Effect):
    """Contact with the world's obstacles and between bodies.

    Args:
        restitution: coefficient of restitution e in [0, 1] (modal and tet impacts; cloth impacts are
            inelastic, as its collision pipeline is).
        friction: Coulomb coefficient mu >= 0.
        margin: contacts are gathered within this distance [m] (plus what the bodies travel in a step).
        thickness: the cloth's collision thickness h [m] (its repulsion distance), > 0.
        iterations: most sequential-impulse sweeps over the simultaneous contacts, >= 1 (they stop once a sweep
            changes no impulse by more than 1e-10 of the largest).
        bodies: names of the bodies that touch (None: all). A contact between two bodies needs both.
    """

    restitution: float = 0.3
    friction: float = 0.5
    margin: float = 1e-3
    thickness: float = 2e-3
    iterations: int = 100
    bodies: tuple | None = None
    name = "contact"

    def __post_init__(self) -> None:
        object.__setattr__(self, "restitution", _number("contact restitution", self.restitution, "-", low=0.0,
                                                        high=1.0))
        object.__setattr__(self, "friction", _number("contact friction", self.friction, "-", low=0.0))
        object.__setattr__(self, "margin", _number("contact margin", self.margin, "m", low=0.0, strict_low=True))
        object.__setattr__(self, "thickness", _number("contact thickness", self.thickness, "m", low=0.0,
                                                      strict_low=True))
        if not isinstance(self.iterations, (int, np.integer)) or int(self.iterations) < 1:
            raise InputError(f"contact iterations must be an integer >= 1, got {self.iterations!r}")
        object.__setattr__(self, "bodies", _bodies(self.bodies))


@dataclass(frozen=True, eq=False)
class SelfCollision(_Effect):
    """A cloth or tet body against itself (the collision pipeline: repulsion, CCD, impact zones).

    Args:
        thickness: collision thickness h [m] (> 0; None: the ``Contact`` effect's, else 2 mm).
        bodies: names of the bodies (None: every cloth and tet body).
    """

    thickness: float | None = None
    bodies: tuple | None = None
    name = "self-collision"

    def __post_init__(self) -> None:
        if self.thickness is not None:
            object.__setattr__(self, "thickness", _number("self-collision thickness", self.thickness, "m", low=0.0,
                                                          strict_low=True))
        object.__setattr__(self, "bodies", _bodies(self.bodies))


@dataclass(frozen=True, eq=False)
class PseudoForces(_Effect):
    """Coriolis, centripetal and Euler loads on the modes of a rotating modal body (the rotation
    coupling stored in the model file by ``ModalModel.from_modes``).

    Args:
        coriolis, centripetal, euler: which terms act.
        bodies: names of the modal bodies (None: every modal body).
    """

    coriolis: bool = True
    centripetal: bool = True
    euler: bool = True
    bodies: tuple | None = None
    name = "pseudo-forces"

    def __post_init__(self) -> None:
        object.__setattr__(self, "bodies", _bodies(self.bodies))


@dataclass(frozen=True, eq=False)
class Sound(_Effect):
    """The modal sound of a modal body's impacts (contacts, strikes), heard by a listener.

    Args:
        listener: direction (3,) from the body to the listener (world, normalised) [-].
        distance: listener distance [m], > 0.
        bodies: names of the modal bodies (None: every modal body).
    """

    listener: tuple = (1.0, 0.0, 0.0)
    distance: float = 1.0
    bodies: tuple | None = None
    name = "sound"

    def __post_init__(self) -> None:
        v = np.asarray(_vec3("sound listener direction", self.listener, "-"))
        if not np.linalg.norm(v) > 0:
            raise InputError("sound listener direction must not be zero")
        object.__setattr__(self, "listener", tuple((v / np.linalg.norm(v)).tolist()))
        object.__setattr__(self, "distance", _number("sound distance", self.distance, "m", low=0.0, strict_low=True))
        object.__setattr__(self, "bodies", _bodies(self.bodies))


#: every effect class by its name
EFFECTS = {c.name: c for c in (Gravity, Wind, Damping, Contact, SelfCollision, PseudoForces, Sound)}

#: the effects each body kind supports
_SUPPORT = {
    "modal": ("gravity", "wind", "damping", "contact", "pseudo-forces", "sound"),
    "tet": ("gravity", "wind", "damping", "contact", "self-collision"),
    "cloth": ("gravity", "wind", "damping", "contact", "self-collision"),
}


def supported(kind: str) -> tuple:
    """Names of the effects a body kind (``"modal"``, ``"tet"``, ``"cloth"``) supports."""
    return _SUPPORT[kind]


def for_modal(effect):
    """The runtime's implementation of a public effect for ``runtime.ModalSolver`` (other objects pass through).

    Raises:
        InputError: an effect a modal body cannot take, or one a single solver cannot (damping lives in the
            body: ``ModalBody(model, damping=(alpha, beta))``; contact needs obstacles: ``runtime.Obstacles`` or a
            ``World``).
    """
    if not isinstance(effect, _Effect):
        return effect
    from modalfem.runtime import effects as rte  # the runtime's implementations

    if isinstance(effect, Gravity):
        return rte.Gravity(effect.g)
    if isinstance(effect, Wind):
        if callable(effect.velocity):
            raise InputError("a modal body takes a constant wind velocity (3 numbers [m/s]); wind fields (x, t) act "
                             "on cloth and tet bodies")
        return rte.Wind(effect.velocity, density=effect.density, drag=effect.drag)
    if isinstance(effect, PseudoForces):
        return rte.PseudoForces(coriolis=effect.coriolis, centripetal=effect.centripetal, euler=effect.euler)
    if effect.name in supported("modal"):
        raise InputError(f"{effect.name} on a single modal solver: give damping to ModalBody(model, damping=(alpha, "
                         "beta)), contact as runtime.Obstacles([...]), sound as runtime.ModalSound, or use a "
                         "modalfem.world.World")
    raise InputError(f"effect {effect.name} cannot act on a modal body: a modal body takes "
                     f"{', '.join(supported('modal'))}")


def for_tet(effect):
    """The tet solver's implementation of a public effect for ``tet.TetSolver`` (other objects pass through).

    Raises:
        InputError: an effect a tet body cannot take, or one that needs a ``World`` (contact, self-collision, a
            wind, which acts on the surface the world knows).
    """
    if not isinstance(effect, _Effect):
        return effect
    from modalfem.tet import effects as te  # the tet solver's implementations

    if isinstance(effect, Gravity):
        return te.Gravity(effect.g)
    if isinstance(effect, Damping):
        return te.RayleighDamping(effect.alpha, effect.beta)
    if effect.name in supported("tet"):
        raise InputError(f"{effect.name} on a single tet solver: use a modalfem.world.World (or tet.Ground for a "
                         "penalty ground)")
    raise InputError(f"effect {effect.name} cannot act on a tet body: a tet body takes {', '.join(supported('tet'))}")
