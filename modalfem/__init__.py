"""modalfem: vibration modes of 3D elastic bodies (FEniCSx or scikit-fem), certified.

Quick start::

    import modalfem
    from modalfem.mesh import box
    mesh = box(size=(1.0, 0.05, 0.05), cells=(40, 3, 3))
    res = modalfem.modes(mesh, modalfem.STEEL, k=6, fixed="x0")
    print(res.frequencies_hz, res.labels, res.certificate.passed)
"""

from modalfem.backends import have_fenicsx, have_slepc
from modalfem.constraints import Fix
from modalfem.errors import (
    BackendUnavailableError,
    ConstraintError,
    InputError,
    MaterialError,
    MeshError,
    ModalfemError,
    SolverError,
)
from modalfem.material import ALUMINIUM, BRASS, STEEL, Material
from modalfem.mesh.core import Mesh
from modalfem.modes import modes  # binds the function over the submodule name
from modalfem.result import Certificate, ModalResult

__version__ = "0.1.0"

_THREADS = ("set_threads", "thread_count", "threads")


def __getattr__(name: str):
    """``set_threads``, ``thread_count`` and ``threads`` (:mod:`modalfem._threads`) load numba, which loads
    scipy, on first use only: ``import modalfem.runtime`` stays light (tested). The kernels import it
    themselves."""
    if name in _THREADS:
        import importlib

        return getattr(importlib.import_module("modalfem._threads"), name)
    raise AttributeError(f"module 'modalfem' has no attribute {name!r}")

__all__ = [
    "modes",
    "Fix",
    "Material",
    "STEEL",
    "ALUMINIUM",
    "BRASS",
    "Mesh",
    "ModalResult",
    "Certificate",
    "ModalfemError",
    "MeshError",
    "MaterialError",
    "ConstraintError",
    "SolverError",
    "BackendUnavailableError",
    "InputError",
    "have_fenicsx",
    "have_slepc",
    "set_threads",
    "thread_count",
    "threads",
    "__version__",
]

