"""The collision pipeline: adversarial random steps end collision-free (independent triangle test and an
exact CCD of every primitive pair), obstacles, pins, stage switches, statistics and bad input."""

from __future__ import annotations

import warnings

import _meshes
import numpy as np
import pytest
from _meshes import all_pairs, grid, stacked_sheets

from modalfem.collision.ccd import edge_edge_ccd, vertex_face_ccd
from modalfem.collision.obstacles import Plane, Sphere, TriangleMeshObstacle
from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline
from modalfem.collision.tritri import intersecting_pairs
from modalfem.errors import InputError, SceneError, SimulationError

DT = 0.01




def _crossings(x0, x1, tri):
    vf, ee = all_pairs(tri)
    hv, _ = vertex_face_ccd(x0[vf], x1[vf])
    he, _ = edge_edge_ccd(x0[ee], x1[ee])
    return int(hv.sum() + he.sum())


@pytest.mark.parametrize("seed", range(4))
def test_adversarial_random_steps_end_collision_free(seed):
    rng = np.random.default_rng(seed)
    x0, tri = stacked_sheets(3, 4, gap=0.03, seed=seed)
    v = rng.normal(scale=3.0, size=x0.shape)  # moves ~10 layer gaps per step
    masses = rng.uniform(0.5, 2.0, len(x0))
    assert _crossings(x0, x0 + DT * v, tri) > 0  # the candidate step does cross
    pipe = CollisionPipeline(tri, config=CollisionConfig(thickness=0.004))
    v_new, st = pipe.resolve(x0, v, masses, DT)
    x1 = x0 + DT * v_new
    assert st.unresolved == 0
    assert len(intersecting_pairs(x1, tri)) == 0
    assert _crossings(x0, x1, tri) == 0
    assert st.touched.any() and np.isfinite(v_new).all()


def test_impact_zones_alone_are_a_fail_safe_and_pins_hold():
    rng = np.random.default_rng(11)
    x0, tri = stacked_sheets(2, 4, gap=0.02, seed=11)
    v = rng.normal(scale=4.0, size=x0.shape)
    masses = np.ones(len(x0))
    pinned = rng.choice(len(x0), 5, replace=False)
    masses[pinned] = np.inf
    v[pinned] = 0.0
    cfg = CollisionConfig(thickness=0.004, repulsion=False, ccd=False)
    v_new, st = CollisionPipeline(tri, config=cfg).resolve(x0, v, masses, DT)
    assert st.unresolved == 0 and st.zone_iterations > 0 and st.zone_sizes
    assert np.array_equal(v_new[pinned], v[pinned])
    assert _crossings(x0, x0 + DT * v_new, tri) == 0


def test_stages_off_leave_velocities_and_report_unresolved():
    rng = np.random.default_rng(2)
    x0, tri = stacked_sheets(2, 4, gap=0.02)
    v = rng.normal(scale=4.0, size=x0.shape)
    cfg = CollisionConfig(thickness=0.004, repulsion=False, ccd=False, impact_zones=False)
    v_new, st = CollisionPipeline(tri, config=cfg).resolve(x0, v, np.ones(len(x0)), DT)
    assert np.array_equal(v_new, v) and st.unresolved > 0 and not st.touched.any()
    cfg = CollisionConfig(thickness=0.004, self_collision=False)
    v_new, st = CollisionPipeline(tri, config=cfg).resolve(x0, v, np.ones(len(x0)), DT)
    assert np.array_equal(v_new, v) and st.unresolved == 0


def test_culling_statistics_on_a_draped_sheet():
    """A flat sheet cannot touch itself: culling removes every test of the traversals it runs in, the
    proximity search by default,
    both with ``swept_culling``. (The thickness is the cell size: the unculled swept search then keeps pairs of
    nearby primitives; with a thinner cloth the searches' box-diagonal test leaves none of a flat sheet's.)"""
    x0, tri = grid(20, 20)
    v = np.zeros_like(x0)
    v[:, 2] = -1.0
    both = CollisionConfig(thickness=0.05, measure_culling=True, swept_culling=True)
    _, st = CollisionPipeline(tri, config=both).resolve(x0, v, np.ones(len(x0)), DT)
    assert st.pair_tests == 0 < st.pair_tests_unculled and st.culled_fraction == 1.0
    default = CollisionConfig(thickness=0.05, measure_culling=True)
    _, st2 = CollisionPipeline(tri, config=default).resolve(x0, v, np.ones(len(x0)), DT)
    assert 0 < st2.pair_tests < st2.pair_tests_unculled  # the swept traversal's tests, unculled
    # what default culling saved is the proximity search's tests, which ``both`` counts too (beside its swept
    # search's, whose margin differs: the traversals prune node pairs apart on a box diagonal, so their counts
    # depend on the margin)
    assert 0 < st2.pair_tests_unculled - st2.pair_tests < st.pair_tests_unculled
    assert st2.candidates_vf + st2.candidates_ee > 0 == st.candidates_vf + st.candidates_ee


@pytest.mark.parametrize(
    "obstacle",
    [Plane([0, 0, -0.01], [0, 0, 1]), Plane([0, 0, -0.01], [0, 0, 1], velocity=[0, 0, 2.0]),
     Sphere([0.5, 0.5, -0.3], 0.29), Sphere([0.5, 0.5, -0.3], 0.29, velocity=[0, 0, 3.0], angular_velocity=[0, 5, 0])],
)
def test_analytic_obstacles_are_not_crossed(obstacle):
    x0, tri = grid(6, 6)
    rng = np.random.default_rng(0)
    v = rng.normal(scale=0.5, size=x0.shape)
    v[:, 2] -= 5.0
    pipe = CollisionPipeline(tri, config=CollisionConfig(thickness=0.004), obstacles=[obstacle])
    assert pipe.check_initial(x0) == 0
    v_new, st = pipe.resolve(x0, v, np.ones(len(x0)), DT)
    assert st.unresolved == 0
    assert (obstacle.signed_distance(x0 + DT * v_new, DT) >= 0).all()
    assert _crossings(x0, x0 + DT * v_new, tri) == 0


def test_repulsion_stops_approach_with_bounded_friction():
    x0, tri = grid(4, 4)
    x0[:, 2] = 0.002
    v = np.zeros_like(x0)
    v[:, 2] = -0.05
    v[:, 0] = 1.0
    cfg = CollisionConfig(thickness=0.004, friction=0.3)
    v_new, st = CollisionPipeline(tri, config=cfg, obstacles=[Plane([0, 0, 0], [0, 0, 1])]).resolve(
        x0, v, np.ones(len(x0)), DT)
    assert st.proximities == len(x0)
    dvn = v_new[:, 2] - v[:, 2]
    assert (v_new[:, 2] >= 0).all()
    assert (v_new[:, 0] <= 1.0).all() and (v_new[:, 0] >= 1.0 - 0.3 * dvn - 1e-12).all()


@pytest.mark.parametrize("moving", [False, True])
def test_triangle_mesh_obstacle_static_and_moving(moving):
    ox, otri = grid(3, 3, size=1.2, z=-0.02, origin=(-0.1, -0.1))
    ox[4, 2] += 0.01  # a bump
    ob = TriangleMeshObstacle(ox, otri, vertices_end=ox + [0, 0, 0.05] if moving else None, t_end=DT)
    x0, tri = grid(5, 5)
    rng = np.random.default_rng(4)
    v = rng.normal(scale=0.5, size=x0.shape)
    v[:, 2] -= 4.0
    pipe = CollisionPipeline(tri, config=CollisionConfig(thickness=0.004), obstacles=[ob])
    v_new, st = pipe.resolve(x0, v, np.ones(len(x0)), DT)
    x1 = x0 + DT * v_new
    assert st.unresolved == 0
    assert len(intersecting_pairs(x1, tri, other_points=ob.positions(DT), other_triangles=otri)) == 0
    assert _crossings(x0, x1, tri) == 0
    # the exact CCD of every cloth primitive against every obstacle primitive over the step
    X0 = np.concatenate([x0, ob.positions(0.0)])
    X1 = np.concatenate([x1, ob.positions(DT)])
    vf, ee = all_pairs(np.concatenate([tri, otri + len(x0)]))
    cloth = lambda q: q < len(x0)
    vf = vf[cloth(vf[:, 0]) != cloth(vf[:, 1])]
    ee = ee[cloth(ee[:, 0]) != cloth(ee[:, 2])]
    assert not vertex_face_ccd(X0[vf], X1[vf])[0].any()
    assert not edge_edge_ccd(X0[ee], X1[ee])[0].any()


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(12))
def test_many_adversarial_steps_with_obstacles_and_pins(seed):
    rng = np.random.default_rng(100 + seed)
    x0, tri = stacked_sheets(int(rng.integers(2, 4)), int(rng.integers(3, 6)), gap=0.02, seed=seed)
    x0[:, 2] += 0.03
    v = rng.normal(scale=rng.uniform(1, 6), size=x0.shape)
    masses = rng.uniform(0.2, 2.0, len(x0))
    pinned = rng.choice(len(x0), int(rng.integers(0, 4)), replace=False)
    masses[pinned] = np.inf
    v[pinned] = 0.0
    floor = Plane([0, 0, 0], [0, 0, 1])
    cfg = CollisionConfig(thickness=0.004, repulsion=bool(seed % 2), ccd_passes=int(seed % 3))
    v_new, st = CollisionPipeline(tri, config=cfg, obstacles=[floor]).resolve(x0, v, masses, DT)
    x1 = x0 + DT * v_new
    assert st.unresolved == 0
    assert np.array_equal(v_new[pinned], v[pinned])
    assert (floor.signed_distance(x1, DT) >= 0).all()
    assert len(intersecting_pairs(x1, tri)) == 0
    assert _crossings(x0, x1, tri) == 0


def test_starting_intersection_warns_with_count_or_raises():
    x0, tri = grid(2, 2)
    x0 = np.vstack([x0, [[0.3, 0.1, -0.5], [0.4, 0.1, 0.5], [0.3, 0.15, 0.5]]])
    tri = np.vstack([tri, [[9, 10, 11]]])
    pipe = CollisionPipeline(tri, config=CollisionConfig(thickness=0.01))
    with pytest.warns(UserWarning, match="1 intersecting pairs"):
        assert pipe.check_initial(x0) == 1
    with pytest.raises(SceneError, match="starts in intersection"):
        pipe.check_initial(x0, strict=True)


def test_bad_input_is_a_clear_error():
    x0, tri = grid(2, 2)
    with pytest.raises(InputError):
        CollisionConfig(thickness=0.0)
    with pytest.raises(InputError):
        CollisionPipeline(tri, config=CollisionConfig(thickness=0.01), obstacles=["floor"])
    with pytest.raises(InputError):
        CollisionPipeline(tri[:, :2], config=CollisionConfig(thickness=0.01))
    pipe = CollisionPipeline(tri, config=CollisionConfig(thickness=0.01))
    m = np.ones(len(x0))
    with pytest.raises(InputError):
        pipe.resolve(x0[:-1], np.zeros_like(x0), m, DT)
    with pytest.raises(SimulationError):
        pipe.resolve(x0, np.zeros_like(x0), m, 0.0)
    with pytest.raises(SimulationError):
        pipe.resolve(x0, np.full_like(x0, np.nan), m, DT)
    with pytest.raises(SimulationError):
        pipe.resolve(x0, np.zeros_like(x0), 0 * m, DT)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pipe.resolve(x0, np.zeros_like(x0), m, DT)


@pytest.mark.parametrize("seed, swept_culling", [(0, False), (1, False), (0, True), (1, True)])
def test_folded_sheet_with_culling_ends_collision_free(seed, swept_culling):
    x0, tri, rest = _meshes.folded_sheet(4, gap=0.05)
    assert len(intersecting_pairs(x0, tri)) == 0
    rng = np.random.default_rng(seed)
    v = rng.normal(scale=3.0, size=x0.shape)
    v[:, 2] -= np.where(x0[:, 2] > 0.04, 8.0, 0.0)  # the upper half is thrown through the lower
    assert _crossings(x0, x0 + DT * v, tri) > 0
    cfg = CollisionConfig(thickness=0.004, measure_culling=True, swept_culling=swept_culling)
    pipe = CollisionPipeline(tri, config=cfg, reference_positions=rest)
    v_new, st = pipe.resolve(x0, v, np.ones(len(x0)), DT)
    assert st.unresolved == 0 and st.pair_tests <= st.pair_tests_unculled
    assert _crossings(x0, x0 + DT * v_new, tri) == 0
    assert len(intersecting_pairs(x0 + DT * v_new, tri)) == 0


def test_obstacle_and_option_validation():
    x0, tri = grid(2, 2)
    with pytest.raises(InputError):
        CollisionPipeline(tri, config=CollisionConfig(thickness=0.01), reference_positions=x0[:-1])
    with pytest.raises(InputError):
        CollisionPipeline(tri, config=CollisionConfig(thickness=0.01), n_vertices=3)
    with pytest.raises(InputError):
        Sphere([0, 0, 0], 0.0)
    with pytest.raises(InputError):
        Plane([0, 0, 0], [0, 0, 0])
    with pytest.raises(InputError):
        TriangleMeshObstacle(x0, tri, vertices_end=x0[:-1])
    with pytest.raises(InputError):
        TriangleMeshObstacle(x0, tri + 100)
    moving = TriangleMeshObstacle(x0, tri, motion=lambda t: x0 + [0, 0, t])
    assert np.allclose(moving.positions(0.5)[:, 2], x0[:, 2] + 0.5)
    keyed = TriangleMeshObstacle(x0, tri, vertices_end=x0 + 1.0, t_start=1.0, t_end=3.0)
    assert np.allclose(keyed.positions(2.0), x0 + 0.5) and np.allclose(keyed.positions(9.0), x0 + 1.0)


@pytest.mark.parametrize("fresh", [0.0, 1.0])
@pytest.mark.parametrize("swept_culling", [False, True])
def test_second_call_with_new_velocities_reuses_the_step_and_ends_collision_free(fresh, swept_culling, monkeypatch):
    """The call after smoothing (same start, other velocities) re-uses the step's candidate pairs: with
    most vertices dirty it searches afresh (fresh = 0: always), else only the dirty
    vertices (fresh = 1: never); either way its answer has no crossing."""
    from modalfem.collision import _stages

    monkeypatch.setattr(_stages, "FRESH_SEARCH", fresh)
    x0, tri, rest = _meshes.folded_sheet(4, gap=0.05)
    rng = np.random.default_rng(7)
    cfg = CollisionConfig(thickness=0.004, swept_culling=swept_culling)
    pipe = CollisionPipeline(tri, config=cfg, reference_positions=rest)
    v = rng.normal(scale=3.0, size=x0.shape)
    v[:, 2] -= np.where(x0[:, 2] > 0.04, 8.0, 0.0)
    v_first, st = pipe.resolve(x0, v, np.ones(len(x0)), DT)
    assert st.unresolved == 0 and st.pair_tests > 0
    v2 = v_first + rng.normal(scale=1.5, size=x0.shape)  # a different, crossing candidate
    assert _crossings(x0, x0 + DT * v2, tri) > 0
    v_new, st2 = pipe.resolve(x0, v2, np.ones(len(x0)), DT)
    assert st2.pair_tests == 0  # the traversals of the first call were re-used
    assert st2.unresolved == 0
    assert _crossings(x0, x0 + DT * v_new, tri) == 0
    assert len(intersecting_pairs(x0 + DT * v_new, tri)) == 0


def _approach_after_repulsion(iterations):
    """Three sheets 2 mm apart (h = 4 mm, every vertex in several close pairs) squeezed together:
    (largest approach speed [m/s] a close pair keeps beyond its target after stage (a) alone, pass-1 CCD
    hits of the full pipeline)."""
    from modalfem.collision.repulsion import repulsion_pairs

    x0, tri = stacked_sheets(3, 6, gap=0.002, seed=5)
    rng = np.random.default_rng(5)
    v = np.zeros_like(x0)
    v[:, 2] = np.where(x0[:, 2] > 0.003, -0.6, np.where(x0[:, 2] > 0.001, 0.0, 0.6))
    v += rng.normal(scale=0.05, size=v.shape)
    masses = np.ones(len(x0))
    only_a = CollisionConfig(thickness=0.004, ccd=False, impact_zones=False, repulsion_iterations=iterations)
    v_a, _ = CollisionPipeline(tri, config=only_a).resolve(x0, v, masses, DT)
    vf, ee = all_pairs(tri)
    quads, w, n, target = repulsion_pairs(x0, vf, ee, thickness=0.004, dt=DT)
    vn = np.einsum("kj,kji,ki->k", w, v_a[quads], n)
    full = CollisionConfig(thickness=0.004, repulsion_iterations=iterations)
    v_full, st = CollisionPipeline(tri, config=full).resolve(x0, v, masses, DT)
    assert st.unresolved == 0 and _crossings(x0, x0 + DT * v_full, tri) == 0
    return float(np.max(target - vn)), st.ccd_hits[0]


def test_repeated_repulsion_sweeps_stop_stacked_layers_approaching():
    """One sweep leaves layers pressed together approaching (a pair's impulse is partly undone by the
    pairs after it); 10 sweeps bring every close pair within a fraction of its wanted normal velocity,
    and the CCD that follows finds fewer colliding pairs."""
    miss1, hits1 = _approach_after_repulsion(1)
    miss10, hits10 = _approach_after_repulsion(10)
    assert miss1 > 0.05  # m/s: one sweep leaves pairs approaching
    assert miss10 < 0.2 * miss1
    assert hits10 < hits1


def test_repulsion_iterations_must_be_positive():
    with pytest.raises(InputError, match="repulsion_iterations"):
        CollisionConfig(thickness=0.004, repulsion_iterations=0)


# below and above two chunks (``OBSTACLE_CHUNK``): the serial pass and the parallel chunks
@pytest.mark.parametrize("n", [5000, 20000])
def test_vertex_hits_on_planes_and_spheres_match_their_definitions_on_one_and_two_threads(n):
    """The compiled vertex-obstacle test (parallel chunks) against the trajectories' definitions in numpy: a
    moving plane (end distance below eta; time of impact where the distance reaches eta) and a moving sphere
    (closest approach of the relative trajectory within radius + eta, or the end inside), same hits, same times."""
    import numba

    from modalfem._threads import thread_count
    from modalfem.collision._stages import _analytic_contacts

    rng = np.random.default_rng(11)
    X0 = rng.uniform(-0.3, 0.3, (n, 3))
    V = rng.normal(0.0, 5.0, (n, 3))
    dt, t, eta = 0.01, 0.02, 1e-3
    plane = Plane([0.0, 0.0, -0.1], [0.1, 0.2, 1.0], velocity=[0.0, 0.0, 0.5])
    ball = Sphere([0.05, 0.0, 0.0], 0.2, velocity=[1.0, 0.0, -2.0])
    d0 = plane.signed_distance(X0, t)
    d1 = plane.signed_distance(X0 + dt * V, t + dt)
    want_plane = d1 < eta
    s_plane = np.clip(np.where(d0 > d1, (d0 - eta) / np.where(d0 > d1, d0 - d1, 1.0), 0.0), 0.0, 1.0)
    r0 = X0 - ball.center_at(t)
    dr = dt * (V - ball.velocity)
    s = np.clip(-np.einsum("ki,ki->k", r0, dr) / np.einsum("ki,ki->k", dr, dr), 0.0, 1.0)
    want_ball = ((np.linalg.norm(r0 + s[:, None] * dr, axis=1) < ball.radius + eta) & (s > 0)) | (
        np.linalg.norm(r0 + dr, axis=1) < ball.radius + eta)
    assert 100 < want_plane.sum() < n - 100 and 100 < want_ball.sum() < n - 100  # both kinds of answer, many times
    runs = []
    for threads in (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,):
        with thread_count(threads):
            runs.append((_analytic_contacts(plane, X0, V, dt, t, eta), _analytic_contacts(ball, X0, V, dt, t, eta)))
    (hp, sp), (hb, sb) = runs[0]
    np.testing.assert_array_equal(hp, want_plane)
    np.testing.assert_allclose(sp, s_plane, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(hb, want_ball)
    np.testing.assert_allclose(sb[hb], s[hb], rtol=1e-12, atol=1e-12)
    assert np.isinf(sb[~hb]).all()
    for (a, b), (c, d) in zip(runs[0], runs[-1]):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, d)


@pytest.mark.parametrize("pairs", [300, 1500])  # one chunk (serial) and parallel chunks (FRAME_CHUNK)
def test_ccd_frames_are_the_contact_frames_at_the_time_of_impact_on_one_and_two_threads(pairs):
    """The CCD impulses' frames and targets in one compiled pass against their definition: contact frames at
    ``X0 + toi dt V`` oriented by ``X0``, start separation ``d0`` along the normal, target end separation
    ``clip(d0 / 2, 2 eta, h)``."""
    import numba

    from modalfem._threads import thread_count
    from modalfem.collision._distance_kernels import ccd_frames
    from modalfem.collision.repulsion import contact_frames

    rng = np.random.default_rng(12)
    X0 = rng.uniform(0.0, 0.05, (400, 3))
    V = rng.normal(0.0, 1.0, (400, 3))
    dt, h, eta = 0.01, 0.004, 4e-6
    for kind in ("vf", "ee"):
        q = np.array([rng.choice(400, 4, replace=False) for _ in range(pairs)])
        toi = rng.uniform(-0.2, 1.2, len(q))  # clipped to [0, 1]
        Pq = X0[q] + (dt * np.clip(toi, 0.0, 1.0))[:, None, None] * V[q]
        w, n, _ = contact_frames(Pq.reshape(-1, 3), np.arange(4 * len(q)).reshape(-1, 4), kind, X0[q].reshape(-1, 3))
        d0 = np.einsum("ki,ki->k", np.einsum("kj,kji->ki", w, X0[q]), n)
        target = (np.clip(0.5 * d0, 2 * eta, h) - d0) / dt
        runs = []
        for threads in (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,):
            with thread_count(threads):
                runs.append(ccd_frames(kind == "vf", X0, V, q, toi, dt, h, eta))
        W, N, T = runs[0]
        np.testing.assert_array_equal(W, w)
        np.testing.assert_array_equal(N, n)
        np.testing.assert_allclose(T, target, rtol=1e-12, atol=1e-12 * np.abs(target).max())
        for a, b in zip(runs[0], runs[-1]):
            np.testing.assert_array_equal(a, b)


def _obstacle_reference(ob, X0, V, invm, dt, t, h, mu, eta, ids, s):
    """Stage (a)'s and the CCD's vertex-obstacle velocity changes in numpy, from their definitions."""
    d = ob.signed_distance(X0, t)
    near = np.nonzero((d < h) & (invm > 0))[0]
    nrm = ob.normal_at(X0[near], t)
    vr = V[near] - ob.velocity_at(X0[near], t)
    vn = np.einsum("ki,ki->k", vr, nrm)
    dvn = np.maximum(0.1 * (h - d[near]) / dt - vn, 0.0)
    vt = vr - vn[:, None] * nrm
    tn = np.linalg.norm(vt, axis=1)
    kf = np.minimum(mu * dvn / np.where(tn > 0, tn, 1.0), 1.0)
    rep = np.zeros_like(V)
    rep[near] = dvn[:, None] * nrm - kf[:, None] * vt
    s = np.clip(s, 0.0, 1.0)
    xs = X0[ids] + (dt * s)[:, None] * V[ids]
    if isinstance(ob, Plane):
        nrm = ob.normal_at(xs, t)
    else:
        r = xs - (ob.center + (t + dt * s)[:, None] * ob.velocity)
        nrm = r / np.linalg.norm(r, axis=1)[:, None]
    d0 = ob.signed_distance(X0[ids], t)
    vn = np.einsum("ki,ki->k", V[ids] - ob.velocity_at(xs, t), nrm)
    want = (np.clip(0.5 * d0, 2 * eta, h) - d0) / dt
    imp = np.zeros_like(V)
    imp[ids] = (np.maximum(want - vn, 0.0) * (invm[ids] > 0))[:, None] * nrm
    return rep, len(near), imp


# 1,000 vertices: the impulses of their few hundred hits in one chunk (serial); 5,000 and 20,000: below and above two
# chunks of the repulsion pass (``OBSTACLE_CHUNK``)
@pytest.mark.parametrize("n", [1000, 5000, 20000])
def test_obstacle_repulsion_and_impulses_match_their_definitions_on_one_and_two_threads(n):
    """Stage (a) against a moving plane and a spinning, moving sphere, and the CCD impulses of the vertices that hit
    them (compiled parallel passes), against the numpy definitions; the same bits on 1 and 2 threads."""
    from types import SimpleNamespace

    import numba

    from modalfem._threads import thread_count
    from modalfem.collision import _stages

    rng = np.random.default_rng(13)
    X0 = rng.uniform(-0.3, 0.3, (n, 3))
    V = rng.normal(0.0, 3.0, (n, 3))
    invm = np.where(rng.uniform(size=n) < 0.05, 0.0, 1.0)
    dt, t = 0.01, 0.02
    cfg = CollisionConfig(thickness=0.05, friction=0.3)
    for ob in (Plane([0.0, 0.0, -0.1], [0.1, 0.2, 1.0], velocity=[0.0, 0.0, 0.5]),
               Sphere([0.05, 0.0, 0.0], 0.2, velocity=[1.0, 0.0, -2.0], angular_velocity=[0.0, 3.0, 1.0])):
        system = SimpleNamespace(analytic=[ob])
        ahits = _stages.analytic_hits(system, X0, V, dt, t, cfg.eta, len(X0))
        rep, count, imp = _obstacle_reference(ob, X0, V, invm, dt, t, cfg.thickness, cfg.friction, cfg.eta,
                                              ahits[0][1], ahits[0][2])
        assert count > 100 and len(ahits[0][1]) > 100
        runs = []
        for threads in (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,):
            with thread_count(threads):
                runs.append((_stages._analytic_repulsion(system, X0, V, invm, dt, t, cfg, len(X0)),
                             _stages._ccd_impulses(system, X0, V, invm, dt, t, [], ahits, cfg)))
        (got_rep, got_count), got_imp = runs[0]
        assert got_count == count
        np.testing.assert_allclose(got_rep, rep, rtol=1e-12, atol=1e-12 * np.abs(rep).max())
        np.testing.assert_allclose(got_imp, imp, rtol=1e-12, atol=1e-12 * np.abs(imp).max())
        np.testing.assert_array_equal(runs[0][0][0], runs[-1][0][0])
        np.testing.assert_array_equal(runs[0][1], runs[-1][1])
