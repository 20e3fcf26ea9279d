"""Reduced bases: Rayleigh-Ritz (affine, affine + quadratic), coarse-to-fine embedding, boundary-only restriction.

* ``modalfem.reduction.ritz``: ``ritz_modes`` (12 or 30 smooth fields, small dense eigenproblem).
* ``modalfem.reduction.embed``: ``embed_points`` (barycentric coordinates of points in a tet mesh).
* ``modalfem.reduction.compare``: frequency errors, MAC, mode matching.
* ``modalfem.reduction.response``: modal impulse response with Rayleigh damping.
"""

from modalfem.reduction.compare import (
    ModeComparison,
    compare_modes,
    frequency_errors,
    mac_matrix,
    match_modes,
)
from modalfem.reduction.embed import Embedding, carry_modes, embed_points
from modalfem.reduction.response import (
    RayleighDamping,
    impulse_response,
    relative_rms_error,
)
from modalfem.reduction.ritz import RitzModes, field_matrix, ritz_modes, solve_reduced

__all__ = [
    "Embedding",
    "ModeComparison",
    "RayleighDamping",
    "RitzModes",
    "carry_modes",
    "compare_modes",
    "embed_points",
    "field_matrix",
    "frequency_errors",
    "impulse_response",
    "mac_matrix",
    "match_modes",
    "relative_rms_error",
    "ritz_modes",
    "solve_reduced",
]
