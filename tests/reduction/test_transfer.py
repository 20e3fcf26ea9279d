"""Coarse physics, fine render surface: exact transfer on the coarse boundary, MAC against a finer
solve on a curved body, volume mass properties and rotation coupling kept, runtime, CLI, bad input."""

from __future__ import annotations

import json

import meshio
import numpy as np
import pytest

import modalfem
from modalfem import runtime as rt
from modalfem.cli import main
from modalfem.errors import InputError
from modalfem.material import STEEL
from modalfem.mesh import box, rod
from modalfem.mesh.surface import boundary_surface
from modalfem.model import ModalModel
from modalfem.reduction.render_surface import (
    RenderSurface,
    read_surface,
)
from modalfem.reduction.transfer import (
    render_surface_model,
    surface_distances,
    transfer_modes,
)
from modalfem.reduction.transfer_check import check_transfer, refine_mesh

EPS = np.finfo(float).eps
BEAM = {"size": (0.4, 0.05, 0.05), "cells": (8, 1, 1)}


def refined_boundary(mesh, n: int):
    """The boundary of ``mesh`` with each triangle cut into n^2 (barycentric grid, shared vertices merged).

    Returns (vertices, triangles, records): ``records[v] = (facet, lambda (3,))`` for each fine vertex,
    one coarse boundary facet holding it and its barycentric coordinates on that facet.
    """
    facets = mesh.boundary_facets
    key_of, pts, rec, tris = {}, [], [], []
    for fi, f in enumerate(facets):
        a, b, c = mesh.points[f]
        local = {}
        for i in range(n + 1):
            for j in range(n + 1 - i):
                lam = np.array([1 - (i + j) / n, i / n, j / n])
                p = lam @ np.array([a, b, c])
                key = tuple(np.round(p / 1e-9).astype(np.int64))
                if key not in key_of:
                    key_of[key] = len(pts)
                    pts.append(p)
                    rec.append((fi, lam))
                local[i, j] = key_of[key]
        for i in range(n):
            for j in range(n - i):
                tris.append((local[i, j], local[i + 1, j], local[i, j + 1]))
                if i + j < n - 1:
                    tris.append((local[i + 1, j], local[i + 1, j + 1], local[i, j + 1]))
    return np.array(pts), np.array(tris, dtype=np.int64), rec


def face_field(mesh, shapes, degree, facet, lam):
    """The coarse FE field (3, k) at a point of a boundary facet from the facet's own nodes (2D shape functions)."""
    d = shapes.reshape(-1, 3, shapes.shape[1])
    if degree == 1:
        return np.einsum("a,acr->cr", lam, d[facet])
    n = np.int64(mesh.point_count)
    keys = mesh.edges[:, 0].astype(np.int64) * n + mesh.edges[:, 1]
    out = np.einsum("a,acr->cr", lam * (2 * lam - 1), d[facet])
    for a, b in ((0, 1), (1, 2), (0, 2)):
        i, j = sorted((int(facet[a]), int(facet[b])))
        mid = mesh.point_count + int(np.searchsorted(keys, i * n + j))
        out = out + 4 * lam[a] * lam[b] * d[mid]
    return out


@pytest.fixture(scope="module")
def beam_modes():
    mesh = box(**BEAM)
    return {deg: (mesh, modalfem.modes(mesh, STEEL, k=4, degree=deg)) for deg in (1, 2)}


@pytest.mark.parametrize("degree", [1, 2])
def test_refined_coarse_boundary_gets_the_coarse_field_exactly(beam_modes, degree):
    mesh, res = beam_modes[degree]
    v, _, rec = refined_boundary(mesh, 3)
    shapes, report = transfer_modes(res, mesh, v)
    scale = np.abs(res.shapes).max()
    expected = np.stack([face_field(mesh, res.shapes, degree, mesh.boundary_facets[fi], lam) for fi, lam in rec])
    np.testing.assert_allclose(shapes.reshape(len(v), 3, -1), expected, rtol=0, atol=100 * EPS * scale)
    # coarse vertices among the fine ones carry the nodal values (P1 interpolation is exact at nodes)
    at_node = [i for i, (_, lam) in enumerate(rec) if lam.max() == 1.0]
    nodes = [int(mesh.boundary_facets[rec[i][0]][np.argmax(rec[i][1])]) for i in at_node]
    assert len(at_node) == len(boundary_surface(mesh).vertices)
    np.testing.assert_allclose(shapes.reshape(len(v), 3, -1)[at_node], res.shapes.reshape(-1, 3, 4)[nodes],
                               rtol=0, atol=100 * EPS * scale)
    assert report.vertex_count == len(v) and report.degree == degree
    assert report.distance_max <= 1e-12 * 0.4 and report.outside_count <= len(v)


def test_model_keeps_the_volume_mass_properties_and_rotation_coupling(beam_modes, tmp_path):
    mesh, res = beam_modes[2]
    v, t, _ = refined_boundary(mesh, 3)
    surface = RenderSurface(v, t, {"file": "beam.obj"})
    fine, report = render_surface_model(res, mesh, STEEL, surface)
    coarse = ModalModel.from_modes(res, mesh, STEEL)
    assert fine.vertex_count == len(v) > 2 * coarse.vertex_count
    assert fine.has_rotation_coupling
    np.testing.assert_array_equal(fine.rotation_T, coarse.rotation_T)
    np.testing.assert_array_equal(fine.rotation_S, coarse.rotation_S)
    np.testing.assert_array_equal(fine.omega, coarse.omega)
    assert fine.mass == coarse.mass
    np.testing.assert_allclose(fine.mass, STEEL.rho * 0.4 * 0.05 * 0.05, rtol=1e-12)  # rho V of the box
    np.testing.assert_allclose(fine.center_of_mass, [0.2, 0.025, 0.025], rtol=1e-12)
    Ixx = fine.mass * (0.05**2 + 0.05**2) / 12  # solid box about its centre
    Iyy = fine.mass * (0.4**2 + 0.05**2) / 12
    np.testing.assert_allclose(np.diag(fine.inertia), [Ixx, Iyy, Iyy], rtol=1e-12)
    rs = fine.provenance["render_surface"]
    assert rs["sha256"] == surface.fingerprint and rs["vertex_count"] == len(v) and rs["source"]["file"] == "beam.obj"
    assert rs["transfer"]["distance_max"] == report.distance_max
    path = tmp_path / "fine.npz"
    fine.save(path)
    back = ModalModel.load(path)
    assert back.provenance["render_surface"]["sha256"] == surface.fingerprint
    np.testing.assert_array_equal(back.shapes, fine.shapes)


def test_spinning_body_same_modal_response_on_the_fine_surface(beam_modes):
    """PseudoForces work on the fine model and give the coarse model's modal response.

    Both models hold the same omega, mass properties and rotation tensors (from the volume), and an
    impulse at a coarse vertex (also a fine vertex) projects on the same mode values there up to the
    rounding of the interpolation (10 weights, each within a few eps of 0 or 1: < 1e-14 of the
    largest shape entry). The response is linear in that projection, so q differs by that relative
    amount times the growth of the modal response over the run (here < 10): tolerance 1e-12 of max |q|.
    """
    mesh, res = beam_modes[2]
    v, t, _ = refined_boundary(mesh, 3)
    fine, _ = render_surface_model(res, mesh, STEEL, RenderSurface(v, t))
    coarse = ModalModel.from_modes(res, mesh, STEEL)
    i_c = int(np.argmin(np.linalg.norm(coarse.vertices - [0.4, 0.05, 0.05], axis=1)))
    i_f = int(np.argmin(np.linalg.norm(fine.vertices - coarse.vertices[i_c], axis=1)))
    assert np.array_equal(fine.vertices[i_f], coarse.vertices[i_c])
    runs = []
    for model, vertex in ((coarse, i_c), (fine, i_f)):
        body = rt.ModalBody(model, dtype=np.float64)
        solver = rt.ModalSolver(body, effects=[rt.PseudoForces()])
        state = solver.state(angular_velocity=(20.0, 5.0, 300.0))  # [rad/s] spinning about z, wobbling
        state = solver.advance(state, 1e-5, rt.Control().add_impulse(vertex, (0.0, 0.0, -0.05)))
        qs = []
        for _ in range(400):
            state = solver.advance(state, 1e-5)
            qs.append(state.q.copy())
        runs.append((np.array(qs), body.positions(state, frame="body")[vertex]))
    (q_c, x_c), (q_f, x_f) = runs
    assert np.abs(q_c).max() > 0
    np.testing.assert_allclose(q_f, q_c, rtol=0, atol=1e-12 * np.abs(q_c).max())
    np.testing.assert_allclose(x_f, x_c, rtol=0, atol=1e-12 * 0.4)
    # the pseudo-forces act: without them the response differs by far more than the tolerance
    body = rt.ModalBody(fine, dtype=np.float64)
    solver = rt.ModalSolver(body)
    state = solver.state(angular_velocity=(20.0, 5.0, 300.0))
    state = solver.advance(state, 1e-5, rt.Control().add_impulse(i_f, (0.0, 0.0, -0.05)))
    for _ in range(400):
        state = solver.advance(state, 1e-5)
    assert np.abs(state.q - q_f[-1]).max() > 1e-6 * np.abs(q_f).max()


def test_runtime_loads_and_steps_the_fine_model(beam_modes, tmp_path):
    mesh, res = beam_modes[2]
    v, t, _ = refined_boundary(mesh, 3)
    model, _ = render_surface_model(res, mesh, STEEL, RenderSurface(v, t))
    model.save(tmp_path / "m.npz")
    body = rt.load(tmp_path / "m.npz")
    assert body.vertex_count == len(v) and body.coupling is not None
    solver = rt.ModalSolver(body, effects=[rt.PseudoForces()])
    state = solver.state(angular_velocity=(0.0, 0.0, 10.0))
    J = np.array([0.0, 0.0, -0.2])  # [N s]
    state = solver.advance(state, 1e-4, rt.Control().add_impulse(body.surface_point(7, (0.2, 0.3, 0.5)), J))
    for _ in range(20):
        state = solver.advance(state, 1e-4)
    np.testing.assert_allclose(state.velocity, J / model.mass, rtol=1e-12)  # momentum of the impulse
    x = body.positions(state)
    assert x.shape == (len(v), 3) and np.all(np.isfinite(x))
    assert body.modal_energy(state) > 0


def _surface_mac(A, B, w):
    """MAC of the columns of B (reference) in the span of the columns of A, weight w per DOF."""
    s = np.sqrt(w)[:, None]
    Q, _ = np.linalg.qr(A * s)
    Bw = B * s
    return np.sum((Q.T @ Bw) ** 2, axis=0) / np.sum(Bw**2, axis=0)


@pytest.fixture(scope="module")
def cylinder():
    coarse, fine = rod(0.2, 0.02, h=0.012), rod(0.2, 0.02, h=0.006)
    k = 6
    return coarse, fine, modalfem.modes(coarse, STEEL, k=k), modalfem.modes(fine, STEEL, k=k + 1)


def test_curved_body_mac_against_the_fine_solve(cylinder):
    """A cylinder at two resolutions; the fine boundary lies outside the coarse polygonal one.

    Bound (derived for a Galerkin eigenvector): writing the approximate mode u_h = cos(t) u + sin(t) v
    with v M-orthogonal to the exact eigenspace of lambda_i, its Rayleigh quotient is
    lambda_h = cos^2(t) lambda_i + sin^2(t) a(v, v), so sin^2(t) <= |lambda_h - lambda_i| / gap_i with
    gap_i the distance from lambda_i [rad^2/s^2] to the nearest other eigenvalue (outside its pair of
    nearly degenerate modes). MAC = cos^2(t), hence MAC >= 1 - |lambda_h - lambda_i| / gap_i, using the
    fine solve as the exact one. Measured on the fine surface vertices, area-weighted.
    """
    coarse, fine, rc, rf = cylinder
    bs = boundary_surface(fine)
    surface = RenderSurface(bs.vertices, bs.triangles)
    shapes, report = transfer_modes(rc, coarse, surface.vertices)
    assert report.outside_count > surface.vertex_count // 2  # most fine vertices are outside the coarse chords
    assert 0 < report.distance_max < 0.1 * report.coarse_edge
    p = bs.vertices[bs.triangles]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    w = np.repeat(np.bincount(bs.triangles.ravel(), np.repeat(area / 3, 3), len(bs.vertices)), 3)
    rows = (3 * bs.mesh_vertices[:, None] + np.arange(3)).ravel()
    ref = rf.shapes[rows]  # the fine solve at its own boundary vertices: no interpolation
    lam_c, lam_f = rc.omega**2, rf.omega**2
    k = len(lam_c)
    groups, i = [], 0  # pairs of nearly degenerate modes (bending y/z of the round section)
    while i < k:
        j = i + 1
        while j < k and lam_f[j] - lam_f[j - 1] < 0.01 * lam_f[j]:
            j += 1
        groups.append(list(range(i, j)))
        i = j
    for g in groups:
        mac = _surface_mac(shapes[:, g], ref[:, g], w)
        lo = lam_f[g[0] - 1] if g[0] > 0 else -np.inf
        gap = min(lam_f[g[0]] - lo, lam_f[g[-1] + 1] - lam_f[g[-1]])
        bound = 1 - np.max(np.abs(lam_c[g] - lam_f[g])) / gap
        assert 0.9 < bound < 1
        assert np.all(mac > bound), (g, mac, bound)


def test_check_transfer_against_the_refined_coarse_mesh(beam_modes):
    """Nested spaces: the refined mesh's P2 space contains the coarse one, so (min-max principle) every
    reference frequency is at or below the coarse one; the MAC meets the Galerkin bound of the
    cylinder test (gap measured from the matched mode's cluster to the other reference modes)."""
    mesh, res = beam_modes[2]
    v, t, _ = refined_boundary(mesh, 2)
    check = check_transfer(res, mesh, STEEL, RenderSurface(v, t))
    assert check.reference == "refined coarse mesh"
    assert check.reference_dof_count == 3 * refine_mesh(mesh).node_count(2)
    assert np.all(check.frequency_error >= -1e-9)
    assert check.max_frequency_error > 1e-3  # 8x1x1 is not converged: the check sees it
    lam_c = (2 * np.pi * check.frequencies_hz) ** 2
    lam_r = (2 * np.pi * check.reference_spectrum_hz) ** 2
    assert len(lam_r) > len(lam_c) and len(set(check.matched.tolist())) == len(lam_c)
    assert (0, 1) in check.clusters  # the two first bendings (square section) form one cluster
    bounds = []
    for i, j in enumerate(check.matched):
        cluster = next(c for c in check.clusters if j in c)
        gap = np.min(np.abs(np.delete(lam_r, cluster) - lam_r[j]))
        bounds.append(1 - abs(lam_c[i] - lam_r[j]) / gap)
    assert np.all(check.mac > bounds), (check.mac, bounds)
    assert min(bounds[:2]) > 0.95  # informative for the bending pair (the torsion's gap to axial is small)


def test_refine_mesh_keeps_geometry_and_tags():
    m = box(size=(0.3, 0.2, 0.1), cells=(3, 2, 1))
    r = refine_mesh(m)
    assert r.cell_count == 8 * m.cell_count and np.all(r.volumes > 0)
    np.testing.assert_allclose(r.volume, m.volume, rtol=1e-13)
    np.testing.assert_allclose(r.volumes.max(), m.volumes.max() / 8 * 2, rtol=0.5)
    for name, f in m.tags.items():
        assert len(r.tags[name]) == 4 * len(f)
        area = lambda P, F: 0.5 * np.linalg.norm(np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]]), axis=1).sum()
        np.testing.assert_allclose(area(r.points, r.tags[name]), area(m.points, f), rtol=1e-13)
    assert len(r.boundary_facets) == 4 * len(m.boundary_facets)


def test_far_surface_is_refused(beam_modes):
    mesh, res = beam_modes[1]
    v, _, _ = refined_boundary(mesh, 2)
    with pytest.raises(InputError, match=r"from the coarse mesh's surface, more than the allowed 0\.025 m"):
        transfer_modes(res, mesh, v * 1000.0)  # millimetres read as metres
    shifted = v + [0.0, 0.0, 0.04]  # 4 cm: refused by default (half the 5 cm coarse edge), allowed with 5 cm
    with pytest.raises(InputError, match="vertices are"):
        transfer_modes(res, mesh, shifted)
    _, report = transfer_modes(res, mesh, shifted, max_distance=0.05)
    assert report.outside_count > 0 and abs(report.outside_distance_max - 0.04) < 1e-12


def _write_obj(path, v, t):
    meshio.write(path, meshio.Mesh(v, [("triangle", t)]))


def test_cli_render_surface_end_to_end(tmp_path, capsys):
    v, t, _ = refined_boundary(box(**BEAM), 3)
    obj = tmp_path / "fine.obj"
    _write_obj(obj, v, t)
    model_path, json_path = tmp_path / "model.npz", tmp_path / "out.json"
    rc = main(["modes", "box", "--size", "0.4", "0.05", "0.05", "--cells", "8", "1", "1", "-k", "4", "--quiet",
               "--render-surface", str(obj), "--save", str(model_path), "--json", str(json_path), "--check-transfer"])
    out = capsys.readouterr().out
    assert rc == 0
    model = ModalModel.load(model_path)
    assert model.vertex_count == len(v) and model.has_rotation_coupling
    assert model.provenance["render_surface"]["sha256"] == read_surface(obj).fingerprint
    data = json.loads(json_path.read_text())
    check = data["render_surface"]["check"]
    assert len(check["mac"]) == 4 and check["min_mac"] > 0.99 and check["reference"] == "refined coarse mesh"
    assert "render surface:" in out and "min MAC" in out and "none outside" in out


@pytest.mark.parametrize("case", ["far", "quad", "no-save", "check-alone", "negative-distance", "zero-scale"])
def test_cli_bad_render_surface_is_one_line(tmp_path, capsys, case):
    v, t, _ = refined_boundary(box(**BEAM), 2)
    obj = tmp_path / "s.obj"
    if case == "quad":
        obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    else:
        _write_obj(obj, v * (3.0 if case == "far" else 1.0), t)
    args = ["modes", "box", "--size", "0.4", "0.05", "0.05", "--cells", "8", "1", "1", "-k", "2", "--quiet"]
    if case != "check-alone":
        args += ["--render-surface", str(obj)]
    if case not in ("no-save", "check-alone"):
        args += ["--save", str(tmp_path / "m.npz")]
    if case == "check-alone":
        args += ["--check-transfer"]
    if case == "negative-distance":
        args += ["--max-transfer-distance", "-1"]
    if case == "zero-scale":
        args += ["--render-unit-scale", "0"]
    rc = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("modalfem: error: ")
    want = {"far": "from the coarse mesh's surface", "quad": "no triangles (quad x 1)",
            "no-save": "--render-surface needs --save", "check-alone": "--check-transfer needs --render-surface",
            "negative-distance": "--max-transfer-distance must be a finite length > 0",
            "zero-scale": "--render-unit-scale must be a finite factor > 0"}[case]
    assert want in err[0]
    assert not (tmp_path / "m.npz").exists()


def test_cli_check_against_a_reference_mesh_of_the_fine_surface(tmp_path, capsys):
    """Coarse rod file, render surface = the fine rod's boundary, reference = the fine rod's mesh."""
    from modalfem.mesh import write

    coarse, fine = rod(0.2, 0.02, h=0.012), rod(0.2, 0.02, h=0.006)
    write(coarse, tmp_path / "coarse.msh")
    write(fine, tmp_path / "fine.msh")
    bs = boundary_surface(fine)
    _write_obj(tmp_path / "fine.obj", bs.vertices * 1e3, bs.triangles)  # the surface in millimetres
    rc = main(["modes", str(tmp_path / "coarse.msh"), "-k", "4", "--quiet", "--render-surface",
               str(tmp_path / "fine.obj"), "--render-unit-scale", "1e-3", "--save", str(tmp_path / "m.npz"),
               "--json", str(tmp_path / "m.json"), "--check-transfer", str(tmp_path / "fine.msh")])
    out = capsys.readouterr().out
    assert rc == 0
    info = json.loads((tmp_path / "m.json").read_text())["render_surface"]
    check = info["check"]
    assert check["reference"].startswith("reference mesh") and check["reference_dof_count"] == 3 * fine.node_count(2)
    assert info["transfer"]["outside_count"] > 0 and info["vertex_count"] == len(bs.vertices)
    # the coarse polygonal section is thinner than the fine one: lower bending frequencies, within a few %
    assert all(-0.05 < e < 0.01 for e in check["frequency_error"]) and check["min_mac"] > 0.999
    assert check["clusters"][0] == [0, 1]  # the two first bendings of the round rod
    model = ModalModel.load(tmp_path / "m.npz")
    np.testing.assert_allclose(model.vertices, bs.vertices, rtol=1e-12)
    assert "transfer check against a finer solve (reference mesh" in out


def test_surface_distances_match_the_box_analytically():
    """Distance to the surface of the box [0, 0.4] x [0, 0.05]^2, inside and outside, in closed form."""
    mesh = box(**BEAM)
    half, c = np.array([0.2, 0.025, 0.025]), np.array([0.2, 0.025, 0.025])
    p = np.random.default_rng(8).uniform(-0.03, 0.43, size=(3000, 3)) * [1, 0.25, 0.25]
    a = np.abs(p - c) - half
    exact = np.where(np.all(a <= 0, axis=1), -a.max(axis=1), np.linalg.norm(np.maximum(a, 0), axis=1))
    dist, allowed, edge = surface_distances(mesh, p, max_distance=1.0)
    assert edge == 0.05 and allowed == 1.0
    np.testing.assert_allclose(dist, exact, rtol=0, atol=1e-12)
    _, report = transfer_modes(modalfem.modes(mesh, STEEL, k=1, degree=1), mesh, p, max_distance=1.0)
    outside = np.any(a > 0, axis=1)
    assert report.outside_count == int(outside.sum())
    np.testing.assert_allclose(report.outside_distance_mean, np.where(outside, exact, 0).mean(), rtol=1e-12)


@pytest.mark.parametrize("degree", [1, 2])
def test_outside_vertices_continue_the_nearest_elements_polynomial(degree):
    """The stated extrapolation rule: outside the coarse mesh, the nearest tetrahedron's polynomial is
    continued, so a field of the element's degree (affine at P1, quadratic at P2) comes out exact."""
    from types import SimpleNamespace

    mesh = box(size=(0.4, 0.05, 0.05), cells=(4, 2, 2))
    rng = np.random.default_rng(11)
    A, b = rng.normal(size=(3, 3)), rng.normal(size=3)

    def field(p):  # (n, 3) -> (n, 3): affine, plus a quadratic part at P2
        u = p @ A.T + b
        return u + (np.column_stack([p[:, 1] * p[:, 2], p[:, 0] ** 2, p[:, 0] * p[:, 1]]) if degree == 2 else 0)

    nodes = mesh.dof_points(degree)
    result = SimpleNamespace(shapes=field(nodes).reshape(-1, 1), degree=degree)
    surface = boundary_surface(mesh).vertices
    normal_out = np.where(np.isclose(surface, [0, 0, 0]), -1.0, np.where(np.isclose(surface, [0.4, 0.05, 0.05]), 1.0, 0))
    p = surface + 0.01 * normal_out  # 1 cm outside every face, edge and corner (threshold 0.05 m)
    shapes, report = transfer_modes(result, mesh, p, max_distance=0.05)
    assert report.outside_count == len(p) and report.extrapolation_max > 0.1
    np.testing.assert_allclose(shapes.reshape(-1, 3), field(p), rtol=0, atol=1e-12)
