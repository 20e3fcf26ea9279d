"""Generators: analytic volumes and face areas, orientation, symmetry, determinism, validation."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from modalfem.errors import InputError
from modalfem.mesh import generators
from modalfem.mesh.generators import GENERATORS, bell, box, plate, rod, tuning_fork


def area(mesh, name):
    """Total area [m^2] of tag ``name``."""
    p = mesh.points[mesh.tags[name]]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()


def normals(mesh, name):
    """Unit normals (k, 3) of the triangles of tag ``name`` (right-hand rule)."""
    p = mesh.points[mesh.tags[name]]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def facet_keys(facets):
    return {tuple(sorted(f)) for f in facets.tolist()}


def check_tags_are_boundary(mesh):
    """Every tag is a set of outward boundary facets; ``boundary`` is all of them."""
    bnd = {tuple(f) for f in mesh.boundary_facets.tolist()}
    assert {tuple(f) for f in mesh.tags["boundary"].tolist()} == bnd
    for name, f in mesh.tags.items():
        assert {tuple(t) for t in f.tolist()} <= bnd, name  # same vertex order = outward


@pytest.fixture(scope="module")
def rod_mesh():
    return rod(0.2, 0.01, h=0.004)


@pytest.fixture(scope="module")
def fork_mesh():
    return tuning_fork()


@pytest.fixture(scope="module")
def bell_mesh():
    return bell()


def test_registry_names():
    assert set(GENERATORS) == {"box", "plate", "rod", "tuning_fork", "bell"}
    assert GENERATORS["box"] is box


# ---------------------------------------------------------------------- box / plate
def test_box_exact_volume_areas_and_normals():
    size, n, origin = (0.3, 0.2, 0.1), (3, 4, 2), (-1.0, 2.0, 0.5)
    mesh = box(size, n, origin=origin)
    assert mesh.cell_count == 6 * 3 * 4 * 2
    assert np.all(mesh.volumes > 0)
    assert mesh.volume == pytest.approx(0.3 * 0.2 * 0.1, rel=1e-12)
    lo, hi = mesh.bounds
    np.testing.assert_allclose(lo, origin)
    np.testing.assert_allclose(hi, np.add(origin, size))
    face = {"x": 0.2 * 0.1, "y": 0.3 * 0.1, "z": 0.3 * 0.2}
    for axis, letter in enumerate("xyz"):
        for side, sign in (("0", -1.0), ("1", 1.0)):
            name = letter + side
            assert area(mesh, name) == pytest.approx(face[letter], rel=1e-12)
            np.testing.assert_allclose(normals(mesh, name)[:, axis], sign)
    # a conforming mesh has no interior facet counted as boundary
    assert area(mesh, "boundary") == pytest.approx(2 * sum(face.values()), rel=1e-12)
    check_tags_are_boundary(mesh)


def test_box_even_counts_symmetric_about_mid_planes():
    size = (0.4, 0.2, 0.2)
    mesh = box(size, (4, 2, 2))
    cells = {tuple(sorted(c)) for c in mesh.cells.tolist()}
    lookup = {tuple(np.round(p, 12)): i for i, p in enumerate(mesh.points)}
    for axis in range(3):
        mirrored = mesh.points.copy()
        mirrored[:, axis] = size[axis] - mirrored[:, axis]
        image = np.array([lookup[tuple(np.round(p, 12))] for p in mirrored])
        assert {tuple(sorted(image[c])) for c in mesh.cells.tolist()} == cells


def test_box_is_deterministic():
    assert box((1, 2, 3), (2, 3, 1)).fingerprint == box((1, 2, 3), (2, 3, 1)).fingerprint


def test_plate_is_thin_box():
    mesh = plate((0.2, 0.1, 0.002), (10, 5, 1))
    assert mesh.volume == pytest.approx(0.2 * 0.1 * 0.002, rel=1e-12)
    assert area(mesh, "z0") == pytest.approx(0.02, rel=1e-12)
    assert mesh.piece_count == 1


# ---------------------------------------------------------------------- rod
def test_rod_volume_and_areas(rod_mesh):
    L, r = 0.2, 0.01
    # the section is a polygon inscribed in the circle with >= 12 sides
    polygon = 12 / (2 * math.pi) * math.sin(2 * math.pi / 12)
    assert np.all(rod_mesh.volumes > 0)
    assert polygon * math.pi * r**2 * L <= rod_mesh.volume <= math.pi * r**2 * L
    for end in ("x0", "x1"):
        assert polygon * math.pi * r**2 <= area(rod_mesh, end) <= math.pi * r**2
    assert 0.95 * 2 * math.pi * r * L <= area(rod_mesh, "side") <= 2 * math.pi * r * L
    np.testing.assert_allclose(normals(rod_mesh, "x0")[:, 0], -1.0, atol=1e-9)
    np.testing.assert_allclose(normals(rod_mesh, "x1")[:, 0], 1.0, atol=1e-9)
    np.testing.assert_allclose(rod_mesh.bounds[0][0], 0.0, atol=1e-12)
    np.testing.assert_allclose(rod_mesh.bounds[1][0], L, rtol=1e-12)
    assert rod_mesh.piece_count == 1
    check_tags_are_boundary(rod_mesh)


def test_rod_is_deterministic_and_thread_safe(rod_mesh):
    results = []
    threads = [threading.Thread(target=lambda: results.append(rod(0.2, 0.01, h=0.004))) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 2
    assert {m.fingerprint for m in results} == {rod_mesh.fingerprint}


def test_gmsh_left_as_found():
    import gmsh

    rod(0.05, 0.01, h=0.01)
    assert not gmsh.isInitialized()
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 123.0)
        gmsh.model.add("mine")
        rod(0.05, 0.01, h=0.01)
        assert gmsh.model.getCurrent() == "mine"
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 123.0
    finally:
        gmsh.finalize()


# ---------------------------------------------------------------------- tuning fork / bell
def test_tuning_fork_volume_and_tags(fork_mesh):
    L, w, g, t, b, hl, r = 0.08, 0.004, 0.008, 0.006, 0.012, 0.035, 0.0025
    boxes = t * (2 * w * L + (g + 2 * w) * b)
    stem = math.pi * r**2 * hl
    polygon = 12 / (2 * math.pi) * math.sin(2 * math.pi / 12)
    assert np.all(fork_mesh.volumes > 0)
    assert boxes + polygon * stem <= fork_mesh.volume * (1 + 1e-12)
    assert fork_mesh.volume <= (boxes + stem) * (1 + 1e-12)
    assert polygon * math.pi * r**2 <= area(fork_mesh, "handle") <= math.pi * r**2
    np.testing.assert_allclose(normals(fork_mesh, "handle")[:, 1], -1.0, atol=1e-9)
    # prongs: the faces above the base, i.e. 2 x (4 sides + tip) minus nothing else
    assert area(fork_mesh, "prongs") == pytest.approx(2 * (2 * L * (w + t) + w * t), rel=1e-9)
    assert fork_mesh.piece_count == 1
    assert 1000 <= fork_mesh.cell_count <= 20000
    check_tags_are_boundary(fork_mesh)


def test_bell_shape_and_tags(bell_mesh):
    D, H, t = 0.2, 0.16, 0.006
    R = D / 2
    assert np.all(bell_mesh.volumes > 0)
    lo, hi = bell_mesh.bounds
    np.testing.assert_allclose(hi[:2] - lo[:2], D, rtol=2e-3)
    np.testing.assert_allclose([lo[2], hi[2]], [0.0, H], atol=1e-9)
    # centroid on the axis (solid of revolution)
    centroid = (bell_mesh.points[bell_mesh.cells].mean(axis=1) * bell_mesh.volumes[:, None]).sum(0) / bell_mesh.volume
    assert np.hypot(*centroid[:2]) < 1e-3 * D
    polygon = 12 / (2 * math.pi) * math.sin(2 * math.pi / 12)
    crown = math.pi * (0.5 * R) ** 2
    lip = math.pi * (R**2 - (R - 2.5 * t) ** 2)
    assert polygon * crown <= area(bell_mesh, "crown") <= crown
    assert 0.95 * lip <= area(bell_mesh, "lip") <= lip * 1.001
    np.testing.assert_allclose(normals(bell_mesh, "crown")[:, 2], 1.0, atol=1e-9)
    np.testing.assert_allclose(normals(bell_mesh, "lip")[:, 2], -1.0, atol=1e-9)
    # outer, inner, crown and lip partition the boundary
    parts = [facet_keys(bell_mesh.tags[n]) for n in ("crown", "lip", "outer", "inner")]
    assert sum(len(p) for p in parts) == len(bell_mesh.tags["boundary"])
    assert set().union(*parts) == facet_keys(bell_mesh.tags["boundary"])
    # outer normals point away from the axis, inner wall normals towards it (area-weighted)
    for name, sign in (("outer", 1.0), ("inner", -1.0)):
        p = bell_mesh.points[bell_mesh.tags[name]]
        c = p.mean(axis=1)
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        radial = np.c_[c[:, :2], np.zeros(len(c))]
        assert sign * np.einsum("ij,ij->", n, radial) > 0
    assert bell_mesh.piece_count == 1
    assert 1000 <= bell_mesh.cell_count <= 20000
    check_tags_are_boundary(bell_mesh)


# ---------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "name, kwargs, match",
    [
        ("box", {"size": (1.0, 0.0, 1.0)}, r"size\[1\]"),
        ("box", {"size": (1.0, float("nan"), 1.0)}, r"size\[1\]"),
        ("box", {"size": (1.0, 1.0)}, "3 entries"),
        ("box", {"cells": (2, 0, 2)}, r"cells\[1\]"),
        ("box", {"cells": (2, 1.5, 2)}, r"cells\[1\]"),
        ("box", {"cells": (10_000, 10_000, 10)}, "limit"),
        ("box", {"origin": (0.0, float("inf"), 0.0)}, r"origin\[1\]"),
        ("plate", {"size": (0.2, 0.1, -0.002)}, r"size\[2\]"),
        ("rod", {"length": -1.0}, "length"),
        ("rod", {"radius": 0.0}, "radius"),
        ("rod", {"h": 0.0}, "h must"),
        ("rod", {"h": 1e-6}, "tetrahedra"),
        ("tuning_fork", {"gap": -0.001}, "gap"),
        ("tuning_fork", {"handle_radius": 0.004}, "handle_radius"),
        ("tuning_fork", {"h": "fine"}, "h must"),
        ("bell", {"height": 1.0}, "height"),
        ("bell", {"thickness": 0.05}, "thickness"),
        ("bell", {"h": float("inf")}, "h must"),
    ],
)
def test_bad_arguments_raise_input_error(name, kwargs, match):
    with pytest.raises(InputError, match=match):
        GENERATORS[name](**kwargs)


def test_size_limit_constant_is_sane():
    assert generators.MAX_CELLS >= 1_000_000
