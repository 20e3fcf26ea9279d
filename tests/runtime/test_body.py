"""Reconstruction of the surface (positions and normals) and surface points."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.errors import InputError, SimulationError
from modalfem.runtime import ModalBody, State
from modalfem.runtime.rotation import quat_from_axis_angle, quat_to_matrix


def _state(body, rng):
    q = quat_from_axis_angle(np.array([1.0, 2.0, -0.5]) / np.sqrt(5.25), 0.9)
    return State(rng.normal(size=body.mode_count) * 1e-3, np.zeros(body.mode_count),
                 position=(0.3, -0.2, 1.1), orientation=q)


def test_positions_are_c_plus_R_times_rest_plus_shapes_q(small_body, small_model):
    rng = np.random.default_rng(0)
    st = _state(small_body, rng)
    R = quat_to_matrix(st.orientation)
    x = small_body.positions(st)
    for i in range(0, small_model.vertex_count, 5):  # vertex by vertex, from the model arrays
        u = small_model.shapes[3 * i : 3 * i + 3] @ st.q
        expect = st.position + R @ (small_model.vertices[i] - small_model.center_of_mass + u)
        assert np.allclose(x[i], expect, rtol=0, atol=1e-14)
    out = np.empty_like(x)
    assert small_body.positions(st, out=out) is out and np.array_equal(out, x)


def test_float32_reconstruction_agrees_to_single_precision(small_model):
    rng = np.random.default_rng(1)
    b64, b32 = ModalBody(small_model, dtype=np.float64), ModalBody(small_model)  # float32 is the default
    st = _state(b64, rng)
    x64, x32 = b64.positions(st), b32.positions(st)
    assert x32.dtype == np.float32 and np.allclose(x32, x64, rtol=0, atol=1e-6 * np.abs(x64).max())
    # precise: only the deformation carries the float32 rounding of the shapes
    xp = b32.positions(st, precise=True)
    u = (x64 - st.position) @ st.rotation() - b64.rest  # body-axes deformation
    assert xp.dtype == np.float64
    assert np.abs(xp - x64).max() <= 1e-6 * np.abs(u).max() + 1e-15 * np.abs(x64).max()
    assert np.abs(xp - x64).max() < np.abs(x32 - x64).max()


def test_normals_are_outward_unit_and_face_normals_on_flat_faces(small_body, small_model):
    st = State.rest(small_body, position=(0, 0, 0))
    x = small_body.positions(st)
    n = small_body.normals(x)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", n, x - st.position) > 0)  # convex body: outward
    lo, hi = x.min(axis=0), x.max(axis=0)
    on_face = np.isclose(x, lo) | np.isclose(x, hi)
    interior = on_face.sum(axis=1) == 1  # on exactly one face: not on an edge
    axis = np.argmax(on_face[interior], axis=1)
    sign = np.where(np.isclose(x[interior], hi)[np.arange(interior.sum()), axis], 1.0, -1.0)
    expect = np.zeros((interior.sum(), 3))
    expect[np.arange(len(axis)), axis] = sign
    assert np.allclose(n[interior], expect, atol=1e-12)


def test_normals_rotate_with_the_body_and_follow_the_deformation(small_body):
    rng = np.random.default_rng(2)
    st = _state(small_body, rng)
    R = quat_to_matrix(st.orientation)
    n_world = small_body.normals(small_body.positions(st))
    n_body = small_body.normals(small_body.local_positions(st.q))
    assert np.allclose(n_world, n_body @ R.T, atol=1e-12)
    # a small deformation tilts the normals by a small amount, a large one by more
    n0 = small_body.normals(small_body.local_positions(np.zeros(small_body.mode_count)))
    tilt = [np.abs(small_body.normals(small_body.local_positions(s * st.q)) - n0).max() for s in (1.0, 10.0)]
    assert 0 < tilt[0] < tilt[1]


def test_surface_points_interpolate_the_vertices(small_body):
    tri = small_body.triangles[3]
    p = small_body.surface_point(3, (0.2, 0.3, 0.5))
    assert np.allclose(small_body.point_shapes(p), np.einsum("k,kcr->cr", [0.2, 0.3, 0.5],
                                                             small_body.shapes.reshape(-1, 3, small_body.mode_count)[tri]))
    v = small_body.surface_point(3, (1.0, 0.0, 0.0))
    assert np.allclose(small_body.point_shapes(v), small_body.point_shapes(int(tri[0])))
    assert np.allclose(small_body.point_rest(v), small_body.point_rest(int(tri[0])))


@pytest.mark.parametrize("tri,bary", [(10**6, (1 / 3, 1 / 3, 1 / 3)), (-1, (1 / 3, 1 / 3, 1 / 3)), (0, (0.5, 0.6, -0.1)),
                                      (0, (0.5, 0.5, 0.5)), (0, (np.nan, 0.5, 0.5)), (0, (1.0, 0.0))])
def test_points_off_the_surface_are_refused(small_body, tri, bary):
    with pytest.raises(SimulationError, match="surface|barycentric"):
        small_body.surface_point(tri, bary)


def test_vertex_index_off_the_surface_is_refused(small_body):
    with pytest.raises(SimulationError, match="off the surface"):
        small_body.point_shapes(small_body.vertex_count)


def test_segmented_and_scatter_normals_agree(small_body):
    """The sorted-corner (reduceat) path and the bincount fallback give the same normals."""
    st = _state(small_body, np.random.default_rng(3))
    x = small_body.positions(st)
    fast = small_body.normals(x)
    small_body._every_vertex_used = False
    assert np.allclose(small_body.normals(x), fast, rtol=0, atol=1e-14)


def test_locate_finds_the_surface_point_under_a_world_point(small_body):
    st = _state(small_body, np.random.default_rng(4))
    x = small_body.positions(st)
    tri = small_body.triangles[17]
    bary = np.array([0.2, 0.5, 0.3])
    target = bary @ x[tri]
    p = small_body.locate(st, target)
    assert np.allclose(np.asarray(p.barycentric) @ x[small_body.triangles[p.triangle]], target, atol=1e-12)
    assert np.allclose(st.position + st.rotation() @ small_body.point_local(p, st.q), target, atol=1e-12)
    corner = small_body.locate(st, x[5])
    assert np.allclose(np.asarray(corner.barycentric) @ x[small_body.triangles[corner.triangle]], x[5], atol=1e-12)


@pytest.mark.parametrize("where", [(0.0, 0.0, 5.0), (np.nan, 0.0, 0.0)])
def test_locate_refuses_points_off_the_surface(small_body, where):
    st = State.rest(small_body)
    with pytest.raises(SimulationError, match="off the surface|finite"):
        small_body.locate(st, where)


@pytest.mark.parametrize("nv", [1, 2, 3, 255, 256, 257, 513, 1001])
def test_rotate_translate_blocks_equal_the_plain_formula(nv):
    from modalfem.runtime.body import _rotate_translate

    rng = np.random.default_rng(nv)
    u = rng.standard_normal(3 * nv)
    Rt = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    c = rng.standard_normal(3)
    out = np.full((nv, 3), np.nan)
    _rotate_translate(u, Rt, c, out)
    np.testing.assert_allclose(out, u.reshape(-1, 3) @ Rt + c, rtol=0, atol=1e-14)


def test_positions_refuses_a_wrong_out_buffer(small_body):
    st = State.rest(small_body)
    with pytest.raises(InputError, match="C-contiguous"):
        small_body.positions(st, out=np.empty((small_body.vertex_count, 3), dtype=np.float32))
    with pytest.raises(InputError, match="C-contiguous"):
        small_body.positions(st, out=np.empty((3, small_body.vertex_count)).T)


def test_modal_normals_are_exact_at_rest_and_second_order_in_the_deformation(small_model):
    body = ModalBody(small_model, dtype=np.float64)
    rng = np.random.default_rng(5)
    st = _state(body, rng)
    q0 = rng.normal(size=body.mode_count)
    q0 *= 0.02 / np.abs(body.shapes @ q0).max()  # 2 cm peak displacement on a 0.2 m block
    errors = []
    for scale in (0.0, 1.0, 0.1):
        st.q[:] = scale * q0
        exact = body.normals(body.positions(st))
        modal = body.modal_normals(st)
        assert np.allclose(np.linalg.norm(modal, axis=1), 1.0)
        errors.append(np.abs(modal - exact).max())
    assert errors[0] < 1e-12  # rest normals, rotated into the world
    assert errors[1] > 1e-6  # the deformation is large enough to see the linearisation
    assert 50 < errors[1] / errors[2] < 200  # error ~ q^2: 10x smaller q, ~100x smaller error


def test_modal_normals_in_float32_match_float64(small_model):
    b64, b32 = ModalBody(small_model, dtype=np.float64), ModalBody(small_model)
    st = _state(b64, np.random.default_rng(6))
    n32 = b32.modal_normals(st)
    assert n32.dtype == np.float32 and np.abs(n32 - b64.modal_normals(st)).max() < 1e-5


def test_decayed_modes_are_left_out_so_no_product_is_subnormal(small_model):
    """A mode rung down to q ~ 1e-40 would make q_i * phi subnormal (slow arithmetic): such modes are
    dropped from the product (their displacement is below 1e-20 m); live modes are kept exactly."""
    from modalfem.runtime.body import NEGLIGIBLE, _coefficients

    for dtype in (np.float32, np.float64):
        body = ModalBody(small_model, dtype=dtype)
        st = State.rest(body)
        st.q[:] = 1e-40
        st.q[0] = 1e-3
        coef = _coefficients(st.q, body.shapes_t.dtype, body._row_scale)
        assert coef[0] == np.asarray(1e-3, dtype) and np.all(coef[1:-1] == 0) and coef[-1] == 1
        prod = coef[:, None] * body._basis
        tiny = np.finfo(dtype).tiny
        assert not np.any((prod != 0) & (np.abs(prod) < tiny))  # no subnormal product
        kept = ModalBody(small_model, dtype=np.float64)
        st.q[:] = 1e-3  # every mode alive: the flushed basis entries change nothing visible
        assert np.allclose(body.positions(st), kept.positions(st), rtol=0, atol=1e-6)
        assert NEGLIGIBLE <= 1e-20


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_body_frame_positions_and_normals_with_the_model_matrix_give_the_world_ones(small_model, dtype):
    """frame="body" is X + Phi q (no rigid motion), and model_matrix maps it to the world positions."""
    body = ModalBody(small_model, dtype=dtype)
    st = _state(body, np.random.default_rng(7))
    tol = 1e-13 if dtype == np.float64 else 1e-6
    xb = body.positions(st, frame="body")
    assert xb.dtype == dtype
    expect = (small_model.vertices - small_model.center_of_mass) + (small_model.shapes @ st.q).reshape(-1, 3)
    assert np.abs(xb - expect).max() <= tol * np.abs(expect).max()
    M = body.model_matrix(st)
    assert M.shape == (4, 4) and np.array_equal(M[3], [0, 0, 0, 1])
    world = xb.astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    x = body.positions(st)
    assert np.abs(world - x).max() <= 2 * tol * np.abs(x).max()
    out = np.empty_like(xb)
    assert body.positions(st, out=out, frame="body") is out and np.array_equal(out, xb)
    # the rigid motion does not enter the body frame
    moved = State(st.q.copy(), st.qdot.copy(), position=(-4.0, 2.0, 0.5), orientation=(0.0, 1.0, 0.0, 0.0))
    assert np.array_equal(body.positions(moved, frame="body"), xb)
    precise = body.positions(st, precise=True, frame="body")
    assert precise.dtype == np.float64 and np.abs(precise - expect).max() <= tol * np.abs(expect).max()
    nb = body.modal_normals(st, frame="body")
    assert np.abs(nb.astype(np.float64) @ M[:3, :3].T - body.modal_normals(st)).max() <= 10 * tol


def test_an_unknown_frame_is_refused(small_body):
    st = State.rest(small_body)
    with pytest.raises(InputError, match="frame"):
        small_body.positions(st, frame="camera")
    with pytest.raises(InputError, match="frame"):
        small_body.modal_normals(st, frame="local")
