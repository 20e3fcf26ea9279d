"""Outputs people look at: the JSON summary, mode shapes for ParaView, a PNG sheet of mode shapes.

All outputs of one command form an ``OutputSet``: each is written to a temporary next to its target
and all are moved into place together, or none is (``staged_dir`` and ``write_text_atomic`` are the
one-target cases).
"""

from modalfem.output.paraview import mode_field_names, modes_meshio, write_modes, write_xdmf
from modalfem.output.sheet import plot_mode_sheet, surface_triangles
from modalfem.output.staging import OUT_FILES, OutputSet, check_targets, staged_dir, write_text_atomic
from modalfem.output.summary import SUMMARY_FORMAT, summary, summary_json, versions

__all__ = [
    "SUMMARY_FORMAT",
    "summary",
    "summary_json",
    "versions",
    "mode_field_names",
    "modes_meshio",
    "write_modes",
    "write_xdmf",
    "plot_mode_sheet",
    "surface_triangles",
    "OUT_FILES",
    "OutputSet",
    "check_targets",
    "staged_dir",
    "write_text_atomic",
]
