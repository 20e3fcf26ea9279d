"""Every tutorial is a notebook ending in asserts on the numbers it shows: execute them all.

Globs ``tutorials/*.py`` (future tutorials are picked up automatically). Each tutorial is converted
with jupytext and executed cell by cell with nbclient in a Jupyter kernel running this interpreter
(a kernelspec written to a temporary directory, so nothing under the user's home is touched), from
the repository root with ``MODALFEM_OUT`` pointing at a temporary directory. A failing cell, its
asserts included, fails the test. Every picture the tutorial writes (``.png``, ``.gif``) must also
appear, byte for byte, among the images the executed notebook shows inline.

That one run covers the plain-script path too (same cells, same namespace; outside a kernel
``modalfem.output.notebook.show`` only checks its files, tested in ``tests/output``). Where the
Jupyter stack is not installed (the ``test`` extra brings it), each tutorial runs as a script instead.
"""

from __future__ import annotations

import base64
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = sorted((ROOT / "tutorials").glob("*.py"))
TIMEOUT_S = 300  # per tutorial (script) or per cell (notebook)
IMAGE_MIME = ("image/png", "image/gif")
IMAGE_SUFFIXES = (".png", ".gif")
HAVE_JUPYTER = all(importlib.util.find_spec(m) is not None for m in ("jupytext", "nbclient", "nbformat", "ipykernel"))
IDS = [p.stem for p in TUTORIALS]


def test_there_are_tutorials():
    assert TUTORIALS, "no tutorials/*.py found"


@pytest.fixture
def jupyter_env(tmp_path, monkeypatch):
    """A kernelspec for this interpreter, and Jupyter/IPython state, in tmp_path; returns the kernel name."""
    name = "modalfem-tutorial"
    spec_dir = tmp_path / "jupyter" / "kernels" / name
    spec_dir.mkdir(parents=True)
    spec = {"argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
            "display_name": f"modalfem tests ({sys.executable})", "language": "python"}
    (spec_dir / "kernel.json").write_text(json.dumps(spec))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    monkeypatch.setenv("JUPYTER_RUNTIME_DIR", str(tmp_path / "runtime"))  # connection files
    monkeypatch.setenv("JUPYTER_CONFIG_DIR", str(tmp_path / "config"))
    monkeypatch.setenv("JUPYTER_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("IPYTHONDIR", str(tmp_path / "ipython"))  # the kernel's profile
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")
    return name


def _shown_images(nb) -> list[bytes]:
    """The decoded bytes of every image/png or image/gif output of an executed notebook."""
    images = []
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            for mime in IMAGE_MIME:
                data = out.get("data", {}).get(mime)
                if data is not None:
                    images.append(base64.b64decode(data if isinstance(data, str) else "".join(data)))
    return images


@pytest.mark.skipif(not HAVE_JUPYTER, reason="needs jupytext, nbclient, nbformat, ipykernel (pip install -e '.[test]')")
@pytest.mark.parametrize("path", TUTORIALS, ids=IDS)
def test_tutorial_runs_as_notebook(path, tmp_path, monkeypatch, jupyter_env):
    import jupytext
    from nbclient import NotebookClient
    from nbclient.exceptions import CellExecutionError

    out = tmp_path / "out"
    monkeypatch.setenv("MODALFEM_OUT", str(out))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    nb = jupytext.read(path)
    client = NotebookClient(nb, kernel_name=jupyter_env, timeout=TIMEOUT_S, resources={"metadata": {"path": str(ROOT)}})
    failure = None
    try:
        client.execute()
    except CellExecutionError as exc:  # the failing cell and its traceback, without the kernel's ANSI colours
        failure = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))
    if failure is not None:
        pytest.fail(f"{path.name} failed as a notebook:\n{failure[-4000:]}")

    written = sorted(p for p in out.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    shown = _shown_images(nb)
    if written:  # a figure-producing tutorial: it shows at least one figure, and every one it writes
        assert shown, f"{path.name} writes {[p.name for p in written]} but shows no image inline"
        missing = [p.name for p in written if p.read_bytes() not in shown]
        assert not missing, f"{path.name} writes {missing} but does not show them inline (modalfem.output.notebook.show)"


@pytest.mark.skipif(HAVE_JUPYTER, reason="covered by test_tutorial_runs_as_notebook (the same cells)")
@pytest.mark.parametrize("path", TUTORIALS, ids=IDS)
def test_tutorial_runs_as_script(path, tmp_path):
    env = dict(os.environ, MODALFEM_OUT=str(tmp_path), MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(path)], cwd=ROOT, env=env, capture_output=True, text=True, check=False,
                          timeout=TIMEOUT_S)
    assert proc.returncode == 0, f"{path.name} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"


@pytest.mark.parametrize("path", TUTORIALS, ids=IDS)
def test_tutorial_is_jupytext_notebook(path):
    jupytext = pytest.importorskip("jupytext")
    nb = jupytext.read(path)
    kinds = {c.cell_type for c in nb.cells}
    assert {"markdown", "code"} <= kinds
    assert nb.cells[-1].cell_type == "code" and "assert" in nb.cells[-1].source


@pytest.mark.parametrize("path", TUTORIALS, ids=IDS)
def test_tutorial_image_links_resolve(path):
    """A markdown image link (``![alt](target)``) names a file next to the tutorial or a URL.

    Pictures the tutorial makes itself live in ``MODALFEM_OUT`` and are shown with ``show``, not linked.
    """
    jupytext = pytest.importorskip("jupytext")
    nb = jupytext.read(path)
    targets = [t for c in nb.cells if c.cell_type == "markdown"
               for t in re.findall(r"!\[[^\]]*\]\(\s*<?([^)\s>]+)", c.source)]
    broken = [t for t in targets if not re.match(r"[a-z][a-z0-9+.-]*://", t) and not (path.parent / t).is_file()]
    assert not broken, f"{path.name} links images that do not exist next to it: {broken}"
