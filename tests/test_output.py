"""Output writers: ParaView files carry the true (P2) field, JSON is strict, staging is all-or-nothing."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import modalfem
from modalfem.mesh import box
from modalfem.output import staged_dir, summary, summary_json, write_modes, write_text_atomic
from modalfem.output.summary import jsonable


@pytest.fixture(scope="module")
def p2_result():
    mesh = box(size=(1.0, 0.1, 0.1), cells=(6, 1, 1))
    res = modalfem.modes(mesh, modalfem.STEEL, k=3, fixed="x0", backend="skfem", solver="scipy")
    return mesh, res


def test_vtu_holds_tetra10_and_the_exact_nodal_field(p2_result, tmp_path):
    import meshio

    mesh, res = p2_result
    path = write_modes(tmp_path / "m.vtu", mesh, res)
    m = meshio.read(path)
    assert m.cells[0].type == "tetra10" and len(m.cells[0].data) == mesh.cell_count
    np.testing.assert_allclose(m.points, res.dof_points)
    for i in range(3):
        np.testing.assert_allclose(m.point_data[f"mode_{i + 1:02d}"], res.shape(i))
        np.testing.assert_allclose(m.point_data[f"|mode_{i + 1:02d}|"], np.linalg.norm(res.shape(i), axis=1))
    # tetra10 midside nodes (VTK order) sit at the midpoints of their cell's edges
    c = m.cells[0].data
    p = m.points
    np.testing.assert_allclose(p[c[:, 4]], 0.5 * (p[c[:, 0]] + p[c[:, 1]]), atol=1e-14)
    np.testing.assert_allclose(p[c[:, 9]], 0.5 * (p[c[:, 2]] + p[c[:, 3]]), atol=1e-14)


@pytest.mark.parametrize("heavy", ["hdf", "xml"])
def test_xdmf_reads_back_with_meshio_exactly(p2_result, tmp_path, heavy):
    """Both XDMF layouts: meshio (which needs h5py for any XDMF) returns the exact nodal fields."""
    pytest.importorskip("h5py", reason="meshio's XDMF reader needs h5py (a modalfem dependency)")
    import meshio

    from modalfem.output import modes_meshio, write_xdmf

    mesh, res = p2_result
    written = write_xdmf(tmp_path / "m.xdmf", modes_meshio(mesh, res), heavy=heavy)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in written)
    assert (heavy == "hdf") == ((tmp_path / "m.h5") in written)
    root = ET.parse(tmp_path / "m.xdmf").getroot()
    assert root.find(".//Topology").get("TopologyType") == "Tetrahedron_10"
    m = meshio.read(tmp_path / "m.xdmf")
    assert m.cells[0].type == "tetra10" and len(m.cells[0].data) == mesh.cell_count
    np.testing.assert_array_equal(m.points, res.dof_points)
    for i in range(3):
        np.testing.assert_array_equal(m.point_data[f"mode_{i + 1:02d}"], res.shape(i))
        np.testing.assert_array_equal(m.point_data[f"|mode_{i + 1:02d}|"], np.linalg.norm(res.shape(i), axis=1))


def test_write_modes_xdmf_uses_hdf5_when_h5py_imports(p2_result, tmp_path):
    pytest.importorskip("h5py")
    mesh, res = p2_result
    write_modes(tmp_path / "m.xdmf", mesh, res)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.h5", "m.xdmf"]


def test_json_is_strict_and_matches_the_result(p2_result):
    mesh, res = p2_result
    data = summary(res, mesh=mesh, material=modalfem.STEEL, source={"generator": "box"})
    text = summary_json(data)
    back = json.loads(text)
    np.testing.assert_allclose(back["frequencies_hz"], res.frequencies_hz)
    assert back["labels"] == list(res.labels) and back["certificate"]["passed"] is True
    assert jsonable({"a": float("nan"), "b": np.float32(np.inf), "c": np.arange(2)}) == {"a": None, "b": None, "c": [0, 1]}


def test_staged_dir_is_all_or_nothing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with staged_dir(out) as tmp:
            (tmp / "a.txt").write_text("partial")
            raise RuntimeError("failed half way")
    assert not out.exists() and list(tmp_path.iterdir()) == []
    with staged_dir(out) as tmp:
        (tmp / "a.txt").write_text("complete")
    assert (out / "a.txt").read_text() == "complete" and [p.name for p in tmp_path.iterdir()] == ["out"]
    write_text_atomic(out / "b.json", "{}\n")
    assert sorted(p.name for p in out.iterdir()) == ["a.txt", "b.json"]
    with staged_dir(out) as tmp:  # an existing folder is replaced as a whole, not file by file
        (tmp / "c.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["c.txt"] and [p.name for p in tmp_path.iterdir()] == ["out"]


def _tree(path):
    return {str(p.relative_to(path)): (p.read_bytes() if p.is_file() else None) for p in sorted(path.rglob("*"))}


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, SystemExit, OSError])
def test_output_set_commit_interrupted_between_moves_restores_everything(tmp_path, monkeypatch, interrupt):
    """A kill between the renames of a commit undoes the ones done: the old folder and files are back."""
    import os

    from modalfem.errors import InputError
    from modalfem.output import OutputSet

    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "modes.json").write_text("old json")
    (tmp_path / "s.json").write_text("old summary")
    before = _tree(tmp_path)
    real, calls = os.replace, []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:  # the folder is in place, the file is next
            raise interrupt("killed between two moves") if interrupt is not OSError else OSError(5, "I/O error")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(InputError if interrupt is OSError else interrupt):
        with OutputSet() as outs:
            (outs.folder(tmp_path / "out") / "modes.json").write_text("new json")
            outs.file(tmp_path / "s.json").write_text("new summary")
            outs.commit()
    assert _tree(tmp_path) == before


def test_output_set_creates_missing_parents_and_removes_them_on_failure(tmp_path):
    from modalfem.output import OutputSet

    with pytest.raises(RuntimeError):
        with OutputSet() as outs:
            outs.file(tmp_path / "a" / "b" / "s.json").write_text("x")
            raise RuntimeError("failed")
    assert list(tmp_path.iterdir()) == []
    with OutputSet() as outs:
        outs.file(tmp_path / "a" / "b" / "s.json").write_text("x")
        outs.folder(tmp_path / "c" / "out")
        outs.commit()
    assert (tmp_path / "a" / "b" / "s.json").read_text() == "x" and (tmp_path / "c" / "out").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "c"]


@pytest.mark.parametrize("make, needle", [
    (lambda d: (d / "out").mkdir() or (d / "out" / "notes.txt").write_text("mine"), "holds files modalfem does not write"),
    (lambda d: (d / "out").write_text("a file"), "is not a directory"),
])
def test_check_targets_refuses_an_out_folder_it_would_destroy(tmp_path, make, needle):
    from modalfem.errors import InputError
    from modalfem.output import check_targets

    make(tmp_path)
    with pytest.raises(InputError, match=needle):
        check_targets(out_dir=tmp_path / "out")


def test_check_targets_refuses_a_file_that_is_out_or_given_twice(tmp_path):
    from modalfem.errors import InputError
    from modalfem.output import check_targets

    with pytest.raises(InputError, match="is the --out folder"):
        check_targets(out_dir=tmp_path / "o", files=(tmp_path / "o",))
    with pytest.raises(InputError, match="given twice"):
        check_targets(files=(tmp_path / "s.json", tmp_path / "s.json"))
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "m.npz").write_text("a model of the previous run")
    check_targets(out_dir=tmp_path / "o", files=(tmp_path / "o" / "m.npz",))  # its own target: not foreign
    with pytest.raises(InputError, match="m.npz"):
        check_targets(out_dir=tmp_path / "o")


def test_sheet_camera_is_orthonormal_and_every_panel_shows_the_body(p2_result, tmp_path):
    from PIL import Image

    from modalfem.output.sheet import _view_basis, _view_vector, plot_mode_sheet

    for elev, azim in ((22.0, -58.0), (-40.0, 130.0), (89.0, 0.0)):
        B = _view_basis(elev, azim)
        np.testing.assert_allclose(B @ B.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(B) == pytest.approx(1.0)  # right-handed: x right, y up, z towards the viewer
        np.testing.assert_allclose(B[2], _view_vector(elev, azim))
    mesh, res = p2_result
    path = plot_mode_sheet(tmp_path / "s.png", mesh, res, count=3, title="t")
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    h, w, _ = img.shape
    coloured = (np.abs(img - img.mean(axis=2, keepdims=True)).max(axis=2) > 40)  # not white/grey/black
    for i in range(3):  # one panel per mode, side by side
        panel = coloured[int(0.15 * h):, int(i * 0.92 * w / 3):int((i + 1) * 0.92 * w / 3)]
        assert panel.mean() > 0.02, i
