"""Meshes: the ``Mesh`` dataclass, meshio I/O and gmsh generators.

Public names: ``Mesh``, ``read``, ``write``, ``box``, ``plate``, ``rod``, ``tuning_fork``, ``bell``,
``from_surface`` and ``tetrahedralize`` (solid meshes from STL/OBJ/PLY/OFF surfaces).
"""

from modalfem.mesh.core import Mesh

__all__ = ["Mesh", "read", "write", "box", "plate", "rod", "tuning_fork", "bell", "GENERATORS", "from_surface", "tetrahedralize"]


def __getattr__(name: str):
    if name in ("read", "write"):
        from modalfem.mesh import io

        return getattr(io, name)
    if name in ("box", "plate", "rod", "tuning_fork", "bell", "GENERATORS"):
        from modalfem.mesh import generators

        return getattr(generators, name)
    if name in ("from_surface", "tetrahedralize"):
        from modalfem.mesh import solid as module

        return getattr(module, name)
    raise AttributeError(f"module 'modalfem.mesh' has no attribute {name!r}")
