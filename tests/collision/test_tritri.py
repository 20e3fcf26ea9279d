"""The independent triangle-triangle check against hand-made cases, a third formulation, and an exact
rational reference for coplanar and nearly coplanar pairs."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from modalfem.collision.tritri import intersecting_pairs
from modalfem.errors import InputError


def _pair(t1, t2):
    x = np.vstack([t1, t2]).astype(float)
    return intersecting_pairs(x, np.array([[0, 1, 2], [3, 4, 5]]))


def test_hand_made_cases():
    base = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert len(_pair(base, [[0.2, 0.2, -1], [0.2, 0.2, 1], [2, 2, 0.5]])) == 1  # pierces
    assert len(_pair(base, [[0.2, 0.2, 0.1], [0.5, 0.2, 1], [0.2, 0.5, 1]])) == 0  # above
    assert len(_pair(base, [[2, 2, -1], [2, 2, 1], [3, 2, 0]])) == 0  # beside


def test_shared_vertex_and_shared_edge():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0], [0.3, 0.3, -1], [0.3, 0.3, 1]])
    # triangles sharing vertex 0: the second pierces the first
    assert len(intersecting_pairs(x, np.array([[0, 1, 2], [0, 4, 5]]))) == 1
    # sharing an edge, folded: never reported
    assert len(intersecting_pairs(x, np.array([[0, 1, 2], [1, 2, 3]]))) == 0
    # sharing vertex 0 but apart
    x2 = x.copy()
    x2[4:] = [[-0.5, 0.0, 1], [0.0, -0.5, 1]]
    assert len(intersecting_pairs(x2, np.array([[0, 1, 2], [0, 4, 5]]))) == 0


def _reference(P, Q):
    """Edge crossings by line-plane parameter + barycentric inside test (a different formulation)."""
    def crosses(T, U):
        n = np.cross(T[1] - T[0], T[2] - T[0])
        for e in range(3):
            a, b = U[e], U[(e + 1) % 3]
            den = n @ (b - a)
            if den == 0:
                continue
            s = n @ (T[0] - a) / den
            if not 0 <= s <= 1:
                continue
            y = a + s * (b - a)
            m = np.array([T[1] - T[0], T[2] - T[0]]).T
            uv = np.linalg.lstsq(m, y - T[0], rcond=None)[0]
            if uv.min() >= 0 and uv.sum() <= 1:
                return True
        return False
    return crosses(P, Q) or crosses(Q, P)


def test_random_pairs_agree_with_reference_and_other_mesh_mode():
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 1, size=(3 * 120, 3))
    tri = np.arange(len(x)).reshape(-1, 3)
    found = {tuple(p) for p in intersecting_pairs(x, tri)}
    ref = {(i, j) for i in range(len(tri)) for j in range(i + 1, len(tri)) if _reference(x[tri[i]], x[tri[j]])}
    assert len(ref) > 100 and found == ref
    # the same as two meshes
    a, b = tri[:60], tri[60:] - 180
    cross = {(i, j + 60) for i, j in intersecting_pairs(x, a, other_points=x[180:], other_triangles=b)}
    assert cross == {p for p in ref if p[0] < 60 <= p[1]}


def test_bad_input():
    with pytest.raises(InputError):
        intersecting_pairs(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(InputError):
        intersecting_pairs(np.zeros((3, 3)), np.array([[0, 1, 2]]), other_points=np.zeros((3, 3)))


# --- exact answers for coplanar and nearly coplanar pairs --------------------------------------------


def _sub(a, b):
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _clip(poly, T, n):
    """Sutherland-Hodgman clip of a convex point list by the closed triangle T (normal n), in rationals."""
    for i in range(3):
        a, e = T[i], _sub(T[(i + 1) % 3], T[i])
        f = [_dot(_cross(e, _sub(x, a)), n) for x in poly]
        out = []
        for j in range(len(poly)):
            k = (j + 1) % len(poly)
            if f[j] >= 0:
                out.append(poly[j])
            if f[j] * f[k] < 0:
                t = f[j] / (f[j] - f[k])
                out.append([poly[j][c] + t * (poly[k][c] - poly[j][c]) for c in range(3)])
        poly = out
    return poly


def _exact_intersection(T1, T2):
    """Corners of the intersection of two closed non-degenerate triangles, in exact rational arithmetic on
    the float inputs (a different method: T2 cut by the plane of T1, then clipped by T1's sides)."""
    T1 = [[Fraction(float(c)) for c in p] for p in T1]
    T2 = [[Fraction(float(c)) for c in p] for p in T2]
    n = _cross(_sub(T1[1], T1[0]), _sub(T1[2], T1[0]))
    assert any(n)
    d = [_dot(n, _sub(v, T1[0])) for v in T2]
    if all(x == 0 for x in d):
        return _clip(T2, T1, n)
    cut = [T2[i] for i in range(3) if d[i] == 0]
    for i in range(3):
        j = (i + 1) % 3
        if d[i] * d[j] < 0:
            t = d[i] / (d[i] - d[j])
            cut.append([T2[i][c] + t * (T2[j][c] - T2[i][c]) for c in range(3)])
    return _clip(cut, T1, n) if cut else []


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _nearly_coplanar_pairs(rng, count):
    """Triangle pairs around a common plane: exactly coplanar (axis-aligned plane), coplanar up to the
    rounding of a random rotation, and lifted off it by 1e-17..1e-9 [m] per corner."""
    pairs = []
    for k in range(count):
        uv = rng.uniform(0, 1, size=(6, 2))
        uv[3:] += rng.uniform(-0.6, 0.6, 2)
        if k % 4 == 0:
            p = np.column_stack([uv, np.full(6, rng.uniform(-1, 1))])
        else:
            h = np.zeros(6)
            if k % 4 == 2:
                h = rng.choice([-1.0, 0.0, 1.0], 6) * 10.0 ** rng.uniform(-17, -9, 6)
            p = rng.uniform(-1, 1, 3) + np.column_stack([uv, h]) @ _rotation(rng).T
        pairs.append(p)
    return pairs


def test_nearly_coplanar_pairs_match_an_exact_rational_reference():
    rng = np.random.default_rng(11)
    pairs = _nearly_coplanar_pairs(rng, 240)
    # all pairs as one mesh, each pair far from the others
    x = np.concatenate([p + [4.0 * k, 0.0, 0.0] for k, p in enumerate(pairs)])
    tri = np.arange(len(x)).reshape(-1, 3)
    found = {tuple(p) for p in intersecting_pairs(x, tri)}
    ref = {(2 * k, 2 * k + 1) for k in range(len(pairs)) if _exact_intersection(x[6 * k:6 * k + 3], x[6 * k + 3:6 * k + 6])}
    assert 40 < len(ref) < 200  # both answers well represented
    assert found == ref


def _shared_reference(T1, T2, shared):
    """Whether two triangles sharing the corners ``shared`` (none, one vertex or one side) meet elsewhere."""
    pts = _exact_intersection(T1, T2)
    s = [[Fraction(float(c)) for c in x] for x in shared]
    if len(s) == 0:
        return len(pts) > 0
    if len(s) == 1:
        return any(p != s[0] for p in pts)
    return any(any(_cross(_sub(s[1], s[0]), _sub(p, s[0]))) for p in pts)


def test_nearly_coplanar_neighbours_sharing_a_vertex_or_a_side():
    rng = np.random.default_rng(12)
    cases, expected = [], []
    for k in range(160):
        ang = np.sort(rng.uniform(0, 2 * np.pi, 4))
        if k % 3 == 0:
            ang[2:] = ang[:2] + rng.uniform(-0.4, 0.4, 2)  # sectors overlapping or touching
        r = rng.uniform(0.2, 1.0, 4)
        loc = np.column_stack([np.r_[0.0, r * np.cos(ang)], np.r_[0.0, r * np.sin(ang)], np.zeros(5)])
        if k % 2:
            loc[:, 2] = rng.choice([-1.0, 0.0, 1.0], 5) * 10.0 ** rng.uniform(-17, -10, 5)
        R = np.eye(3) if k % 4 == 0 else _rotation(rng)
        p = rng.uniform(-1, 1, 3) + loc @ R.T
        if k % 5 == 4:  # share a side (0, 1): a fold, flat or nearly flat
            tris = np.array([[0, 1, 2], [1, 0, 3]])
            shared = p[[0, 1]]
        else:
            tris = np.array([[0, 1, 2], [0, 3, 4]])
            shared = p[[0]]
        cases.append(len(intersecting_pairs(p, tris)) == 1)
        expected.append(_shared_reference(p[tris[0]], p[tris[1]], shared))
    assert 15 < sum(expected) < 145
    assert cases == expected


def test_flat_and_rotated_sheets_have_no_intersection_and_a_coplanar_overlap_is_found():
    rng = np.random.default_rng(3)
    pts, tri = _grid(8)
    assert len(intersecting_pairs(pts, tri)) == 0
    # a rotated sheet is coplanar only up to rounding, a sheet lifted by 1e-15 m noise is not coplanar
    rot = pts @ _rotation(rng).T + 0.3
    assert len(intersecting_pairs(rot, tri)) == 0
    assert len(intersecting_pairs(rot + 1e-15 * rng.normal(size=rot.shape), tri)) == 0
    # an inner vertex pushed across its neighbours, in the plane: its triangles overlap theirs
    moved = pts.copy()
    v = 4 * 9 + 4
    moved[v, :2] += [0.17, 0.05]
    hit = intersecting_pairs(moved, tri)
    assert len(hit) > 0 and all(v in tri[i] or v in tri[j] for i, j in hit)
    # rotated, the overlapping triangles are no longer exactly coplanar: check the pairs near the moved
    # vertex against the exact reference (sharing a side, a vertex or nothing)
    rmoved = moved @ _rotation(rng).T + 0.1
    found = {tuple(p) for p in intersecting_pairs(rmoved, tri)}
    near = np.flatnonzero((np.linalg.norm(moved[tri] - moved[v], axis=2) < 0.3).any(axis=1))
    ref = set()
    for i in near:
        for j in near[near > i]:
            common = sorted(set(tri[i]) & set(tri[j]))
            if _shared_reference(rmoved[tri[i]], rmoved[tri[j]], rmoved[common]):
                ref.add((i, j))
    assert len(ref) > 0 and found == ref


def test_touching_and_one_ulp_apart():
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    # a corner resting exactly on the other triangle counts (closed triangles)
    top = np.array([[0.25, 0.25, 0.0], [0.5, 0.25, 1.0], [0.25, 0.5, 1.0]])
    assert len(_pair(base, top)) == 1
    lifted = top.copy()
    lifted[0, 2] = np.nextafter(0.0, 1.0)  # the smallest positive float above the plane
    assert len(_pair(base, lifted)) == 0
    # coplanar triangles touching along a side segment, and one ulp apart
    side = np.array([[0.5, 0.5, 0.0], [1.0, 1.0, 0.0], [0.2, 1.2, 0.0]])  # (0.5, 0.5) lies on the hypotenuse
    assert len(_pair(base, side)) == 1
    side[0, :2] = np.nextafter(0.5, 1.0)
    assert len(_pair(base, side)) == 0
    # a flat fold of two triangles sharing a side overlaps; opened by one ulp it does not
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.6, 0.0], [0.6, 0.5, 0.0]])
    assert len(intersecting_pairs(x, np.array([[0, 1, 2], [1, 0, 3]]))) == 1
    x[3, 2] = np.nextafter(0.0, 1.0)
    assert len(intersecting_pairs(x, np.array([[0, 1, 2], [1, 0, 3]]))) == 0


def _grid(n):
    xs, ys = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return pts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
