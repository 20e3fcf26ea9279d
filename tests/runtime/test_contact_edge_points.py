"""Box-edge contacts of a modal body (``contact.find_contacts`` -> ``_contact_edge_kernels.edge_contacts``): where a
box's edge passes under a body face, the contact is a barycentric point of that face against the plane through the
edge point with the face's normal reversed. Checked here: the points found lie on the face over the edge, the rows
of a point are the weighted sum of its face vertices' rows (analytic) and its normal velocity is the rate of its gap
(finite differences of the free motion), and a body with no box among its obstacles never searches."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
import modalfem.runtime.contact as C
from modalfem.runtime.rotation import quat_from_axis_angle

G = 9.81  # [m/s^2]
HALF = (0.05, 0.03, 0.05)  # [m] the narrow box: the block's rows y = +-0.05 m are beyond its sides y = +-0.03 m


def _across(body, *, moving=False):
    """The solver and a state of the body lying across the narrow box (top at z = 0), 1e-6 m above it; with
    ``moving``, turning, moving and ringing (every term of a point's velocity at work)."""
    box = rt.Box((0.0, 0.0, -HALF[2]), HALF)
    solver = rt.ModalSolver(body, effects=[rt.Gravity((0, 0, -G)), rt.Obstacles([box], friction=0.5)])
    st = solver.state(orientation=quat_from_axis_angle((0.3, 0.2, 1.0), 0.01))
    st.position[:] = 0.0  # centred over the box
    if moving:
        st.velocity[:] = (0.02, -0.01, -0.03)
        st.angular_momentum[:] = st.rotation() @ (body.inertia @ np.array([0.2, -0.3, 0.1]))
        st.q[:] = 1e-6 * np.linspace(1.0, -0.5, body.mode_count)
        st.qdot[:] = 1e-3 * np.linspace(0.5, 1.0, body.mode_count)
    st.position[2] -= body.positions(st, precise=True)[:, 2].min() - 1e-6
    return solver, st, box


def _edges(c):
    return np.flatnonzero(c.vertex >= c.points.nv)


def test_the_edge_points_lie_on_the_bodys_bottom_faces_over_the_boxs_edges(small_body):
    solver, st, box = _across(small_body)
    c = solver.collide(st, 1e-3)
    e = _edges(c)
    assert len(e) >= 4  # the edges y = +-0.03 under the faces between the rows, at least their two ends each
    pts = c.points
    R = st.rotation()
    world = (pts.rest[c.vertex[e]] @ R.T) + st.position  # the rest shape's points (q = 0 here)
    # each point is the barycentric combination of its face's deformed vertices, on the body's bottom face
    verts = pts.vertices[c.vertex[e] - pts.nv]
    w = pts.weights[c.vertex[e] - pts.nv]
    assert np.all(w >= 0.0) and np.allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-15)
    corners = small_body.positions(st, precise=True)[verts]  # (p, 3, 3)
    assert np.allclose(np.einsum("pa,pad->pd", w, corners), world, rtol=0, atol=1e-15)
    # the normal is the face's outward normal reversed: up (the bottom face turned by 0.01 rad)
    up = R @ np.array([0.0, 0.0, 1.0])
    assert np.allclose(c.normal[e], up, rtol=0, atol=1e-12)
    # above a box edge: its box-local point is on the top face's boundary (|x| = 0.05 or |y| = 0.03) within the
    # height it is above the box (the point is over the edge along the face normal, tilted by 0.01 rad)
    local = np.abs(world - box.center)
    on_edge = np.minimum(np.abs(local[:, 0] - HALF[0]), np.abs(local[:, 1] - HALF[1]))
    height = world[:, 2]
    assert np.all(on_edge <= 0.011 * np.abs(height) + 1e-15)
    assert np.all(local[:, 0] <= HALF[0] + 0.011 * height) and np.all(local[:, 1] <= HALF[1] + 0.011 * height)
    # the gap is the point's height over the edge point along the normal (> 0 here: the body is above the box)
    assert np.all(c.gap[e] > 0.0) and np.all(c.gap[e] < 0.011 * 0.12)  # (tilted by 0.01 rad over <= 0.12 m)


def test_an_edge_points_rows_are_the_weighted_sum_of_its_face_vertices_rows(small_body):
    """J = [I, -[r]x, R Phi] is linear in the point (r = R (X + Phi q), Phi = sum w_a Phi_a): the rows of the point
    equal sum_a w_a J_a to rounding; its normal velocity (the solve's n . J V) the same sum of its vertices'."""
    solver, st, _ = _across(small_body, moving=True)
    c = solver.collide(st, 1e-3)
    e = _edges(c)
    assert len(e)
    pts = c.points
    verts = pts.vertices[c.vertex[e] - pts.nv]
    w = pts.weights[c.vertex[e] - pts.nv]
    sub = c.subset(e)
    J, _, V, _, _, nm = C._system(solver, st, sub)
    assert nm == small_body.mode_count
    corner = C.Contacts(verts.ravel(), np.repeat(sub.normal, 3, axis=0), np.repeat(sub.gap, 3),
                        np.repeat(sub.effect, 3), sub.effects, obstacle=np.repeat(sub.obstacle, 3))
    Jc, *_ = C._system(solver, st, corner)
    Jw = np.einsum("pa,paij->pij", w, Jc.reshape(len(e), 3, 3, -1))
    scale = np.abs(J).max()
    assert np.abs(J - Jw).max() <= 64 * np.finfo(float).eps * scale
    vn = C.normal_velocities(solver, st, sub)
    vc = C.normal_velocities(solver, st, corner).reshape(len(e), 3)
    assert np.allclose(vn, (w * vc).sum(axis=1), rtol=0, atol=64 * np.finfo(float).eps * np.abs(vc).max())
    assert np.allclose(vn, np.einsum("pi,pij,j->p", sub.normal, J, V), rtol=0, atol=1e-14)


def test_an_edge_points_normal_velocity_is_the_rate_of_its_gap(small_body):
    """Central differences of the point's gap (against its plane, all modes in) over the free motion, h = 1e-8 s:
    the truncation error is ~ (omega_max h)^2 / 6 of the modal part (omega_max h ~ 1.5e-3 here: ~4e-7 of it), the
    rounding of positions ~0.1 m ~ 1e-17 m / h ~ 1e-9 m/s, both far inside 1e-5 of the largest normal velocity."""
    solver, st, _ = _across(small_body, moving=True)
    c = solver.collide(st, 1e-3)
    sub = c.subset(_edges(c))
    vn = C.normal_velocities(solver, st, sub)
    h = 1e-8
    gaps = []
    for s in (-h, h):
        t = st.copy()
        if s > 0:
            solver.advance_free(t, None, s)
        else:
            _back(solver, t, -s)
        gaps.append(C._gaps(sub.effects, sub, small_body, t, np.zeros(small_body.mode_count, dtype=bool))[0])
    rate = (gaps[1] - gaps[0]) / (2 * h)
    assert float(small_body.omega.max()) * h < 2e-3
    assert np.allclose(rate, vn, rtol=0, atol=1e-5 * np.abs(vn).max()), np.abs(rate - vn).max()


def _back(solver, st, h):
    """Free motion backwards by h [s]: reverse the velocities, step forward, reverse again."""
    for a in (st.velocity, st.angular_momentum, st.qdot):
        a *= -1.0
    solver.advance_free(st, None, h)
    for a in (st.velocity, st.angular_momentum, st.qdot):
        a *= -1.0


def test_a_body_on_the_ground_never_searches_box_edges(small_body, monkeypatch):
    calls = []
    real = C._with_edges
    monkeypatch.setattr(C, "_with_edges", lambda *a: calls.append(1) or real(*a))
    ball = rt.Sphere((5, 0, 0), 1.0)
    solver = rt.ModalSolver(small_body, effects=[rt.Gravity((0, 0, -G)), rt.Obstacles([rt.Ground(0.0), ball])])
    st = solver.state()
    st.position[2] -= small_body.positions(st, precise=True)[:, 2].min()
    for _ in range(5):
        c = solver.collide(st, 1e-3)
        assert c.points is None and c.count
        solver.step(st, st, None, c, 1e-3)
    assert not calls
    # with a box (far away) it searches and finds none
    far = rt.Box((5, 0, 1), (1, 1, 1))
    solver = rt.ModalSolver(small_body, effects=[rt.Gravity((0, 0, -G)), rt.Obstacles([rt.Ground(0.0), far])])
    c = solver.collide(st, 1e-3)
    assert calls and c.points is None


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_the_step_record_names_edge_contacts_by_a_vertex_of_their_face(small_body, dt):
    """The step record (sound, logging) lists body vertices only: an edge contact is recorded under its face's
    vertex of largest weight, its impulse added to that vertex's; the total normal impulse over a resting step is
    the step's weight m g dt (the solve converged; friction takes none here, the box top is level)."""
    solver, st, _ = _across(small_body)
    st.orientation[:] = quat_from_axis_angle((0.0, 0.0, 1.0), 1e-5)
    st.position[2] -= small_body.positions(st, precise=True)[:, 2].min()
    for _ in range(int(round(0.2 / dt))):
        c = solver.collide(st, dt)
        solver.step(st, st, None, c, dt)
    assert c.vertex.max() < small_body.vertex_count
    assert len(np.unique(c.vertex)) == c.count
    assert abs(c.impulses.sum() - small_body.mass * G * dt) <= 1e-6 * small_body.mass * G * dt
