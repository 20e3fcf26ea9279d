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
