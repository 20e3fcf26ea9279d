"""Every tutorial is a runnable script ending in asserts on the numbers it shows: run them all.

Globs ``tutorials/*.py`` (future tutorials are picked up automatically), runs each with this
interpreter as a subprocess from the repository root with ``MODALFEM_OUT`` pointing at a temporary
directory, and requires exit code 0. Each tutorial also has to be valid jupytext (it is a notebook too).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = sorted((ROOT / "tutorials").glob("*.py"))
TIMEOUT_S = 300


def test_there_are_tutorials():
    assert TUTORIALS, "no tutorials/*.py found"


@pytest.mark.parametrize("path", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_runs(path, tmp_path):
    env = dict(os.environ, MODALFEM_OUT=str(tmp_path), MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(path)], cwd=ROOT, env=env, capture_output=True, text=True, check=False,
                          timeout=TIMEOUT_S)
    assert proc.returncode == 0, f"{path.name} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"


@pytest.mark.parametrize("path", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_is_jupytext_notebook(path):
    jupytext = pytest.importorskip("jupytext")
    nb = jupytext.read(path)
    kinds = {c.cell_type for c in nb.cells}
    assert {"markdown", "code"} <= kinds
    assert nb.cells[-1].cell_type == "code" and "assert" in nb.cells[-1].source
