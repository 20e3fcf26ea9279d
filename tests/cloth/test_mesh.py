"""ClothMesh: grid generator, meshio reading, validation of bad meshes, lumped masses."""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from modalfem.cloth.mesh import ClothMesh, grid, read_cloth
from modalfem.errors import InputError, MeshError


def test_grid_counts_area_and_hinges():
    m = grid((0.6, 0.4), (7, 5))
    assert m.point_count == 35 and m.triangle_count == 2 * 6 * 4
    assert np.isclose(m.areas.sum(), 0.24)
    # Euler: edges = V + F - 1 for a disc; interior edges = edges - boundary edges
    n_edges = len(m.edges)
    assert n_edges == m.point_count + m.triangle_count - 1
    assert len(m.hinges.vertices) == n_edges - 2 * (6 + 4)
    assert len(m.boundary_vertices) == 2 * (7 + 5) - 4


def test_grid_planes_and_bad_arguments():
    assert np.allclose(grid((1, 2), (3, 3), plane="xz").points[:, 1], 0.0)
    with pytest.raises(InputError, match="plane"):
        grid(plane="ab")
    with pytest.raises(InputError, match="size"):
        grid((0.0, 1.0))
    with pytest.raises(InputError, match="vertex counts"):
        grid((1, 1), (1, 4))


def test_hinge_opposite_vertices_are_in_the_two_triangles():
    m = grid((1, 1), (4, 4))
    tris = {tuple(sorted(t)) for t in m.triangles.tolist()}
    for e0, e1, a, b in m.hinges.vertices.tolist():
        assert tuple(sorted((e0, e1, a))) in tris and tuple(sorted((e0, e1, b))) in tris and a != b


def test_lumped_masses_sum_to_total_and_reject_zero_density():
    m = grid((0.5, 0.5), (5, 5))
    assert np.isclose(m.lumped_masses(0.2).sum(), 0.2 * 0.25)
    with pytest.raises(InputError, match="areal density"):
        m.lumped_masses(0.0)


def test_non_manifold_edge_is_rejected():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    with pytest.raises(MeshError, match="non-manifold: edge \\[0, 1\\] is shared by 3"):
        ClothMesh(pts, [[0, 1, 2], [1, 0, 3], [0, 1, 4]])


def test_degenerate_repeated_duplicate_and_out_of_range_triangles():
    pts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    with pytest.raises(MeshError, match="degenerate"):
        ClothMesh(pts, [[0, 1, 2]])
    with pytest.raises(MeshError, match="repeats a vertex"):
        ClothMesh(pts, [[0, 1, 1]])
    with pytest.raises(MeshError, match="more than once"):
        ClothMesh(pts, [[0, 1, 3], [3, 1, 0]])
    with pytest.raises(MeshError, match="missing point"):
        ClothMesh(pts, [[0, 1, 9]])
    with pytest.raises(MeshError, match="NaN"):
        ClothMesh(np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), [[0, 1, 2]])


def test_read_cloth_round_trip_with_unit_scale(tmp_path):
    m = grid((0.3, 0.2), (4, 3))
    path = tmp_path / "sheet.obj"
    meshio.write(path, meshio.Mesh(m.points * 1000.0, [("triangle", m.triangles)]))
    r = read_cloth(path, unit_scale=1e-3)
    assert np.allclose(r.points, m.points) and np.array_equal(r.triangles, m.triangles)
    with pytest.raises(InputError, match="not found"):
        read_cloth(tmp_path / "nope.obj")
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not an obj file\n")
    with pytest.raises(MeshError):
        read_cloth(bad)
