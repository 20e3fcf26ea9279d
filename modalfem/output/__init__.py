"""Outputs people look at: the JSON summary, mode shapes for ParaView, a PNG sheet of mode shapes.

Every writer is atomic at the level the CLI needs: ``staged_dir`` builds a whole output directory
next to its target and moves it in only on success; ``write_text_atomic`` writes one file through a
temporary file and ``os.replace``.
"""

from modalfem.output.paraview import mode_field_names, modes_meshio, write_modes
from modalfem.output.sheet import plot_mode_sheet, surface_triangles
from modalfem.output.staging import check_targets, staged_dir, write_text_atomic
from modalfem.output.summary import SUMMARY_FORMAT, summary, summary_json, versions

__all__ = [
    "SUMMARY_FORMAT",
    "summary",
    "summary_json",
    "versions",
    "mode_field_names",
    "modes_meshio",
    "write_modes",
    "plot_mode_sheet",
    "surface_triangles",
    "check_targets",
    "staged_dir",
    "write_text_atomic",
]
