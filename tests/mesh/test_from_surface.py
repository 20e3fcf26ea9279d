"""Solid tet meshes from surfaces (modalfem.mesh.solid): volumes, scans, formats, bad files, modes, CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from modalfem.errors import MeshError
from modalfem.mesh import box, from_surface, read, tetrahedralize
from modalfem.mesh.solid import QUALITY_BOUND, read_surface, signed_volumes
from modalfem.mesh.tet_quality import boundary_faces, improve_quality, radius_ratio, surface_distances
from modalfem.meshes import path as shipped


def icosphere(radius: float, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Icosahedron subdivided ``levels`` times, vertices projected on the sphere, outward triangles."""
    from modalfem.bench.surface_bench import subdivide

    t = (1 + 5**0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    for _ in range(levels):
        v, f = subdivide(v, f)
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True), f


def box_surface(size, n) -> tuple[np.ndarray, np.ndarray]:
    """Closed surface of the box [0, size] with an n[a] x n[b] grid of split quads on each face, outward."""
    size = np.asarray(size, dtype=float)
    index: dict = {}
    verts, tris = [], []

    def vid(p):
        key = tuple(np.round(p / size * 1e6).astype(int))
        if key not in index:
            index[key] = len(verts)
            verts.append(p)
        return index[key]

    for ax in range(3):
        a, b = [i for i in range(3) if i != ax]
        for side in (0.0, 1.0):
            for i in range(n[a]):
                for j in range(n[b]):
                    q = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[ax], p[a], p[b] = side * size[ax], (i + di) / n[a] * size[a], (j + dj) / n[b] * size[b]
                        q.append(vid(p))
                    tris += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
    v, f = np.array(verts), np.array(tris)
    normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    inward = np.einsum("ij,ij->i", normal, v[f].mean(axis=1) - size / 2) < 0
    f[inward] = f[inward][:, ::-1]
    return v, f


def bunny_arrays(scale: float = 0.01):
    import meshio

    m = meshio.read(str(shipped("bunny.ply")))
    return m.points.astype(np.float64) * scale, m.cells_dict["triangle"].astype(np.int64)


# ------------------------------------------------------------------ quality and distance helpers
def test_radius_ratio_is_one_for_regular_and_zero_for_flat():
    regular = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], dtype=float)
    sliver = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1e-3]], dtype=float)
    q = radius_ratio(np.vstack([regular, flat, sliver]), np.array([[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]))
    assert q[0] == pytest.approx(1.0, abs=1e-12)
    assert q[1] == 0.0
    assert 0 < q[2] < 0.01


def test_improve_quality_moves_only_interior_vertices_and_raises_the_worst():
    mesh = box(size=(1.0, 1.0, 1.0), cells=(4, 4, 4))
    pts = np.array(mesh.points)
    boundary = np.unique(mesh.boundary_facets)
    interior = np.setdiff1d(np.arange(mesh.point_count), boundary)
    rng = np.random.default_rng(3)
    pts[interior] += rng.uniform(-0.08, 0.08, size=(len(interior), 3))  # 1/3 of the cell size: bad, not inverted
    before = radius_ratio(pts, mesh.cells).min()
    new, cells, info = improve_quality(pts, mesh.cells, bound=0.3)
    assert np.array_equal(new[boundary], pts[boundary])
    assert info["worst_after"] > before
    assert info["worst_after"] == pytest.approx(radius_ratio(new, cells).min())
    assert info["moved_vertices"] > 0


# the star of one interior vertex of an fTetWild mesh of a damaged bunny (coordinates rounded, scaled to 1):
# the vertex (15) sits close to the plane of three boundary vertices and moving it to its neighbours'
# centroid lowers another tetrahedron, so centroid smoothing alone stays at 0.098 < 0.1
_STAR_POINTS = np.array([
    [0.0, 0.8678, 0.4623], [0.0025, 0.7135, 0.1318], [0.2396, 0.8509, 0.9405], [0.2919, 0.7962, 0.5076],
    [0.3091, 0.4562, 0.0], [0.309, 0.7138, 0.2933], [0.4664, 0.7499, 0.7492], [0.4652, 0.2373, 0.0475],
    [0.5505, 0.5305, 0.3765], [0.6538, 0.5122, 0.787], [0.6758, 0.1603, 0.3883], [0.7031, 0.1655, 0.7404],
    [0.1532, 0.0, 0.4203], [0.0871, 0.3316, 0.8051], [0.4045, 0.4142, 1.0], [0.2931, 0.5753, 0.3591]])
_STAR_CELLS = np.array([
    [15, 14, 6, 2], [15, 5, 8, 4], [15, 7, 4, 8], [12, 7, 15, 10], [10, 15, 12, 11], [7, 8, 15, 10], [15, 6, 8, 3],
    [11, 9, 8, 15], [3, 15, 6, 2], [3, 15, 5, 8], [11, 8, 10, 15], [15, 11, 13, 12], [15, 9, 8, 6], [0, 13, 15, 2],
    [1, 15, 0, 12], [15, 14, 11, 9], [15, 14, 13, 11], [15, 14, 2, 13], [12, 7, 1, 15], [0, 15, 13, 12],
    [15, 0, 2, 3], [15, 14, 9, 6], [3, 0, 5, 15], [0, 1, 5, 15], [1, 5, 15, 4], [1, 7, 4, 15]])


def test_improve_quality_climbs_where_the_centroid_does_not_help():
    before = radius_ratio(_STAR_POINTS, _STAR_CELLS)
    assert before.min() < 0.1 and np.all(signed_volumes(_STAR_POINTS, _STAR_CELLS) > 0)
    centre = _STAR_POINTS.mean(axis=0)  # the centroid of the star (what smoothing moves towards) is no better
    for step in (1.0, 0.5, 0.25):
        trial = _STAR_POINTS.copy()
        trial[15] += step * (centre - trial[15])
        assert radius_ratio(trial, _STAR_CELLS).min() <= before.min()
    new, cells, info = improve_quality(_STAR_POINTS, _STAR_CELLS, bound=0.1)
    assert np.array_equal(new[:15], _STAR_POINTS[:15])  # only the interior vertex moves
    assert np.array_equal(cells, _STAR_CELLS)
    assert np.all(signed_volumes(new, cells) > 0)
    assert info["moved_vertices"] == 1
    assert info["worst_after"] == pytest.approx(radius_ratio(new, cells).min())
    assert info["worst_after"] >= 0.1


def test_boundary_sliver_is_removed_when_the_boundary_is_not_a_closed_manifold_elsewhere():
    # fTetWild can return two parts meeting along an edge (that edge used by four boundary faces); a flat cap
    # standing on the boundary elsewhere must still be removed (CI run: a raw scan's worst element stayed 0.068)
    a = box(size=(1.0, 1.0, 1.0), cells=(1, 1, 1))
    b = box(size=(1.0, 1.0, 1.0), cells=(1, 1, 1), origin=(1.0, 1.0, 0.0))  # touches a along x = y = 1
    pts = np.vstack([a.points, b.points])
    cells = np.vstack([a.cells, b.cells + a.point_count])
    pts, index = np.unique(pts, axis=0, return_inverse=True)  # the shared edge's two vertices merged
    cells = index.ravel()[cells]
    faces = boundary_faces(cells)
    e = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, uses = np.unique(e, axis=0, return_counts=True)
    assert uses.max() == 4  # the shared edge: not a closed 2-manifold
    # a cap on a's bottom face (z = 0): apex just outside the face, three new boundary faces, quality ~0.03
    bottom = next(f for f in faces if np.all(pts[f, 2] == 0.0) and np.all(pts[f, :2] <= 1.0))
    apex = pts[bottom].mean(axis=0) - np.array([0.0, 0.0, 0.01])
    pts = np.vstack([pts, apex])
    cap = np.array([[*bottom, len(pts) - 1]])
    if signed_volumes(pts, cap)[0] < 0:
        cap = cap[:, [0, 2, 1, 3]]
    cells = np.vstack([cells, cap])
    assert radius_ratio(pts, cap)[0] < 0.1
    new, kept, info = improve_quality(pts, cells, bound=0.1)
    assert info["removed_slivers"] == 1
    assert len(kept) == len(cells) - 1 and not (kept == len(pts) - 1).any()
    assert info["worst_after"] >= 0.1


def test_surface_distances_of_concentric_spheres():
    inner, outer = icosphere(1.0, 3), icosphere(1.1, 3)
    d_ab, d_ba = surface_distances(inner, outer, samples=2000)
    # vertices lie on the spheres (distance 0.1 exactly); points inside the flat triangles are closer to
    # the centre by at most the sagitta e^2 / (8 R) of the longest edge e
    v, f = inner
    e = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2).max()
    sag = e**2 / 8.0
    assert 0.1 - 1e-12 <= d_ba <= 0.1 + 1.1 * sag
    assert 0.1 - 1.1 * sag - 1e-12 <= d_ab <= 0.1 + 1.1 * sag


# ------------------------------------------------------------------ closed surfaces from arrays
def test_box_from_arrays_has_the_box_volume_and_keeps_the_surface():
    v, f = box_surface((0.3, 0.1, 0.06), (10, 4, 2))
    r = tetrahedralize((v, f), h=0.03)
    assert r.report.method == "gmsh"
    assert r.mesh.volume == pytest.approx(0.3 * 0.1 * 0.06, rel=1e-12)
    assert r.report.hausdorff <= 1e-12 * r.report.diagonal
    assert r.report.worst_quality >= QUALITY_BOUND
    assert "boundary" in r.mesh.tags and len(r.mesh.tags["boundary"]) == len(f)


@pytest.mark.parametrize("h", [0.2, 0.1])
def test_sphere_from_arrays_volume_within_the_chord_error_of_h(h):
    radius = 1.0
    levels = int(math.ceil(math.log2(1.1 * radius / h)))  # icosahedron edge 1.05 R, halved per level
    v, f = icosphere(radius, levels)
    r = tetrahedralize((v, f), h=h)
    edge = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2).max()
    sagitta = edge**2 / (8 * radius)
    exact = 4 / 3 * math.pi * radius**3
    # the inscribed polyhedron misses at most a shell of thickness sagitta: 0 <= 1 - V/V_ball <= 3 s / R
    assert 0 <= 1 - r.mesh.volume / exact <= 3 * sagitta / radius
    assert r.report.volume_error == pytest.approx(0.0, abs=1e-12)
    assert r.report.worst_quality >= QUALITY_BOUND


@pytest.mark.slow
def test_ftetwild_volume_within_its_envelope():
    v, f = icosphere(1.0, 3)
    envelope = 2e-3
    r = tetrahedralize((v, f), h=0.25, method="ftetwild", envelope=envelope)
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    # every boundary point stays within envelope * diagonal of the input surface
    assert r.report.distance_mesh_to_input <= envelope * r.report.diagonal * 1.001
    assert abs(r.mesh.volume - r.report.surface_volume) <= envelope * r.report.diagonal * area
    assert r.report.worst_quality >= QUALITY_BOUND


def test_ftetwild_leaves_nothing_in_the_working_directory(tmp_path, monkeypatch):
    # fTetWild writes a __tracked_surface.stl into its working directory: it runs in a temporary one
    monkeypatch.chdir(tmp_path)
    v, f = icosphere(1.0, 2)
    tetrahedralize((v, f), h=0.5, method="ftetwild")
    assert list(tmp_path.iterdir()) == []


def _fake_ftetwild(monkeypatch, results):
    """solid._ftetwild replaced by one returning ``results`` in turn; the stop energies it was called with
    (None: fTetWild's default)."""
    from modalfem.mesh import solid

    calls = []

    def fake(v, f, h, envelope, stop_energy=None):
        calls.append(stop_energy)
        return results[len(calls) - 1]

    monkeypatch.setattr(solid, "_ftetwild", fake)
    return calls


def _cube_surface():
    from modalfem.mesh.surface import boundary_surface

    skin = boundary_surface(box(size=(1.0, 1.0, 1.0), cells=(2, 2, 2)))
    return skin.vertices, skin.triangles


def test_ftetwild_is_run_again_when_its_mesh_misses_the_quality_bound(monkeypatch):
    import warnings

    from modalfem.mesh import solid

    # first run: a slab 1/50 thick with vertices only on its boundary: every tetrahedron flat (quality << 0.1),
    # none of them can be lifted by moving vertices; second run: a good cube mesh
    slab, cube = box(size=(1.0, 1.0, 0.02), cells=(2, 2, 1)), box(size=(1.0, 1.0, 1.0), cells=(2, 2, 2))
    calls = _fake_ftetwild(monkeypatch, [(slab.points, slab.cells), (cube.points, cube.cells)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", solid.QualityWarning)
        r = tetrahedralize(_cube_surface(), method="ftetwild")
    assert calls == [None, solid.RETRY_STOP_ENERGY] and solid.RETRY_STOP_ENERGY < solid.STOP_ENERGY
    assert r.report.worst_quality == pytest.approx(radius_ratio(cube.points, cube.cells).min(), rel=1e-12)
    assert r.report.worst_quality >= QUALITY_BOUND and r.mesh.cell_count == cube.cell_count
    assert any("fTetWild run again" in line and "the second kept" in line for line in r.report.repairs)
    assert "ftetwild.retry" in r.report.timings


def test_ftetwild_rerun_keeps_the_better_of_two_bad_meshes_and_warns(monkeypatch):
    from modalfem.mesh import solid

    # slabs 1/100 and 1/200 thick, vertices only on the boundary: worst quality ~0.04 and ~0.02 however optimised
    thin, thinner = box(size=(1.0, 1.0, 0.01), cells=(2, 2, 1)), box(size=(1.0, 1.0, 0.005), cells=(2, 2, 1))
    calls = _fake_ftetwild(monkeypatch, [(thin.points, thin.cells), (thinner.points, thinner.cells)])
    with pytest.warns(solid.QualityWarning):
        r = tetrahedralize(_cube_surface(), method="ftetwild")
    assert len(calls) == 2
    assert r.report.worst_quality < QUALITY_BOUND
    assert r.mesh.points[:, 2].max() - r.mesh.points[:, 2].min() == 0.01  # the thicker slab, the better one, kept
    assert any("the first kept" in line for line in r.report.repairs)


# ------------------------------------------------------------------ raw scans
@pytest.mark.slow
def test_scan_with_holes_nonmanifold_edges_flips_and_a_spike_becomes_solid():
    from modalfem.bench.surface_bench import scan_like

    v, f = bunny_arrays()
    closed_volume = tetrahedralize((v, f)).mesh.volume
    holes, hole_radius = 3, 0.04
    sv, sf = scan_like(v, f, holes=holes, hole_radius=hole_radius, fins=6, flips=40, spike=True)
    r = tetrahedralize((sv, sf))
    rep = r.report
    assert rep.method == "ftetwild"
    assert rep.boundary_edges > 0 and rep.nonmanifold_edges >= 6 and rep.flipped_edges > 0
    assert rep.surface_volume is None
    assert rep.worst_quality >= QUALITY_BOUND
    assert r.mesh.piece_count <= 2  # the bunny (and possibly the spike's outer tip)
    # filling a hole of radius r adds or removes at most a cap of height <= r over the disc: pi r^3 each
    r_hole = hole_radius * rep.diagonal
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    spike = (0.04 * rep.diagonal) ** 3 / 3  # the spike tetrahedron's volume (edge 2 sqrt(2) s)
    budget = holes * math.pi * r_hole**3 + 2e-3 * rep.diagonal * area + spike
    assert abs(r.mesh.volume - closed_volume) <= budget


@pytest.mark.slow
def test_real_scan_with_holes_through_the_cli_gives_certified_modes(tmp_path, capsys):
    from modalfem.bench.surface_bench import surface_case
    from modalfem.cli import main

    path, _ = surface_case("aneurysm", str(tmp_path))
    if path is None:
        pytest.skip("gmsh's example data (share/doc/gmsh) is not installed")
    out = tmp_path / "modes.json"
    code = main(["modes", path, "--unit-scale", "1e-3", "-k", "4", "--degree", "1", "--json", str(out),
                 "--material", "aluminium"])
    err = capsys.readouterr().err
    assert code == 0, err
    data = json.loads(out.read_text())
    surface = data["mesh"]["surface"]
    assert surface["boundary_edges"] > 0 and surface["method"] == "ftetwild"
    assert surface["worst_quality"] >= surface["quality_bound"]
    assert data["certificate"]["passed"]
    assert "Hausdorff distance" in err and "worst quality" in err


@pytest.mark.slow
def test_cad_part_through_the_cli_gives_certified_modes(tmp_path, capsys):
    from modalfem.bench.surface_bench import surface_case
    from modalfem.cli import main

    path, _ = surface_case("t13", str(tmp_path))
    if path is None:
        pytest.skip("gmsh's example data (share/doc/gmsh) is not installed")
    out = tmp_path / "modes.json"
    code = main(["modes", path, "--unit-scale", "1e-3", "-k", "4", "--degree", "1", "--json", str(out), "--quiet"])
    assert code == 0
    data = json.loads(out.read_text())
    surface = data["mesh"]["surface"]
    assert surface["boundary_edges"] == 0 and abs(surface["volume_error"]) < 0.01
    assert data["certificate"]["passed"]


# ------------------------------------------------------------------ formats
@pytest.mark.parametrize("name,options", [
    ("s.stl", {"binary": False}), ("s.stl", {"binary": True}), ("s.obj", {}), ("s.ply", {"binary": False}),
    ("s.ply", {"binary": True}), ("s.off", {}),
])
def test_each_format_reads_back_the_same_surface(tmp_path, name, options):
    import meshio

    v, f = icosphere(0.05, 1)
    path = tmp_path / name
    if name.endswith(".stl"):  # STL stores a triangle soup: every triangle its own three vertices
        meshio.write(path, meshio.Mesh(v[f].reshape(-1, 3), [("triangle", np.arange(3 * len(f)).reshape(-1, 3))]),
                     **options)
    else:
        meshio.write(path, meshio.Mesh(v, [("triangle", f)]), **options)
    rv, rf = read_surface(path, unit_scale=2.0)
    assert len(rf) == len(f)
    assert np.allclose(np.sort(rv[rf].reshape(-1, 3), axis=0), np.sort(2.0 * v[f].reshape(-1, 3), axis=0), atol=1e-6)
    mesh = read(path)  # the generic reader makes it solid too
    p = v[f]
    enclosed = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6
    assert mesh.volume == pytest.approx(enclosed, rel=1e-5)


def test_obj_with_quads_is_split_into_triangles(tmp_path):
    path = tmp_path / "cube.obj"
    corners = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    quads = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(f"f {a} {b} {c} {d}\n" for a, b, c, d in quads))
    v, f = read_surface(path)
    assert len(f) == 12
    mesh = from_surface(path, h=0.5, unit_scale=0.1)
    assert mesh.volume == pytest.approx(1e-3, rel=1e-12)


# ------------------------------------------------------------------ surfaces that cannot be made solid
def _write(tmp_path, name, data):
    p = tmp_path / name
    p.write_bytes(data) if isinstance(data, bytes) else p.write_text(data)
    return p


@pytest.mark.parametrize("name,data,needle", [
    ("empty.stl", b"", "0 bytes"),
    ("junk.stl", b"\x00\x01garbage" * 3, "corrupt, truncated or not in that format"),
    ("cloud.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "end_header\n0 0 0\n1 0 0\n0 1 0\n", "no triangles"),
    ("flat.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n", "flat"),
    ("zero.off", "OFF\n3 1 0\n0 0 0\n1 1 1\n2 2 2\n3 0 1 2\n", "zero area"),
    ("bad.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "missing point"),
])
def test_bad_surface_files_fail_with_one_line(tmp_path, name, data, needle):
    p = _write(tmp_path, name, data)
    with pytest.raises(MeshError) as exc:
        from_surface(p)
    assert needle in str(exc.value) and "\n" not in str(exc.value)


def test_open_sheet_is_refused_as_a_sheet():
    x, y = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9), indexing="ij")
    v = np.c_[x.ravel(), y.ravel(), 0.3 * (x.ravel() ** 2 + y.ravel() ** 2)]  # a curved open sheet
    idx = np.arange(81).reshape(9, 9)
    q = np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()]
    f = np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    with pytest.raises(MeshError, match="sheet or a shell"):
        from_surface((v, f))


def test_missing_file_and_bad_options():
    from modalfem.errors import InputError

    with pytest.raises(MeshError, match="not found"):
        from_surface("/nonexistent/part.stl")
    v, f = icosphere(1.0, 1)
    with pytest.raises(InputError, match="method"):
        from_surface((v, f), method="magic")
    with pytest.raises(InputError, match="h must be"):
        from_surface((v, f), h=-1.0)


def test_cli_bad_surface_is_one_line_exit_2(tmp_path, capsys):
    from modalfem.cli import main

    p = _write(tmp_path, "flat.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    code = main(["modes", str(p), "--json", str(tmp_path / "x.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("modalfem: error:") and "flat" in err[-1]
    assert not (tmp_path / "x.json").exists()


# ------------------------------------------------------------------ modes and the CLI path
def test_modes_of_a_box_surface_match_the_box_generator():
    import modalfem

    size = (0.3, 0.1, 0.06)
    steel = modalfem.Material(E=200e9, nu=0.3, rho=7850.0)
    surface_mesh = from_surface(box_surface(size, (10, 4, 2)), h=0.03)
    coarse = modalfem.modes(box(size=size, cells=(10, 4, 2)), steel, k=6).frequencies_hz
    ref = modalfem.modes(box(size=size, cells=(20, 6, 4)), steel, k=6).frequencies_hz
    got = modalfem.modes(surface_mesh, steel, k=6).frequencies_hz
    # the surface mesh has the coarse generator's resolution: its error against the finer generator
    # may be up to twice the coarse generator's own largest error
    allowed = 2 * np.max(np.abs(coarse - ref) / ref)
    assert np.all(np.abs(got - ref) / ref <= allowed), (got, ref, allowed)


def test_cli_modes_of_a_surface_file_prints_and_stores_the_report(tmp_path, capsys):
    from modalfem.cli import main

    out = tmp_path / "modes.json"
    code = main(["modes", str(shipped("bunny.ply")), "--unit-scale", "0.01", "--h", "0.006", "-k", "3",
                 "--degree", "1", "--json", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "worst quality" in captured.err and "Hausdorff distance" in captured.err
    data = json.loads(out.read_text())
    surface = data["mesh"]["surface"]
    assert surface["tets"] == data["mesh"]["cells"]
    assert surface["h"] == pytest.approx(0.006) and surface["method"] == "gmsh"
    assert abs(surface["volume_error"]) < 1e-9  # gmsh keeps the closed bunny's surface
    assert data["certificate"]["passed"]


def test_cli_refuses_generator_options_for_a_surface(tmp_path, capsys):
    from modalfem.cli import main

    code = main(["modes", str(shipped("bunny.ply")), "--size", "1", "1", "1"])
    assert code == 2
    assert "--size is a generator option" in capsys.readouterr().err


def test_a_mesh_below_the_quality_bound_warns_and_says_so():
    from modalfem.mesh.solid import QualityWarning

    v, f = box_surface((1.0, 1.0, 1.0), (40, 1, 1))  # faces cut into 40:1 strips: flat tets along them
    with pytest.warns(QualityWarning, match="below the bound"):
        r = tetrahedralize((v, f), method="gmsh", h=0.5)
    assert r.report.worst_quality < QUALITY_BOUND
    assert r.report.worst_quality == pytest.approx(radius_ratio(r.mesh.points, r.mesh.cells).min())
    assert "BELOW the bound" in str(r.report)


def test_a_dome_scanned_without_its_base_is_filled():
    v, f = icosphere(1.0, 3)
    keep = v[f].mean(axis=1)[:, 2] > 0  # the upper half: a hemisphere open at z = 0 (open fraction ~0.5)
    r = tetrahedralize((v, f[keep]))
    assert r.report.boundary_edges > 0 and r.report.method == "ftetwild"
    half_ball = 2 / 3 * math.pi
    # filled where the generalised winding number exceeds 1/2; on the rim's plane it is 1/2 itself, so the fill
    # may stop short of that plane: most of the half ball, never more (5.5 % short when written)
    assert 0.9 * half_ball < r.mesh.volume <= half_ball


def test_tiny_h_is_refused_and_a_part_in_millimetres_warns(tmp_path):
    import meshio

    from modalfem.errors import InputError
    from modalfem.mesh.io import UnitWarning
    from modalfem.mesh.solid import load_surface

    v, f = box_surface((60.0, 20.0, 10.0), (6, 2, 1))  # a part in millimetres
    with pytest.raises(InputError, match="millions of tetrahedra"):
        from_surface((v, f), h=0.01)
    path = tmp_path / "part.stl"
    meshio.write(path, meshio.Mesh(v, [("triangle", f)]))
    with pytest.warns(UnitWarning, match="unit_scale=0.001"):
        mesh, source = load_surface(path, h=10.0)
    assert source["surface"]["tets"] == mesh.cell_count
