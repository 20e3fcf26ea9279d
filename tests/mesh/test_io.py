"""Mesh I/O: exact round trips, unit_scale, gmsh-written files, errors, atomic writes."""

from __future__ import annotations

import os
import re
import warnings

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
def _read_error(path, **kwargs) -> str:
    """The MeshError message of ``read(path)``: exactly MeshError, one line, naming the file, no warnings."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no RuntimeWarning cascade on the way to the error
        with pytest.raises(MeshError) as info:
            read(path, **kwargs)
    assert type(info.value) is MeshError
    text = str(info.value)
    assert "\n" not in text and os.path.basename(str(path)) in text, text
    return text


def test_missing_file(tmp_path):
    assert "not found" in _read_error(tmp_path / "nothere.msh")


def test_directory(tmp_path):
    (tmp_path / "folder.msh").mkdir()
    assert "is a directory" in _read_error(tmp_path / "folder.msh")


@pytest.mark.parametrize("name", ["zero.msh", "zero.vtu", "zero.xdmf", "zero.stl", "zero.vtk"])
def test_zero_byte_file(tmp_path, name):
    (tmp_path / name).write_bytes(b"")
    assert re.search(r"empty mesh file .*: it has 0 bytes", _read_error(tmp_path / name))


@pytest.mark.parametrize("name", ["m.foo", "m.txt", "mesh", "m.msh.bak"])
def test_unknown_extension(tmp_path, tagged, name):
    write(tagged, tmp_path / "m.msh")
    os.replace(tmp_path / "m.msh", tmp_path / name)  # a valid mesh, but under a name no reader claims
    text = _read_error(tmp_path / name)
    assert "not a mesh of a known format" in text
    listed = set(re.findall(r"\.[a-z0-9.]*[a-z0-9]", text.split("known extensions:")[1]))
    assert {".msh", ".vtu", ".xdmf", ".vtk", ".inp", ".med", ".stl"} <= listed


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("name, fmt", [("r.msh", "gmsh .msh"), ("r.vtu", "VTK XML .vtu"), ("r.xdmf", "XDMF")])
def test_random_binary_bytes(tmp_path, seed, name, fmt):
    path = tmp_path / name
    path.write_bytes(np.random.default_rng(seed).bytes(3000))
    text = _read_error(path)
    assert f"is not a valid {fmt} file" in text and "binary data" in text


def test_text_that_is_not_the_format(tmp_path):
    (tmp_path / "notes.msh").write_text("solid cube\nfacet normal 0 0 1\n")
    assert "does not begin with $MeshFormat" in _read_error(tmp_path / "notes.msh")
    (tmp_path / "old.msh").write_text("$NOD\n0\n$ENDNOD\n")
    assert "MSH 1 format, which is not supported" in _read_error(tmp_path / "old.msh")
    (tmp_path / "v3.msh").write_text("$MeshFormat\n3.0 0 8\n$EndMeshFormat\n")
    assert "version '3.0'" in _read_error(tmp_path / "v3.msh")
    (tmp_path / "image.vtu").write_text('<?xml version="1.0"?>\n<VTKFile type="ImageData" version="0.1">\n')
    assert "VTK ImageData file, not an UnstructuredGrid" in _read_error(tmp_path / "image.vtu")


def test_garbage_in_other_meshio_formats(tmp_path):
    path = tmp_path / "junk.stl"
    path.write_bytes(b"\x00\x01garbage\xff\xfe not a mesh\n" * 3)
    text = _read_error(path)
    assert "cannot read mesh file" in text and "as .stl (stl): corrupt, truncated or not in that format" in text


def test_empty_vtu(tmp_path):
    meshio.Mesh(np.zeros((0, 3)), []).write(tmp_path / "empty.vtu")
    assert re.search(r"empty mesh file .*empty\.vtu: it has no points", _read_error(tmp_path / "empty.vtu"))
    m = box((0.1, 0.1, 0.1), (1, 1, 1))
    meshio.Mesh(m.points, []).write(tmp_path / "points.vtu")
    assert "it has no cells" in _read_error(tmp_path / "points.vtu")


@pytest.mark.parametrize(
    "name, kwargs",
    [
        ("e22.msh", {"file_format": "gmsh22", "binary": False}),
        ("e41.msh", {"file_format": "gmsh", "binary": False}),
        ("e41b.msh", {"file_format": "gmsh", "binary": True}),
        ("e.xdmf", {}),
        ("e.vtu", {}),
        ("e.vtk", {}),
    ],
)
def test_mesh_without_points_or_cells(tmp_path, name, kwargs):
    path = tmp_path / name
    m = box((0.1, 0.1, 0.1), (1, 1, 1))
    no_tets = [] if name.endswith(".vtk") else [("tetra", np.zeros((0, 4), dtype=int))]  # meshio's vtk writer needs []
    meshio.write(path, meshio.Mesh(np.zeros((0, 3)), no_tets), **kwargs)
    assert re.search(r"empty mesh file .*: it has no points", _read_error(path))
    meshio.write(path, meshio.Mesh(m.points, no_tets), **kwargs)
    assert re.search(r"empty mesh file .*: it has (8 points but )?no cells", _read_error(path))


TRUNCATABLE = [
    ("t41.msh", {}, "gmsh MSH 4.1 binary"),
    ("t41a.msh", {"binary": False}, "gmsh MSH 4.1 ASCII"),
    ("t22.msh", {"msh_version": "2.2"}, "gmsh MSH 2.2 binary"),
    ("t22a.msh", {"msh_version": "2.2", "binary": False}, "gmsh MSH 2.2 ASCII"),
    ("t.vtu", {}, "VTK XML .vtu"),
    ("t.xdmf", {}, "XDMF"),
]


@pytest.mark.parametrize("name, kwargs, fmt", TRUNCATABLE)
def test_truncated_file(tmp_path, tagged, name, kwargs, fmt):
    """Cut a valid file at many places: always 'truncated <format>', with what was expected."""
    full = write(tagged, tmp_path / name, **kwargs).read_bytes()
    cut_file = tmp_path / f"cut_{name}"
    for fraction in np.linspace(0.02, 0.98, 25):
        cut_file.write_bytes(full[: int(len(full) * fraction)])
        text = _read_error(cut_file)
        assert text.startswith("truncated"), (fraction, text)
        assert fmt in text, (fraction, text)
        if name.endswith(".msh"):
            assert re.search(r"the \$(\w+) section has no \$End\1|it has no \$(Nodes|Elements) section", text), text
        else:
            assert "closing </" in text


@pytest.mark.parametrize("name, kwargs, fmt", TRUNCATABLE)
def test_damaged_files_only_ever_raise_one_line_mesh_errors(tmp_path, tagged, name, kwargs, fmt, capfd):
    """Bytes flipped, a chunk deleted, or random bytes after a cut: MeshError, one line, nothing else.

    (A flip may also leave a readable mesh, e.g. in a coordinate; that is not an error.)
    """
    full = write(tagged, tmp_path / name, **kwargs).read_bytes()
    rng = np.random.default_rng(7)
    path = tmp_path / f"damaged_{name}"
    for trial in range(30):
        data = bytearray(full)
        if trial % 3 == 0:
            for i in rng.integers(0, len(data), size=3):
                data[i] = int(rng.integers(0, 256))
        elif trial % 3 == 1:
            start = int(rng.integers(0, len(data)))
            del data[start : start + int(rng.integers(1, 200))]
        else:
            data = data[: int(rng.integers(0, len(data)))] + rng.bytes(int(rng.integers(1, 500)))
        path.write_bytes(bytes(data))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                read(path)
            except MeshError as exc:
                assert "\n" not in str(exc) and path.name in str(exc), str(exc)
    assert capfd.readouterr() == ("", "")  # meshio's own "Warning: ..." prints are not let through


def test_truncated_gmsh_written_file(tmp_path):
    """A file written by gmsh itself (not modalfem), cut after its nodes."""
    path = tmp_path / "g.msh"
    _gmsh_box_file(path, 4.1)
    full = path.read_bytes()
    path.write_bytes(full[: full.index(b"$Elements")])
    assert "has no $Elements section" in _read_error(path, unit_scale=1e-3)


def test_corrupt_msh_content(tmp_path, tagged):
    """Complete sections with a damaged number: 'corrupt', not truncated, never a raw exception."""
    text = write(tagged, tmp_path / "c.msh", msh_version="2.2", binary=False).read_text()
    head, nodes = text.split("$Nodes\n", 1)
    count, first, rest = nodes.split("\n", 2)
    (tmp_path / "c.msh").write_text(head + "$Nodes\n" + count + "\n" + "1 0.0 abc\n" + rest)
    text = _read_error(tmp_path / "c.msh")
    assert re.match(r"corrupt gmsh MSH 2\.2 ASCII file .*c\.msh: its sections are complete", text)


def test_meshio_errors_inside_conversion_become_mesh_errors(tmp_path, monkeypatch):
    m = box((0.1, 0.1, 0.1), (1, 1, 1))
    write(m, tmp_path / "ok.vtu")

    def broken(*args):
        raise IndexError("list index out of range")

    monkeypatch.setattr(mio, "_tags_from_meshio", broken)
    assert "do not fit together" in _read_error(tmp_path / "ok.vtu")


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


# ---------------------------------------------------------------------- size / unit warning
def test_part_in_millimetres_warns_once_with_the_fix(tmp_path):
    path = write(box((300.0, 20.0, 10.0), (3, 1, 1)), tmp_path / "bracket_mm.vtu")  # a 300 mm part, file in mm
    with pytest.warns(mio.UnitWarning) as record:
        m = read(path)
    assert len(record) == 1
    text = str(record[0].message)
    assert "\n" not in text and "bracket_mm.vtu" in text
    assert "301 m across" in text  # sqrt(300^2 + 20^2 + 10^2) = 300.8
    assert "millimetres" in text and "unit_scale=0.001" in text and "--unit-scale 0.001" in text
    assert issubclass(mio.UnitWarning, UserWarning)
    assert record[0].filename == __file__  # points at the caller of read(), not at modalfem
    np.testing.assert_array_equal(m.points, box((300.0, 20.0, 10.0), (3, 1, 1)).points)  # still read as given


@pytest.mark.parametrize(
    "size, unit_scale, suggestion",
    [
        ((3e5, 2e4, 1e4), 1.0, "micrometres, pass unit_scale=1e-06"),  # 0.3 m part in micrometres
        ((300.0, 20.0, 10.0), 1e-3, None),  # the right scale: no warning
        ((0.05, 0.02, 0.01), 1e-3, "if the file is in metres, drop unit_scale (CLI: --unit-scale 1)"),
        ((5e4, 2e3, 1e3), 1e-3, "micrometres, pass unit_scale=1e-06"),  # 50 mm part in um, read as mm
        ((1e13, 5e12, 5e12), 1.0, "check the file's unit"),  # nothing plausible fits
    ],
)
def test_unit_suggestion(tmp_path, size, unit_scale, suggestion):
    path = write(box(size, (2, 1, 1)), tmp_path / "part.vtu")
    if suggestion is None:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            read(path, unit_scale=unit_scale)
        return
    with pytest.warns(mio.UnitWarning, match=re.escape(suggestion)):
        read(path, unit_scale=unit_scale)


@pytest.mark.parametrize("name", ["m.msh", "m.vtu", "m.xdmf"])
@pytest.mark.parametrize(
    "size", [(0.3, 0.2, 0.1), (1.0, 0.05, 0.05), (40.0, 25.0, 10.0), (1e-4, 5e-5, 5e-5), (2e-3, 1e-3, 1e-3)]
)
def test_plausible_bodies_read_without_any_warning(tmp_path, name, size):
    """Bodies from a 0.1 mm part to a 48 m structure: no warning at all (errors on any warning)."""
    path = write(box(size, (2, 1, 1)), tmp_path / name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read(path)


@pytest.mark.parametrize(
    "length, warns",
    [(49.9, False), (50.1, True), (1.1e-4, False), (0.9e-4, True)],  # rods of thickness length/1000
)
def test_thresholds_are_50_m_and_1e_4_m(tmp_path, length, warns):
    """The bounding-box diagonal (~ the length here, within 1e-6) is compared with 50 m and 1e-4 m."""
    path = write(box((length, length * 1e-3, length * 1e-3), (2, 1, 1)), tmp_path / "rod.vtu")
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        read(path)
    assert [w.category for w in record] == ([mio.UnitWarning] if warns else [])
