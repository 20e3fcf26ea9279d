"""The JSON summary of a modal analysis: what was solved, the answer, the evidence, the provenance."""

from __future__ import annotations

import importlib.metadata
import json
import math
import platform
import sys
from typing import Any

import numpy as np

from modalfem.material import Material
from modalfem.mesh.core import Mesh
from modalfem.result import ModalResult

__all__ = ["SUMMARY_FORMAT", "summary", "summary_json", "versions"]

#: identifies the layout of the summary; bump when a key changes meaning
SUMMARY_FORMAT = "modalfem.modes/1"


def jsonable(value: Any) -> Any:
    """``value`` with numpy scalars/arrays, tuples and paths turned into JSON types; NaN/inf -> None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def _dist_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def versions() -> dict[str, str]:
    """Versions of Python and of the numerical stack that is installed (absent ones are left out).

    PETSc and SLEPc library versions are read only if ``petsc4py.PETSc`` / ``slepc4py.SLEPc`` are
    already imported (importing them initialises PETSc); otherwise the Python binding versions are
    reported.
    """
    import scipy

    import modalfem

    out: dict[str, str | None] = {
        "python": platform.python_version(),
        "modalfem": modalfem.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
    }
    for dist, key in (
        ("scikit-fem", "scikit-fem"),
        ("meshio", "meshio"),
        ("gmsh", "gmsh"),
        ("matplotlib", "matplotlib"),
        ("fenics-dolfinx", "dolfinx"),
        ("petsc4py", "petsc4py"),
        ("slepc4py", "slepc4py"),
    ):
        out[key] = _dist_version(dist)
    if out["dolfinx"] is None and "dolfinx" in sys.modules:
        out["dolfinx"] = getattr(sys.modules["dolfinx"], "__version__", None)
    for mod, key, attr in (("petsc4py.PETSc", "petsc", "Sys"), ("slepc4py.SLEPc", "slepc", "Sys")):
        m = sys.modules.get(mod)
        if m is not None:
            try:
                out[key] = ".".join(map(str, getattr(m, attr).getVersion()))
            except Exception:  # a broken binding must not break the report
                pass
    return {k: v for k, v in out.items() if v is not None}


def summary(
    result: ModalResult,
    *,
    mesh: Mesh,
    material: Material,
    source: dict | None = None,
    constraints: dict | None = None,
    timings: dict[str, float] | None = None,
    outputs: dict[str, str] | None = None,
    command: list[str] | None = None,
) -> dict:
    """The JSON-ready summary of ``result``.

    Args:
        result: the modal analysis.
        mesh: the mesh it was computed on.
        material: its material.
        source: where the mesh came from (file and unit scale, or generator and parameters).
        constraints: the constraints as given (e.g. ``{"fixed": ["x0"], "roller": []}``).
        timings: extra wall seconds (mesh generation, output) merged over ``result.timings``.
        outputs: names of the other files written with it.
        command: the command line.

    Returns:
        A dict of JSON types: ``frequencies_hz`` [Hz], ``omega`` [rad/s], ``labels``, ``modes``
        (one record per mode), ``rigid_mode_count``, ``certificate`` (``Certificate.to_dict``),
        ``pairs`` (0-based indices into ``frequencies_hz``), ``mesh``, ``material`` (E [Pa], nu, rho [kg/m^3]),
        ``constraints``, ``backend``, ``solver``, ``timings`` [s], ``versions``, ``info``.
    """
    cert = result.certificate
    f = result.frequencies_hz
    residuals = list(cert.residuals) if len(cert.residuals) == len(f) else [None] * len(f)
    node_count = len(result.dof_points)
    dof_count = 3 * node_count
    lo, hi = mesh.bounds
    data = {
        "format": SUMMARY_FORMAT,
        "command": command,
        "k": len(f),
        "frequencies_hz": f,
        "omega": result.omega,
        "labels": list(result.labels),
        "modes": [
            {"mode": i + 1, "label": lab, "frequency_hz": fi, "omega": wi, "residual": ri}
            for i, (lab, fi, wi, ri) in enumerate(zip(result.labels, f, result.omega, residuals))
        ],
        "rigid_mode_count": result.rigid_mode_count,
        "certificate": cert.to_dict(),
        "pairs": [list(p) for p in cert.pairs],
        "backend": result.backend,
        "solver": result.solver,
        "degree": result.degree,
        "mesh": {
            **(source or {}),
            "points": mesh.point_count,
            "cells": mesh.cell_count,
            "pieces": mesh.piece_count,
            "nodes": node_count,
            "dofs": dof_count,
            "free_dofs": int(dof_count - np.count_nonzero(result.fixed_dofs)),
            "bounds": [lo, hi],
            "volume": mesh.volume,
            "tags": sorted(mesh.tags),
            "fingerprint": mesh.fingerprint,
        },
        "material": {"name": material.name, "E": material.E, "nu": material.nu, "rho": material.rho},
        "constraints": constraints or {},
        "timings": {**result.timings, **(timings or {})},
        "versions": versions(),
        "info": result.info,
        "outputs": outputs or {},
    }
    return jsonable(data)


def summary_json(data: dict) -> str:
    """Strict JSON text (no NaN) of a ``summary`` dict, indented, ending with a newline."""
    return json.dumps(jsonable(data), indent=2, allow_nan=False) + "\n"
