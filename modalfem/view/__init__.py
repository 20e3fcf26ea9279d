"""Live browser viewer: ``Viewer`` (meshes, per-frame updates, controls, callbacks) and ``ModeExplorer``.

``modalfem view MODEL.npz`` (``modalfem.view.cli``) serves a ``ModeExplorer`` of a model file: pick
a mode, set its amplitude, animate it, click the surface to strike the body and hear it. Standard
library and numpy only on the server side; the page is WebGL2 without dependencies. See
``modalfem.view.server`` for the protocol (per frame only the modal coordinates, or positions for
bodies without modes).
"""

from modalfem.view.explorer import ModeExplorer
from modalfem.view.server import Viewer

__all__ = ["ModeExplorer", "Viewer"]
