"""The single-body contact kernels (runtime/_contact_body_kernels.py) against independent references: the rigid
solve against the general row-based solve, the crossing prediction against the roots of each gap's quadratic,
the fused contact search against the candidate + exact-gap pipeline it replaced, and the reuse of contacts found
at the state of the step."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem.runtime as rt
from modalfem.runtime import _contact_body_kernels as KB
from modalfem.runtime import _contact_kernels as K


def _skew_rows(r):
    """Rows J = [I, -[r]x] (k, 3, 6) of rigid contacts at lever arms r (k, 3)."""
    k = len(r)
    J = np.zeros((k, 3, 6))
    J[:, :, :3] = np.eye(3)
    for i, (a, b, c) in enumerate(r):
        J[i, :, 3:] = -np.array([[0.0, -c, b], [c, 0.0, -a], [-b, a, 0.0]])
    return J


@pytest.mark.parametrize("friction", [0.0, 0.7])
@pytest.mark.parametrize("guess", [False, True])
def test_the_rigid_solve_is_the_general_solve_on_rigid_rows(friction, guess):
    """solve_rigid (six velocities in registers) against _contact_kernels.solve given the rows [I, -[r]x] and
    W J^T: the same impulses and velocities, to the rigid solve's velocity tolerance (it skips updates below
    1e-12 of the problem's velocity scale), for random contacts on a tilted face with sliding and spin."""
    rng = np.random.default_rng(3)
    k, mass = 40, 2.5
    A = rng.normal(size=(3, 3))
    inertia = A @ A.T + 0.05 * np.eye(3)
    Iw_inv = np.linalg.inv(inertia)
    r = rng.uniform(-0.1, 0.1, size=(k, 3))
    r[:, 2] = -0.05 + 0.01 * r[:, 0]
    n = np.tile([0.1, 0.0, 1.0] / np.linalg.norm([0.1, 0.0, 1.0]), (k, 1))
    target = rng.uniform(-0.02, 0.3, size=k)
    shift = np.tile([0.0, 0.0, -0.005], (k, 1))
    mu = np.full(k, friction)
    V0 = np.array([0.3, -0.2, -1.0, 2.0, -1.0, 0.5])
    J = _skew_rows(r)
    WJ = np.empty_like(J)
    WJ[:, :, :3] = J[:, :, :3] / mass
    WJ[:, :, 3:] = J[:, :, 3:] @ Iw_inv  # rows of W J^T (Iw_inv symmetric)
    out = {}
    for name in ("general", "rigid"):
        V = V0.copy()
        lam, jt, lam_n = np.zeros((k, 3)), np.zeros((k, 3)), np.zeros(k)
        if name == "general":
            z = np.zeros(k, dtype=np.int64)
            K.solve(z, z - 1, J, WJ, J, WJ, V, np.zeros(1, dtype=np.int64), np.array([6]), n, target, mu, shift, 30,
                    lam, jt, lam_n, guess)
        else:
            KB.solve_rigid(r, mass, Iw_inv, V, n, target, mu, shift, 30, lam, jt, lam_n, guess)
        out[name] = (V, lam_n, jt)
    scale = np.abs(V0).max() + np.abs(target).max()
    assert np.abs(out["rigid"][0] - out["general"][0]).max() <= 1e-8 * scale
    big = np.abs(out["general"][1]).max()
    assert big > 0.0
    assert np.abs(out["rigid"][1] - out["general"][1]).max() <= 1e-6 * big
    assert np.abs(out["rigid"][2] - out["general"][2]).max() <= 1e-6 * big


def _reference_crossings(gap, vn, an, thr, horizon):
    """Per contact, the earliest t in (0, horizon] with gap + vn t + an t^2 / 2 = 0 and a negative velocity
    there (numpy.roots), t = 0 for a contact touching and not leaving; then the earliest fast and slow ones."""
    fast, j, slow = None, -1, None
    for i in range(len(gap)):
        first, speed = np.inf, 0.0
        roots = np.roots([0.5 * an[i], vn[i], gap[i]]) if (an[i] != 0.0 or vn[i] != 0.0) else []
        for t in roots:
            if abs(t.imag) > 0 or not 0.0 < t.real <= horizon:
                continue
            v = vn[i] + an[i] * t.real
            if v < 0.0 and t.real < first:
                first, speed = t.real, v
        if gap[i] <= 0.0 and vn[i] <= thr[i]:
            first, speed = 0.0, min(vn[i], 0.0)
        if not np.isfinite(first):
            continue
        if speed < -thr[i]:
            if first > 0.0 and (fast is None or first < fast):
                fast, j = first, i
        elif slow is None or first < slow:
            slow = first
    return fast, j, slow


def test_crossing_prediction_matches_the_roots_of_each_gap_trajectory():
    rng = np.random.default_rng(7)
    for trial in range(200):
        k = int(rng.integers(1, 12))
        gap = rng.choice([0.0, 1.0], size=k) * rng.uniform(-1e-4, 2e-2, size=k)
        vn = rng.uniform(-2.0, 1.0, size=k)
        normal = rng.normal(size=(k, 3))
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        accel = np.array([0.0, 0.0, -9.81]) * rng.uniform(0.0, 2.0)
        thr = np.full(k, 0.05)
        horizon = float(rng.choice([1e-3, 1e-2, 1.0]))
        an = normal @ accel
        t_fast, j, t_slow = KB.crossings(gap, vn, normal, accel, thr, horizon)
        r_fast, rj, r_slow = _reference_crossings(gap, vn, an, thr, horizon)
        assert (j >= 0) == (rj >= 0), trial
        if rj >= 0:
            assert t_fast == pytest.approx(r_fast, rel=1e-9, abs=1e-15), trial
            assert gap[j] + vn[j] * t_fast + 0.5 * an[j] * t_fast**2 == pytest.approx(0.0, abs=1e-12)
        assert np.isnan(t_slow) == (r_slow is None), trial
        if r_slow is not None:
            assert t_slow == pytest.approx(r_slow, rel=1e-9, abs=1e-15), trial


@pytest.mark.parametrize("obstacle", [rt.Ground(0.0), rt.Sphere((0.0, 0.0, -0.3), 0.35),
                                      rt.Box((0.0, 0.0, -0.2), (0.3, 0.3, 0.21))])
def test_the_fused_contact_search_finds_what_candidates_and_exact_gaps_find(small_model, obstacle):
    """KB.find (one pass) against the pipeline it replaced: rigid candidates within margin + deformation
    bound, their exact deformed positions, the gaps of those, kept when within the margin."""
    from modalfem.runtime.contact import _skip, deformation_bound, local_positions, vertex_modes

    body = rt.ModalBody(small_model)
    solver = rt.ModalSolver(body)
    rng = np.random.default_rng(11)
    effect = rt.Obstacles([obstacle])
    for trial in range(10):
        st = solver.state(position=(0.0, 0.0, 0.02 + 0.03 * rng.uniform()))
        st.q[:] = 1e-3 * rng.normal(size=body.mode_count)
        st.orientation[:] = rng.normal(size=4)
        st.orientation /= np.linalg.norm(st.orientation)
        R = st.rotation()
        margin = np.array([0.02])
        bound = deformation_bound(body, st.q)
        vs, og, gap, nrm = KB.find(effect.kinds, effect.params, margin, body.rest, vertex_modes(body), st.q,
                                   _skip(body, st.q), R, st.position, bound)
        cv, co = K.candidates(effect.kinds, effect.params, body.rest, R, st.position, bound, margin)
        x = K.world_positions(local_positions(body, st.q, cv), R, st.position)
        g, n = K.gaps_of(x, co, effect.kinds, effect.params)
        keep = g < margin[co]
        assert np.array_equal(vs, cv[keep]) and np.array_equal(og, co[keep])
        assert np.allclose(gap, g[keep], rtol=0, atol=1e-15) and np.allclose(nrm, n[keep], atol=1e-12)
        # and every vertex within the margin is found (exact positions of all vertices)
        x_all = K.world_positions(local_positions(body, st.q, np.arange(body.vertex_count)), R, st.position)
        g_all, _ = obstacle.signed_distance(x_all)
        assert set(np.flatnonzero(g_all < margin[0] - 1e-12)) <= set(vs.tolist())


def test_contacts_found_at_the_state_are_reused_and_give_the_same_step(small_model, monkeypatch):
    """ModalSolver.advance finds the contacts (collide) and the step reuses them instead of searching again at
    the same state; the stepped state is the same bit for bit as with the search repeated."""
    import modalfem.runtime.contact as C

    body = rt.ModalBody(small_model)
    solver = rt.ModalSolver(body, effects=[rt.Gravity(), rt.Obstacles([rt.Ground(0.0)], friction=0.5)])
    st0 = solver.state(position=(0, 0, 0.012), velocity=(0.3, 0.0, -0.2), angular_velocity=(1.0, 2.0, 0.5))
    runs = {}
    for reuse in (True, False):
        if not reuse:
            monkeypatch.setattr(C, "_fresh", lambda *a: False)
        calls = []
        find = C.find_contacts

        def counted(*a, **kw):
            calls.append(1)
            return find(*a, **kw)

        monkeypatch.setattr(C, "find_contacts", counted)
        st = st0.copy()
        for _ in range(40):
            solver.step(st, st, None, solver.collide(st, 2e-3), 2e-3)
        runs[reuse] = (C.snapshot(st), len(calls))
        monkeypatch.setattr(C, "find_contacts", find)
    (a, calls_reuse), (b, calls_search) = runs[True], runs[False]
    assert all(np.array_equal(x, y) for x, y in zip(a[:-1], b[:-1]))
    assert calls_reuse < calls_search  # (collide itself calls find_contacts through the module too)


def test_box_only_refit_gives_the_boxes_and_query_of_the_full_refit():
    """BroadPhaseBVH.refit_boxes (the pairs' refit: no normal cones) against refit on the same positions."""
    from modalfem.collision.bvh import BroadPhaseBVH
    from modalfem.mesh import box
    from modalfem.mesh.surface import boundary_surface

    surf = boundary_surface(box(size=(0.1, 0.05, 0.02), cells=(6, 3, 2)))
    tri, x0 = surf.triangles, surf.vertices
    rng = np.random.default_rng(5)
    x = x0 + 1e-3 * rng.normal(size=x0.shape)
    a, b = BroadPhaseBVH(tri, x0, leaf_size=4), BroadPhaseBVH(tri, x0, leaf_size=4)
    a.refit(x, margin=1e-4)
    b.refit_boxes(x, margin=1e-4)
    for name in ("tri_lo", "tri_hi", "lo", "hi", "_slo", "_shi"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    p = x[rng.integers(0, len(x), 50)]
    qa, qb = a.query(p - 2e-3, p + 2e-3), b.query(p - 2e-3, p + 2e-3)
    assert np.array_equal(qa[0], qb[0]) and np.array_equal(qa[1], qb[1]) and len(qa[0]) > 50
    assert np.all(b.cone_angle == np.pi)  # no culling after a box-only refit
