"""Solid tetrahedral meshes from surface meshes (STL, OBJ, PLY, OFF or arrays), with a quality report.

``from_surface(source, h=...)`` returns a ``Mesh``; ``tetrahedralize(source, ...)`` returns the mesh
and a ``SurfaceReport``. The pipeline (``method="auto"``), chosen by measurement (``modalfem bench
surface``, BENCHMARKS.md):

1. **Clean**: merge coincident vertices, drop degenerate and duplicate triangles, count boundary
   edges (holes), non-manifold edges and orientation flips. A surface that cannot be made solid is
   refused with one ``MeshError`` line: no triangles, a point cloud, a flat (planar) surface, or an
   open sheet/shell (its boundary loops span more than ``max_open_fraction`` of its area).
2. **Decimate** scans much finer than ``h`` (quadric decimation, ``fast-simplification``) to at most
   ``max_triangles`` triangles.
3. **Closed, manifold, consistently oriented surfaces**: gmsh meshes the volume inside the
   (cleaned) triangles, with interior size ``h``: 2-10x faster than fTetWild and exact to the input
   surface (bench: the bunny in ~3 s). Its tetrahedra inherit the input's triangles, so CAD STLs with
   long skinny triangles give slivers (worst radius ratio 0.000-0.026 on gmsh's own example parts):
   below a quarter of the bound, or still below the bound after optimising, or when gmsh fails
   (self-intersections: "PLC Error"), step 4 is taken instead.
4. **Anything else** (holes, non-manifold edges, self-intersections, flipped triangles): fTetWild
   (``pytetwild``, MPL-2.0), which keeps the tetrahedra inside the input's generalised winding
   number and stays within an envelope ``envelope * diagonal`` of the input surface. It runs in a
   child process (it holds the GIL for its whole run: the CLI's progress line and Ctrl-C stay alive).
5. **Optimise** (``modalfem.mesh.tet_quality.improve_quality``): boundary slivers removed, interior
   vertices smoothed, until the worst radius ratio ``3 r_in / R_circ`` reaches ``quality_bound``
   (0.1 by default). fTetWild's output varies from run to run: when its optimised mesh misses the
   bound, fTetWild runs once more asking for better elements (AMIPS stop energy ``RETRY_STOP_ENERGY``
   instead of 10; slower) and the better of the two meshes is kept. A mesh that still misses the bound
   gets a ``QualityWarning`` and says so in the report.

The report gives tets, worst quality, the volume against the surface's own (signed volume of the
closed surface; not defined for a surface with holes) and the sampled Hausdorff distance between the
input surface and the tet mesh's boundary, both ways.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import math
import os
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from modalfem.errors import BackendUnavailableError, InputError, MeshError
from modalfem.mesh.core import Mesh, signed_volumes
from modalfem.mesh.io import SURFACE_SUFFIXES  # file suffixes read as surfaces by mesh.read and the CLI
from modalfem.mesh.surface_read import clean_surface, decimate, edge_stats, open_fraction, read_surface
from modalfem.mesh.tet_quality import improve_quality, radius_ratio, sampled_distances

__all__ = ["SURFACE_SUFFIXES", "QUALITY_BOUND", "QualityWarning", "SurfaceReport", "Tetrahedralization", "load_surface",
           "from_surface", "is_surface_file", "read_surface", "tetrahedralize"]

#: default lower bound of the worst tetrahedron's radius ratio 3 r_in / R_circ after optimisation
QUALITY_BOUND = 0.1
STOP_ENERGY = 10.0  # fTetWild's default AMIPS stop energy
RETRY_STOP_ENERGY = 8.0  # its second run, when the first one's optimised mesh misses the quality bound
#: default target element size as a fraction of the bounding-box diagonal (fTetWild's default)
H_FRACTION = 0.05
#: smallest h accepted, as a fraction 1/MAX_DIVISIONS of the bounding-box diagonal (a cube: ~7e7 tets)
MAX_DIVISIONS = 400


class QualityWarning(UserWarning):
    """The tetrahedralised surface's worst element stays below the quality bound after optimisation."""


@dataclass(frozen=True)
class SurfaceReport:
    """What became of a surface: cleaning, method, size, quality, volume and distance to the input.

    Attributes:
        source: file name or ``"arrays"``.
        method: ``"gmsh"`` (volume inside the kept surface) or ``"ftetwild"``.
        input_triangles: triangles in the input.
        triangles_meshed: triangles handed to the mesher (after cleaning and decimation).
        boundary_edges: edges of the cleaned input used by one triangle (holes).
        nonmanifold_edges: edges used by three or more triangles.
        flipped_edges: manifold edges whose two triangles disagree in orientation.
        repairs: what cleaning, decimation and optimisation did, one phrase each.
        h: target element size [m].
        tets: tetrahedra of the result.
        points: vertices of the result.
        worst_quality: worst radius ratio after optimisation (1 regular, 0 flat).
        worst_quality_before: worst radius ratio as the mesher left it.
        quality_bound: the bound aimed at.
        volume: volume of the tet mesh [m^3].
        surface_volume: volume enclosed by the cleaned input [m^3] (None if it has holes or
            non-manifold edges: then it encloses no well-defined volume).
        volume_error: ``volume / surface_volume - 1`` (None when surface_volume is None).
        hausdorff: sampled Hausdorff distance [m] between input surface and tet boundary.
        distance_input_to_mesh: largest sampled distance [m] from the input to the tet boundary.
        distance_mesh_to_input: largest sampled distance [m] from the tet boundary to the input.
        distance_p95: 95th percentile [m] of the sampled distances both ways (holes filled, fins and
            spikes dropped by the repair dominate the Hausdorff distance; this shows the rest).
        diagonal: bounding-box diagonal of the input [m].
        timings: wall seconds per stage.
    """

    source: str
    method: str
    input_triangles: int
    triangles_meshed: int
    boundary_edges: int
    nonmanifold_edges: int
    flipped_edges: int
    repairs: tuple[str, ...]
    h: float
    tets: int
    points: int
    worst_quality: float
    worst_quality_before: float
    quality_bound: float
    volume: float
    surface_volume: float | None
    volume_error: float | None
    hausdorff: float
    distance_input_to_mesh: float
    distance_mesh_to_input: float
    distance_p95: float
    diagonal: float
    timings: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready dict (stored in modes.json as ``source.surface``)."""
        d = asdict(self)
        d["repairs"] = list(self.repairs)
        return d

    def lines(self) -> list[str]:
        """The report as a few readable lines."""
        defects = (f"{self.boundary_edges} boundary edges, {self.nonmanifold_edges} non-manifold edges, "
                   f"{self.flipped_edges} flipped edges")
        vol = (f"volume {self.volume:.6g} m^3 vs the surface's {self.surface_volume:.6g} m^3 "
               f"({100 * self.volume_error:+.2f} %)" if self.surface_volume is not None
               else f"volume {self.volume:.6g} m^3 (the input has holes: it encloses no volume to compare)")
        ok = "above" if self.worst_quality >= self.quality_bound else "BELOW"
        return [
            f"surface {self.source}: {self.input_triangles} triangles ({defects})"
            + (f"; {'; '.join(self.repairs)}" if self.repairs else ""),
            f"solid: {self.method}, h {self.h:.4g} m -> {self.tets} tets, {self.points} points, worst quality "
            f"{self.worst_quality:.3f} ({ok} the bound {self.quality_bound:g}; {self.worst_quality_before:.3f} "
            f"before optimisation)",
            f"{vol}; Hausdorff distance {self.hausdorff:.3g} m = {100 * self.hausdorff / self.diagonal:.2f} % of the "
            f"diagonal (input->mesh {self.distance_input_to_mesh:.3g} m, mesh->input {self.distance_mesh_to_input:.3g} m; "
            f"95 % of the samples within {self.distance_p95:.3g} m)",
        ]

    def __str__(self) -> str:
        return "\n".join(self.lines())


@dataclass(frozen=True, eq=False)
class Tetrahedralization:
    """A solid tetrahedral mesh made from a surface, with its ``SurfaceReport``."""

    mesh: Mesh
    report: SurfaceReport


def is_surface_file(path) -> bool:
    """True when ``path``'s suffix is one of ``SURFACE_SUFFIXES`` (case-insensitive)."""
    return isinstance(path, (str, os.PathLike)) and Path(path).suffix.lower() in SURFACE_SUFFIXES



# ---------------------------------------------------------------------------------- meshers
def _gmsh_volume(v, f, h):
    """gmsh: the volume inside the given (closed, manifold) triangles, interior size ``h`` [m]."""
    from modalfem.mesh.generators import _gmsh_session

    options = {"Mesh.MeshSizeMax": h, "Mesh.MeshSizeMin": 0.0, "Mesh.Optimize": 1, "Mesh.OptimizeNetgen": 1,
               "Mesh.Algorithm3D": 1}
    with _gmsh_session("surface volume", options) as gmsh:
        s = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addNodes(2, s, np.arange(1, len(v) + 1), v.ravel())
        gmsh.model.mesh.addElementsByType(s, 2, [], (f + 1).ravel())
        loop = gmsh.model.geo.addSurfaceLoop([s])
        gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        gmsh.model.mesh.generate(3)
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        _, nodes = gmsh.model.mesh.getElementsByType(4)
    if len(nodes) == 0:
        raise MeshError("gmsh made no tetrahedra inside the surface")
    tags = tags.astype(np.int64)
    lookup = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    lookup[tags] = np.arange(len(tags))
    return xyz.reshape(-1, 3), lookup[nodes.astype(np.int64)].reshape(-1, 4)


def _tetwild_module():
    """fTetWild's compiled wrapper from ``pytetwild``, without its package ``__init__`` (which imports
    pyvista and VTK only for its PyVista helpers; modalfem needs the arrays-in, arrays-out call)."""
    spec = importlib.util.find_spec("pytetwild")
    if spec is None or not spec.submodule_search_locations:
        raise BackendUnavailableError(
            "this surface needs fTetWild (holes, non-manifold edges or self-intersections): pip install pytetwild")
    folder = list(spec.submodule_search_locations)[0]
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        so = os.path.join(folder, "PyfTetWildWrapper" + suffix)
        if os.path.exists(so):
            s = importlib.util.spec_from_file_location("PyfTetWildWrapper", so)
            module = importlib.util.module_from_spec(s)
            s.loader.exec_module(module)
            return module
    raise BackendUnavailableError(f"pytetwild at {folder} has no compiled PyfTetWildWrapper: reinstall pytetwild")


def _ftetwild_here(v, f, h, envelope, stop_energy=STOP_ENERGY):
    """fTetWild in this process (it holds the GIL for its whole run), on one thread: with its threads the result
    changes more from run to run (a real scan's worst element came out 0.085 in one run and above the 0.1 bound in
    others); on one thread it still varies (the damaged bunny's worst element before optimisation: 0.06-0.20 over
    20 runs), which the quality optimiser has to absorb. ``stop_energy``: fTetWild optimises until its worst
    element's AMIPS energy is below it (10 by default; lower asks for better elements, takes longer)."""
    wrapper = _tetwild_module()
    points, cells = wrapper.tetrahedralize_mesh(
        np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(f, dtype=np.uint32),
        True, False, 0.05, float(h), float(envelope), float(stop_energy), False, 1, 80, 6, True, False, False,
        np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int32), np.zeros(0))
    return np.asarray(points, dtype=np.float64), np.asarray(cells, dtype=np.int64)


def _ftetwild_worker(folder: str) -> None:
    """Child-process entry: ``folder/in.npz`` -> ``folder/out.npz``."""
    data = np.load(os.path.join(folder, "in.npz"))
    points, cells = _ftetwild_here(data["v"], data["f"], float(data["h"]), float(data["envelope"]),
                                   float(data["stop_energy"]))
    np.savez(os.path.join(folder, "out.npz"), points=points, cells=cells)


def _ftetwild(v, f, h, envelope, stop_energy=STOP_ENERGY):
    """fTetWild in a child process: it holds the GIL for its whole run, which would freeze the
    caller's progress display and its Ctrl-C/SIGTERM handling; the child is killed on either."""
    import subprocess
    import sys
    import tempfile

    _tetwild_module()  # a missing pytetwild is reported here, in one line
    with tempfile.TemporaryDirectory(prefix="modalfem-ftetwild-") as folder:
        np.savez(os.path.join(folder, "in.npz"), v=v, f=f, h=h, envelope=envelope, stop_energy=stop_energy)
        root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # holds modalfem/
        code = (f"import sys; sys.path.insert(0, {root!r}); from modalfem.mesh.solid import _ftetwild_worker; "
                f"_ftetwild_worker({folder!r})")
        # in the temporary folder: fTetWild writes a __tracked_surface.stl into its working directory
        child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 cwd=folder)
        try:
            _, err = child.communicate()
        except BaseException:
            child.kill()
            child.wait()
            raise
        if child.returncode != 0:
            lines = err.decode("utf-8", "replace").strip().splitlines()
            raise MeshError(f"fTetWild failed (exit code {child.returncode}): {lines[-1] if lines else 'no message'}")
        out = np.load(os.path.join(folder, "out.npz"))
        return np.asarray(out["points"], dtype=np.float64), np.asarray(out["cells"], dtype=np.int64)


# ---------------------------------------------------------------------------------- pipeline
def tetrahedralize(source, *, h: float | None = None, unit_scale: float = 1.0, method: str = "auto",
                   quality_bound: float = QUALITY_BOUND, envelope: float = 2e-3, max_triangles: int = 20000,
                   max_open_fraction: float = 0.6, progress: Callable[[str], None] | None = None) -> Tetrahedralization:
    """Make a solid tetrahedral mesh from a surface and report how close and how good it is.

    Args:
        source: a surface file (.stl, .obj, .ply, .off) or ``(vertices (n, 3), triangles (m, 3))``.
        h: target element size [m] (after ``unit_scale``); default 5 % of the bounding-box diagonal.
        unit_scale: factor turning file or array coordinates into metres.
        method: ``"auto"`` (gmsh for clean closed surfaces, else fTetWild), ``"gmsh"`` or ``"ftetwild"``.
        quality_bound: worst radius ratio to reach by optimisation (0 < bound < 1).
        envelope: fTetWild's envelope, the largest distance of the result's boundary from the input,
            as a fraction of the bounding-box diagonal.
        max_triangles: inputs with more triangles (and finer than ``h``) are decimated first.
        max_open_fraction: refuse open surfaces whose boundary loops span more than this fraction
            of their area: 1 for a flat sheet, ~0.8-1 for curved sheets, 0.5 for a hemisphere open at
            its base (a scanned dome without its bottom is accepted and filled), small for scans with holes.
        progress: called with one line per stage.

    Returns:
        ``Tetrahedralization`` (``mesh``: ``Mesh`` [m] with a ``"boundary"`` tag; ``report``: ``SurfaceReport``).

    Raises:
        MeshError: unreadable file, or a surface that cannot be made solid (one line saying why).
        InputError: bad option values.
        BackendUnavailableError: fTetWild needed but ``pytetwild`` not installed.

    Warns:
        QualityWarning: the worst tetrahedron stays below ``quality_bound`` (for fTetWild: after a second run).
    """
    say = progress or (lambda msg: None)
    if method not in ("auto", "gmsh", "ftetwild"):
        raise InputError(f"method must be 'auto', 'gmsh' or 'ftetwild', got {method!r}")
    if not (isinstance(quality_bound, (int, float)) and 0 < quality_bound < 1):
        raise InputError(f"quality_bound must be a number in (0, 1), got {quality_bound!r}")
    if not (isinstance(envelope, (int, float)) and 0 < envelope < 0.1):
        raise InputError(f"envelope must be a fraction of the diagonal in (0, 0.1), got {envelope!r}")
    timings: dict[str, float] = {}
    t = time.perf_counter()
    if isinstance(source, (str, os.PathLike)):
        where = str(source)
        v, f = read_surface(source, unit_scale=unit_scale)
    elif isinstance(source, (tuple, list)) and len(source) == 2:
        from modalfem.mesh.generators import _positive

        where = "arrays"
        v = np.asarray(source[0], dtype=np.float64) * _positive("unit_scale", unit_scale, unit="metres per unit")
        f = np.asarray(source[1])
    else:
        raise InputError(f"source must be a surface file path or (vertices, triangles), got {type(source).__name__}")
    input_triangles = len(f) if np.ndim(f) == 2 else 0
    v, f, repairs, diag = clean_surface(v, f, where)
    boundary, nonmanifold, flipped, bedges = edge_stats(f)
    if h is None:
        h = H_FRACTION * diag
    else:
        from modalfem.mesh.generators import _positive

        h = _positive("h", h)
    if h < diag / MAX_DIVISIONS:
        raise InputError(f"h = {h:.3g} m is below 1/{MAX_DIVISIONS} of the surface's {diag:.3g} m diagonal: that would "
                         f"make millions of tetrahedra (h is in metres after unit_scale={unit_scale:g})")
    if boundary:
        frac = open_fraction(v, f, bedges)
        if frac > max_open_fraction:
            raise MeshError(
                f"surface {where} cannot be made solid: it is open ({boundary} boundary edges) and its holes span "
                f"{100 * frac:.0f} % of its area, so it is a sheet or a shell, not the skin of a solid "
                f"(accepted up to {100 * max_open_fraction:.0f} %: close it, or give it a thickness)")
    closed = boundary == 0 and nonmanifold == 0 and flipped == 0
    surface_volume = None
    if closed:
        p = v[f]
        surface_volume = abs(float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0))
    timings["read+clean"] = time.perf_counter() - t
    say(f"surface: {input_triangles} triangles, {boundary} boundary / {nonmanifold} non-manifold / {flipped} flipped "
        f"edges, h {h:.3g} m")
    # decimation: only inputs much finer than h
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    wanted = int(min(max_triangles, max(2000, 4.0 * area / (math.sqrt(3) / 4 * h * h))))
    vm, fm = v, f
    if len(f) > 1.5 * wanted:
        t = time.perf_counter()
        say(f"surface: decimating {len(f)} -> {wanted} triangles")
        vm, fm = decimate(v, f, wanted)
        repairs.append(f"decimated {len(f)} -> {len(fm)} triangles")
        timings["decimate"] = time.perf_counter() - t
    result = None
    notes = []
    if method == "gmsh" or (method == "auto" and closed):
        t = time.perf_counter()
        say("surface: gmsh volume mesh inside the surface")
        try:
            result = ("gmsh", *_gmsh_volume(vm, fm, h))
        except MeshError as exc:
            if method == "gmsh":
                raise MeshError(f"surface {where}: gmsh could not mesh its inside ({exc}); try method='ftetwild'") from None
            notes.append("gmsh failed (self-intersecting surface?)")
        timings["gmsh"] = time.perf_counter() - t
        if result is not None:
            raw = float(radius_ratio(result[1], result[2]).min())
            if method == "auto" and raw < 0.25 * quality_bound:  # slivers on skinny input triangles
                notes.append(f"gmsh's worst quality {raw:.3f} (on the input's skinny triangles): fTetWild used")
                result = None
            else:
                result = _finish(result, quality_bound, say, timings)
            if result is not None and method == "auto" and result[3]["worst_after"] < quality_bound:
                notes.append(f"gmsh's worst quality {result[3]['worst_after']:.3f} < {quality_bound:g}")
                result = None
    if result is None:
        t = time.perf_counter()
        say(f"surface: fTetWild on {len(fm)} triangles (envelope {envelope:g} of the diagonal)")
        result = ("ftetwild", *_ftetwild(vm, fm, h, envelope))
        timings["ftetwild"] = time.perf_counter() - t
        if len(result[2]) == 0:
            raise MeshError(f"surface {where} cannot be made solid: fTetWild found no inside (it encloses no volume)")
        result = _finish(result, quality_bound, say, timings)
        if result[3]["worst_after"] < quality_bound:
            # fTetWild's output varies from run to run and a few runs leave elements the optimiser cannot
            # lift: a second run asking fTetWild for better elements; the better of the two is kept
            first = result[3]["worst_after"]
            say(f"surface: worst quality {first:.3f} < {quality_bound:g}: fTetWild again (stop energy "
                f"{RETRY_STOP_ENERGY:g})")
            t = time.perf_counter()
            again = ("ftetwild", *_ftetwild(vm, fm, h, envelope, RETRY_STOP_ENERGY))
            timings["ftetwild.retry"] = time.perf_counter() - t
            if len(again[2]):
                retry_timings: dict[str, float] = {}
                again = _finish(again, quality_bound, say, retry_timings)
                timings["ftetwild.retry.optimise"] = retry_timings["ftetwild.optimise"]
                second = again[3]["worst_after"]
                notes.append(f"fTetWild run again (stop energy {RETRY_STOP_ENERGY:g}): worst quality {first:.3f} -> "
                             f"{second:.3f}, the {'second' if second > first else 'first'} kept")
                if second > first:
                    result = again
    name, points, cells, info = result
    repairs += notes
    if info["removed_slivers"] or info["moved_vertices"]:
        repairs.append(f"optimised: {info['removed_slivers']} boundary slivers removed, "
                       f"{info['moved_vertices']} interior vertices moved")
    t = time.perf_counter()
    say("surface: checking the solid against the input (volume, Hausdorff distance)")
    mesh = Mesh(points, cells)
    mesh = Mesh(mesh.points, mesh.cells, {"boundary": mesh.boundary_facets})
    from modalfem.mesh.surface import boundary_surface

    skin = boundary_surface(mesh)
    near_in, near_out = sampled_distances((v, f), (skin.vertices, skin.triangles))
    d_in, d_out = float(near_in.max()), float(near_out.max())
    p95 = float(np.percentile(np.concatenate([near_in, near_out]), 95))
    timings["check"] = time.perf_counter() - t
    report = SurfaceReport(
        source=where, method=name, input_triangles=input_triangles, triangles_meshed=len(fm),
        boundary_edges=boundary, nonmanifold_edges=nonmanifold, flipped_edges=flipped, repairs=tuple(repairs),
        h=float(h), tets=mesh.cell_count, points=mesh.point_count, worst_quality=info["worst_after"],
        worst_quality_before=info["worst_before"], quality_bound=float(quality_bound), volume=mesh.volume,
        surface_volume=surface_volume,
        volume_error=None if surface_volume is None else mesh.volume / surface_volume - 1.0,
        hausdorff=max(d_in, d_out), distance_input_to_mesh=d_in, distance_mesh_to_input=d_out,
        distance_p95=p95, diagonal=diag,
        timings=timings)
    if report.worst_quality < quality_bound:
        warnings.warn(f"surface {where}: worst tetrahedron quality {report.worst_quality:.3f} stays below the bound "
                      f"{quality_bound:g} after optimisation", QualityWarning, stacklevel=2)
    return Tetrahedralization(mesh=mesh, report=report)


def _finish(result, bound, say, timings):
    """Orient the mesher's cells positively, drop flat ones, optimise; (name, points, cells, info)."""
    name, points, cells = result
    vol = signed_volumes(points, cells)
    cells = np.where((vol < 0)[:, None], cells[:, [0, 2, 1, 3]], cells)
    cells = cells[np.abs(vol) > 0]
    t = time.perf_counter()
    say(f"surface: optimising {len(cells)} tets (worst quality {radius_ratio(points, cells).min():.3f}, bound {bound:g})")
    points, cells, info = improve_quality(points, cells, bound=bound)
    timings[f"{name}.optimise"] = time.perf_counter() - t
    return name, points, cells, info


def from_surface(source, *, h: float | None = None, unit_scale: float = 1.0, method: str = "auto",
                 quality_bound: float = QUALITY_BOUND, progress: Callable[[str], None] | None = None) -> Mesh:
    """Solid tetrahedral ``Mesh`` [m] from a surface file or ``(vertices, triangles)`` arrays.

    Same arguments as :func:`tetrahedralize` (``h`` [m]: target element size, default 5 % of the
    bounding-box diagonal); use that function for the quality and distance report.

    Raises:
        MeshError: the surface cannot be read or made solid (one line saying why).
    """
    return tetrahedralize(source, h=h, unit_scale=unit_scale, method=method, quality_bound=quality_bound,
                          progress=progress).mesh


def load_surface(path, *, h: float | None = None, unit_scale: float = 1.0, progress=None,
                 others: dict | None = None) -> tuple[Mesh, dict]:
    """The CLI's mesh loading for a surface file: (mesh, source record with the report under "surface").

    ``progress`` (the CLI's stage printer) gets the stages and, at the end, the report's lines
    (through its ``done`` method when it has one). ``others``: generator options given on the
    command line, refused here in one line.
    """
    for opt, value in (others or {}).items():
        if value is not None:
            raise InputError(f"--{opt} is a generator option; {str(path)!r} is a surface file (it takes --h, --unit-scale)")
    result = tetrahedralize(path, h=h, unit_scale=unit_scale, progress=progress)
    from modalfem.mesh.io import _warn_about_size

    _warn_about_size(result.mesh, Path(path), float(unit_scale))  # a part in mm read as metres, ...
    done = getattr(progress, "done", None)
    for line in result.report.lines():
        if done is not None:
            done(line)
        elif progress is not None:
            progress(line)
    source = {"file": str(path), "unit_scale": unit_scale, "h": h, "surface": result.report.as_dict()}
    return result.mesh, source
