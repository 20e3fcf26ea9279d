"""Meshes: the ``Mesh`` dataclass, meshio I/O and gmsh generators.

Public names: ``Mesh``, ``read``, ``write``, ``box``, ``plate``, ``rod``, ``tuning_fork``, ``bell``.
"""

from modalfem.mesh.core import Mesh

__all__ = ["Mesh", "read", "write", "box", "plate", "rod", "tuning_fork", "bell", "GENERATORS"]


def __getattr__(name: str):
    if name in ("read", "write"):
        from modalfem.mesh import io

        return getattr(io, name)
    if name in ("box", "plate", "rod", "tuning_fork", "bell", "GENERATORS"):
        from modalfem.mesh import generators

        return getattr(generators, name)
    raise AttributeError(f"module 'modalfem.mesh' has no attribute {name!r}")
