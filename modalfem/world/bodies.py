"""The three body kinds of a ``World``: ``Modal``, ``Tet``, ``Cloth``. Each is a fixed model plus where it starts.

Every kind follows one contract inside the world: a fixed model, a state (``runtime.State``, ``tet.TetState``,
``ClothState``), a control (impulses, scripted vertices) and a step the world calls through its plan; its
surface (vertices, outward triangles) is what contact, the cloth pipeline and pictures see.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from modalfem.effects import vec3
from modalfem.errors import InputError

__all__ = ["Cloth", "ClothState", "Modal", "Tet"]

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]{0,63}$")


def _name(name) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise InputError(f"a body name must be 1-64 letters, digits, '_', '-', '.', starting with a letter, "
                         f"got {name!r}")
    return name


def _vec(name: str, value, unit: str) -> np.ndarray | None:
    return None if value is None else vec3(name, value, unit)


class Modal:
    """A modal body: rigid motion plus linear vibration modes (a ``ModalModel`` or its file).

    Args:
        model: a ``modalfem.model.ModalModel`` or the path of its ``.npz`` file.
        name: the body's name in the world.
        position: centre of mass (3,) [m] at t = 0 (default: where the model's mesh puts it).
        orientation: quaternion (w, x, y, z) body -> world (default identity).
        velocity: centre-of-mass velocity (3,) [m/s].
        angular_velocity: (3,) [rad/s], world.
    """

    kind = "modal"

    def __init__(self, model, *, name: str, position=None, orientation=None, velocity=None,
                 angular_velocity=None) -> None:
        from modalfem.model import ModalModel

        if not isinstance(model, ModalModel):
            model = ModalModel.load(model)
        self.model = model
        self.name = _name(name)
        self.position = _vec(f"{name}: position", position, "m")
        self.velocity = _vec(f"{name}: velocity", velocity, "m/s")
        self.angular_velocity = _vec(f"{name}: angular_velocity", angular_velocity, "rad/s")
        self.orientation = None
        if orientation is not None:
            q = np.asarray(orientation, dtype=np.float64).reshape(-1)
            if q.shape != (4,) or not np.all(np.isfinite(q)) or not np.linalg.norm(q) > 0:
                raise InputError(f"{name}: orientation must be a non-zero quaternion (w, x, y, z), got {orientation!r}")
            self.orientation = q / np.linalg.norm(q)


class Tet:
    """A large-deformation tetrahedral body (``modalfem.tet``: corotated / stable energies, implicit steps).

    Args:
        model: a ``modalfem.tet.TetModel`` (``tet.tet_model(mesh, material, energy=...)``).
        name: the body's name in the world.
        position: translation (3,) [m] applied to the rest mesh at t = 0.
        velocity: initial velocity (3,) [m/s] of every vertex.
        pins: vertex indices held at their start positions.
        newton_max, linear_solver: the implicit solver's options (``tet.TetSolver``).
    """

    kind = "tet"

    def __init__(self, model, *, name: str, position=None, velocity=None, pins=None, newton_max: int = 8,
                 linear_solver: str = "cg") -> None:
        from modalfem.tet import TetModel

        if not isinstance(model, TetModel):
            raise InputError(f"{name}: a tet body needs a modalfem.tet.TetModel (tet.tet_model(mesh, material)), "
                             f"got {type(model).__name__}")
        self.model = model
        self.name = _name(name)
        self.position = _vec(f"{name}: position", position, "m")
        self.velocity = _vec(f"{name}: velocity", velocity, "m/s")
        self.pins = None
        if pins is not None:
            p = np.asarray(pins)
            if p.ndim != 1 or (p.size and (not np.issubdtype(p.dtype, np.integer) or p.min() < 0
                                          or p.max() >= model.point_count)):
                raise InputError(f"{name}: pins must be vertex indices in [0, {model.point_count})")
            self.pins = p.astype(np.int64)
        self.newton_max = int(newton_max)
        self.linear_solver = linear_solver


class Cloth:
    """A cloth (``modalfem.cloth.ClothModel``: shells with stretching, shearing and bending; handles).

    Args:
        model: the ``ClothModel``.
        name: the body's name in the world.
        x0: start positions (n, 3) [m] (default: the rest shape).
        v0: start velocities (n, 3) [m/s] (default 0).
        smoothing: post-collision smoothing time s [s] >= 0 (``ClothScene`` stage (d)): the collision pipeline's
            velocity change is smoothed over the sheet by ``(M + dt s K) dv_s = M dv`` and checked again, so
            impulses on single vertices do not strain the sheet (0: off).
        linear_solver: ``"cg"`` or ``"splu"``.
    """

    kind = "cloth"

    def __init__(self, model, *, name: str, x0=None, v0=None, smoothing: float = 0.02,
                 linear_solver: str = "cg") -> None:
        from modalfem.cloth.model import ClothModel

        if not isinstance(model, ClothModel):
            raise InputError(f"{name}: a cloth body needs a modalfem.cloth.model.ClothModel, got {type(model).__name__}")
        self.model = model
        self.name = _name(name)
        n = model.mesh.point_count
        self.x0 = None if x0 is None else _rows(f"{name}: x0", x0, n)
        self.v0 = None if v0 is None else _rows(f"{name}: v0", v0, n)
        self.smoothing = float(smoothing)
        if not (np.isfinite(self.smoothing) and self.smoothing >= 0.0):
            raise InputError(f"{name}: smoothing must be finite and >= 0 [s], got {smoothing!r}")
        self.linear_solver = linear_solver


def _rows(name: str, a, n: int) -> np.ndarray:
    try:
        a = np.array(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an ({n}, 3) array of numbers") from None
    if a.shape != (n, 3) or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be a finite ({n}, 3) array, got shape {a.shape}")
    return a


@dataclass
class ClothState:
    """State of a cloth body: positions ``x`` (n, 3) [m], velocities ``v`` (n, 3) [m/s], and the contact
    constraints released by the last step (adhesion release, ``ClothScene``)."""

    x: np.ndarray
    v: np.ndarray
    released: np.ndarray

    def copy(self) -> ClothState:
        return ClothState(self.x.copy(), self.v.copy(), self.released.copy())
