"""Light runtime: ``modalfem.runtime`` (and loading a model file with it) imports numpy only."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.errors import ModelFileError

HEAVY = ("scipy", "skfem", "dolfinx", "petsc4py", "ufl", "basix", "slepc4py", "meshio", "gmsh")


def _heavy_after(code: str) -> list[str]:
    probe = code + f"\nimport sys\nprint(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    return eval(out.stdout.strip().splitlines()[-1])  # a printed list of module names


def test_runtime_import_loads_no_fem_or_sparse_library():
    assert _heavy_after("import modalfem.runtime") == []


def test_loading_and_stepping_a_model_file_loads_no_fem_or_sparse_library(tmp_path, small_model):
    path = tmp_path / "block.npz"
    small_model.save(path)
    code = (f"import numpy as np, modalfem.runtime as rt\nb = rt.load({str(path)!r})\n"
            "s = rt.ModalSolver(b, effects=[rt.Gravity(), rt.Obstacles([rt.Ground(-1.0)])])\n"
            "st = s.state()\nst.qdot[:] = 1.0\ns.advance(st, 1e-3)\nb.normals(b.positions(st))")
    # contact runs compiled (numba) kernels, and numba itself loads scipy when it compiles or loads a kernel
    # (its version check, then scipy.linalg.cython_blas for its BLAS bindings, whose package imports
    # scipy.sparse): the runtime's own code uses no scipy, and no FEM library is loaded
    assert [m for m in _heavy_after(code) if m != "scipy"] == []


def test_load_returns_a_body_of_the_file(tmp_path, small_model):
    path = tmp_path / "block.npz"
    small_model.save(path)
    body = rt.load(path, damping=(1.0, 1e-7), dtype=np.float64)
    assert body.mode_count == small_model.mode_count and body.vertex_count == small_model.vertex_count
    # entries below 1e-15 of their mode's largest are flushed to zero (no subnormal products)
    assert np.allclose(body.shapes, small_model.shapes, rtol=0, atol=1e-15 * np.abs(small_model.shapes).max())
    light = rt.load(path)  # default: float32 shapes for the reconstruction
    assert light.shapes.dtype == np.float32
    assert np.allclose(light.shapes, small_model.shapes, rtol=1e-6, atol=1e-7 * np.abs(small_model.shapes).max())
    assert np.allclose(body.mu, 1.0 + 1e-7 * small_model.omega**2)


def test_a_model_file_from_a_newer_schema_is_refused(tmp_path, small_model):
    path = tmp_path / "block.npz"
    small_model.save(path)
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data["schema_version"] = np.array(small_model.SCHEMA_VERSION + 1)
    newer = tmp_path / "newer.npz"
    np.savez(newer, **data)
    with pytest.raises(ModelFileError, match="schema version 2.*newer"):
        rt.load(newer)
