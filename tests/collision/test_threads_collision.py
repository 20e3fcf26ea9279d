"""The parallel collision kernels on 1 and 2 threads: the same pairs in the same order, the same times of
impact and contact frames to the last bit; the parallel BVH traversal lists exactly the pairs of one
serial depth-first walk, in its order."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from _meshes import stacked_sheets

from modalfem.collision import _bvh_kernels, _distance_kernels
from modalfem.collision._system import System
from modalfem.collision.bvh import BroadPhaseBVH
from modalfem.collision.ccd import ccd_pairs
from modalfem._threads import thread_count

pytestmark = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")


def _sheets(seed: int = 4):
    pts, tri = stacked_sheets(4, 16, gap=0.01, seed=seed)
    rng = np.random.default_rng(seed)
    x0 = pts + 0.004 * rng.standard_normal(pts.shape)
    x1 = x0 + 0.01 * rng.standard_normal(pts.shape)
    return pts, tri, x0, x1


def _serial_walk(bvh: BroadPhaseBVH):
    """One depth-first walk from the root (no split), then its leaves' triangle pairs."""
    leaves = _bvh_kernels._walk(1, 1, -1, True, True, bvh.P, bvh.lo, bvh.hi, bvh.nonempty, bvh.P, bvh.lo, bvh.hi,
                                bvh.nonempty, bvh.connected, bvh.cone_axis, bvh.cone_angle, bvh._adj, bvh._bnd_start,
                                bvh._bnd_edge, bvh._bnd_id, int(bvh.contour_limit), bvh._x0, bvh._x1, False,
                                bool(bvh.boundary_check), np.zeros(0, dtype=bool), np.zeros((0, 8)), 0.0)
    return _bvh_kernels._leaf_triangle_pairs(leaves, len(leaves), True, bvh.P, bvh.lo, bvh.hi, bvh.slot_tri, bvh._slo,
                                             bvh._shi, bvh.P, bvh.lo, bvh.hi, bvh.slot_tri, bvh._slo, bvh._shi, False,
                                             np.zeros(0, dtype=bool))


def test_traversal_and_queries_give_the_same_ordered_pairs_on_any_thread_count():
    pts, tri, x0, x1 = _sheets()
    bvh = BroadPhaseBVH(tri, pts, leaf_size=4)
    bvh.refit(x0, x1, margin=2e-3)
    out = {}
    for t in (1, 2):
        with thread_count(t):
            out[t] = (bvh.self_pairs(culling=True), bvh.query(bvh.tri_lo[::3], bvh.tri_hi[::3]))
    (p1, n1), (q1, r1) = out[1]
    (p2, n2), (q2, r2) = out[2]
    assert len(p1) > 5000 and len(q1) > 5000  # many chunks of tasks and of queries
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(q1, q2)
    np.testing.assert_array_equal(r1, r2)
    assert n1 == n2
    serial, tests = _serial_walk(bvh)
    np.testing.assert_array_equal(p1, serial)
    assert n1 == tests


def test_pair_expansion_ccd_and_frames_are_the_same_on_one_and_two_threads():
    pts, tri, x0, x1 = _sheets(7)
    system = System(tri, ())
    system.build_cloth_bvh(pts)
    got = {}
    for t in (1, 2):
        with thread_count(t):
            c = system.candidates(x0, x1, margin=5e-3, self_collision=True, culling=False)
            hits = [ccd_pairs(kind, x0, x1, q, eta=1e-4) for kind, q in (("vf", c.vf), ("ee", c.ee))]
            frames = [_distance_kernels.contact_frames(kind == "vf", x1, q, x0) for kind, q in
                      (("vf", c.vf), ("ee", c.ee))]
            got[t] = (c.vf, c.ee, hits, frames)
    vf1, ee1, hits1, frames1 = got[1]
    vf2, ee2, hits2, frames2 = got[2]
    assert len(vf1) > 2000 and len(ee1) > 2000  # several chunks of triangle pairs, CCD queries and frames
    assert sum(int(h.sum()) for h, _ in hits1) > 50
    np.testing.assert_array_equal(vf1, vf2)
    np.testing.assert_array_equal(ee1, ee2)
    for (h1, t1), (h2, t2) in zip(hits1, hits2):
        np.testing.assert_array_equal(h1, h2)
        np.testing.assert_array_equal(t1, t2)
    for f1, f2 in zip(frames1, frames2):
        for a, b in zip(f1, f2):
            np.testing.assert_array_equal(a, b)


def test_close_frames_are_the_masked_contact_frames_on_one_and_two_threads():
    """Stage (a)'s compiled selection of the pairs closer than h equals the frames of every candidate
    masked by d < h (numpy), rows in candidate order, bit for bit on 1 and 2 threads."""
    pts, tri, x0, _ = _sheets(11)
    system = System(tri, ())
    system.build_cloth_bvh(pts)
    h = 0.012
    c = system.candidates(x0, x0, margin=0.5 * h, self_collision=True, culling=False)
    for kind, q in (("vf", c.vf), ("ee", c.ee)):
        W, N, D = _distance_kernels.contact_frames(kind == "vf", x0, q, x0)
        close = D < h
        assert 0 < close.sum() < len(q) and len(q) > 2000  # some pairs kept, some dropped, several chunks
        for t in (1, 2):
            with thread_count(t):
                got = _distance_kernels.close_frames(kind == "vf", x0, q, x0, h)
            for a, b in zip(got, (q[close], W[close], N[close], D[close])):
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("culling", [False, True])
def test_fused_traversal_expansion_equals_the_gathered_triangle_pairs_expanded(culling):
    """``System.candidates`` expands each traversal chunk's triangle pairs inside the traversal: the pairs and
    their order are those of the whole triangle-pair list expanded after the traversal, on 1 and 2 threads."""
    pts, tri, x0, x1 = _sheets(9)
    system = System(tri, ())
    system.build_cloth_bvh(pts)
    margin = 4e-3
    system.cloth_bvh.refit(x0, x1, margin=margin)
    tp, tests = system.cloth_bvh.self_pairs(culling=culling)
    vlo, vhi = system.vertex_boxes(x0, x1, margin)
    vf, ee = system._primitive_pairs(tp, vlo, vhi)
    assert len(vf) > 2000 and len(ee) > 2000
    for t in (1, 2):
        with thread_count(t):
            c = system.candidates(x0, x1, margin=margin, self_collision=True, culling=culling)
        np.testing.assert_array_equal(c.vf, vf)
        np.testing.assert_array_equal(c.ee, ee)
        assert c.tests == tests


def test_pipeline_steps_with_rechecks_are_bit_identical_on_one_and_two_threads_and_intersection_free():
    """Four squeezed sheets falling on a floor: every stage (repulsion, CCD passes, impact zones, the pair
    store's stamped drops), and a second call per step with other velocities from the same start (the re-check
    after smoothing: the dirty searches), give the same velocities to the last bit on 1 and 2 threads, leave
    nothing unresolved and no intersection."""
    from modalfem.collision.obstacles import Plane
    from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline

    pts, tri = stacked_sheets(4, 12, gap=0.006, size=0.5, seed=9)
    rng = np.random.default_rng(9)
    layer = np.repeat(np.arange(4), len(pts) // 4)
    v0 = np.zeros_like(pts)
    v0[:, 2] = -0.4 * layer - 0.3  # upper layers faster: they close the gaps
    v0 += 0.05 * rng.standard_normal(pts.shape)
    masses = np.full(len(pts), 1e-3)
    runs = []
    for threads in (1, 2):
        with thread_count(threads):
            floor = Plane((0, 0, -0.004), (0, 0, 1))
            pipe = CollisionPipeline(tri, config=CollisionConfig(thickness=0.004), obstacles=(floor,))
            x, v, out, hits = pts.copy(), v0.copy(), [], 0
            for k in range(8):
                v_col, st = pipe.resolve(x, v, masses, 0.01, t=0.01 * k)
                assert st.unresolved == 0
                hits += sum(st.ccd_hits) + len(st.zone_sizes)
                wobble = v_col + 0.02 * np.sin(np.arange(len(x)) + k)[:, None]  # a "smoothed" answer to check again
                v_chk, st2 = pipe.resolve(x, wobble, masses, 0.01, t=0.01 * k)
                assert st2.unresolved == 0
                out += [v_col, v_chk]
                x = x + 0.01 * v_chk
                v = v_chk + np.array([0.0, 0.0, -0.1])
            assert pipe.check_initial(x, t=0.08) == 0
            runs.append((out, hits))
    assert runs[0][1] > 20  # the stages had work to do
    for a, b in zip(runs[0][0], runs[1][0]):
        np.testing.assert_array_equal(a, b)
