"""The compiled broad-phase kernels against brute force: refit boxes and normal cones, box queries, the
primitive-pair expansion of a candidate search, the contour culling on crumpled sheets."""

from __future__ import annotations

import numpy as np
from _meshes import grid, stacked_sheets

from modalfem.collision._system import System
from modalfem.collision.bvh import BroadPhaseBVH


def _crumpled(seed: int, n: int = 10, amp: float = 0.08):
    pts, tri = grid(n, n)
    rng = np.random.default_rng(seed)
    x0 = pts + amp * rng.standard_normal(pts.shape) * [0.2, 0.2, 1.0]
    x1 = x0 + 0.3 * amp * rng.standard_normal(pts.shape)
    return pts, tri, x0, x1


def test_refit_boxes_and_cones_bound_every_triangle_and_normal():
    pts, tri, x0, x1 = _crumpled(1)
    bvh = BroadPhaseBVH(tri, pts, leaf_size=4)
    bvh.refit(x0, x1, margin=1e-3, static_margin=2e-2)
    p0, p1 = x0[tri], x1[tri]
    lo = np.minimum(np.minimum(p0.min(axis=1), p1.min(axis=1)) - 1e-3, p0.min(axis=1) - 2e-2)
    hi = np.maximum(np.maximum(p0.max(axis=1), p1.max(axis=1)) + 1e-3, p0.max(axis=1) + 2e-2)
    assert np.array_equal(bvh.tri_lo, lo) and np.array_equal(bvh.tri_hi, hi)
    # every node's box holds its triangles' boxes; its cone holds their normals along the trajectory
    node_of = bvh.leaf_of_tri.copy()
    s = np.linspace(0.0, 1.0, 11)[:, None, None, None]
    x = p0[None] + s * (p1 - p0)[None]
    nrm = np.cross(x[..., 1, :] - x[..., 0, :], x[..., 2, :] - x[..., 0, :])
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)  # (11, m, 3)
    for _ in range(bvh.levels + 1):
        for node in np.unique(node_of):
            mine = node_of == node
            assert (bvh.lo[node] <= lo[mine]).all() and (bvh.hi[node] >= hi[mine]).all()
            if bvh.cone_angle[node] < np.pi:
                cos = np.clip(nrm[:, mine] @ bvh.cone_axis[node], -1, 1)
                assert np.arccos(cos).max() <= bvh.cone_angle[node] + 1e-9
        node_of >>= 1


def test_query_equals_brute_force():
    pts, tri, x0, x1 = _crumpled(2)
    bvh = BroadPhaseBVH(tri, pts)
    bvh.refit(x0, x1, margin=0.0)
    rng = np.random.default_rng(3)
    c = rng.uniform(-0.1, 1.1, size=(60, 3)) * [1, 1, 0.2]
    qlo, qhi = c - 0.05, c + 0.05
    qi, t = bvh.query(qlo, qhi)
    got = set(zip(qi.tolist(), t.tolist()))
    ok = ((qlo[:, None] <= bvh.tri_hi[None]) & (bvh.tri_lo[None] <= qhi[:, None])).all(axis=2)
    assert got == set(zip(*map(np.ndarray.tolist, np.nonzero(ok)))) and len(got) > 20


def _brute_primitive_pairs(tri, vlo, vhi):
    """Every vertex-face and edge-edge pair not sharing a vertex whose boxes overlap."""
    e = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1), axis=0)
    flo, fhi = vlo[tri].min(axis=1), vhi[tri].max(axis=1)
    elo, ehi = vlo[e].min(axis=1), vhi[e].max(axis=1)
    v = np.arange(len(vlo))
    ok = ((vlo[:, None] <= fhi[None]) & (flo[None] <= vhi[:, None])).all(axis=2)
    ok &= ~(tri[None] == v[:, None, None]).any(axis=2)
    vf = {(int(a), *map(int, tri[f])) for a, f in zip(*np.nonzero(ok))}
    ok = ((elo[:, None] <= ehi[None]) & (elo[None] <= ehi[:, None])).all(axis=2)
    ok &= ~(e[:, None, :, None] == e[None, :, None, :]).any(axis=(2, 3))
    ee = {tuple(sorted((tuple(map(int, e[a])), tuple(map(int, e[b]))))) for a, b in zip(*np.nonzero(ok))}
    return vf, ee


def test_candidates_equal_brute_force_primitive_pairs():
    pts, tri = stacked_sheets(3, 5, gap=0.02, seed=4)
    rng = np.random.default_rng(5)
    x0 = pts + 0.01 * rng.standard_normal(pts.shape)
    x1 = x0 + 0.02 * rng.standard_normal(pts.shape)
    system = System(tri, ())
    system.build_cloth_bvh(pts)
    margin = 0.01
    c = system.candidates(x0, x1, margin=margin, self_collision=True, culling=False)
    vlo, vhi = system.vertex_boxes(x0, x1, margin)
    vf, ee = _brute_primitive_pairs(tri, vlo, vhi)
    got_vf = {tuple(map(int, q)) for q in c.vf}
    got_ee = [tuple(sorted(((int(q[0]), int(q[1])), (int(q[2]), int(q[3]))))) for q in c.ee]
    assert len(got_vf) == len(c.vf) and len(set(got_ee)) == len(got_ee)  # each pair once
    assert got_vf == vf and set(got_ee) == ee and len(vf) > 100 and len(ee) > 100
    # the dirty filter keeps exactly the pairs holding a flagged vertex
    dirty = np.zeros(len(pts), dtype=bool)
    dirty[rng.choice(len(pts), 20, replace=False)] = True
    d = system.candidates(x0, x1, margin=margin, self_collision=True, culling=False, dirty=dirty)
    assert {tuple(map(int, q)) for q in d.vf} == {q for q in vf if dirty[list(q)].any()}


def test_culled_pairs_hold_every_intersecting_pair_of_crumpled_sheets():
    """Culling (normal cones and contours) never drops a pair of triangles whose boxes overlap and that
    come within the margin: checked against the unculled search on random crumpled sheets."""
    from modalfem.collision.tritri import intersecting_pairs

    total_hits = removed = 0
    for seed in range(4):
        for amp in (0.15, 0.03):
            pts, tri, x0, x1 = _crumpled(10 + seed, n=12, amp=amp)
            bvh = BroadPhaseBVH(tri, pts, leaf_size=4)
            hits = {tuple(sorted(map(int, p))) for p in intersecting_pairs(x0, tri)}
            for end in (x0, x1):
                bvh.refit(x0, end, margin=1e-3)
                culled = {tuple(sorted(map(int, p))) for p in bvh.self_pairs(culling=True)[0]}
                full = {tuple(sorted(map(int, p))) for p in bvh.self_pairs(culling=False)[0]}
                assert hits <= culled <= full  # intersecting pairs at the start survive culling
                total_hits += len(hits)
                removed += len(full) - len(culled)
    assert total_hits > 20 and removed > 100  # both the property and the culling are exercised


def test_dirty_search_equals_brute_force_primitive_pairs():
    pts, tri = stacked_sheets(3, 6, gap=0.02, seed=6)
    rng = np.random.default_rng(7)
    x0 = pts + 0.01 * rng.standard_normal(pts.shape)
    x1 = x0 + 0.02 * rng.standard_normal(pts.shape)
    system = System(tri, ())
    system.candidates(x0, x1, margin=0.01, self_collision=True, culling=True)
    vlo, vhi = system.vertex_boxes(x0, x1, 0.01)
    vf_all, ee_all = _brute_primitive_pairs(tri, vlo, vhi)
    for count in (3, 30, 120):  # a few dirty vertices, then most of them
        dirty = np.zeros(len(pts), dtype=bool)
        dirty[rng.choice(len(pts), count, replace=False)] = True
        c = system.dirty_candidates(vlo, vhi, dirty, self_collision=True)
        vf = [tuple(map(int, q)) for q in c.vf]
        ee = [tuple(sorted(((int(q[0]), int(q[1])), (int(q[2]), int(q[3]))))) for q in c.ee]
        assert len(set(vf)) == len(vf) and len(set(ee)) == len(ee)  # each pair once
        assert set(vf) == {q for q in vf_all if dirty[list(q)].any()} and len(vf) > 3
        assert set(ee) == {q for q in ee_all if dirty[[*q[0], *q[1]]].any()}
