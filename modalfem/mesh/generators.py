"""Mesh generators: a structured box/plate (numpy) and gmsh-built rod, tuning fork and bell.

Every generator returns a validated linear-tetrahedron :class:`~modalfem.mesh.Mesh` whose boundary
tags are outward-oriented triangles, always including ``"boundary"`` (every boundary facet).
Output is deterministic: the same arguments give the same points, cells and tags (gmsh runs
single-threaded with fixed algorithms). gmsh is imported lazily, is never left initialised by
these functions, and is guarded by a process-wide lock, so generators may be called from any
thread (calls are serialised). If the caller already has a gmsh session open, it is reused in a
temporary model and the options touched here are restored afterwards.

``GENERATORS`` maps the CLI names ``box, plate, rod, tuning_fork, bell`` to these functions; every
argument has a default, so ``GENERATORS[name]()`` works.
"""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from modalfem.errors import InputError, MeshError
from modalfem.mesh.core import Mesh, signed_volumes, unique_rows

__all__ = ["box", "plate", "rod", "tuning_fork", "bell", "GENERATORS"]

#: refuse to build meshes larger than this (a typo such as h=1e-5 would otherwise hang)
MAX_CELLS = 5_000_000
#: gmsh tets per h^3: a regular tet of edge h has volume h^3 / (6 sqrt 2)
_TETS_PER_H3 = 6.0 * math.sqrt(2.0)
_GMSH_LOCK = threading.RLock()


# ---------------------------------------------------------------------- argument checks
def _positive(name: str, value, *, unit: str = "m") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number [{unit}], got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a finite number > 0 [{unit}], got {value!r}")
    return v


def _triple(name: str, value, check: Callable) -> tuple:
    try:
        items = list(value)
    except TypeError:
        raise InputError(f"{name} must have 3 entries (x, y, z), got {value!r}") from None
    if len(items) != 3:
        raise InputError(f"{name} must have 3 entries (x, y, z), got {value!r}")
    return tuple(check(f"{name}[{i}]", v) for i, v in enumerate(items))


def _count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def _finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number [m], got {value!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{name} must be finite [m], got {value!r}")
    return v


def _check_size(what: str, volume: float, h: float) -> None:
    estimate = volume / h**3 * _TETS_PER_H3
    if estimate > MAX_CELLS:
        raise InputError(
            f"{what}: mesh size h={h:g} m would give ~{estimate:.2g} tetrahedra (limit {MAX_CELLS}); use a larger h"
        )


# ---------------------------------------------------------------------- shared finishing
def _outward_tags(points: np.ndarray, cells: np.ndarray, tags: dict[str, np.ndarray]) -> Mesh:
    """Validated mesh whose tags are re-oriented like ``boundary_facets``, plus tag ``"boundary"``."""
    used = np.zeros(len(points), dtype=bool)
    used[cells.ravel()] = True
    new = np.full(len(points), -1, dtype=np.int64)
    new[used] = np.arange(int(used.sum()))
    points, cells = points[used], new[cells]
    tags = {k: new[np.asarray(f, dtype=np.int64).reshape(-1, 3)] for k, f in tags.items()}
    for name, f in tags.items():
        if (f < 0).any():
            raise MeshError(f"tag {name!r} uses points that no tetrahedron uses")
    bare = Mesh(points, cells)
    bnd = bare.boundary_facets
    oriented = {"boundary": bnd}
    bkey = np.sort(bnd, axis=1)
    for name, facets in tags.items():
        f = np.asarray(facets, dtype=np.int64).reshape(-1, 3)
        if not len(f):
            oriented[name] = f
            continue
        allkeys = np.vstack([bkey, np.sort(f, axis=1)])
        _, inv = unique_rows(allkeys, len(bare.points), return_inverse=True)
        inv = inv.ravel()
        where = np.full(inv.max() + 1, -1, dtype=np.int64)
        where[inv[: len(bnd)]] = np.arange(len(bnd))
        idx = where[inv[len(bnd) :]]
        if (idx < 0).any():
            raise MeshError(f"tag {name!r}: {int((idx < 0).sum())} triangles are not boundary faces of the mesh")
        oriented[name] = bnd[idx]
    return Mesh(bare.points, bare.cells, oriented)


# ---------------------------------------------------------------------- structured box
def box(size=(1.0, 0.1, 0.1), cells=(20, 2, 2), *, origin=(0.0, 0.0, 0.0)) -> Mesh:
    """Structured tetrahedral box ``[origin, origin + size]``, each hexahedron split into 6 tets.

    The split follows a main diagonal of each hexahedron (Kuhn triangulation), mirrored in every
    other cell along each axis, so faces match across neighbours and, with even cell counts, the
    mesh is symmetric about the box's mid-planes (symmetric mode pairs stay exactly degenerate).
    All cells are positively oriented. Points are numbered with z fastest, then y, then x.

    Args:
        size: edge lengths (Lx, Ly, Lz) [m], each > 0.
        cells: hexahedra per axis (nx, ny, nz), each an integer >= 1.
        origin: lower corner (x, y, z) [m].

    Returns:
        Mesh with ``6 nx ny nz`` tetrahedra and tags ``x0, x1, y0, y1, z0, z1`` (faces at the min /
        max of each axis) and ``boundary``.

    Raises:
        InputError: non-positive or non-finite size, cell counts < 1 or not integers, too many cells.
    """
    size = _triple("size", size, _positive)
    n = _triple("cells", cells, _count)
    origin = _triple("origin", origin, _finite)
    if 6 * n[0] * n[1] * n[2] > MAX_CELLS:
        raise InputError(f"box: cells={n} would give {6 * n[0] * n[1] * n[2]} tetrahedra (limit {MAX_CELLS})")
    axes = [np.linspace(o, o + s, k + 1) for o, s, k in zip(origin, size, n)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    ids = np.arange(points.shape[0]).reshape(n[0] + 1, n[1] + 1, n[2] + 1)
    ijk = np.stack(np.meshgrid(*(np.arange(k) for k in n), indexing="ij"), axis=-1).reshape(-1, 3)
    mirror = ijk % 2  # odd cells start their diagonal at the opposite corner
    tets = []
    for perm in itertools.permutations(range(3)):
        corner = mirror.copy()
        path = [ids[tuple((ijk + corner).T)]]
        for axis in perm:
            corner[:, axis] = 1 - corner[:, axis]
            path.append(ids[tuple((ijk + corner).T)])
        tets.append(np.column_stack(path))
    tets = np.vstack(tets)
    flip = signed_volumes(points, tets) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    bare = Mesh(points, tets)
    bnd = bare.boundary_facets
    centre = bare.points[bnd].mean(axis=1)
    tags = {}
    for axis, letter in enumerate("xyz"):
        lo, hi = axes[axis][0], axes[axis][-1]
        tol = 1e-9 * size[axis]
        tags[f"{letter}0"] = bnd[np.abs(centre[:, axis] - lo) <= tol]
        tags[f"{letter}1"] = bnd[np.abs(centre[:, axis] - hi) <= tol]
    tags["boundary"] = bnd
    return Mesh(bare.points, bare.cells, tags)


def plate(size=(0.2, 0.1, 0.002), cells=(20, 10, 1), *, origin=(0.0, 0.0, 0.0)) -> Mesh:
    """Thin structured plate, thin in z: a :func:`box` with plate-like defaults.

    Args:
        size: (Lx, Ly, thickness t) [m], each > 0.
        cells: hexahedra per axis (nx, ny, nz); ``nz`` = 1 or 2 is usual for a plate.
        origin: lower corner [m].

    Returns:
        Mesh with tags ``x0, x1, y0, y1, z0, z1`` (``z0``/``z1`` are the two faces) and ``boundary``.

    Raises:
        InputError: as :func:`box`.
    """
    return box(size, cells, origin=origin)


# ---------------------------------------------------------------------- gmsh plumbing
def _import_gmsh():
    try:
        import gmsh
    except ImportError as exc:  # pragma: no cover - gmsh is a hard dependency
        raise MeshError(f"gmsh is needed for this generator: pip install gmsh ({exc})") from None
    return gmsh


@contextmanager
def _gmsh_session(model: str, options: dict[str, float] | None = None) -> Iterator:
    """A private gmsh model with ``options`` set; gmsh errors become one-line ``MeshError``s."""
    gmsh = _import_gmsh()
    with _GMSH_LOCK:
        owned = not gmsh.isInitialized()
        saved: dict[str, float] = {}
        previous = None
        if owned:
            gmsh.initialize(readConfigFiles=False, interruptible=False)
        else:
            previous = gmsh.model.getCurrent()
        try:
            opts = {"General.Terminal": 0, "General.Verbosity": 0, "General.NumThreads": 1}
            opts.update(options or {})
            for key, value in opts.items():
                if not owned:
                    saved[key] = gmsh.option.getNumber(key)
                gmsh.option.setNumber(key, value)
            gmsh.model.add(f"modalfem_{model}_{threading.get_ident()}")
            try:
                yield gmsh
            except MeshError:
                raise
            except Exception as exc:
                if type(exc) is not Exception:  # only gmsh's own errors are translated
                    raise
                msg = str(exc).strip().splitlines()[0] if str(exc).strip() else "unknown gmsh error"
                raise MeshError(f"gmsh failed on {model}: {msg}") from exc
        finally:
            if owned:
                gmsh.finalize()
            else:
                gmsh.model.remove()
                for key, value in saved.items():
                    gmsh.option.setNumber(key, value)
                if previous:
                    gmsh.model.setCurrent(previous)


def _mesh_options(h: float) -> dict[str, float]:
    return {
        "Mesh.MeshSizeMax": h,
        "Mesh.MeshSizeMin": 0.0,
        "Mesh.MeshSizeFromPoints": 0,
        "Mesh.MeshSizeFromCurvature": 12,  # at least 12 elements per full turn of a curve
        "Mesh.MeshSizeExtendFromBoundary": 1,
        "Mesh.MinimumCircleNodes": 12,
        "Mesh.Algorithm": 6,
        "Mesh.Algorithm3D": 1,
        "Mesh.MaxNumThreads1D": 1,
        "Mesh.MaxNumThreads2D": 1,
        "Mesh.MaxNumThreads3D": 1,
        "Mesh.ElementOrder": 1,
        "Mesh.Optimize": 1,
        "Geometry.OCCUnionUnify": 0,
    }


def _generate(gmsh, what: str, surfaces: dict[str, list[int]]) -> Mesh:
    """Mesh the current OCC model in 3D and collect tets and the triangles of ``surfaces``."""
    gmsh.model.occ.synchronize()
    gmsh.model.mesh.generate(3)
    node_tags, coords, _ = gmsh.model.mesh.getNodes()
    node_tags = node_tags.astype(np.int64)
    index = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    index[node_tags] = np.arange(len(node_tags))
    points = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    _, tet_nodes = gmsh.model.mesh.getElementsByType(4)
    if len(tet_nodes) == 0:
        raise MeshError(f"gmsh produced no tetrahedra for {what}; check the dimensions and h")
    cells = index[tet_nodes.astype(np.int64).reshape(-1, 4)]
    flip = signed_volumes(points, cells) < 0
    cells[flip] = cells[flip][:, [0, 2, 1, 3]]
    tags = {}
    for name, surface_tags in surfaces.items():
        chunks = [np.zeros((0, 3), dtype=np.int64)]
        for s in surface_tags:
            _, tri_nodes = gmsh.model.mesh.getElementsByType(2, s)
            chunks.append(index[tri_nodes.astype(np.int64).reshape(-1, 3)])
        tags[name] = np.vstack(chunks)
    return _outward_tags(points, cells, tags)


def _surfaces(gmsh) -> list[tuple[int, np.ndarray]]:
    """(tag, bounding box [xmin, ymin, zmin, xmax, ymax, zmax]) of every model surface, sorted by tag."""
    out = []
    for _, tag in sorted(gmsh.model.getEntities(2)):
        out.append((tag, np.array(gmsh.model.getBoundingBox(2, tag))))
    return out


# ---------------------------------------------------------------------- rod
def rod(length=0.2, radius=0.01, *, h=None) -> Mesh:
    """Solid circular cylinder along +x from the origin, meshed with gmsh (OpenCASCADE).

    Args:
        length: length L [m] along x, > 0.
        radius: radius r [m], > 0.
        h: target tetrahedron edge length [m], > 0; default ``radius / 2``. Curved edges get at
            least 12 segments per turn whatever ``h``.

    Returns:
        Mesh with tags ``x0`` (disk at x = 0), ``x1`` (disk at x = L), ``side`` (lateral surface)
        and ``boundary``. The circle is approximated by an inscribed polygon, so the volume is
        slightly below pi r^2 L.

    Raises:
        InputError: non-positive or non-finite arguments, or h so small the mesh would be huge.
        MeshError: gmsh failed.
    """
    length = _positive("length", length)
    radius = _positive("radius", radius)
    h = radius / 2 if h is None else _positive("h", h)
    _check_size("rod", math.pi * radius**2 * length, h)
    with _gmsh_session("rod", _mesh_options(h)) as gmsh:
        gmsh.model.occ.addCylinder(0, 0, 0, length, 0, 0, radius)
        gmsh.model.occ.synchronize()
        tol = 1e-4 * min(length, radius)  # OCC bounding boxes are padded by ~1e-7 m
        groups: dict[str, list[int]] = {"x0": [], "x1": [], "side": []}
        for tag, bb in _surfaces(gmsh):
            if bb[3] - bb[0] > tol:
                groups["side"].append(tag)
            else:
                groups["x0" if abs(bb[0]) <= tol else "x1"].append(tag)
        return _generate(gmsh, "rod", groups)


# ---------------------------------------------------------------------- tuning fork
def tuning_fork(
    *,
    prong_length=0.08,
    prong_width=0.004,
    gap=0.008,
    thickness=0.006,
    base_length=0.012,
    handle_length=0.035,
    handle_radius=0.0025,
    h=0.002,
) -> Mesh:
    """A steel-fork-sized tuning fork: two prongs on a U base with a round stem (handle).

    Layout: prongs along +y from y = 0 to ``prong_length``, separated in x by ``gap`` and centred
    on x = 0; the base spans ``y in [-base_length, 0]``; the stem is a cylinder along -y below the
    base, centred in the thickness (z in [0, thickness]). With the defaults (80 mm prongs,
    4 mm in the bending direction, steel) the clamped-prong estimate is ~510 Hz and the flexible
    base brings the fundamental near 440 Hz.

    Args:
        prong_length: prong length [m].
        prong_width: prong size in x, the direction they vibrate in [m].
        gap: distance between the prongs [m].
        thickness: size in z of prongs and base [m].
        base_length: length in y of the base joining the prongs [m].
        handle_length: stem length [m].
        handle_radius: stem radius [m], smaller than ``thickness / 2``.
        h: target tetrahedron edge length [m].

    Returns:
        Mesh with tags ``handle`` (the stem's end disk), ``prongs`` (the sides and tips of both
        prongs, y > 0) and ``boundary``.

    Raises:
        InputError: non-positive sizes, a stem wider than the fork, h too small.
        MeshError: gmsh failed.
    """
    L = _positive("prong_length", prong_length)
    w = _positive("prong_width", prong_width)
    g = _positive("gap", gap)
    t = _positive("thickness", thickness)
    b = _positive("base_length", base_length)
    hl = _positive("handle_length", handle_length)
    r = _positive("handle_radius", handle_radius)
    h = _positive("h", h)
    if 2 * r >= t or 2 * r >= g + 2 * w:
        raise InputError(
            f"handle_radius={r:g} m must be smaller than thickness/2={t / 2:g} m and than half the fork width"
        )
    width = g + 2 * w
    volume = t * (2 * w * L + width * b) + math.pi * r**2 * hl
    _check_size("tuning_fork", volume, h)
    with _gmsh_session("tuning_fork", _mesh_options(h)) as gmsh:
        occ = gmsh.model.occ
        parts = [
            occ.addBox(-width / 2, -b, 0, width, b, t),
            occ.addBox(-width / 2, 0, 0, w, L, t),
            occ.addBox(g / 2, 0, 0, w, L, t),
            occ.addCylinder(0, -b, t / 2, 0, -hl, 0, r),
        ]
        occ.fuse([(3, parts[0])], [(3, p) for p in parts[1:]])
        occ.synchronize()
        if len(gmsh.model.getEntities(3)) != 1:
            raise MeshError("tuning_fork: the parts did not fuse into one solid")
        tol = 1e-4 * min(w, t)
        groups: dict[str, list[int]] = {"handle": [], "prongs": []}
        for tag, bb in _surfaces(gmsh):
            if bb[4] - bb[1] <= tol and abs(bb[1] + b + hl) <= tol:
                groups["handle"].append(tag)
            elif bb[1] >= -tol and bb[4] > tol:  # above the base, not the crotch at y = 0
                groups["prongs"].append(tag)
        return _generate(gmsh, "tuning_fork", groups)


# ---------------------------------------------------------------------- bell
def _bell_profile(R: float, H: float, t: float) -> tuple[list, list, float, float]:
    """Outer and inner (r, z) spline points of a church-bell section, lip at z = 0, crown at z = H.

    Proportions follow the classic minor-third bell: shoulder radius ~0.55 R, waist ~0.63 R at
    mid-height, and a sound bow (near the lip) about 2.5 times thicker than the waist ``t``.
    """
    bow = 2.5 * t
    outer = [(R, 0.0), (0.985 * R, 0.08 * H), (0.86 * R, 0.25 * H), (0.68 * R, 0.5 * H),
             (0.6 * R, 0.75 * H), (0.56 * R, 0.93 * H)]  # fmt: skip
    inner = [(R - bow, 0.0), (R - 1.2 * bow, 0.1 * H), (0.86 * R - 1.3 * t, 0.27 * H),
             (0.68 * R - t, 0.5 * H), (0.6 * R - t, 0.75 * H), (0.56 * R - 1.2 * t, H - 1.6 * t)]  # fmt: skip
    crown_r = 0.5 * R  # radius of the flat crown on top
    return outer, inner, crown_r, H - 1.6 * t


def bell(*, diameter=0.2, height=0.16, thickness=0.006, h=0.01) -> Mesh:
    """A church-bell-shaped solid of revolution about the z axis (lip at z = 0, crown on top).

    The profile is a thick-walled bell section (see ``_bell_profile``): a flat crown, shoulder,
    waist and a thickened sound bow ending in a flat lip, revolved by 360 degrees with gmsh OCC.
    The defaults are a 200 mm bronze hand-bell size.

    Args:
        diameter: outer diameter at the lip [m].
        height: height from lip to the top of the crown [m]; between 0.4 and 1.5 diameters.
        thickness: wall thickness at the waist [m] (the sound bow is 2.5 times thicker); less than
            diameter / 12.
        h: target tetrahedron edge length [m].

    Returns:
        Mesh with tags ``crown`` (the flat top, where it hangs), ``lip`` (bottom rim annulus),
        ``outer`` (outside of the wall), ``inner`` (inside of the wall and crown) and ``boundary``.

    Raises:
        InputError: non-positive sizes, out-of-proportion height or thickness, h too small.
        MeshError: gmsh failed.
    """
    D = _positive("diameter", diameter)
    H = _positive("height", height)
    t = _positive("thickness", thickness)
    h = _positive("h", h)
    if not 0.4 * D <= H <= 1.5 * D:
        raise InputError(f"bell height={H:g} m must be between 0.4 and 1.5 times the diameter {D:g} m")
    if t >= D / 12:
        raise InputError(f"bell thickness={t:g} m must be less than diameter/12 = {D / 12:g} m")
    R = D / 2
    _check_size("bell", 2 * math.pi * 0.75 * R * 1.3 * H * 1.5 * t, h)
    outer, inner, crown_r, crown_z = _bell_profile(R, H, t)
    with _gmsh_session("bell", _mesh_options(h)) as gmsh:
        occ = gmsh.model.occ

        def pts(rz):
            return [occ.addPoint(r, 0, z) for r, z in rz]

        top_axis, top_edge = occ.addPoint(0, 0, H), occ.addPoint(crown_r, 0, H)
        o = pts(outer)
        i = pts(inner)
        in_axis = occ.addPoint(0, 0, crown_z)
        curves = [
            occ.addLine(top_axis, top_edge),
            occ.addSpline([top_edge] + o[::-1]),
            occ.addLine(o[0], i[0]),
            occ.addSpline(i),
            occ.addLine(i[-1], in_axis),
            occ.addLine(in_axis, top_axis),
        ]
        face = occ.addPlaneSurface([occ.addCurveLoop(curves)])
        occ.revolve([(2, face)], 0, 0, 0, 0, 0, 1, 2 * math.pi)
        occ.remove([(2, face)])  # the generating face would otherwise stay as a loose surface
        occ.synchronize()
        if len(gmsh.model.getEntities(3)) != 1:
            raise MeshError("bell: the revolved profile is not one solid")
        tol = 1e-4 * t
        groups: dict[str, list[int]] = {"crown": [], "lip": [], "outer": [], "inner": []}
        for tag, bb in _surfaces(gmsh):
            flat = bb[5] - bb[2] <= tol
            if flat and abs(bb[2] - H) <= tol:
                groups["crown"].append(tag)
            elif flat and abs(bb[2]) <= tol:
                groups["lip"].append(tag)
            elif bb[3] > R - 1.25 * t:
                groups["outer"].append(tag)
            else:
                groups["inner"].append(tag)
        return _generate(gmsh, "bell", groups)


#: CLI name -> generator; every argument has a default.
GENERATORS: dict[str, Callable[..., Mesh]] = {
    "box": box,
    "plate": plate,
    "rod": rod,
    "tuning_fork": tuning_fork,
    "bell": bell,
}
