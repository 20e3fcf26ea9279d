"""Barycentric embedding of points in a tetrahedral mesh (coarse-to-fine transfer of fields).

``embed_points`` locates every query point [m] in a tetrahedron of a mesh and returns its barycentric
coordinates. The search is vectorised over all points with a uniform bucket grid: each tetrahedron is
registered in every bucket its bounding box overlaps (bucket size ~ the median tetrahedron size), and
each point tests only the tetrahedra of its own bucket (no per-point Python loop). The containing
tetrahedron is the candidate whose smallest barycentric coordinate is largest.

Points outside the mesh (smallest coordinate below ``-tol``) use the *nearest* tetrahedron: the one
owning the nearest boundary triangle (exact point-triangle distances over the few triangles with the
nearest centroids). Their barycentric coordinates with respect to that tetrahedron are kept as they
are (some negative): the field is continued linearly from the nearest cell, so a linear field is
reproduced exactly everywhere, and ``distance`` [m] says how far outside each point is.

``Embedding.matrix(degree=...)`` turns the coordinates into a sparse interpolation matrix from the mesh's
P1 or P2 nodes (canonical order of ``modalfem.mesh.core``) to the points; ``transfer`` applies it to
node-major DOF vectors (3 components per node), e.g. mode shapes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = ["Embedding", "carry_modes", "embed_points", "point_triangle_distance"]

#: query points per vectorised batch (bounds the memory of the point x candidate pairs)
_BATCH = 20_000


@dataclass(frozen=True, eq=False)
class Embedding:
    """Where query points sit in a tetrahedral mesh.

    Attributes:
        mesh: the ``modalfem.mesh.Mesh`` the points were embedded in.
        cell: containing (or nearest) tetrahedron of each point (n,).
        bary: barycentric coordinates (n, 4) [-], rows sum to 1 (negative entries only outside).
        outside: points not inside any tetrahedron (n,) bool.
        distance: distance to the mesh [m] (n,), 0 inside.
    """

    mesh: object
    cell: np.ndarray
    bary: np.ndarray
    outside: np.ndarray
    distance: np.ndarray

    @property
    def point_count(self) -> int:
        return len(self.cell)

    def matrix(self, *, degree: int = 1):
        """Sparse interpolation matrix (n, node_count(degree)) from mesh nodes to the points.

        Degree 1 uses the barycentric coordinates; degree 2 the quadratic Lagrange shape functions
        ``l_i (2 l_i - 1)`` (vertices) and ``4 l_i l_j`` (edge midpoints, ``TET_EDGES`` order).

        Raises:
            InputError: degree is not 1 or 2.
        """
        import scipy.sparse as sp

        from modalfem.mesh.core import TET_EDGES

        if degree not in (1, 2):
            raise InputError(f"degree must be 1 or 2, got {degree!r}")
        lam = self.bary
        if degree == 1:
            w = lam
        else:
            w = np.hstack([lam * (2.0 * lam - 1.0), 4.0 * lam[:, TET_EDGES[:, 0]] * lam[:, TET_EDGES[:, 1]]])
        nodes = self.mesh.cell_nodes(degree)[self.cell]
        n = self.point_count
        rows = np.repeat(np.arange(n), w.shape[1])
        A = sp.csr_matrix((w.ravel(), (rows, nodes.ravel())), shape=(n, self.mesh.node_count(degree)))
        A.sum_duplicates()
        return A

    def interpolate(self, values: np.ndarray, *, degree: int = 1) -> np.ndarray:
        """Nodal values (node_count(degree), ...) of a field -> values (n, ...) at the points."""
        values = np.asarray(values)
        return (self.matrix(degree=degree) @ values.reshape(values.shape[0], -1)).reshape((self.point_count,) + values.shape[1:])

    def transfer(self, dofs: np.ndarray, *, degree: int = 1) -> np.ndarray:
        """Node-major DOF vectors (3 * node_count(degree), k) -> (3 * n, k) at the points."""
        dofs = np.asarray(dofs, dtype=np.float64)
        one = dofs.ndim == 1
        d = dofs.reshape(-1, 3, 1 if one else dofs.shape[1])
        out = self.interpolate(d, degree=degree).reshape(3 * self.point_count, -1)
        return out[:, 0] if one else out


def _bary(T_inv: np.ndarray, v0: np.ndarray, cells: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (k, 4) of points p (k, 3) in tetrahedra ``cells`` (k,)."""
    l123 = np.einsum("kij,kj->ki", T_inv[cells], p - v0[cells])
    return np.column_stack([1.0 - l123.sum(axis=1), l123])


def _bucket_grid(points: np.ndarray, cells: np.ndarray):
    lo = points.min(axis=0)
    hi = points.max(axis=0)
    P = points[cells]
    clo, chi = P.min(axis=1), P.max(axis=1)
    h = float(np.median(np.max(chi - clo, axis=1)))
    ext = np.maximum(hi - lo, h * 1e-9)
    dims = np.maximum(np.ceil(ext / max(h, 1e-300)).astype(np.int64), 1)
    while np.prod(dims) > 8 * len(cells) + 64:  # cap memory on strongly graded meshes
        dims = np.maximum(dims // 2, 1)
    size = ext / dims
    i0 = np.clip(np.floor((clo - lo) / size).astype(np.int64), 0, dims - 1)
    i1 = np.clip(np.floor((chi - lo) / size).astype(np.int64), 0, dims - 1)
    span = i1 - i0 + 1
    count = np.prod(span, axis=1)
    tet = np.repeat(np.arange(len(cells)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    sy, sz = span[tet, 1], span[tet, 2]
    ix = i0[tet, 0] + local // (sy * sz)
    iy = i0[tet, 1] + (local // sz) % sy
    iz = i0[tet, 2] + local % sz
    key = (ix * dims[1] + iy) * dims[2] + iz
    order = np.argsort(key, kind="stable")
    ptr = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=int(np.prod(dims))))])
    return lo, size, dims, ptr, tet[order]


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Euclidean distance [m] from points p (k, 3) to triangles (a, b, c) (each (k, 3)), vectorised."""
    ab, ac, ap = b - a, c - a, p - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    # barycentric of the projection onto the plane
    d1 = np.einsum("ij,ij->i", np.cross(ap, ac), n)
    d2 = np.einsum("ij,ij->i", np.cross(ab, ap), n)
    with np.errstate(invalid="ignore", divide="ignore"):
        v, w = d1 / nn, d2 / nn
    inside = (v >= 0) & (w >= 0) & (v + w <= 1) & (nn > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        plane = np.abs(np.einsum("ij,ij->i", ap, n)) / np.sqrt(nn)

    def seg(x0, x1):
        d = x1 - x0
        dd = np.einsum("ij,ij->i", d, d)
        t = np.clip(np.einsum("ij,ij->i", p - x0, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
        return np.linalg.norm(p - (x0 + t[:, None] * d), axis=1)

    edge = np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))
    return np.where(inside, plane, edge)


def embed_points(mesh, query: np.ndarray, *, tol: float = 1e-10, nearest_candidates: int = 12) -> Embedding:
    """Embed query points in the tetrahedra of ``mesh`` (see the module docstring).

    Args:
        mesh: ``modalfem.mesh.Mesh`` [m] (e.g. a coarse mesh of a shape).
        query: points (n, 3) [m] (e.g. a fine mesh's vertices or boundary vertices).
        tol: a point is inside a cell when its smallest barycentric coordinate is >= -tol [-].
        nearest_candidates: boundary triangles (nearest centroids) checked exactly for outside points.

    Returns:
        ``Embedding`` with cell, barycentric coordinates, outside flags and distances [m].

    Raises:
        InputError: query is not an (n, 3) array of finite numbers.
    """
    from scipy.spatial import cKDTree

    q = np.asarray(query, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 3 or not np.all(np.isfinite(q)):
        raise InputError(f"query points must be a finite (n, 3) array [m], got shape {q.shape}")
    pts, cells = mesh.points, mesh.cells
    v0 = pts[cells[:, 0]]
    T = np.stack([pts[cells[:, 1]] - v0, pts[cells[:, 2]] - v0, pts[cells[:, 3]] - v0], axis=2)
    T_inv = np.linalg.inv(T)
    lo, size, dims, ptr, tets = _bucket_grid(pts, cells)
    n = len(q)
    cell = np.zeros(n, dtype=np.int64)
    score = np.full(n, -np.inf)
    for s in range(0, n, _BATCH):
        qb = q[s : s + _BATCH]
        ijk = np.floor((qb - lo) / size).astype(np.int64)
        slack = 1e-9 * size
        inb = np.all((qb >= lo - slack) & (qb <= lo + dims * size + slack), axis=1)
        ijk = np.clip(ijk, 0, dims - 1)
        key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        cnt = np.where(inb, ptr[key + 1] - ptr[key], 0)
        if cnt.sum() == 0:
            continue
        pid = np.repeat(np.arange(len(qb)), cnt)
        off = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        cand = tets[ptr[key[pid]] + off]
        sc = _bary(T_inv, v0, cand, qb[pid]).min(axis=1)
        best = np.full(len(qb), -np.inf)
        np.maximum.at(best, pid, sc)
        hit = np.flatnonzero(sc == best[pid])
        first_pid, first = np.unique(pid[hit], return_index=True)
        cell[s + first_pid] = cand[hit[first]]
        score[s + first_pid] = best[first_pid]
    outside = score < -tol
    distance = np.zeros(n)
    if outside.any():
        facets = mesh.boundary_facets
        face_cell = _facet_cells(mesh, facets)
        tree = cKDTree(pts[facets].mean(axis=1))
        qo = q[outside]
        kk = min(nearest_candidates, len(facets))
        _, near = tree.query(qo, k=kk)
        near = near.reshape(len(qo), kk)
        f = facets[near.ravel()]
        d = point_triangle_distance(np.repeat(qo, kk, axis=0), pts[f[:, 0]], pts[f[:, 1]], pts[f[:, 2]])
        d = d.reshape(len(qo), kk)
        j = np.argmin(d, axis=1)
        cell[outside] = face_cell[near[np.arange(len(qo)), j]]
        distance[outside] = d[np.arange(len(qo)), j]
    bary = _bary(T_inv, v0, cell, q)
    return Embedding(mesh=mesh, cell=cell, bary=bary, outside=outside, distance=distance)


def carry_modes(result, mesh, points: np.ndarray) -> np.ndarray:
    """Coarse-to-fine: the deformation modes of ``result`` (computed on ``mesh``) at other points.

    Args:
        result: ``ModalResult`` of ``modalfem.modes`` on ``mesh`` (P1 or P2).
        mesh: the (coarse) ``Mesh`` the modes were computed on [m].
        points: target points (n, 3) [m], e.g. a fine mesh's boundary vertices or P2 nodes.

    Returns:
        mode shapes (3 n, k) at the points, node-major, interpolated with the result's own Lagrange
        degree (linear continuation from the nearest tetrahedron for points outside ``mesh``).
    """
    return embed_points(mesh, points).transfer(result.shapes, degree=result.degree)


def _facet_cells(mesh, facets: np.ndarray) -> np.ndarray:
    """The tetrahedron owning each boundary triangle (b,)."""
    from modalfem.mesh.core import TET_FACES

    n = np.int64(mesh.point_count)
    faces = np.sort(mesh.cells[:, TET_FACES].reshape(-1, 3), axis=1)
    fkey = (faces[:, 0] * n + faces[:, 1]) * n + faces[:, 2]
    sf = np.sort(facets, axis=1)
    bkey = (sf[:, 0] * n + sf[:, 1]) * n + sf[:, 2]
    order = np.argsort(fkey)
    pos = np.searchsorted(fkey[order], bkey)
    return order[pos] // 4
