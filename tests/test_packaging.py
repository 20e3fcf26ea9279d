"""Packaging: every subpackage ships, and forms/ and meshes/ are mapped into the installed package."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _config():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_subpackage_is_listed():
    listed = set(_config()["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "modalfem").rglob("__init__.py")
        if "__pycache__" not in p.parts
    }
    assert found - listed == set(), f"subpackages missing from pyproject.toml: {sorted(found - listed)}"


def test_forms_and_meshes_are_mapped_into_the_package():
    cfg = _config()
    assert cfg["package-dir"]["modalfem.forms"] == "forms"
    assert cfg["package-dir"]["modalfem.meshes"] == "meshes"
    assert {"modalfem.forms", "modalfem.meshes"} <= set(cfg["packages"])
    import modalfem.forms.skfem_elasticity
    import modalfem.meshes

    assert Path(modalfem.forms.skfem_elasticity.__file__).resolve().parent == ROOT / "forms"
    assert Path(modalfem.meshes.__file__).resolve().parent == ROOT / "meshes"


def _cpu_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def test_openblas_uses_this_cpus_vector_kernels():
    """Setup pins OPENBLAS_CORETYPE when an old OpenBLAS (Debian 12's 0.3.21) does not know the CPU
    and falls back to its SSE3 'Prescott' kernels (2-4x slower small products): in this interpreter's
    environment OpenBLAS must not report such a fallback on an AVX2/AVX-512 machine."""
    import os
    import subprocess
    import sys

    import pytest

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}  # what setup left, not the shell
    env["OPENBLAS_VERBOSE"] = "2"
    p = subprocess.run([sys.executable, "-c", "import numpy"], env=env, capture_output=True, text=True, timeout=60,
                       check=False)
    core = [ln.split(":", 1)[1].strip() for ln in (p.stdout + p.stderr).splitlines() if ln.startswith("Core:")]
    if not core:
        pytest.skip("numpy's BLAS does not report an OpenBLAS core type")
    flags = _cpu_flags()
    if not ({"avx2", "fma"} <= flags):
        pytest.skip("CPU without AVX2: the SSE kernels are the right ones")
    assert core[0] not in {"Prescott", "Core2", "Nehalem", "Atom"}, (
        f"OpenBLAS runs its {core[0]} (SSE) kernels on an AVX2/AVX-512 CPU: rerun scripts/setup.sh")
