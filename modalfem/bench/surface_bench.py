"""``modalfem bench surface``: time and quality of turning surfaces into solid tet meshes, per method.

Surfaces (all from packages, nothing downloaded at run time):

* ``t13`` and ``object``: CAD-like closed STL parts shipped with the PyPI ``gmsh`` wheel
  (``share/doc/gmsh``; skipped with a note when that folder is absent): long skinny triangles.
* ``bunny``: the closed, decimated Stanford bunny of ``modalfem.meshes`` (bunny.ply).
* ``aneurysm``: a scan-derived vessel surface shipped with ``gmsh`` (open at its vessel ends).
* ``bunny-scan``: the bunny subdivided twice (58,784 triangles) and damaged like a raw scan by
  :func:`scan_like`: 3 holes, 6 non-manifold fins, 40 flipped triangles, a self-intersecting spike,
  written as an STL triangle soup.

Methods, each case in a fresh process with a timeout: ``gmsh`` (volume inside the kept surface),
``repair+gmsh`` (trimesh's repair first: orientation fixed, holes fan-filled; trimesh and networkx come
with the test extras), ``ftetwild`` (fTetWild through pytetwild on the input, or its decimation when finer than h), and
``auto`` (what ``modalfem.mesh.from_surface`` does, optimisation included). Reported per case: wall
time, tets, worst radius ratio before and after optimisation, volume against the closed surface's,
sampled Hausdorff distance as % of the bounding-box diagonal, and the time ratio to ``auto``.

Usage: ``python -m modalfem bench surface [--out BENCHMARKS.md] [--quick] [--timeout S]``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import glob
import json
import os
import shlex
import subprocess
import sys
import time
import warnings

import numpy as np

__all__ = ["CASES", "SECTION", "command", "run_case_here", "scan_like", "subdivide", "surface_case"]

SECTION = "## Surfaces to solids: `from_surface`"
CASES = ("t13", "object", "bunny", "aneurysm", "bunny-scan")
QUICK_CASES = ("bunny",)
METHODS = ("gmsh", "repair+gmsh", "ftetwild", "auto")


def subdivide(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into 4 at its edge midpoints (shared midpoints, same shape)."""
    e = np.sort(f[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    mid = len(v) + inv.ravel().reshape(-1, 3)
    v2 = np.vstack([v, 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])])
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    f2 = np.vstack([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]])
    return v2, f2


def scan_like(v: np.ndarray, f: np.ndarray, *, holes: int = 3, hole_radius: float = 0.06, fins: int = 6,
              flips: int = 40, spike: bool = True, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Damage a closed surface the way raw scans are damaged (deterministic for a seed).

    Args:
        v, f: vertices (n, 3) and triangles (m, 3) of a closed surface.
        holes: triangles within ``hole_radius`` x diagonal of that many random vertices are removed.
        fins: triangles added on random edges, sticking out (each edge then has 3 triangles).
        flips: triangles whose orientation is reversed.
        spike: add a small closed tetrahedron poking through the surface (self-intersections).

    Returns:
        (vertices, triangles) with holes, non-manifold edges, flipped triangles and intersections.
    """
    rng = np.random.default_rng(seed)
    v, f = np.array(v, dtype=np.float64), np.array(f, dtype=np.int64)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    centroid = v[f].mean(axis=1)
    keep = np.ones(len(f), dtype=bool)
    for c in rng.choice(len(v), size=holes, replace=False):
        keep &= np.linalg.norm(centroid - v[c], axis=1) > hole_radius * diag
    f = f[keep]
    normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    extra_v, extra_f = [], []
    for t in rng.choice(len(f), size=fins, replace=False):
        a, b = f[t, 0], f[t, 1]
        tip = 0.5 * (v[a] + v[b]) + 0.03 * diag * normal[t]
        extra_v.append(tip)
        extra_f.append([a, b, len(v) + len(extra_v) - 1])
    if spike:
        t = int(rng.integers(len(f)))
        c = v[f[t]].mean(axis=0)
        s = 0.02 * diag
        tet = c + s * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
        base = len(v) + len(extra_v)
        extra_v += list(tet)
        extra_f += [[base + i, base + j, base + k] for i, j, k in ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1))]
    flip = rng.choice(len(f), size=min(flips, len(f)), replace=False)
    f[flip] = f[flip][:, ::-1]
    v = np.vstack([v] + ([np.array(extra_v)] if extra_v else []))
    f = np.vstack([f] + ([np.array(extra_f, dtype=np.int64)] if extra_f else []))
    return v, f


def _gmsh_data(name: str) -> str | None:
    hits = glob.glob(os.path.join(sys.prefix, "share", "doc", "gmsh", "**", name), recursive=True)
    return hits[0] if hits else None


def surface_case(name: str, folder: str) -> tuple[str | None, str]:
    """(path of the surface file for case ``name``, one-line description); path None when unavailable."""
    from modalfem.meshes import path as shipped

    if name == "t13":
        return _gmsh_data("t13_data.stl"), "CAD part (gmsh t13_data.stl), closed, skinny triangles"
    if name == "object":
        return _gmsh_data("object.stl"), "CAD part (gmsh object.stl), closed"
    if name == "aneurysm":
        return _gmsh_data("aneurysm_data.stl"), "scan-derived vessel (gmsh aneurysm_data.stl), open ends"
    bunny = str(shipped("bunny.ply"))
    if name == "bunny":
        return bunny, "Stanford bunny, closed (modalfem.meshes bunny.ply)"
    if name == "bunny-scan":
        import meshio

        m = meshio.read(bunny)
        v, f = m.points.astype(np.float64), m.cells_dict["triangle"].astype(np.int64)
        v, f = subdivide(*subdivide(v, f))
        v, f = scan_like(v, f)
        out = os.path.join(folder, "bunny_scan.stl")
        meshio.write(out, meshio.Mesh(v[f].reshape(-1, 3), [("triangle", np.arange(3 * len(f)).reshape(-1, 3))]),
                     binary=True)
        return out, "bunny subdivided x2 + scan damage (holes, fins, flips, spike), STL soup"
    raise ValueError(f"unknown case {name!r}")


def reference_volume(name: str) -> float | None:
    """Volume [file units^3] the solid of a damaged case should have: the undamaged closed bunny's for
    ``bunny-scan`` (subdividing at edge midpoints does not change it), None for the others."""
    if name != "bunny-scan":
        return None
    import meshio

    from modalfem.meshes import path as shipped

    m = meshio.read(str(shipped("bunny.ply")))
    p = m.points.astype(np.float64)[m.cells_dict["triangle"]]
    return float(abs(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum()) / 6.0)


def _trimesh_repair(path: str) -> tuple[np.ndarray, np.ndarray]:
    """The repair step a graphics user would try first: trimesh (MIT; test extras, bench only) merging
    vertices, dropping degenerate and duplicate faces, fixing the orientation and filling holes."""
    try:
        import trimesh
    except ImportError:
        raise RuntimeError("trimesh and networkx not installed (test extras): pip install trimesh networkx") from None
    from modalfem.mesh.surface_read import read_surface

    m = trimesh.Trimesh(*read_surface(path), process=True)
    m.update_faces(m.nondegenerate_faces())
    m.update_faces(m.unique_faces())
    trimesh.repair.fix_normals(m)
    trimesh.repair.fill_holes(m, use_fan=True)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def run_case_here(path: str, method: str) -> dict:
    """Tetrahedralise ``path`` with ``method`` in this process; returns the report's numbers and the time."""
    from modalfem.mesh.solid import tetrahedralize

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if method == "repair+gmsh":
            r = tetrahedralize(_trimesh_repair(path), method="gmsh").report
        else:
            r = tetrahedralize(path, method=method).report
    out = r.as_dict()
    out["seconds"] = time.perf_counter() - t0
    return out


def _run_case(path: str, method: str, timeout: float) -> dict:
    cmd = [sys.executable, "-m", "modalfem.bench.surface_bench", "--case", json.dumps([path, method])]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout:.0f} s"}
    if p.returncode != 0:
        return {"error": (p.stderr.strip().splitlines() or ["failed"])[-1][:160]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def _load() -> str:
    try:
        one, five, _ = os.getloadavg()
        return f"load average {one:.1f} (1 min) / {five:.1f} (5 min) at the start"
    except OSError:
        return "load average unknown"


def _section(rows, command_line: str, seconds: float, load: str) -> str:
    from modalfem.bench.cli import _machine

    today = _dt.datetime.now(_dt.timezone.utc).date().isoformat()
    head = (f"Command: `{command_line}` ({today}, {seconds:.0f} s). Machine: {_machine()}; {load} (a load above "
            f"the core count means other work shared the machine: times are then upper bounds). Each case runs in "
            f"a fresh process; fTetWild uses every core.")
    method = ("Methods: `gmsh` meshes the volume inside the kept (cleaned) surface triangles, interior size h; "
              "`repair+gmsh` first runs trimesh's repair (merge, degenerate and duplicate faces dropped, "
              "`fix_normals`, `fill_holes(use_fan=True)`: fans across each boundary loop; non-manifold edges and "
              "intersections stay); "
              "`ftetwild` runs fTetWild (pytetwild) with edge length h and envelope 2e-3 of the diagonal on the "
              "input (decimated to <= 20,000 triangles when finer than h); `auto` is `from_surface`: gmsh for "
              "clean closed surfaces unless its worst tet is below 1/4 of the bound, else fTetWild, then the "
              "optimiser (boundary slivers removed, interior vertices smoothed) towards worst radius ratio >= 0.1. "
              "h = 5 % of the bounding-box diagonal. Quality: radius ratio 3 r_in / R_circ (1 regular, 0 flat). "
              "Volume: against the closed input's enclosed volume ('-' for open inputs; for bunny-scan against the "
              "undamaged bunny's). Hausdorff: sampled both ways between the input and the tet boundary (vertices + "
              "5,000 random points each); on damaged inputs it measures the repair (filled holes, dropped fins and "
              "spikes), the 95th percentile of the same samples the fidelity elsewhere. fTetWild runs with threads "
              "and is not deterministic: `ftetwild` and `auto (ftetwild)` rows are two runs of the same pipeline.")
    lines = [SECTION, "", head, "", method, "",
             "| surface | triangles | defects (boundary / non-manifold / flipped edges) | method | s | vs auto | tets "
             "| worst q (raw -> optimised) | volume vs surface | Hausdorff % diag | 95 % of samples within, % diag |",
             "|---|---:|---|---|---:|---:|---:|---|---:|---:|---:|"]
    for name, desc, method_name, r, ref in rows:
        if "error" in r:
            lines.append(f"| {name}: {desc} | | | {method_name} | failed: {r['error']} | | | | | | |")
            continue
        ratio = f"{r['seconds'] / ref['seconds']:.2f}x" if ref and "error" not in ref else "-"
        vol = "-" if r["volume_error"] is None else f"{100 * r['volume_error']:+.2f} %"
        if r.get("volume_reference"):
            vol += f" ({r['volume_reference']})"
        lines.append(
            f"| {name}: {desc} | {r['input_triangles']} | {r['boundary_edges']} / {r['nonmanifold_edges']} / "
            f"{r['flipped_edges']} | {method_name}{' (' + r['method'] + ')' if method_name == 'auto' else ''} | "
            f"{r['seconds']:.1f} | {ratio} | {r['tets']} | {r['worst_quality_before']:.3f} -> {r['worst_quality']:.3f} "
            f"| {vol} | {100 * r['hausdorff'] / r['diagonal']:.3f} | {100 * r['distance_p95'] / r['diagonal']:.3f} |")
    return "\n".join(lines) + "\n"


def command(argv: list[str]) -> int:
    """``modalfem bench surface``: run every case and method, print the section, write it into ``--out``."""
    import tempfile

    from modalfem.bench.cli import update_section

    ap = argparse.ArgumentParser(prog="modalfem bench surface")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose surface section is replaced")
    ap.add_argument("--quick", action="store_true", help="the closed bunny only (smoke test)")
    ap.add_argument("--timeout", type=float, default=600.0, help="kill a case after S seconds")
    a = ap.parse_args(argv)
    command_line = "python -m modalfem bench surface" + ("" if not argv else " " + shlex.join(argv))
    load = _load()
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for name in QUICK_CASES if a.quick else CASES:
            path, desc = surface_case(name, folder)
            if path is None:
                rows.append((name, desc, "-", {"error": "file not found (gmsh's share/doc folder absent)"}, None))
                continue
            results = {}
            for method in METHODS:
                print(f"[bench surface] {name} {method} ...", file=sys.stderr, flush=True)
                results[method] = _run_case(path, method, a.timeout)
                r = results[method]
                brief = r.get("error") or f"{r['seconds']:.1f} s, {r['tets']} tets, q {r['worst_quality']:.3f}"
                print(f"[bench surface] {name} {method}: {brief}", file=sys.stderr, flush=True)
            ref_volume = reference_volume(name)
            for r in results.values():
                if ref_volume is not None and "error" not in r:
                    r["volume_error"], r["volume_reference"] = r["volume"] / ref_volume - 1.0, "undamaged"
            rows += [(name, desc, m, results[m], results["auto"]) for m in METHODS]
    text = _section(rows, command_line, time.perf_counter() - t0, load)
    print(text)
    update_section(a.out, text)
    return 0 if all("error" not in r for _, _, m, r, _ in rows if m == "auto") else 1


def _main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", required=True)
    path, method = json.loads(ap.parse_args().case)
    print(json.dumps(run_case_here(path, method)))
    return 0


if __name__ == "__main__":
    sys.exit(_main())
