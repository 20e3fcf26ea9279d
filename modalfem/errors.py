"""One exception family for modalfem.

Every error a user can cause (bad mesh, impossible material, unknown tag, k too large, ...) is a
``ModalfemError`` with a one-line message naming the problem. The CLI prints that line and exits 2.
"""

from __future__ import annotations

__all__ = [
    "ModalfemError",
    "MeshError",
    "MaterialError",
    "ConstraintError",
    "SolverError",
    "BackendUnavailableError",
    "InputError",
    "ModelFileError",
    "SimulationError",
    "SceneError",
]


class ModalfemError(Exception):
    """Base class of every error modalfem raises on purpose."""


class MeshError(ModalfemError):
    """A mesh is unreadable, malformed or fails a quality check."""


class MaterialError(ModalfemError):
    """A material parameter is impossible (E <= 0, nu outside (-1, 0.5), rho <= 0, not finite)."""


class ConstraintError(ModalfemError):
    """A constraint names an unknown tag, a bad component, or a predicate with a bad result."""


class SolverError(ModalfemError):
    """An eigen solve could not be done or could not be certified (k too large, no convergence)."""


class BackendUnavailableError(ModalfemError):
    """A requested backend (FEniCSx, SLEPc) is not installed; the message says how to get it."""


class InputError(ModalfemError):
    """Any other invalid argument (negative k, unknown option value, bad file name)."""


class ModelFileError(ModalfemError):
    """A model file is unreadable, truncated, edited (checksum mismatch), or from a newer schema."""


class SimulationError(ModalfemError):
    """A time-stepping input is invalid (dt <= 0, non-finite state or impulse, point off the surface)."""


class SceneError(ModalfemError):
    """A scene (cloth, obstacles, effects) is malformed or starts in an invalid state."""
