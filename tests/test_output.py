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


def test_xdmf_is_one_self_contained_xml_file(p2_result, tmp_path):
    mesh, res = p2_result
    path = write_modes(tmp_path / "m.xdmf", mesh, res)
    root = ET.parse(path).getroot()
    topo = root.find(".//Topology")
    assert topo.get("TopologyType") == "Tetrahedron_10"
    names = {a.get("Name") for a in root.iter("Attribute")}
    assert {"mode_01", "|mode_03|"} <= names
    assert not list(tmp_path.glob("*.h5"))


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
