"""Tetrahedron quality, a quality optimiser that keeps the boundary, and surface-to-surface distances.

* ``radius_ratio(points, cells)``: ``3 r_in / R_circ`` per tetrahedron, 1 for the regular
  tetrahedron and 0 for a flat one (slivers, needles and caps all go to 0).
* ``improve_quality(points, cells, bound=...)``: raises the worst radius ratio without moving the
  boundary: (1) flat tetrahedra lying on the boundary (two or three boundary faces, quality below
  the bound) are removed when that makes no boundary edge open or non-manifold, (2) interior vertices of bad
  tetrahedra are moved towards the centroid of their neighbours (full, half or quarter step),
  then, if that is not enough, uphill on the worst quality of the tetrahedra around the vertex
  (finite-difference gradient, backtracking); a move is kept only when it raises the worst
  quality of the tetrahedra around the vertex and inverts none.
* ``surface_distances(a, b)``: sampled one-sided distances between two triangle surfaces (every
  vertex plus area-uniform random points), exact point-triangle distances, for a Hausdorff
  distance (its maximum both ways).
"""

from __future__ import annotations

import numpy as np

__all__ = ["distance_to_surface", "improve_quality", "radius_ratio", "sampled_distances", "surface_distances"]

_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


def radius_ratio(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Normalised radius ratio ``3 r_in / R_circ`` (m,) of tetrahedra ``cells`` (m, 4) over ``points`` (n, 3) [m].

    1 for a regular tetrahedron, 0 for a degenerate one; scale-invariant, independent of the
    orientation (inverted cells get the ratio of their mirror image).
    """
    p = np.asarray(points, dtype=np.float64)[np.asarray(cells)]
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    six_v = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    area = np.zeros(len(p))
    for i, j, k in _FACES:
        area += 0.5 * np.linalg.norm(np.cross(p[:, j] - p[:, i], p[:, k] - p[:, i]), axis=1)
    num = (np.einsum("ij,ij->i", a, a)[:, None] * np.cross(b, c) + np.einsum("ij,ij->i", b, b)[:, None]
           * np.cross(c, a) + np.einsum("ij,ij->i", c, c)[:, None] * np.cross(a, b))
    with np.errstate(divide="ignore", invalid="ignore"):
        r_in = 0.5 * six_v / area  # 3 V / A
        r_circ = np.linalg.norm(num, axis=1) / (2.0 * six_v)
        q = 3.0 * r_in / r_circ
    return np.where(six_v > 0, np.nan_to_num(q, nan=0.0), 0.0)


def boundary_faces(cells: np.ndarray) -> np.ndarray:
    """Faces (b, 3) used by exactly one tetrahedron, outward for positively oriented cells."""
    faces = np.asarray(cells)[:, _FACES].reshape(-1, 3)
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inv.ravel()] == 1]


def _bad_edges(faces: np.ndarray) -> set:
    """Edges of the triangles ``faces`` not used by exactly two of them (boundary or non-manifold edges)."""
    e = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    u, counts = np.unique(e, axis=0, return_counts=True)
    return {(int(a), int(b)) for a, b in u[counts != 2]}


def _remove_boundary_slivers(points, cells, bound):
    """Drop bad tetrahedra with two or more boundary faces where that adds no open or non-manifold boundary edge.

    The check is relative to the mesh's own boundary: fTetWild may return a boundary that is not a closed
    manifold already (two parts meeting along an edge, used by four boundary faces); a sliver elsewhere is
    still removed as long as its removal makes no edge bad that was not bad before.
    """
    faces = cells[:, _FACES].reshape(-1, 3)
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    on_boundary = (counts[inv.ravel()] == 1).reshape(-1, 4).sum(axis=1)
    q = radius_ratio(points, cells)
    drop = (q < bound) & (on_boundary >= 2)
    if not drop.any():
        return cells, 0
    before = _bad_edges(boundary_faces(cells))
    kept = cells[~drop]
    if len(kept):
        after = boundary_faces(kept)
        if len(after) and _bad_edges(after) <= before:
            return kept, int(drop.sum())
    # one at a time (worst first) when removing them all at once breaks the boundary
    removed = 0
    for c in np.flatnonzero(drop)[np.argsort(q[drop])]:
        trial = np.delete(cells, np.flatnonzero((cells == cells[c]).all(axis=1))[:1], axis=0)
        if not len(trial):
            continue
        after = boundary_faces(trial)
        if len(after) and _bad_edges(after) <= before:
            cells, removed = trial, removed + 1
    return cells, removed


def _positive(points: np.ndarray, local: np.ndarray) -> bool:
    p = points[local]
    d = p[:, 1:] - p[:, :1]
    return bool(np.all(np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) > 0))


def _ascend(points: np.ndarray, v: int, local: np.ndarray, q_ring: float, iterations: int = 12) -> float:
    """Move vertex ``v`` uphill on the worst quality of its ring ``local`` (in place); the ring's new worst.

    Each iteration: central-difference gradient of the worst tetrahedron's quality with respect to the
    vertex, then a backtracking step along it (a quarter of the ring's mean edge down to 1/1000 of it),
    kept only if no tetrahedron of the ring inverts and the ring's worst quality rises. The worst
    tetrahedron changes between iterations, so this climbs the non-smooth minimum (optimisation-based
    smoothing) where moving to the neighbours' centroid does not help: a vertex just above the plane of
    three boundary vertices, whose centroid lies on the wrong side of another face.
    """
    p = points[local]
    scale = float(np.mean([np.linalg.norm(p[:, i] - p[:, j], axis=1).mean() for i in range(4) for j in range(i)]))
    h = 1e-6 * scale
    for _ in range(iterations):
        worst = local[int(np.argmin(radius_ratio(points, local)))][None, :]
        x = points[v].copy()
        grad = np.zeros(3)
        for axis in range(3):
            points[v, axis] = x[axis] + h
            up = radius_ratio(points, worst)[0]
            points[v, axis] = x[axis] - h
            grad[axis] = (up - radius_ratio(points, worst)[0]) / (2 * h)
            points[v, axis] = x[axis]
        norm = float(np.linalg.norm(grad))
        if not np.isfinite(norm) or norm == 0.0:
            break
        step, moved = 0.25 * scale, False
        while step > 1e-3 * scale:
            points[v] = x + step * grad / norm
            if _positive(points, local):
                q = float(radius_ratio(points, local).min())
                if q > q_ring:
                    q_ring, moved = q, True
                    break
            step *= 0.5
        if not moved:
            points[v] = x
            break
    return q_ring


def improve_quality(points: np.ndarray, cells: np.ndarray, *, bound: float, sweeps: int = 12,
                    target: float | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Raise the worst radius ratio of a tetrahedral mesh without moving its boundary vertices.

    Args:
        points: vertex coordinates (n, 3) [m].
        cells: positively oriented tetrahedra (m, 4).
        bound: quality the worst tetrahedron should reach (radius ratio, 0..1).
        sweeps: smoothing passes over the vertices of tetrahedra below ``target``.
        target: tetrahedra below this quality are worked on (default ``1.5 * bound``).

    Returns:
        (points (n, 3) [m], cells (m', 4), info) with info keys ``removed_slivers``, ``moved_vertices``,
        ``worst_before`` and ``worst_after``.
    """
    points = np.array(points, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    target = 1.5 * bound if target is None else float(target)
    worst_before = float(radius_ratio(points, cells).min())
    cells, removed = _remove_boundary_slivers(points, cells, bound)
    fixed = np.zeros(len(points), dtype=bool)
    fixed[boundary_faces(cells).ravel()] = True
    # vertex -> cells (CSR) and vertex -> neighbour vertices
    order = np.argsort(cells.ravel(), kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(cells.ravel(), minlength=len(points)))])
    cell_of = order // 4
    moved: set[int] = set()
    for _ in range(sweeps):
        q = radius_ratio(points, cells)
        bad = q < target
        if not bad.any():
            break
        verts = np.unique(cells[bad].ravel())
        verts = verts[~fixed[verts]]
        changed = 0
        for v in verts[np.argsort([q[cell_of[ptr[v]:ptr[v + 1]]].min() for v in verts])]:
            ring = cell_of[ptr[v]:ptr[v + 1]]
            local = cells[ring]
            old = points[v].copy()
            q_old = radius_ratio(points, local).min()
            centre = points[np.unique(local.ravel())].mean(axis=0)
            best, best_q = old, q_old
            for step in (1.0, 0.5, 0.25):
                points[v] = old + step * (centre - old)
                p = points[local]
                d = p[:, 1:] - p[:, :1]
                if np.any(np.einsum("ij,ij->i", d[:, 0], np.cross(d[:, 1], d[:, 2])) <= 0):
                    continue
                qn = radius_ratio(points, local).min()
                if qn > best_q:
                    best, best_q = points[v].copy(), qn
            points[v] = best
            if best_q < target:  # the centroid does not reach it: climb the worst tetrahedron's quality
                best_q = _ascend(points, v, local, best_q)
            if best_q > q_old:
                moved.add(int(v))
                changed += 1
        if changed == 0:
            break
    worst_after = float(radius_ratio(points, cells).min())
    return points, cells, {"removed_slivers": removed, "moved_vertices": len(moved),
                           "worst_before": worst_before, "worst_after": worst_after}


def _sample(vertices: np.ndarray, triangles: np.ndarray, count: int, rng) -> np.ndarray:
    """Every vertex plus ``count`` area-uniform random points of the triangles."""
    p = vertices[triangles]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    if count <= 0 or area.sum() <= 0:
        return vertices[np.unique(triangles)]
    t = rng.choice(len(triangles), size=count, p=area / area.sum())
    u, w = rng.random(count), rng.random(count)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    pts = p[t, 0] + u[:, None] * (p[t, 1] - p[t, 0]) + w[:, None] * (p[t, 2] - p[t, 0])
    return np.vstack([vertices[np.unique(triangles)], pts])


def distance_to_surface(query: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Exact distance [m] from points ``query`` (k, 3) to the triangle surface (vertices, triangles).

    Candidates: triangles whose bounding sphere (centroid, radius R_t) meets the ball around the
    query point reaching its nearest surface vertex (that vertex bounds the distance from above).
    """
    from scipy.spatial import cKDTree

    from modalfem.reduction.embed import point_triangle_distance

    q = np.asarray(query, dtype=np.float64)
    p = vertices[triangles]
    centre = p.mean(axis=1)
    radius = np.linalg.norm(p - centre[:, None], axis=2).max(axis=1)
    upper, _ = cKDTree(vertices).query(q)
    tree = cKDTree(centre)
    k = min(16, len(centre))
    dk, idx = tree.query(q, k=k)
    dk, idx = dk.reshape(len(q), k), idx.reshape(len(q), k)
    d = point_triangle_distance(np.repeat(q, k, axis=0), *(p[idx.ravel(), i] for i in range(3))).reshape(len(q), k)
    out = np.minimum(d.min(axis=1), upper)
    # a triangle not among the k nearest centroids is at least dk[:, -1] - R_max away
    unsure = np.flatnonzero(out > dk[:, -1] - radius.max()) if k < len(centre) else np.zeros(0, dtype=np.int64)
    chunk = 512
    for s in range(0, len(unsure), chunk):
        ids = unsure[s:s + chunk]
        lists = tree.query_ball_point(q[ids], out[ids] + radius.max())
        lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
        tri = np.fromiter((t for x in lists for t in x), dtype=np.int64, count=int(lens.sum()))
        who = np.repeat(np.arange(len(ids)), lens)
        dd = point_triangle_distance(q[ids][who], p[tri, 0], p[tri, 1], p[tri, 2])
        best = np.full(len(ids), np.inf)
        np.minimum.at(best, who, dd)
        out[ids] = np.minimum(best, out[ids])
    return out


def sampled_distances(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], *,
                      samples: int = 5000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Distances [m] of sample points of surface ``a`` to surface ``b`` and of ``b``'s samples to ``a``.

    Samples: every vertex plus ``samples`` area-uniform random points per surface (seeded).
    """
    rng = np.random.default_rng(seed)
    (va, ta), (vb, tb) = a, b
    return (distance_to_surface(_sample(va, ta, samples, rng), vb, tb),
            distance_to_surface(_sample(vb, tb, samples, rng), va, ta))


def surface_distances(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], *,
                      samples: int = 5000, seed: int = 0) -> tuple[float, float]:
    """Sampled one-sided distances [m] between triangle surfaces ``a`` and ``b`` ((vertices, triangles) each).

    Returns:
        (max over samples of a of the distance to b, max over samples of b of the distance to a);
        their maximum is the sampled Hausdorff distance. Samples: every vertex plus ``samples``
        area-uniform random points per surface (seeded), so the true value exceeds the sampled one
        by at most the gap between neighbouring samples.
    """
    d_ab, d_ba = sampled_distances(a, b, samples=samples, seed=seed)
    return float(d_ab.max()), float(d_ba.max())
