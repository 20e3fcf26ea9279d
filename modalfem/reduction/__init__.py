"""Reduced bases: Rayleigh-Ritz (affine, affine + quadratic), coarse-to-fine embedding, boundary-only restriction.

* ``modalfem.reduction.ritz``: ``ritz_modes`` (12 or 30 smooth fields, small dense eigenproblem).
* ``modalfem.reduction.embed``: ``embed_points`` (barycentric coordinates of points in a tet mesh).
* ``modalfem.reduction.compare``: frequency errors, MAC, mode matching.
* ``modalfem.reduction.response``: modal impulse response with Rayleigh damping.
* ``modalfem.reduction.transfer``: coarse physics, fine render surface (``render_surface_model``);
  ``render_surface`` reads the surface (``read_surface``), ``transfer_check`` measures the transfer
  against a finer solve (``check_transfer``, ``refine_mesh``).
"""

from modalfem.reduction.compare import (
    ModeComparison,
    compare_modes,
    frequency_errors,
    mac_matrix,
    match_modes,
)
from modalfem.reduction.embed import Embedding, carry_modes, embed_points
from modalfem.reduction.render_surface import RenderSurface, read_surface
from modalfem.reduction.response import (
    RayleighDamping,
    impulse_response,
    relative_rms_error,
)
from modalfem.reduction.ritz import RitzModes, field_matrix, ritz_modes, solve_reduced
from modalfem.reduction.transfer import (
    TransferReport,
    render_surface_model,
    transfer_modes,
)
from modalfem.reduction.transfer_check import TransferCheck, check_transfer, refine_mesh

__all__ = [
    "Embedding",
    "ModeComparison",
    "RayleighDamping",
    "RenderSurface",
    "RitzModes",
    "TransferCheck",
    "TransferReport",
    "carry_modes",
    "check_transfer",
    "compare_modes",
    "embed_points",
    "field_matrix",
    "frequency_errors",
    "impulse_response",
    "mac_matrix",
    "match_modes",
    "read_surface",
    "refine_mesh",
    "relative_rms_error",
    "render_surface_model",
    "ritz_modes",
    "solve_reduced",
    "transfer_modes",
]
