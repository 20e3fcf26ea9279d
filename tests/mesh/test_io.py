"""Mesh I/O: exact round trips, unit_scale, gmsh-written files, errors, atomic writes."""

from __future__ import annotations

import os

import meshio
import numpy as np
import pytest

from modalfem.errors import InputError, MeshError
from modalfem.mesh import io as mio
from modalfem.mesh import read, write
from modalfem.mesh.core import Mesh
from modalfem.mesh.generators import box


@pytest.fixture(scope="module")
def tagged():
    """A box with the generator tags, an empty tag, a reversed copy of ``x0`` and a tag ``domain``."""
    m = box((0.3, 0.2, 0.1), (3, 2, 2), origin=(0.1, -0.2, 0.3))
    tags = {**m.tags, "empty": np.zeros((0, 3), dtype=np.int64), "x0 reversed": m.tags["x0"][::-1]}
    tags["domain"] = m.tags["y1"]  # the name .msh files give the volume group by default
    # irrational-looking coordinates, so that text formats must carry all digits
    return Mesh(m.points * (1 + 1 / 3), m.cells, tags)


FORMATS = [
    ("m41.msh", {}),
    ("m22.msh", {"msh_version": "2.2"}),
    ("m.vtu", {}),
    ("m.xdmf", {}),
]


@pytest.mark.parametrize("name, kwargs", FORMATS)
def test_round_trip_is_exact(tmp_path, tagged, name, kwargs):
    path = write(tagged, tmp_path / name, **kwargs)
    assert path == tmp_path / name
    back = read(path)
    assert sorted(back.tags) == sorted(tagged.tags)
    np.testing.assert_array_equal(back.points, tagged.points)
    np.testing.assert_array_equal(back.cells, tagged.cells)
    for k in tagged.tags:
        np.testing.assert_array_equal(back.tags[k], tagged.tags[k], err_msg=k)
    assert back.fingerprint == tagged.fingerprint
    assert sorted(os.listdir(tmp_path)) == [name]  # one self-contained file, no temporaries, no .h5


def test_ascii_msh_round_trip_to_16_digits(tmp_path, tagged):
    back = read(write(tagged, tmp_path / "a.msh", binary=False))
    np.testing.assert_allclose(back.points, tagged.points, rtol=1e-15, atol=1e-16)
    np.testing.assert_array_equal(back.cells, tagged.cells)
    assert {k: v.tolist() for k, v in back.tags.items()} == {k: v.tolist() for k, v in tagged.tags.items()}


@pytest.mark.parametrize("name", ["n.msh", "n.vtu", "n.xdmf"])
def test_boundary_tag_added_when_missing(tmp_path, name):
    m = box((0.1, 0.1, 0.1), (1, 1, 2))
    bare = Mesh(m.points, m.cells, {"x0": m.tags["x0"]})
    back = read(write(bare, tmp_path / name))
    assert sorted(back.tags) == ["boundary", "x0"]
    np.testing.assert_array_equal(back.tags["boundary"], bare.boundary_facets)
    np.testing.assert_array_equal(back.tags["x0"], bare.tags["x0"])


def test_unit_scale(tmp_path):
    mm = box((300.0, 20.0, 10.0), (3, 1, 1))  # a file in millimetres
    path = write(mm, tmp_path / "mm.vtu")
    m = read(path, unit_scale=1e-3)
    np.testing.assert_allclose(m.points, mm.points * 1e-3, rtol=1e-15)
    assert m.volume == pytest.approx(0.3 * 0.02 * 0.01, rel=1e-12)


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "mm", None, True])
def test_bad_unit_scale(tmp_path, bad):
    with pytest.raises(InputError, match="unit_scale"):
        read(tmp_path / "whatever.msh", unit_scale=bad)


def _gmsh_box_file(path, version, *, mm=True):
    """A file written by gmsh itself: OCC box, physical groups (one face in two groups, one unnamed)."""
    import gmsh

    s = 1000.0 if mm else 1.0
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.05 * s)
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.model.occ.addBox(0, 0, 0, 0.2 * s, 0.1 * s, 0.1 * s)
        gmsh.model.occ.synchronize()
        faces = {}
        for _, tag in gmsh.model.getEntities(2):
            bb = gmsh.model.getBoundingBox(2, tag)
            if bb[3] - bb[0] < 1e-6 * s:
                faces["left" if bb[0] < 1e-6 * s else "right"] = tag
        gmsh.model.addPhysicalGroup(2, [faces["left"]], 1)
        gmsh.model.setPhysicalName(2, 1, "left")
        gmsh.model.addPhysicalGroup(2, [faces["right"]], 7)  # unnamed
        gmsh.model.addPhysicalGroup(3, [1], 2)
        gmsh.model.setPhysicalName(3, 2, "steel")
        if version > 4:  # a face in two groups (msh 2.2 stores one group per element)
            gmsh.model.addPhysicalGroup(2, [faces["left"]], 3)
            gmsh.model.setPhysicalName(2, 3, "clamp")
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("version", [4.1, 2.2])
def test_read_gmsh_written_file(tmp_path, version):
    path = tmp_path / "g.msh"
    _gmsh_box_file(path, version)
    m = read(path, unit_scale=1e-3)
    assert m.volume == pytest.approx(0.2 * 0.1 * 0.1, rel=1e-9)
    expected = {"left", "tag_7", "boundary"} | ({"clamp"} if version > 4 else set())
    assert set(m.tags) == expected
    for name in ("left", "tag_7"):
        p = m.points[m.tags[name]]
        a = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
        assert a == pytest.approx(0.01, rel=1e-9)
    np.testing.assert_allclose(m.points[m.tag_points("left"), 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(m.points[m.tag_points("tag_7"), 0], 0.2, rtol=1e-12)
    if version > 4:
        assert facet_set(m.tags["clamp"]) == facet_set(m.tags["left"])


def facet_set(f):
    return {tuple(sorted(t)) for t in f.tolist()}


def test_second_order_tets_read_by_corners(tmp_path):
    m = box((0.2, 0.1, 0.1), (2, 1, 1))
    e = m.cell_edges  # local edge order (01, 02, 03, 12, 13, 23)
    mid = m.point_count + e[:, [0, 3, 1, 2, 4, 5]]  # meshio tetra10 order: 01, 12, 02, 03, 13, 23
    tet10 = np.hstack([m.cells, mid])
    mm = meshio.Mesh(m.dof_points(2), [("tetra10", tet10)])
    mm.write(tmp_path / "q.vtu")
    back = read(tmp_path / "q.vtu")
    np.testing.assert_array_equal(back.points, m.points)
    np.testing.assert_array_equal(back.cells, m.cells)


# ---------------------------------------------------------------------- errors
def test_missing_file(tmp_path):
    with pytest.raises(MeshError, match=r"not found: .*nothere\.msh"):
        read(tmp_path / "nothere.msh")


@pytest.mark.parametrize("name", ["junk.msh", "junk.vtu", "junk.xdmf", "junk.stl"])
def test_garbage_file(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"\x00\x01garbage\xff\xfe not a mesh\n" * 3)
    with pytest.raises(MeshError, match=rf"cannot read mesh file .*{name}"):
        read(path)


def test_truncated_msh(tmp_path, tagged):
    path = write(tagged, tmp_path / "t.msh", binary=False)
    text = path.read_bytes()
    path.write_bytes(text[: len(text) // 2])
    with pytest.raises(MeshError, match=r"t\.msh"):
        read(path)


def test_file_without_tetrahedra(tmp_path):
    m = box((0.1, 0.1, 0.1), (1, 1, 1))
    meshio.Mesh(m.points, [("triangle", m.boundary_facets)]).write(tmp_path / "surface.vtu")
    with pytest.raises(MeshError, match=r"surface\.vtu: no tetrahedra.*triangle x 12"):
        read(tmp_path / "surface.vtu")


def test_quality_failure_names_file(tmp_path):
    m = box((0.1, 0.1, 0.1), (1, 1, 1))
    cells = np.array(m.cells)
    cells[2] = cells[2][[1, 0, 2, 3]]
    meshio.Mesh(m.points, [("tetra", cells)]).write(tmp_path / "inv.vtu")
    with pytest.raises(MeshError, match=r"inv\.vtu: .*inverted \(first: cell 2"):
        read(tmp_path / "inv.vtu")


@pytest.mark.parametrize(
    "target, match", [("m.stl", "unsupported suffix"), ("nodir/m.msh", "does not exist")]
)
def test_write_bad_target(tmp_path, tagged, target, match):
    with pytest.raises(InputError, match=match):
        write(tagged, tmp_path / target)


def test_write_bad_arguments(tmp_path, tagged):
    with pytest.raises(InputError, match="msh_version"):
        write(tagged, tmp_path / "m.msh", msh_version="3.0")
    with pytest.raises(InputError, match="Mesh"):
        write("not a mesh", tmp_path / "m.msh")
    bad = Mesh(tagged.points, tagged.cells, {'say "hi"': tagged.tags["x0"]})
    with pytest.raises(InputError, match="tag name"):
        write(bad, tmp_path / "m.msh")
    assert os.listdir(tmp_path) == []


def test_write_is_atomic(tmp_path, tagged, monkeypatch):
    path = write(tagged, tmp_path / "m.vtu")
    before = path.read_bytes()

    def broken(*args, **kwargs):
        with open(args[1], "wb") as f:
            f.write(b"half a file")
        raise OSError("disk full")

    monkeypatch.setattr(mio, "_write_meshio", broken)
    with pytest.raises(MeshError, match=r"cannot write mesh file .*m\.vtu: OSError: disk full"):
        write(tagged, path)
    assert path.read_bytes() == before  # the old file is untouched
    assert os.listdir(tmp_path) == ["m.vtu"]  # and the temporary is gone
