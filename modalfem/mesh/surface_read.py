"""Reading and cleaning triangle surfaces (STL, OBJ, PLY, OFF) before they are made solid.

* ``read_surface(path, unit_scale=...)``: vertices [m] and triangles of a surface file (quads and
  polygons split into fans), one-line ``MeshError`` for what cannot be read.
* ``clean_surface(v, f, where)``: coincident vertices merged, degenerate and duplicate triangles
  dropped; flat and fully degenerate surfaces refused.
* ``edge_stats(f)``: boundary, non-manifold and flipped edge counts; ``open_fraction``: how much of a
  surface its holes span (1 for a flat sheet); ``decimate``: quadric decimation (fast-simplification).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from modalfem.errors import MeshError
from modalfem.mesh.core import check_simplices
from modalfem.mesh.io import SURFACE_SUFFIXES

__all__ = ["clean_surface", "decimate", "edge_stats", "open_fraction", "read_surface"]


# ---------------------------------------------------------------------------------- reading
def read_surface(path, *, unit_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle surface from STL (ASCII or binary), OBJ, PLY (ASCII or binary) or OFF.

    Quads and polygons are split into triangle fans; other cells (lines, points) are ignored.

    Args:
        path: surface file.
        unit_scale: factor turning file coordinates into metres (1e-3 for a file in mm).

    Returns:
        (vertices (n, 3) [m], triangles (m, 3) int64).

    Raises:
        MeshError: missing, empty or unparsable file, or no triangles in it (one line).
    """
    from modalfem.mesh.generators import _positive

    scale = _positive("unit_scale", unit_scale, unit="metres per file unit")
    p = Path(path)
    if not p.exists():
        raise MeshError(f"surface file not found: {p}")
    if not p.is_file():
        raise MeshError(f"surface path is not a regular file: {p}")
    if p.suffix.lower() not in SURFACE_SUFFIXES:
        raise MeshError(f"{p} is not a surface file (known: {', '.join(SURFACE_SUFFIXES)})")
    if p.stat().st_size == 0:
        raise MeshError(f"empty mesh file {p}: it has 0 bytes")
    import contextlib
    import io

    import meshio

    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = meshio.read(p, file_format={".stl": "stl", ".obj": "obj", ".ply": "ply", ".off": "off"}[p.suffix.lower()])
    except (Exception, SystemExit) as exc:
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        fmt = p.suffix.lower()
        raise MeshError(f"cannot read mesh file {p} as {fmt} ({fmt[1:]}): corrupt, truncated or not in that format "
                        f"({detail})") from None
    points = np.asarray(m.points, dtype=np.float64)
    if points.ndim == 2 and points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    tris = []
    for block in m.cells:
        data = np.asarray(block.data, dtype=np.int64)
        if block.type == "triangle":
            tris.append(data)
        elif block.type in ("quad", "polygon") or (block.type.startswith("polygon") and data.ndim == 2):
            k = data.shape[1]
            tris += [data[:, [0, i, i + 1]] for i in range(1, k - 1)]
    if not tris or sum(len(t) for t in tris) == 0:
        kinds = ", ".join(f"{b.type} x {len(b.data)}" for b in m.cells) or "no faces"
        raise MeshError(f"{p} has no triangles to make a solid from ({len(points)} points, {kinds})")
    return points * scale, np.vstack(tris)


# ---------------------------------------------------------------------------------- cleaning
def clean_surface(v: np.ndarray, f: np.ndarray, where: str):
    """Merge coincident vertices, drop degenerate and duplicate triangles; (v, f, repairs, diagonal)."""
    v, f = check_simplices(v, f, corners=3, noun=f"surface {where}", cell="triangle", cells_name="triangles")
    repairs = []
    diag = float(np.linalg.norm(v[np.unique(f)].max(axis=0) - v[np.unique(f)].min(axis=0)))
    if diag == 0:
        raise MeshError(f"surface {where} is degenerate: all its triangles collapse to one point")
    key = np.round(v / (1e-10 * diag)).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    merged = len(v) - len(first)
    v, f = v[first], inv.ravel()[f]
    if merged:
        repairs.append(f"merged {merged} coincident vertices")
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    good = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]) & (area > 1e-14 * diag**2)
    if not good.all():
        repairs.append(f"dropped {int((~good).sum())} degenerate triangles")
    f = f[good]
    if len(f) == 0:
        raise MeshError(f"surface {where} is degenerate: all {len(good)} triangles have zero area")
    _, keep = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    if len(keep) < len(f):
        repairs.append(f"dropped {len(f) - len(keep)} duplicate triangles")
    f = f[np.sort(keep)]
    used = np.unique(f)
    new = np.full(len(v), -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    v, f = v[used], new[f]
    spread = np.linalg.svd(v - v.mean(axis=0), compute_uv=False)
    if spread[-1] <= 1e-6 * spread[0]:
        raise MeshError(f"surface {where} is flat (all {len(v)} vertices lie in one plane): it encloses no volume")
    return v, f, repairs, diag


def edge_stats(f: np.ndarray):
    """(boundary edge count, non-manifold edge count, flipped edge count, boundary edges (b, 2))."""
    directed = f[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    und = np.sort(directed, axis=1)
    uniq, inv, counts = np.unique(und, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    forward = np.bincount(inv, weights=(directed[:, 0] < directed[:, 1]).astype(float), minlength=len(uniq))
    flipped = int(np.sum((counts == 2) & (forward != 1)))
    return int(np.sum(counts == 1)), int(np.sum(counts > 2)), flipped, uniq[counts == 1]


def open_fraction(v, f, boundary_edges) -> float:
    """Sum of the vector areas of the boundary loops over the surface area (1 for a flat sheet)."""
    if len(boundary_edges) == 0:
        return 0.0
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(v)
    e = boundary_edges
    g = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, label = connected_components(g, directed=False)
    # vector area of each loop: 0.5 sum p_i x p_j over its edges, oriented by walking the loop
    adj: dict[int, list[int]] = {}
    for a, b in e.tolist():
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, []).append(a)
    seen: set[tuple[int, int]] = set()
    loops = np.zeros((label.max() + 1, 3))
    for a0, b0 in e.tolist():
        if (a0, b0) in seen or (b0, a0) in seen:
            continue
        a, b = a0, b0
        while (a, b) not in seen and (b, a) not in seen:
            seen.add((a, b))
            loops[label[a]] += 0.5 * np.cross(v[a], v[b])
            nxt = [c for c in adj[b] if c != a and (b, c) not in seen and (c, b) not in seen]
            if not nxt:
                break
            a, b = b, nxt[0]
    p = v[f]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    return float(np.linalg.norm(loops, axis=1).sum() / area)


def decimate(v, f, target: int):
    import fast_simplification

    vv, ff = fast_simplification.simplify(v, f.astype(np.int32), target_reduction=1.0 - target / len(f))
    return np.asarray(vv, dtype=np.float64), np.asarray(ff, dtype=np.int64)
