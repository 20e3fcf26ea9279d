"""Quality checks of ``Mesh``: each rejection names the problem; unused points; pieces."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.errors import MeshError
from modalfem.mesh.core import Mesh
from modalfem.mesh.generators import box

UNIT_TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)


def two_tets():
    points = np.vstack([UNIT_TET, [[1.0, 1.0, 1.0]]])
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    return points, cells


def test_two_tets_fixture_is_valid():
    points, cells = two_tets()
    mesh = Mesh(points, cells)
    assert mesh.cell_count == 2 and np.all(mesh.volumes > 0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinate_rejected(bad):
    points, cells = two_tets()
    points[4, 1] = bad
    with pytest.raises(MeshError, match=r"NaN/inf.*point 4"):
        Mesh(points, cells)


def test_inverted_cell_is_named():
    points, cells = two_tets()
    cells[1] = cells[1][[0, 2, 1, 3]]
    with pytest.raises(MeshError, match=r"inverted \(first: cell 1,"):
        Mesh(points, cells)


def test_zero_volume_cell_is_named():
    points = np.vstack([UNIT_TET, [[0.5, 0.5, 0.0]]])  # point 4 lies in the plane z = 0
    cells = np.array([[0, 1, 2, 3], [0, 1, 2, 4]])
    with pytest.raises(MeshError, match=r"zero volume \(first: cell 1,"):
        Mesh(points, cells)


def test_cell_referencing_missing_point():
    points, cells = two_tets()
    cells[1, 2] = 7
    with pytest.raises(MeshError, match=r"cell 1 references a missing point"):
        Mesh(points, cells)


@pytest.mark.parametrize(
    "points, cells", [(np.zeros((0, 3)), np.zeros((0, 4), int)), (UNIT_TET, np.zeros((0, 4), int))]
)
def test_empty_mesh_rejected(points, cells):
    with pytest.raises(MeshError, match="empty"):
        Mesh(points, cells)


def test_wrong_shapes_rejected():
    with pytest.raises(MeshError, match=r"\(n, 3\)"):
        Mesh(UNIT_TET[:, :2], [[0, 1, 2, 3]])
    with pytest.raises(MeshError, match="tetrahedra"):
        Mesh(UNIT_TET, [[0, 1, 2]])


def test_unused_points_dropped_and_renumbered():
    points, cells = two_tets()
    # put an unused point first, so that every index must shift by one
    padded = np.vstack([[[9.0, 9.0, 9.0]], points, [[5.0, 5.0, 5.0]]])
    tags = {"bottom": np.array([[1, 3, 2]])}
    mesh = Mesh(padded, cells + 1, tags)
    ref = Mesh(points, cells, {"bottom": np.array([[0, 2, 1]])})
    assert mesh.dropped_point_count == 2
    assert mesh.fingerprint == ref.fingerprint
    assert mesh.volume == pytest.approx(ref.volume)


def test_tag_on_unused_point_rejected():
    points, cells = two_tets()
    padded = np.vstack([points, [[5.0, 5.0, 5.0]]])
    with pytest.raises(MeshError, match="tag 'bad'"):
        Mesh(padded, cells, {"bad": np.array([[0, 1, 5]])})


def test_disconnected_pieces_counted():
    a = box((0.1, 0.1, 0.1), (2, 2, 2))
    b = box((0.1, 0.1, 0.1), (1, 2, 3), origin=(0.5, 0.0, 0.0))
    both = Mesh(np.vstack([a.points, b.points]), np.vstack([a.cells, b.cells + a.point_count]))
    assert a.piece_count == 1 and b.piece_count == 1
    assert both.piece_count == 2
    assert np.bincount(both.point_piece).tolist() == [a.point_count, b.point_count]
