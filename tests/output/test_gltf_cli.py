"""``modalfem export``: outputs, one-line errors for bad input, and all-or-nothing writing."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem
from modalfem.cli import main
from modalfem.mesh import box
from modalfem.model import ModalModel

pygltflib = pytest.importorskip("pygltflib", reason="pygltflib is in the test extras (pip install -e .[test])")


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=6, degree=1, backend="skfem", solver="scipy")
    path = tmp_path_factory.mktemp("model") / "block.npz"
    ModalModel.from_modes(res, mesh, modalfem.STEEL, rotation_coupling=False).save(path)
    return path


def _error_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    err = [line for line in lines if not line.startswith("[")]  # the rest are progress lines "[  0.00 s] ..."
    assert len(err) == 1, lines
    assert err[0].startswith("modalfem: error: ")
    return err[0]


def test_export_writes_the_glb_and_the_page(model_file, tmp_path, capsys):
    assert main(["export", str(model_file), str(tmp_path / "b.glb"), "--html", str(tmp_path / "b.html"), "-k", "4",
                 "--damping", "2", "1e-9"]) == 0
    out = capsys.readouterr().out
    assert "4 modes" in out and "b.glb" in out and "b.html" in out
    g = pygltflib.GLTF2.load_from_bytes((tmp_path / "b.glb").read_bytes())
    assert len(g.meshes[0].primitives[0].targets) == 4
    assert g.extras["modalfem"]["source"]["model_file"] == "block.npz"
    assert g.extras["modalfem"]["rayleigh_damping"] == {"alpha_per_s": 2.0, "beta_s": 1e-9}
    page = (tmp_path / "b.html").read_text(encoding="utf-8")
    assert "<title>block: 4 modes</title>" in page
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.glb", "b.html"]  # no temporaries left


@pytest.mark.parametrize("case, expect", [
    ("text", "not a .npz archive"),
    ("newer", "newer than the version"),
    ("missing", "does not exist"),
    ("k", "out of range: the model has 6 modes"),
    ("suffix", "must name a .glb file"),
    ("html-suffix", "--html must name a .html file"),
    ("self", "is the model file itself"),
    ("damping", "Rayleigh damping (alpha, beta) must be finite and >= 0"),
])
def test_bad_input_is_one_line_and_writes_nothing(model_file, tmp_path, capsys, case, expect):
    model, glb, extra = model_file, tmp_path / "out.glb", []
    if case == "text":
        model = tmp_path / "notes.npz"
        model.write_text("not a model\n")
    elif case == "newer":
        with np.load(model_file) as z:
            data = {k: z[k] for k in z.files}
        data["schema_version"] = np.array(ModalModel.SCHEMA_VERSION + 1)
        model = tmp_path / "future.npz"
        np.savez(model, **data)
    elif case == "missing":
        model = tmp_path / "nothing.npz"
    elif case == "k":
        extra = ["-k", "7"]
    elif case == "suffix":
        glb = tmp_path / "out.gltf"
    elif case == "html-suffix":
        extra = ["--html", str(tmp_path / "page.txt")]
    elif case == "damping":
        extra = ["--damping", "-1", "0"]
    elif case == "self":
        glb = tmp_path / "copy.glb"
        model = glb
        glb.write_bytes(model_file.read_bytes())
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert main(["export", str(model), str(glb), *extra]) == 2
    assert expect in _error_line(capsys)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_a_failure_while_writing_leaves_the_previous_outputs(model_file, tmp_path, capsys, monkeypatch):
    """The .glb temporary is complete when writing the page's fails: neither file is replaced."""
    from pathlib import Path

    glb, html = tmp_path / "b.glb", tmp_path / "b.html"
    glb.write_bytes(b"old glb")
    html.write_text("old page")
    write_bytes = Path.write_bytes
    written = []

    def disk_full_on_the_page(self, data):
        if ".b.html." in self.name:  # the page's temporary (modalfem.atomic.temp_prefix)
            raise OSError(28, "No space left on device")
        written.append(self.name)
        return write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", disk_full_on_the_page)
    assert main(["export", str(model_file), str(glb), "--html", str(html)]) == 2
    assert "cannot write" in (line := _error_line(capsys)) and "No space left on device" in line
    assert any(".b.glb." in name for name in written)  # the .glb was written, then discarded
    assert glb.read_bytes() == b"old glb" and html.read_text() == "old page"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.glb", "b.html"]
