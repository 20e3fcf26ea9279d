"""An independent triangle-triangle intersection check (shares no code with the CCD or the BVH).

Closed triangles (touching counts) intersect exactly when a side of one meets the other (for two
coplanar triangles too: one inside the other puts its sides inside). Everything is decided by the
signs of orientation determinants, computed *exactly*: the floating-point determinant is trusted
when it exceeds a bound on its rounding error (Shewchuk's static filter, with a wide margin), and the
few uncertain ones (coplanar and nearly coplanar configurations) are re-evaluated in integer
arithmetic on the float inputs (every float is an integer times a power of two). So there is no
tolerance: nearly coplanar triangles get the answer of the exact geometry of their float corners.

A side ``q0 q1`` meets triangle ``a b c`` when

- it is not in the triangle's plane: its ends are not strictly on one side of the plane, and the line
  ``q0 q1`` passes through the closed triangle (three orientations of one sign or zero);
- it lies in the plane: in the projection dropping the largest component of the triangle's normal
  (an affine bijection of the plane, so incidences are kept), an end is inside the triangle or the
  segment meets a side (2D orientations).

Adjacent triangles of a mesh always share their common vertex or side, which is not an intersection:
triangles sharing one vertex intersect when a side opposite the shared vertex meets the other
triangle (then they share more than that vertex); triangles sharing a side intersect when they are
folded flat onto each other (the two opposite vertices coplanar with the side and on the same side
of it). Exactly degenerate triangles (collinear corners) are tested only through their sides against
the other triangle. Candidates come from a sort and sweep of the triangles' boxes along the axis of
largest spread; float separating-plane certificates (with a margin above their rounding, so their
answer is exact) settle most neighbours of a flat sheet before any orientation is computed.
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import InputError

__all__ = ["intersecting_pairs", "orient2d_sign", "orient3d_sign", "segment_crosses_triangle"]

_CHUNK = 2_000_000
#: relative rounding bound of the float determinants (Shewchuk's bounds are 7.8e-16 (3D) and 3.3e-16
#: (2D) times the permanent; a wider margin only sends a few more determinants to the exact path)
_ERRBOUND = 1e-14
#: nonzero differences smaller than this [m] could underflow in the products: decided exactly
_TINY = 1e-90


def _integers(P: np.ndarray) -> np.ndarray:
    """Exact integer images (object array of Python ints) of float points P (k, p, d): every float is
    an integer mantissa times a power of two, scaled here by one power of two per query (row)."""
    m, e = np.frexp(P)
    M = (m * 9007199254740992.0).astype(np.int64)  # times 2**53: exact
    big = np.iinfo(np.int64).max
    E = np.where(M == 0, big, e.astype(np.int64) - 53)
    E0 = E.min(axis=(1, 2), keepdims=True)
    shift = np.where(M == 0, 0, E - np.where(E0 == big, 0, E0))
    return M.astype(object) << shift.astype(object)


def _sign(det: np.ndarray) -> np.ndarray:
    return (det > 0).astype(np.int8) - (det < 0).astype(np.int8)


def _exact_sign3(P: np.ndarray) -> np.ndarray:
    """Exact sign of ``det[b - a, c - a, d - a]`` for (k, 4, 3) float points, in integer arithmetic."""
    Z = _integers(P)
    u, v, w = Z[:, 1] - Z[:, 0], Z[:, 2] - Z[:, 0], Z[:, 3] - Z[:, 0]
    return _sign(u[:, 0] * (v[:, 1] * w[:, 2] - v[:, 2] * w[:, 1]) - u[:, 1] * (v[:, 0] * w[:, 2] - v[:, 2] * w[:, 0])
                 + u[:, 2] * (v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]))


def _exact_sign2(P: np.ndarray) -> np.ndarray:
    """Exact sign of ``det[b - a, c - a]`` for (k, 3, 2) float points, in integer arithmetic."""
    Z = _integers(P)
    u, v = Z[:, 1] - Z[:, 0], Z[:, 2] - Z[:, 0]
    return _sign(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])


def _uncertain(det: np.ndarray, perm: np.ndarray, diffs: tuple) -> np.ndarray:
    tiny = np.zeros(det.shape, dtype=bool)
    for d in diffs:
        a = np.abs(d)
        tiny |= ((a > 0) & (a < _TINY)).any(axis=-1)
    return (np.abs(det) <= _ERRBOUND * perm) & ~((perm == 0) & ~tiny) | tiny


def orient3d_sign(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Exact sign of the orientation ``det[b - a, c - a, d - a]`` (six times the signed volume).

    Args:
        a, b, c, d: (k, 3) points [m] (finite floats).

    Returns:
        (k,) int8 in {-1, 0, 1}: 1 when ``d`` is on the side of plane ``a b c`` its normal
        ``(b - a) x (c - a)`` points to, 0 exactly when the four points are coplanar.
    """
    u, v, w = b - a, c - a, d - a
    t0 = v[..., 1] * w[..., 2] - v[..., 2] * w[..., 1]
    t1 = v[..., 0] * w[..., 2] - v[..., 2] * w[..., 0]
    t2 = v[..., 0] * w[..., 1] - v[..., 1] * w[..., 0]
    det = u[..., 0] * t0 - u[..., 1] * t1 + u[..., 2] * t2
    av, aw = np.abs(v), np.abs(w)
    perm = (np.abs(u[..., 0]) * (av[..., 1] * aw[..., 2] + av[..., 2] * aw[..., 1])
            + np.abs(u[..., 1]) * (av[..., 0] * aw[..., 2] + av[..., 2] * aw[..., 0])
            + np.abs(u[..., 2]) * (av[..., 0] * aw[..., 1] + av[..., 1] * aw[..., 0]))
    sign = np.sign(det).astype(np.int8)
    unsure = np.nonzero(_uncertain(det, perm, (u, v, w)))[0]
    if len(unsure):
        sign[unsure] = _exact_sign3(np.stack([a[unsure], b[unsure], c[unsure], d[unsure]], axis=1))
    return sign


def orient2d_sign(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact sign of ``det[b - a, c - a]`` for (k, 2) points [m]: 1 counter-clockwise, 0 collinear."""
    u, v = b - a, c - a
    det = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    perm = np.abs(u[..., 0] * v[..., 1]) + np.abs(u[..., 1] * v[..., 0])
    sign = np.sign(det).astype(np.int8)
    unsure = np.nonzero(_uncertain(det, perm, (u, v)))[0]
    if len(unsure):
        sign[unsure] = _exact_sign2(np.stack([a[unsure], b[unsure], c[unsure]], axis=1))
    return sign


def _projection_axis(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(k,) axis to drop so that triangle a b c projects to a non-degenerate triangle (-1: degenerate)."""
    n = np.cross(b - a, c - a)
    order = np.argsort(-np.abs(n), axis=1)
    axis = np.full(len(a), -1)
    todo = np.arange(len(a))
    for j in range(3):
        if len(todo) == 0:
            break
        k = order[todo, j]
        keep = [(k + 1) % 3, (k + 2) % 3]
        rows = todo[:, None]
        s = orient2d_sign(a[rows, np.stack(keep, 1)], b[rows, np.stack(keep, 1)], c[rows, np.stack(keep, 1)])
        axis[todo[s != 0]] = k[s != 0]
        todo = todo[s == 0]
    return axis


def _segment_in_triangle_2d(q0, q1, a, b, c) -> np.ndarray:
    """Closed segments against closed non-degenerate triangles, all (k, 2)."""
    s = orient2d_sign(a, b, c)
    hit = np.zeros(len(a), dtype=bool)
    o = {}
    for name, (x, y) in {"ab": (a, b), "bc": (b, c), "ca": (c, a)}.items():
        o[name] = (s * orient2d_sign(x, y, q0), s * orient2d_sign(x, y, q1))
    for end in (0, 1):
        hit |= (o["ab"][end] >= 0) & (o["bc"][end] >= 0) & (o["ca"][end] >= 0)
    side = {"a": orient2d_sign(q0, q1, a), "b": orient2d_sign(q0, q1, b), "c": orient2d_sign(q0, q1, c)}
    for name in ("ab", "bc", "ca"):
        o1, o2 = side[name[0]], side[name[1]]
        o3, o4 = o[name]
        hit |= (o1 * o2 <= 0) & (o3 * o4 <= 0) & ~((o1 == 0) & (o2 == 0))
    return hit


def segment_crosses_triangle(q0, q1, a, b, c) -> np.ndarray:
    """Whether closed segments meet closed triangles (touching included), decided exactly.

    Args:
        q0, q1: (k, 3) segment ends [m].
        a, b, c: (k, 3) triangle corners [m].

    Returns:
        (k,) bool. A segment in the plane of a triangle with collinear corners counts as not meeting it.
    """
    q0, q1, a, b, c = (np.asarray(z, dtype=float).reshape(-1, 3) for z in (q0, q1, a, b, c))
    s0, s1 = orient3d_sign(a, b, c, q0), orient3d_sign(a, b, c, q1)
    flat = (s0 == 0) & (s1 == 0)
    hit = np.zeros(len(a), dtype=bool)
    live = np.nonzero(~flat & (s0 * s1 <= 0))[0]
    if len(live):
        p0, p1 = q0[live], q1[live]
        v1 = orient3d_sign(p0, p1, a[live], b[live])
        v2 = orient3d_sign(p0, p1, b[live], c[live])
        v3 = orient3d_sign(p0, p1, c[live], a[live])
        hit[live] = ((v1 >= 0) & (v2 >= 0) & (v3 >= 0)) | ((v1 <= 0) & (v2 <= 0) & (v3 <= 0))
    cop = np.nonzero(flat)[0]
    if len(cop):
        axis = _projection_axis(a[cop], b[cop], c[cop])
        good = axis >= 0
        cop, axis = cop[good], axis[good]
        keep = np.stack([(axis + 1) % 3, (axis + 2) % 3], 1)
        rows = cop[:, None]
        hit[cop] = _segment_in_triangle_2d(q0[rows, keep], q1[rows, keep], a[rows, keep], b[rows, keep],
                                           c[rows, keep])
    return hit


def _sweep(lo: np.ndarray, hi: np.ndarray, group: np.ndarray | None):
    """Yield chunks of candidate pairs (i, j) whose boxes overlap (different groups if given)."""
    axis = int(np.argmax(hi.max(axis=0) - lo.min(axis=0)))
    order = np.argsort(lo[:, axis], kind="stable")
    slo = lo[order, axis]
    end = np.searchsorted(slo, hi[order, axis], side="right")
    count = np.maximum(end - np.arange(len(order)) - 1, 0)
    start = 0
    while start < len(order):
        stop = start + 1
        total = count[start]
        while stop < len(order) and total + count[stop] <= _CHUNK:
            total += count[stop]
            stop += 1
        rows = np.arange(start, stop)
        i = np.repeat(rows, count[rows])
        offs = np.arange(len(i)) - np.repeat(np.cumsum(count[rows]) - count[rows], count[rows])
        j = i + 1 + offs
        i, j = order[i], order[j]
        ok = ((lo[i] <= hi[j]) & (lo[j] <= hi[i])).all(axis=1)
        if group is not None:
            ok &= group[i] != group[j]
        yield i[ok], j[ok]
        start = stop


def _certified_apart(U: np.ndarray, W: np.ndarray, axes: np.ndarray, *, strict_zero: bool) -> np.ndarray:
    """Float separation certificates, exact in their answer: (k,) True where some axis ``w`` of ``axes``
    (k, a, 3) has ``w . u < -tol`` for every point u of ``U`` (k, p, 3) and ``w . v > tol`` for every v of
    ``W`` (k, q, 3), or the reverse, ``tol`` bounding the rounding of the dot products (so the two point
    sets, hence their convex hulls, lie in disjoint open half-spaces). With ``strict_zero`` the points are
    offsets from a shared vertex (the hulls' cones then meet only at that vertex); otherwise ``W`` is
    compared to the projections of ``U`` through ``max(U . w) < min(W . w)`` with the same margin."""
    ext = np.maximum(np.abs(U).max(axis=(1, 2)), np.abs(W).max(axis=(1, 2)))
    tol = 1e-13 * np.linalg.norm(axes, axis=2) * ext[:, None]  # (k, a)
    pu = np.einsum("kpi,kai->kap", U, axes)
    pw = np.einsum("kqi,kai->kaq", W, axes)
    if strict_zero:
        ok = ((pu.max(axis=2) < -tol) & (pw.min(axis=2) > tol)) | ((pu.min(axis=2) > tol) & (pw.max(axis=2) < -tol))
    else:
        ok = (pw.min(axis=2) - pu.max(axis=2) > tol) | (pu.min(axis=2) - pw.max(axis=2) > tol)
    return ok.any(axis=1)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _pair_test(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Intersection of triangles A[k] and B[k] (corner index arrays into P), sharing no vertex."""
    # a float separating-axis certificate first (face normals and in-plane side normals): it settles
    # nearly coplanar neighbours of a flat sheet without exact arithmetic
    o = P[A[:, 0]]
    U, W = P[A] - o[:, None], P[B] - o[:, None]
    eu, ew = np.roll(U, -1, axis=1) - U, np.roll(W, -1, axis=1) - W
    nu, nw = np.cross(eu[:, 0], eu[:, 1]), np.cross(ew[:, 0], ew[:, 1])
    axes = np.concatenate([nu[:, None], nw[:, None], np.cross(nu[:, None], eu), np.cross(nw[:, None], ew)], axis=1)
    apart = _certified_apart(U, W, axes, strict_zero=False)
    for S, T in ((A, B), (B, A)):
        # exact rejection: the three corners of S strictly on one side of T's plane
        ta, tb, tc = P[T[:, 0]], P[T[:, 1]], P[T[:, 2]]
        side = np.stack([orient3d_sign(ta, tb, tc, P[S[:, e]]) for e in range(3)], axis=1)
        apart |= (side > 0).all(axis=1) | (side < 0).all(axis=1)
    hit = np.zeros(len(A), dtype=bool)
    for S, T in ((A, B), (B, A)):
        for e in range(3):
            live = np.nonzero(~apart & ~hit)[0]
            if len(live) == 0:
                return hit
            q0, q1 = P[S[live, e]], P[S[live, (e + 1) % 3]]
            hit[live] = segment_crosses_triangle(q0, q1, P[T[live, 0]], P[T[live, 1]], P[T[live, 2]])
    return hit


def _shared_vertex_test(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Triangles sharing exactly one vertex: the sides opposite it against the other triangle."""
    r = np.arange(len(A))
    ka = np.argmax((A[:, :, None] == B[:, None, :]).any(axis=2), axis=1)
    kb = np.argmax((B[:, :, None] == A[:, None, :]).any(axis=2), axis=1)
    s = P[A[r, ka]]
    # float certificate first: a plane through the shared vertex with each triangle's other corners
    # strictly on its own side (the normal crossed with gap bisectors and with the sides)
    U = np.stack([P[A[r, (ka + 1) % 3]] - s, P[A[r, (ka + 2) % 3]] - s], axis=1)
    W = np.stack([P[B[r, (kb + 1) % 3]] - s, P[B[r, (kb + 2) % 3]] - s], axis=1)
    n = np.cross(U[:, 0], U[:, 1])[:, None]
    uu, ww = _unit(U), _unit(W)
    dirs = np.concatenate([uu, ww, uu[:, [0, 0, 1, 1]] + ww[:, [0, 1, 0, 1]]], axis=1)
    apart = _certified_apart(U, W, np.cross(n, dirs), strict_zero=True)
    hit = np.zeros(len(A), dtype=bool)
    for S, T in ((A, B), (B, A)):
        shared = (S[:, :, None] == T[:, None, :]).any(axis=2)
        k = np.argmax(shared, axis=1)
        q0 = P[S[np.arange(len(S)), (k + 1) % 3]]
        q1 = P[S[np.arange(len(S)), (k + 2) % 3]]
        live = np.nonzero(~hit & ~apart)[0]
        hit[live] = segment_crosses_triangle(q0[live], q1[live], P[T[live, 0]], P[T[live, 1]], P[T[live, 2]])
    return hit


def _shared_edge_test(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Triangles sharing a side ``p q``: folded flat onto each other (their opposite corners ``c`` and
    ``d`` coplanar with the side and on the same side of it)."""
    r = np.arange(len(A))
    k = np.argmin((A[:, :, None] == B[:, None, :]).any(axis=2), axis=1)
    c = A[r, k]
    d = B[r, np.argmin((B[:, :, None] == A[:, None, :]).any(axis=2), axis=1)]
    p, q = A[r, (k + 1) % 3], A[r, (k + 2) % 3]
    hit = np.zeros(len(A), dtype=bool)
    idx = np.nonzero(orient3d_sign(P[p], P[q], P[c], P[d]) == 0)[0]
    axis = _projection_axis(P[p[idx]], P[q[idx]], P[c[idx]])
    idx, axis = idx[axis >= 0], axis[axis >= 0]
    keep = np.stack([(axis + 1) % 3, (axis + 2) % 3], 1)
    rows = np.arange(len(idx))[:, None]
    p2, q2, c2, d2 = (P[v[idx]][rows, keep] for v in (p, q, c, d))
    hit[idx] = orient2d_sign(p2, q2, c2) * orient2d_sign(p2, q2, d2) > 0
    return hit


def intersecting_pairs(
    x: np.ndarray,
    triangles: np.ndarray,
    *,
    other_points: np.ndarray | None = None,
    other_triangles: np.ndarray | None = None,
) -> np.ndarray:
    """Intersecting triangle pairs of one mesh (self) or between two meshes.

    Args:
        x: (n, 3) vertex positions [m].
        triangles: (m, 3) int vertex indices.
        other_points: (n2, 3) positions [m] of a second mesh (then only pairs between the meshes).
        other_triangles: (m2, 3) int triangles of the second mesh.

    Returns:
        (k, 2) int array of triangle index pairs: ``i < j`` in the mesh (self), or
        (triangle of the mesh, triangle of the other mesh).

    Raises:
        InputError: malformed arrays, non-finite points, or only one of the ``other_*`` given.
    """
    x = np.asarray(x, dtype=float)
    tri = np.asarray(triangles, dtype=np.int64)
    if x.ndim != 2 or x.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3:
        raise InputError(f"intersecting_pairs needs points (n, 3) and triangles (m, 3), got {x.shape}, {tri.shape}")
    if (other_points is None) != (other_triangles is None):
        raise InputError("give both other_points and other_triangles, or neither")
    m = len(tri)
    group = None
    if other_points is not None:
        op = np.asarray(other_points, dtype=float)
        ot = np.asarray(other_triangles, dtype=np.int64)
        tri = np.concatenate([tri, ot + len(x)])
        x = np.concatenate([x, op])
        group = np.arange(len(tri)) >= m
    if not np.isfinite(x).all():
        raise InputError("intersecting_pairs needs finite points")
    if len(tri) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    corners = x[tri]
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    found = []
    for i, j in _sweep(lo, hi, group):
        A, B = tri[i], tri[j]
        nshared = (A[:, :, None] == B[:, None, :]).sum(axis=(1, 2))
        hit = np.zeros(len(i), dtype=bool)
        s0, s1, s2 = nshared == 0, nshared == 1, nshared == 2
        hit[s0] = _pair_test(x, A[s0], B[s0])
        hit[s1] = _shared_vertex_test(x, A[s1], B[s1])
        hit[s2] = _shared_edge_test(x, A[s2], B[s2])
        found.append(np.stack([i[hit], j[hit]], axis=1))
    pairs = np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
    if group is not None:
        pairs = np.sort(pairs, axis=1)
        pairs[:, 1] -= m
    else:
        pairs = np.sort(pairs, axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))] if len(pairs) else pairs.reshape(0, 2)
