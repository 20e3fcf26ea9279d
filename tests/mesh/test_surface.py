"""Boundary surface extraction and exact mass properties of tetrahedral meshes."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem
from modalfem.errors import MaterialError
from modalfem.mesh import Mesh, box
from modalfem.mesh.surface import boundary_surface, mass_properties


def _rotation(axis, angle) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _check_closed_outward(mesh: Mesh) -> None:
    s = boundary_surface(mesh)
    assert s.vertices.dtype == np.float64 and s.triangles.dtype == np.int64
    assert np.array_equal(s.vertices, mesh.points[s.mesh_vertices])
    assert np.all(np.diff(s.mesh_vertices) > 0)
    assert np.array_equal(np.unique(s.triangles), np.arange(s.vertex_count))  # every vertex used
    # closed and consistently oriented: each directed edge once, and its reverse once
    e = s.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n = s.vertex_count
    fwd = e[:, 0] * n + e[:, 1]
    rev = e[:, 1] * n + e[:, 0]
    assert len(np.unique(fwd)) == len(fwd) and np.array_equal(np.sort(fwd), np.sort(rev))
    # outward: the divergence theorem gives the mesh volume with a positive sign
    assert s.enclosed_volume() == pytest.approx(mesh.volume, rel=1e-12)


def test_box_surface_counts_and_outward_normals():
    nx, ny, nz = 4, 3, 2
    mesh = box(size=(0.4, 0.3, 0.2), cells=(nx, ny, nz), origin=(1.0, -2.0, 0.5))
    s = boundary_surface(mesh)
    assert s.vertex_count == (nx + 1) * (ny + 1) * (nz + 1) - (nx - 1) * (ny - 1) * (nz - 1)
    assert s.triangle_count == 4 * (nx * ny + ny * nz + nz * nx)
    lo, hi = mesh.bounds
    on_face = np.isclose(s.vertices, lo).any(axis=1) | np.isclose(s.vertices, hi).any(axis=1)
    assert on_face.all()
    p = s.vertices[s.triangles]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    away = p.mean(axis=1) - 0.5 * (lo + hi)
    assert np.all(np.einsum("ij,ij->i", normal, away) > 0)  # convex body: every normal points away
    _check_closed_outward(mesh)


def test_generated_tuning_fork_surface_is_closed_and_outward():
    from modalfem.mesh import tuning_fork

    _check_closed_outward(tuning_fork(h=0.004))


def _box_inertia(mass, a, b, c) -> np.ndarray:
    return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def test_box_mass_properties_are_analytic():
    a, b, c, rho = 0.5, 0.2, 0.1, 7850.0
    origin = np.array([0.3, -1.0, 2.0])
    mp = mass_properties(box(size=(a, b, c), cells=(5, 3, 2), origin=tuple(origin)), rho)
    m = rho * a * b * c
    assert mp.mass == pytest.approx(m, rel=1e-13) and mp.volume == pytest.approx(a * b * c, rel=1e-13)
    assert np.allclose(mp.center_of_mass, origin + 0.5 * np.array([a, b, c]), rtol=0, atol=1e-14)
    assert np.allclose(mp.inertia, _box_inertia(m, a, b, c), rtol=0, atol=1e-13 * m * a * a)
    assert np.allclose(mp.principal_moments, np.sort(np.diag(_box_inertia(m, a, b, c))), rtol=1e-12)


def test_translated_rotated_box():
    a, b, c, rho = 0.5, 0.2, 0.1, 2700.0
    ref = box(size=(a, b, c), cells=(4, 2, 2))
    R = _rotation([1.0, 2.0, -0.5], 0.7)
    t = np.array([10.0, -3.0, 5.0])
    moved = Mesh((ref.points - 0.5 * np.array([a, b, c])) @ R.T + t, ref.cells)  # centre at t
    mp = mass_properties(moved, rho)
    m = rho * a * b * c
    assert mp.mass == pytest.approx(m, rel=1e-12)
    assert np.allclose(mp.center_of_mass, t, rtol=0, atol=1e-12)
    expected = R @ _box_inertia(m, a, b, c) @ R.T
    assert np.allclose(mp.inertia, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    assert np.allclose(mp.inertia, mp.inertia.T, rtol=0, atol=0)


@pytest.mark.parametrize("degree", [1, 2])
def test_mass_properties_match_the_fe_mass_matrix(degree):
    """Consistent FE mass integrates 1, x and x x^T exactly (they lie in the P1/P2 space)."""
    from modalfem.backends.skfem import assemble
    from modalfem.mesh import bell

    mesh = bell(h=0.03) if degree == 1 else box(size=(0.3, 0.1, 0.05), cells=(3, 2, 1))
    R = _rotation([0.3, -1.0, 0.4], 1.1)
    mesh = Mesh(mesh.points @ R.T + np.array([0.2, 0.1, -0.4]), mesh.cells)
    mat = modalfem.BRASS
    _, M = assemble(mesh, mat, degree=degree)
    Mx = M[0::3, 0::3]  # one component block (N, N) [kg]
    X = mesh.dof_points(degree)  # (N, 3) nodal coordinates: interpolate x exactly
    one = np.ones(len(X))
    mp = mass_properties(mesh, mat.rho)
    assert mp.mass == pytest.approx(one @ (Mx @ one), rel=1e-11)
    com = (one @ (Mx @ X)) / mp.mass
    assert np.allclose(mp.center_of_mass, com, rtol=0, atol=1e-11 * np.abs(X).max())
    second = X.T @ (Mx @ X) - mp.mass * np.outer(com, com)  # int rho (x-c)(x-c)^T
    inertia = np.trace(second) * np.eye(3) - second
    assert np.allclose(mp.inertia, inertia, rtol=0, atol=1e-9 * np.abs(inertia).max())


@pytest.mark.parametrize("rho", [0.0, -1.0, float("nan"), "dense"])
def test_bad_density(rho):
    with pytest.raises(MaterialError, match="density"):
        mass_properties(box(cells=(1, 1, 1)), rho)


def test_two_pieces_follow_the_parallel_axis_theorem():
    rho = 1000.0
    a = box(size=(0.2, 0.1, 0.1), cells=(2, 1, 1), origin=(0.0, 0.0, 0.0))
    b = box(size=(0.1, 0.3, 0.05), cells=(1, 3, 1), origin=(0.5, -0.2, 0.3))
    both = Mesh(np.vstack([a.points, b.points]), np.vstack([a.cells, b.cells + a.point_count]))
    pa, pb, p = mass_properties(a, rho), mass_properties(b, rho), mass_properties(both, rho)
    assert p.mass == pytest.approx(pa.mass + pb.mass, rel=1e-13)
    com = (pa.mass * pa.center_of_mass + pb.mass * pb.center_of_mass) / p.mass
    assert np.allclose(p.center_of_mass, com, rtol=0, atol=1e-14)
    expected = np.zeros((3, 3))
    for q in (pa, pb):
        d = q.center_of_mass - com
        expected += q.inertia + q.mass * (d @ d * np.eye(3) - np.outer(d, d))
    assert np.allclose(p.inertia, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    surf = boundary_surface(both)
    assert surf.enclosed_volume() == pytest.approx(both.volume, rel=1e-12)
