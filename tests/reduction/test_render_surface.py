"""Render surfaces: OBJ/STL/PLY/OFF reading with units, refusals in one line, consistent outward orientation."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from modalfem.errors import MeshError
from modalfem.mesh import box
from modalfem.mesh.surface import boundary_surface
from modalfem.reduction.render_surface import orient_outward, read_surface


@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "off"])
def test_read_surface_formats_units_and_orientation(tmp_path, ext):
    m = box(size=(0.3, 0.2, 0.1), cells=(2, 1, 1))
    bs = boundary_surface(m)
    path = tmp_path / f"s.{ext}"
    meshio.write(path, meshio.Mesh(bs.vertices * 1000.0, [("triangle", bs.triangles[:, ::-1])]))  # mm, inward
    s = read_surface(path, unit_scale=1e-3)
    assert len(s.triangles) == len(bs.triangles) and s.source["flipped_triangles"] == len(bs.triangles)
    p = s.vertices[s.triangles]
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    np.testing.assert_allclose(vol, 0.3 * 0.2 * 0.1, rtol=1e-6)


def test_read_surface_refuses_what_is_not_a_triangle_surface(tmp_path):
    quad = tmp_path / "q.obj"
    quad.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    with pytest.raises(MeshError, match=r"no triangles \(quad x 1\)"):
        read_surface(quad)
    (tmp_path / "x.vtu").write_text("<VTKFile/>")
    with pytest.raises(MeshError, match="unknown extension '.vtu'"):
        read_surface(tmp_path / "x.vtu")
    empty = tmp_path / "e.stl"
    empty.write_text("solid e\nendsolid e\n")
    with pytest.raises(MeshError, match="has no triangles|cannot be read"):
        read_surface(empty)
    with pytest.raises(MeshError, match="does not exist"):
        read_surface(tmp_path / "missing.stl")
    bad = tmp_path / "b.ply"
    bad.write_bytes(b"ply\nformat nonsense\n\x00\x01")
    with pytest.raises(MeshError, match="cannot be read"):
        read_surface(bad)


def test_orient_outward_makes_every_piece_consistent_and_outward():
    a = boundary_surface(box(size=(0.3, 0.2, 0.1), cells=(3, 2, 1)))
    b = boundary_surface(box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1), origin=(1.0, 0.0, 0.0)))
    v = np.vstack([a.vertices, b.vertices])
    t = np.vstack([a.triangles, b.triangles + len(a.vertices)])  # two pieces, both outward
    scrambled = t.copy()
    flip = np.random.default_rng(3).random(len(t)) < 0.4
    scrambled[flip] = scrambled[flip][:, ::-1]
    scrambled[len(a.triangles):] = scrambled[len(a.triangles):, ::-1]  # and the second piece mostly inward
    out, flipped = orient_outward(v, scrambled)
    np.testing.assert_array_equal(out, t)
    assert flipped == int(np.sum(np.any(scrambled != t, axis=1)))


def test_orient_outward_with_repeated_vertices_and_an_open_sheet():
    a = boundary_surface(box(size=(0.3, 0.2, 0.1), cells=(3, 2, 1)))
    v = a.vertices[a.triangles].reshape(-1, 3)  # every face with its own three vertices (flat-shaded export)
    t = np.arange(len(v)).reshape(-1, 3)
    scrambled = t.copy()
    flip = np.random.default_rng(4).random(len(t)) < 0.3
    scrambled[flip] = scrambled[flip][:, ::-1]
    out, flipped = orient_outward(v, scrambled)
    np.testing.assert_array_equal(out, t)
    assert flipped == int(flip.sum())
    sheet = a.triangles[np.all(a.vertices[a.triangles][:, :, 2] == 0.0, axis=1)]  # the open z = 0 face
    mixed = sheet.copy()
    mixed[:2] = mixed[:2, ::-1]  # a minority reversed: the file's majority orientation is kept
    out, flipped = orient_outward(a.vertices, mixed)
    np.testing.assert_array_equal(out, sheet)
    assert flipped == 2
