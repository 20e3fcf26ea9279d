"""Gmsh geometry scripts and sample meshes, installed as ``modalfem.meshes``."""

from importlib.resources import files


def path(name: str):
    """Path of a shipped file, e.g. ``path("bell.geo")``."""
    return files(__name__).joinpath(name)
