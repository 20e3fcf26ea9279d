"""Assembly backends: FEniCSx (UFL forms compiled by dolfinx) and scikit-fem.

Both implement ``assemble(mesh, material, *, degree=2, lumped=False) -> (K, M)`` returning
``scipy.sparse.csr_matrix`` stiffness K [N/m] and mass M [kg] over ALL DOFs (no constraints) in
the canonical node-major order of ``modalfem.mesh.core``.
"""

from __future__ import annotations

from modalfem.errors import BackendUnavailableError, InputError

__all__ = ["have_fenicsx", "have_slepc", "get_backend", "resolve_backend", "BACKENDS"]

BACKENDS = ("fenicsx", "skfem")


def have_fenicsx() -> bool:
    """True when dolfinx, petsc4py and ufl import (Debian's python3-dolfinx)."""
    try:
        import dolfinx  # noqa: F401
        import petsc4py  # noqa: F401
        import ufl  # noqa: F401
    except Exception:
        return False
    return True


def have_slepc() -> bool:
    """True when slepc4py and petsc4py import."""
    try:
        import petsc4py  # noqa: F401
        import slepc4py  # noqa: F401
    except Exception:
        return False
    return True


def resolve_backend(name: str = "auto") -> str:
    """Map ``"auto"`` to ``"fenicsx"`` where it is installed, else ``"skfem"``; validate names."""
    if name == "auto":
        return "fenicsx" if have_fenicsx() else "skfem"
    if name not in BACKENDS:
        raise InputError(f"unknown backend {name!r}; choose one of: auto, {', '.join(BACKENDS)}")
    if name == "fenicsx" and not have_fenicsx():
        raise BackendUnavailableError(
            "backend 'fenicsx' needs Debian's python3-dolfinx, python3-petsc4py and python3-slepc4py "
            "seen from a venv built with --system-site-packages (run `make setup` as root)"
        )
    return name


def get_backend(name: str = "auto"):
    """The backend module (with an ``assemble`` function) for ``name``."""
    name = resolve_backend(name)
    if name == "fenicsx":
        from modalfem.backends import fenicsx as mod
    else:
        from modalfem.backends import skfem as mod
    return mod
