"""Constraint masks: tags (with P2 midpoints), predicates, rollers, and every malformed input."""

import numpy as np
import pytest

from modalfem.constraints import Fix, fixed_mask
from modalfem.errors import ConstraintError


def _held_nodes(mask, comp=None):
    m = mask.reshape(-1, 3)
    return np.flatnonzero(m.any(axis=1) if comp is None else m[:, comp])


@pytest.mark.parametrize("degree", [1, 2])
def test_tag_fixes_all_nodes_on_the_face(beam, degree):
    mask = fixed_mask(beam, degree, "x0")
    pts = beam.dof_points(degree)
    on_face = np.isclose(pts[:, 0], 0.0)
    assert mask.shape == (3 * beam.node_count(degree),) and mask.dtype == bool
    np.testing.assert_array_equal(mask.reshape(-1, 3), np.repeat(on_face[:, None], 3, axis=1))
    if degree == 2:  # edge midpoints on the face are held too
        assert np.any(on_face[beam.point_count :])


def test_predicate_equals_tag(beam):
    np.testing.assert_array_equal(fixed_mask(beam, 2, lambda p: p[:, 0] < 1e-9), fixed_mask(beam, 2, "x0"))


def test_roller_and_union(plate):
    mask = fixed_mask(plate, 2, [Fix("z0", components="z"), Fix("x0", components="yx")])
    m = mask.reshape(-1, 3)
    pts = plate.dof_points(2)
    np.testing.assert_array_equal(m[:, 2], np.isclose(pts[:, 2], 0.0))
    np.testing.assert_array_equal(m[:, 0], np.isclose(pts[:, 0], 0.0))
    np.testing.assert_array_equal(m[:, 0], m[:, 1])


def test_none_and_empty_list_fix_nothing(cube):
    assert not fixed_mask(cube, 1, None).any()
    assert not fixed_mask(cube, 1, []).any()


def test_unknown_tag_lists_known_tags(cube):
    with pytest.raises(ConstraintError, match=r"unknown tag 'left'.*x0, x1"):
        fixed_mask(cube, 2, "left")


@pytest.mark.parametrize(
    "pred, match",
    [
        (lambda p: p[:, 0] < 0, "selects no nodes"),
        (lambda p: True, r"shape \(\)"),
        (lambda p: p[:, :2] < 1, r"shape \(\d+, 2\)"),
        (lambda p: p[:, 0], "dtype float64"),
        (lambda p: None, "dtype object"),
        (lambda p: 1 / 0, "ZeroDivisionError"),
    ],
)
def test_bad_predicates_raise_one_clear_error(cube, pred, match):
    with pytest.raises(ConstraintError, match=match):
        fixed_mask(cube, 2, pred)


def test_integer_zero_one_mask_is_accepted(cube):
    np.testing.assert_array_equal(
        fixed_mask(cube, 1, lambda p: (p[:, 2] < 1e-9).astype(int)), fixed_mask(cube, 1, "z0")
    )


@pytest.mark.parametrize("components", ["", "xw", "xx", 3])
def test_bad_components(components):
    with pytest.raises(ConstraintError, match="components"):
        Fix("x0", components=components)


def test_bad_where_and_bad_fixed_types(cube):
    with pytest.raises(ConstraintError, match="tag name or a predicate"):
        Fix(3)
    with pytest.raises(ConstraintError, match="fixed must be"):
        fixed_mask(cube, 1, 3.5)
    with pytest.raises(ConstraintError, match="fixed entries"):
        fixed_mask(cube, 1, ["x0", 7])


def test_empty_tag_selects_nothing(make_box):
    import numpy as np

    from modalfem.mesh.core import Mesh

    m = make_box((0.1, 0.1, 0.1), (1, 1, 1))
    m2 = Mesh(m.points, m.cells, {"hole": np.zeros((0, 3), dtype=int)})
    with pytest.raises(ConstraintError, match="hole.*selects no nodes"):
        fixed_mask(m2, 1, "hole")
