"""The body of ``CollisionPipeline.resolve``: stages (a) repulsion, (b) CCD passes, (c) impact zones.

Tried and dropped (issue 20): a sparse re-check after smoothing. The cloth step re-sent the smoothed velocities with
the smallest smoothed departures from the first call's answer ``v_col`` set back to ``v_col`` exactly (vertices in
order of ``m |dv_s - dv0|^2``, as many as keep the answer within ``rtol`` of the smoothed one in the mass norm, the
dropped linear momentum put back on the kept vertices), and ``resolve`` kept the velocities its last resolved call
certified for the same ``X0``, ``dt``, ``t``, so that the re-check's first CCD pass tested only pairs holding a
vertex whose velocity differed from them. It does not pay on the 64x64 pile: in the dense phase the
first call touches 55-65 % of the vertices and smoothing's change ``dv_s - dv0`` is 3-5 times ``|dv_s|`` in the mass
norm (median vertex 0.9-1.5 times the mass-weighted RMS of ``dv_s``, against the solve's rtol 0.1), so with rtol 0.1
59 % of the vertices kept their smoothed change (85 % in steps 40-80) and 86 % were flagged after the re-check's
repulsion in steps 40-80: 98 % of the store's pairs (stale ones counted) still had a flagged vertex (rtol 0.5: 66 %
of the vertices, 96 % of the pairs). Pile, one thread, CPU, Intel Xeon, load 8-10, alternating processes: smoothing
(solve + re-check) 31.2 ms/step without (the one run not paying compilation), 32.5 and 32.5 with rtol 0.1, 34.6-35.1
with rtol 0.5 (more impact zones: 6.9 against 6.1 per step); 0 intersections in all. Scratch: /tmp/h9/d9b
(sparse_recheck.patch, recheck.py).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from modalfem.collision import _pair_kernels
from modalfem.collision._distance_kernels import ccd_frames, obstacle_impulses, obstacle_repulsion
from modalfem.collision._system import PairStore, diagonal_test, update_diagonal_test
from modalfem.collision.ccd import MAX_INTERVALS
from modalfem.collision.obstacles import Plane
from modalfem.collision.repulsion import (
    apply_pair_impulses,
    pair_order,
    repulsion_pairs,
    sequential_pair_impulses,
)
from modalfem.collision.zones import UnionFind, rigid_zone_velocities
from modalfem.errors import SimulationError
from modalfem._threads import serial_blas

__all__ = ["PIPELINE_DEPTH", "analytic_hits", "ccd_hits", "resolve"]

#: CCD bisection depth in the pipeline: a near miss within eta + L * 2**-20 counts as a hit (L: the
#: pair's relative displacement over the step), a conservative answer that costs fewer levels
PIPELINE_DEPTH = 20
#: spare box margin of the candidate pairs as a fraction of the thickness, without culling: a vertex
#: whose trajectory moves by up to about ``SLACK * thickness`` keeps its pairs (larger: fewer
#: re-searches, more candidates)
SLACK = 0.1
#: fraction of dirty cloth vertices above which the candidate pairs are searched afresh
FRESH_SEARCH = 0.2
#: a re-searched (dirty) vertex's new box: its old box joined with its trajectory grown by ``DIRTY_GROW`` times
#: the margin (43 % of a step's dirty vertices were dirty before in the same step: the joined, wider box keeps
#: more of them clean). Replayed 64x64 pile (154 pipeline calls, one thread, CPU, Intel Xeon, load 1.6-2.1,
#: variants interleaved in one process, fastest of 4): 39.3 ms per call with the new box alone, 37.0-37.8 joined,
#: 36.7-37.2 joined and grown 2x, 37.5 at 3x. The answer does not depend on it (``ccd_hits``' canonical order)
DIRTY_GROW = 2.0


def _rows_any(a: np.ndarray) -> np.ndarray:
    """``a.any(axis=1)`` of a (k, 3) bool array, as the or of its columns: the same answer, without numpy's slow
    reduction along a length-3 axis (4200 x 3: 117 -> 7 us with numpy 1.24, 299 -> 7 with numpy 2.4, Intel
    Xeon). ~1,700 such masks in 154 replayed 64x64 pile calls: about 0.5 ms per call."""
    return a[:, 0] | a[:, 1] | a[:, 2]


def _analytic_contacts(ob, X0, V, dt, t, eta):
    """Vertex trajectories against a plane or sphere: (hit mask, time of impact in [0, 1]) (one compiled parallel
    pass, :func:`modalfem.collision._distance_kernels.obstacle_vertex_hits`)."""
    from modalfem.collision._distance_kernels import obstacle_vertex_hits

    X0, V = np.ascontiguousarray(X0, dtype=float), np.ascontiguousarray(V, dtype=float)
    if isinstance(ob, Plane):
        off = np.array([(ob.point + t * ob.velocity) @ ob.normal, (ob.point + (t + dt) * ob.velocity) @ ob.normal])
        return obstacle_vertex_hits(False, X0, V, dt, ob.normal, off, 0.0, eta)
    return obstacle_vertex_hits(True, X0, V, dt, ob.center_at(t), ob.velocity, float(ob.radius), eta)


def analytic_hits(system, X0, V, dt, t, eta, n):
    """List of (obstacle index, vertex indices, toi) for cloth vertices hitting planes/spheres."""
    out = []
    for k, ob in enumerate(system.analytic):
        hit, s = _analytic_contacts(ob, X0[:n], V[:n], dt, t, eta)
        ids = np.nonzero(hit)[0]
        if len(ids):
            out.append((k, ids, s[ids]))
    return out


def ccd_hits(system, X0, V, dt, store, invm, eta, roots=None, only=None):
    """Colliding candidate pairs of ``store`` (a ``PairStore``): [("vf"|"ee", quads (k, 4), toi (k,))],
    skipping all-kinematic pairs, pairs inside one zone (``roots``) and, if ``only`` ((N,) bool) is
    given, pairs without a flagged vertex (their trajectories did not change since they were last found
    collision-free). The cheap index filters run first, then the trajectory boxes (within ``eta``) and their
    projections on the box diagonals, then the CCD (one compiled parallel pass over all the store's segments,
    :func:`modalfem.collision._ccd_kernels.ccd_segments`).

    The hits come in a canonical order, not the store's: an edge-edge pair with its smaller edge (by vertex
    indices) first, all sorted by their four vertex indices. Every store holds every pair whose trajectory
    boxes come within ``eta``, so the hits are those of the trajectories alone (without swept culling), and
    the impulses built from them do not depend on how the candidates were kept (``SLACK``, ``DIRTY_GROW``,
    ``FRESH_SEARCH``, the order a search wrote them in): tests/collision/test_hits_independent_of_candidates.py."""
    from modalfem.collision import _ccd_kernels

    X0 = np.ascontiguousarray(X0, dtype=float)
    # end positions, their diagonal intervals and gap in one parallel pass
    X1, diag, gap = _ccd_kernels.trajectory_diagonals(X0, np.ascontiguousarray(V, dtype=float), float(dt), float(eta))
    movable = invm > 0
    zones = np.zeros(0, dtype=np.int64) if roots is None else np.ascontiguousarray(roots, dtype=np.int64)
    only = None if only is None else np.ascontiguousarray(only, dtype=bool)
    # the store's large blocks go to the CCD as they are, with the vertices whose pairs in them are gone and
    # ``only`` (filtered in the CCD's parallel pass), the selected pairs of the small ones as a list; all segments
    # of both kinds in one parallel region (ccd_segments): hits in the store's order
    segs = [(kind == "vf", q, gone, flags) for kind in ("vf", "ee") for q, gone, flags in store.segments(kind, only)
            if len(q)]
    found = _ccd_kernels.ccd_segments(segs, X0, X1, movable, zones, eta, PIPELINE_DEPTH, MAX_INTERVALS, diag, gap)
    out = []
    for kind in ("vf", "ee"):
        qs, ts = [], []
        for (vf, q, _, _), (idx, toi) in zip(segs, found):
            if vf == (kind == "vf") and len(idx):
                qs.append(q[idx].astype(np.int64))
                ts.append(toi)
        if qs:
            q, toi = np.concatenate(qs), np.concatenate(ts)
            if kind == "ee":  # the smaller edge first (the search writes a pair's edges in its triangles' order)
                swap = (q[:, 2] < q[:, 0]) | ((q[:, 2] == q[:, 0]) & (q[:, 3] < q[:, 1]))
                q[swap] = q[swap][:, [2, 3, 0, 1]]
            order = np.lexsort(q.T[::-1])
            out.append((kind, q[order], toi[order]))
    return out


def _ccd_impulses(system, X0, V, invm, dt, t, hits, ahits, cfg):
    h, eta = cfg.thickness, cfg.eta
    quads, ws, ns, tv = [], [], [], []
    for kind, q, toi in hits:
        # frames at each pair's time of impact, the velocity that ends the step at clip(d0 / 2, 2 eta, h)
        # (one compiled parallel pass)
        w, n, target = ccd_frames(kind == "vf", X0, V, np.ascontiguousarray(q, dtype=np.int64),
                                  np.ascontiguousarray(toi, dtype=float), dt, h, eta)
        quads.append(q)
        ws.append(w)
        ns.append(n)
        tv.append(target)
    dV = np.zeros_like(V)
    if quads:
        dV, _ = apply_pair_impulses(V, invm, np.concatenate(quads), np.concatenate(ws), np.concatenate(ns),
                                    np.concatenate(tv), friction=0.0)
    for k, ids, s in ahits:  # one compiled parallel pass per obstacle
        sphere, a, off, radius, lin, ang = _obstacle_args(system.analytic[k], t)
        obstacle_impulses(sphere, X0, V, invm, np.ascontiguousarray(ids, dtype=np.int64),
                          np.ascontiguousarray(s, dtype=float), dt, a, off, radius, lin, ang, h, eta, dV)
    return dV


def _obstacle_args(ob, t):
    """A plane's or sphere's arguments of the compiled obstacle kernels at time ``t``: (sphere?, plane normal or
    sphere centre, plane offset, radius, velocity, angular velocity)."""
    if isinstance(ob, Plane):
        return False, ob.normal, float((ob.point + t * ob.velocity) @ ob.normal), 0.0, ob.velocity, np.zeros(3)
    return True, ob.center_at(t), 0.0, float(ob.radius), ob.velocity, ob.angular_velocity


def _analytic_repulsion(system, X0, V, invm, dt, t, cfg, n):
    h, mu = cfg.thickness, cfg.friction
    dV = np.zeros_like(V)
    count = 0
    for ob in system.analytic:  # one compiled parallel pass per obstacle over the cloth vertices
        sphere, a, off, radius, lin, ang = _obstacle_args(ob, t)
        count += obstacle_repulsion(sphere, X0[:n], V[:n], invm[:n], a, off, radius, lin, ang, h, mu, dt, dV[:n])
    return dV, count


def _step_cache(system, cfg, X0, dt, t) -> dict:
    """The broad-phase results kept between calls with the same start positions, step and config (the
    pipeline call after smoothing re-uses those of the first call: same ``X0``, other velocities)."""
    c = getattr(system, "step_cache", None)
    if c is not None and c["cfg"] is cfg and c["dt"] == dt and c["t"] == t and np.array_equal(c["X0"], X0):
        return c
    system.step_cache = {"cfg": cfg, "dt": dt, "t": t, "X0": X0.copy(), "cand": None, "V": None, "lo": None, "hi": None,
                         "near": None, "diag": None}
    return system.step_cache


@serial_blas
def resolve(system, cfg, x0, v, masses, dt, t):
    """Run stages (a)-(c); see ``CollisionPipeline.resolve``."""
    from modalfem.collision.pipeline import CollisionStats

    tic = time.perf_counter()
    stats = CollisionStats()
    sec = {"broad_phase": 0.0, "repulsion": 0.0, "ccd": 0.0, "impact_zones": 0.0}
    n = system.n_cloth
    Xo0 = system.obstacle_positions(t)
    Xo1 = system.obstacle_positions(t + dt)
    X0 = np.concatenate([x0, Xo0])
    V = np.concatenate([v, (Xo1 - Xo0) / dt])
    invm = np.concatenate([1.0 / masses, np.zeros(len(Xo0))])
    eta = cfg.eta
    # spare box margin [m] of the candidate pairs. With swept culling a vertex whose end position moves by
    # more than eta is dirty anyway (the normal cones that culled its pairs were for the old trajectory), so
    # a wider margin would only add candidates
    swept_culling = cfg.culling and cfg.swept_culling
    culls = swept_culling and cfg.self_collision
    slack = eta if culls else max(eta, SLACK * cfg.thickness)
    margin = 0.5 * eta + 2 * slack
    cache = _step_cache(system, cfg, X0, dt, t)

    def candidates():
        """Pairs whose swept boxes come within eta, valid for the current V.

        Each vertex keeps the box its pairs were found with (trajectory grown by ``margin``); a vertex
        whose trajectory grown by eta / 2 leaves that box is dirty, and only the pairs holding a dirty
        vertex are searched again (for the dirty triangles only, its box now the old one joined with the new
        trajectory grown by ``DIRTY_GROW * margin``); the others stay valid. When more than
        ``FRESH_SEARCH`` of the cloth vertices are dirty (typically the call after smoothing) all pairs are
        searched afresh instead, as at the step's first call."""
        t0 = time.perf_counter()
        if cache["cand"] is None:
            measured = cfg.measure_culling or not swept_culling
            X1 = X0 + dt * V
            c = system.candidates(X0, X1, margin=margin, self_collision=cfg.self_collision, culling=swept_culling,
                                  count_unculled=cfg.measure_culling, diagonals=True)
            stats.pair_tests += c.tests
            if measured:
                stats.pair_tests_unculled = (stats.pair_tests_unculled or 0) + c.tests_unculled
            stats.candidates_vf += len(c.vf)
            stats.candidates_ee += len(c.ee)
            cache["cand"], cache["store"], cache["V"] = c, PairStore(c), V.copy()
            cache["lo"], cache["hi"] = system.vertex_boxes(X0, X1, margin)
            cache["diag"] = None
        else:
            # dirty: the trajectory grown by eta / 2 leaves the box its pairs were found with, or (with
            # swept culling: the normal cones that culled pairs were for the old trajectories) the end
            # position moved by more than eta
            lo, hi = cache["lo"], cache["hi"]
            # (one compiled pass: the velocity test, the mask's or and the mean were numpy passes over all rows
            # on each of the ~15 calls per step)
            X1, dirty, n_cloth, n_all = _pair_kernels.outgrown(X0, V, dt, 0.5 * eta, lo, hi, cache["V"],
                                                                eta if culls else np.inf, n)
            if n and n_cloth / n > FRESH_SEARCH:
                # most vertices dirty (the call after smoothing): one full search, as at the step's first
                # call, shares the descent that the dirty search would repeat per dirty triangle
                c = system.candidates(X0, X1, margin=margin, self_collision=cfg.self_collision, culling=swept_culling,
                                      diagonals=True)
                cache["store"], cache["V"] = PairStore(c), V.copy()
                cache["lo"], cache["hi"] = system.vertex_boxes(X0, X1, margin)
                cache["diag"] = None
            elif n_all:
                ids = np.flatnonzero(dirty)  # the same rows in the same order as the mask, fewer passes over N
                cache["V"][ids] = V[ids]
                nlo, nhi = system.vertex_boxes(X0[ids], X1[ids], DIRTY_GROW * margin)
                lo[ids], hi[ids] = np.minimum(lo[ids], nlo), np.maximum(hi[ids], nhi)
                # the boxes' diagonal intervals and gap: only the dirty rows changed (and grew) since they were
                # computed, so only those are recomputed (the same numbers as from scratch, without two O(N)
                # passes per dirty search)
                if cache["diag"] is None:
                    cache["diag"] = diagonal_test(lo, hi)
                else:
                    cache["diag"] = update_diagonal_test(cache["diag"], lo, hi, ids)
                cache["store"].drop(dirty)
                cache["store"].add(system.dirty_candidates(lo, hi, dirty, self_collision=cfg.self_collision,
                                                           diag=cache["diag"]))
        sec["broad_phase"] += time.perf_counter() - t0
        return cache["store"]

    if cfg.repulsion:
        t0 = time.perf_counter()
        if cache["near"] is None:  # pairs closer than h at X0: independent of the velocities
            # boxes at X0 grown by h / 2, normal cones of the static triangles (a traversal of its own)
            t1 = time.perf_counter()
            cand = system.candidates(X0, X0, margin=0.5 * cfg.thickness, self_collision=cfg.self_collision,
                                     culling=cfg.culling, count_unculled=cfg.measure_culling, within=cfg.thickness)
            stats.pair_tests += cand.tests
            if cfg.measure_culling or not cfg.culling:
                stats.pair_tests_unculled = (stats.pair_tests_unculled or 0) + cand.tests_unculled
            sec["broad_phase"] += time.perf_counter() - t1
            t0 += time.perf_counter() - t1
            # boxes grown by h / 2 overlap: the primitives' boxes are within h (distance < h is tested next)
            near = repulsion_pairs(X0, cand.vf, cand.ee, thickness=cfg.thickness, dt=dt)
            # the pairs in the sweeps' parallel order (groups sharing no cloth vertex): every cloth vertex counts as
            # movable, so the order holds for any masses of a later call
            cache["near"] = pair_order(X0, np.arange(len(X0)) < n, near[0]).arrange(*near)
        quads, w, nrm, tv, order = cache["near"]
        dA, acount = _analytic_repulsion(system, X0, V, invm, dt, t, cfg, n)
        if len(quads):
            V, _, _ = sequential_pair_impulses(V, invm, quads, w, nrm, tv, friction=cfg.friction, order=order,
                                               sweeps=cfg.repulsion_iterations)
        V = V + dA
        stats.proximities = len(quads) + acount
        sec["repulsion"] += time.perf_counter() - t0
    remaining = None
    only = None
    if cfg.ccd:
        only = None  # pass 1 tests every pair; later passes only pairs with a vertex changed since
        for _ in range(int(cfg.ccd_passes)):
            cand = candidates()
            t0 = time.perf_counter()
            hits = ccd_hits(system, X0, V, dt, cand, invm, eta, only=only)
            ahits = analytic_hits(system, X0, V, dt, t, eta, n)
            nh = sum(len(h[1]) for h in hits) + sum(len(a[1]) for a in ahits)
            stats.ccd_hits.append(nh)
            if nh:
                # invariant: a pair without a vertex in `only` was found collision-free on its current
                # trajectory; changed vertices and vertices of hit pairs are retested
                dV = _ccd_impulses(system, X0, V, invm, dt, t, hits, ahits, cfg)
                only = _pair_kernels.rows_nonzero(dV)
                for _, q, _ in hits:
                    only[q.ravel()] = True
                for _, ids, _ in ahits:
                    only[ids] = True
                V = V + dV
            sec["ccd"] += time.perf_counter() - t0
            if nh == 0:
                remaining = 0
                break
    if cfg.impact_zones and remaining != 0:
        t0 = time.perf_counter()
        bp0 = sec["broad_phase"]
        uf = UnionFind(len(X0) + len(system.analytic))
        inconsistent = np.zeros(0, dtype=np.int64)
        # first iteration: pairs flagged by the CCD passes (all if none ran); then pairs touching the
        # zones just recomputed
        only = only if cfg.ccd else None
        for it in range(int(cfg.max_zone_iterations) + 1):
            roots = uf.roots()
            skip = roots.copy()
            if len(inconsistent):
                bad = np.isin(roots, inconsistent)
                skip[bad] = -1 - np.arange(len(roots))[bad]
            cand = candidates()
            hits = ccd_hits(system, X0, V, dt, cand, invm, eta, roots=skip, only=only)
            ahits = [(k, ids[skip[ids] != skip[len(X0) + k]], s[skip[ids] != skip[len(X0) + k]])
                     for k, ids, s in analytic_hits(system, X0, V, dt, t, eta, n)]
            remaining = sum(len(h[1]) for h in hits) + sum(len(a[1]) for a in ahits)
            if remaining == 0 or it == cfg.max_zone_iterations:
                break
            for _, q, _ in hits:
                uf.union_quads(q)
            for k, ids, _ in ahits:
                uf.union(ids, np.full(len(ids), len(X0) + k))
            roots = uf.roots()
            hit_nodes = np.concatenate([q.ravel() for _, q, _ in hits] + [a[1] for a in ahits]
                                       + [np.array([len(X0) + a[0]]) for a in ahits])
            V_old = V
            V, inconsistent = rigid_zone_velocities(X0, V, invm, roots, system.analytic, t)
            hit_root = np.zeros(len(roots), dtype=bool)
            hit_root[roots[hit_nodes]] = True
            only = hit_root[roots[: len(X0)]] | _rows_any(V != V_old)
        stats.zone_iterations = it
        roots = uf.roots()
        sizes = np.bincount(roots[:n], minlength=len(roots))
        stats.zone_sizes = sorted((int(s) for s in sizes[sizes > 1]), reverse=True)
        sec["impact_zones"] += time.perf_counter() - t0 - (sec["broad_phase"] - bp0)
    elif remaining is None:
        cand = candidates()
        remaining = sum(len(h[1]) for h in ccd_hits(system, X0, V, dt, cand, invm, eta)) + sum(
            len(a[1]) for a in analytic_hits(system, X0, V, dt, t, eta, n))
    stats.unresolved = int(remaining)
    if stats.unresolved and cfg.impact_zones:
        warnings.warn(f"collision pipeline left {stats.unresolved} colliding pairs (impact zones did not converge)",
                      stacklevel=3)
    v_new = V[:n]
    v_new[masses == np.inf] = v[masses == np.inf]
    if not np.isfinite(v_new).all():
        raise SimulationError("collision response produced non-finite velocities")
    stats.touched = _rows_any(v_new != v)
    sec["total"] = time.perf_counter() - tic
    stats.seconds = sec
    return v_new, stats
