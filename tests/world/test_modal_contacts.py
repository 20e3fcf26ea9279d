"""The compiled modal contacts of the World's solid solve (``world.modal_contacts``): the same contacts as the
Python search (``proximity.SurfaceProximity`` / ``EdgeProximity``, and a brute-force scan over every vertex and
triangle), Jacobian rows that give the contact point's true relative velocity, and a pile of bodies whose every
body-body impulse conserves momentum and whose contacts never add energy."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.collision.distance import point_triangle
from modalfem.effects import Contact, Gravity
from modalfem.runtime.rotation import quat_from_axis_angle
from modalfem.world import _contact_rows as CR
from modalfem.world.proximity import EdgeProximity

#: coordinates here are below ~0.5 m; a rigid change of frame rounds them by ~1e-16 relative, so two codes computing
#: one distance in different frames agree to ~1e-16 m; this allows 1000x that
ROUND = 1e-13


def _pair_world(bar_model, rng, overlap: float):
    """Two bars crossed on each other (the second's lower face about ``overlap`` [m] into the first's upper face,
    turned about the vertical and tilted a little), deformed by modal coordinates giving ~1 mm displacements."""
    axis = np.array([0.05 * rng.normal(), 0.05 * rng.normal(), 1.0])  # turned about z, tilted a little
    q = quat_from_axis_angle(axis / np.linalg.norm(axis), rng.uniform(0.2, 1.2))
    bodies = [mw.Modal(bar_model, name="a", position=(0, 0, 0)),
              mw.Modal(bar_model, name="b", position=(0.02, 0.01, 0.05 - overlap), orientation=q)]
    w = mw.World(bodies=bodies, effects=[Contact(margin=3e-3)])
    s = w.state()
    for n in ("a", "b"):
        body = w._modal[n]["body"]
        amp = 1e-3 / np.abs(body.shapes).max()
        s[n].q[:] = amp * rng.normal(size=body.mode_count) / np.sqrt(body.mode_count)
        s[n].qdot[:] = rng.normal(size=body.mode_count)
        s[n].velocity[:] = rng.normal(size=3)
        s[n].angular_momentum[:] = 1e-3 * rng.normal(size=3)
    return w, s


def _collect(w, s, dt=1e-5):
    fast = w._fast
    names = fast.names
    off = {n: 0 if i == 0 else 6 + w._modal[names[0]]["body"].mode_count for i, n in enumerate(names)}
    speed = {n: 0.0 for n in names}
    return fast.collect(s.bodies, off, speed, dt, {n: i for i, n in enumerate(names)}, None), off


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_vertex_contacts_are_the_brute_force_closest_triangles(bar_model, seed):
    """Every vertex within the margin of the other deformed surface is found (none missed by the rest-frame tree
    and its deformation bound), with a closest triangle at the least distance and its plane gap and normal."""
    rng = np.random.default_rng(seed)
    w, s = _pair_world(bar_model, rng, overlap=2e-3)
    data, _ = _collect(w, s)
    margin = 3e-3
    x = {n: w.surface(s, n)[0] for n in ("a", "b")}
    tri = w._modal["a"]["body"].triangles
    kind = data["keys"] // CR.FEATURES % 3
    found = 0
    for p, q, ip in (("a", "b", 0), ("b", "a", 1)):
        X, Y = x[p], x[q]
        A, B, C = Y[tri[:, 0]], Y[tri[:, 1]], Y[tri[:, 2]]
        sel = np.flatnonzero((kind == 0) & (data["body"] == ip))
        verts = data["keys"][sel] % CR.FEATURES
        ref = []
        for v in range(len(X)):
            d, _ = point_triangle(np.repeat(X[v:v + 1], len(tri), axis=0), A, B, C)
            if d.min() <= margin:
                ref.append(v)
                j = np.flatnonzero(verts == v)
                assert len(j) == 1, f"vertex {v} of {p} within the margin of {q} not found once"
                c = sel[j[0]]
                # the chosen triangle is one of those at the least distance; its plane gap and normal
                ties = np.flatnonzero(d <= d.min() + ROUND)
                nrm = np.cross(B - A, C - A)
                nrm /= np.linalg.norm(nrm, axis=1)[:, None]
                match = [t for t in ties if np.allclose(nrm[t], data["normal"][c], atol=1e-9)]
                assert match, f"vertex {v}: normal of no closest triangle"
                t = match[0]
                ww = data["_modal"][5][c]
                closest = ww[0] * A[t] + ww[1] * B[t] + ww[2] * C[t]
                assert abs(data["gap"][c] - (X[v] - closest) @ nrm[t]) < ROUND
                assert np.allclose(data["point"][c], X[v], atol=ROUND)
        assert sorted(verts.tolist()) == ref
        found += len(ref)
    assert found >= 4  # the bars do touch


@pytest.mark.parametrize("seed", [0, 1])
def test_edge_contacts_are_the_python_searchs(bar_model, seed):
    rng = np.random.default_rng(seed)
    w, s = _pair_world(bar_model, rng, overlap=1e-3)
    data, _ = _collect(w, s)
    xa, xb = w.surface(s, "a")[0], w.surface(s, "b")[0]
    ep = EdgeProximity(w._modal["b"]["body"].triangles, w._modal["b"]["body"].rest)
    ea = ep.edges
    h = ep.query(xa[ea[:, 0]], xa[ea[:, 1]], xb, 3e-3)
    kind = data["keys"] // CR.FEATURES % 3
    sel = np.flatnonzero(kind == 1)
    mine = data["keys"][sel] % CR.FEATURES // len(ea)  # the key's feature: mine * (b's edge count) + b's edge
    assert len(h.mine) > 0
    ref = sorted(zip(h.mine.tolist(), np.round(h.gap / ROUND).astype(np.int64).tolist()))
    got = sorted(zip(mine.tolist(), np.round(data["gap"][sel] / ROUND).astype(np.int64).tolist()))
    assert len(ref) == len(got)
    for (e1, g1), (e2, g2) in zip(ref, got):
        assert e1 == e2 and abs(g1 - g2) <= 2


def test_rows_give_the_contact_points_relative_velocity(bar_model):
    """J V is the velocity of the contact point on a minus that of the touching point on b (rigid motion at the
    shared world point, modes at each body's own point), from the states alone."""
    rng = np.random.default_rng(5)
    w, s = _pair_world(bar_model, rng, overlap=2e-3)
    data, off = _collect(w, s, dt=1e-6)  # every mode slow enough to take part
    from modalfem.world import _kernels

    V = np.concatenate([np.concatenate([s[n].velocity, w._modal[n]["body"].angular_velocity(s[n]), s[n].qdot])
                        for n in ("a", "b")])
    u = _kernels.contact_velocities(V, data["ptr"], data["off"], data["nd"], data["jptr"], data["J"])
    body_a, verts_a, w_a, body_b, verts_b, w_b, R = data["_modal"]
    names = ("a", "b")

    def vel(i, verts, wts, point):
        n = names[i]
        body = w._modal[n]["body"]
        st = s[n]
        om = body.angular_velocity(st)
        phi = np.einsum("j,jcr->cr", wts, body.vertex_shapes(verts))
        return st.velocity + np.cross(om, point - st.position) + st.rotation() @ (phi @ st.qdot)

    assert len(u) > 10
    for c in range(len(u)):
        ref = vel(body_a[c], verts_a[c], w_a[c], data["point"][c])
        if body_b[c] >= 0:
            ref = ref - vel(body_b[c], verts_b[c], w_b[c], data["point"][c])
        assert np.allclose(u[c], ref, rtol=1e-12, atol=1e-12 * np.abs(V).max())
    # the effective inverse masses the solve takes with the entries: the contact velocities a unit impulse gives
    k = len(u)
    for d in range(3):
        for c in range(0, k, max(1, k // 20)):
            dV = np.zeros_like(V)
            lam = np.zeros((k, 3))
            lam[c, d] = 1.0
            _kernels.apply_impulses(dV, data["ptr"], data["off"], data["nd"], data["jptr"], data["WJt"], lam)
            col = _kernels.contact_velocities(dV, data["ptr"], data["off"], data["nd"], data["jptr"], data["J"])[c]
            assert np.allclose(data["K"][c, :, d], col, rtol=1e-12, atol=1e-12 * np.abs(col).max())


def _reference_sweeps(V, data, K, target, mu, iterations, lam_n, lam_t, vtol):
    """Projected Gauss-Seidel as ``_kernels.sequential_impulses`` documents it, with dense per-contact Jacobians
    (3, len(V)) and every contact visited in every sweep; in place on V, lam_n, lam_t; returns the sweeps."""
    k = len(data["ptr"]) - 1
    Js, Ws = np.zeros((k, 3, len(V))), np.zeros((k, len(V), 3))
    for c in range(k):
        for e in range(data["ptr"][c], data["ptr"][c + 1]):
            o, m, b = data["off"][e], data["nd"][e], data["jptr"][e]
            Js[c][:, o:o + m] += data["J"][b:b + 3 * m].reshape(3, m)
            Ws[c][o:o + m, :] += data["WJt"][b:b + 3 * m].reshape(m, 3)
    n = data["normal"]
    for it in range(iterations):
        change = vchange = scale = 0.0
        for c in range(k):
            kn = n[c] @ K[c] @ n[c]
            if not kn > 0:
                continue
            u = Js[c] @ V
            new = max(0.0, lam_n[c] + (target[c] - u @ n[c]) / kn)
            d = (new - lam_n[c]) * n[c]
            lam_n[c] = new
            if mu[c] > 0:
                w = u + K[c] @ d
                t = w - (w @ n[c]) * n[c]
                lt = lam_t[c].copy()
                if np.linalg.norm(t) > 0:
                    ee = t / np.linalg.norm(t)
                    if ee @ K[c] @ ee > 0:
                        lt -= np.linalg.norm(t) / (ee @ K[c] @ ee) * ee
                if np.linalg.norm(lt) > mu[c] * new:
                    lt *= mu[c] * new / np.linalg.norm(lt)
                d = d + lt - lam_t[c]
                lam_t[c] = lt
            if np.any(d != 0):
                V += Ws[c] @ d
                change = max(change, np.abs(d).sum())
                vchange = max(vchange, kn * np.abs(d).sum())
            scale = max(scale, lam_n[c])
        if change <= 1e-10 * scale or vchange <= vtol:
            return it + 1
    return iterations


@pytest.mark.parametrize("seed", [0, 1])
def test_the_solve_passing_separating_contacts_is_the_plain_sweeps(bar_model, seed):
    """``sequential_impulses`` passes a contact without impulse whose normal velocity, from its normal rows alone,
    is above its target: the impulses and velocities are those of visiting every contact in every sweep (the
    dense reference above), with about half the contacts separating at the start, some approaching, some
    warm-started."""
    from modalfem.world import _kernels

    rng = np.random.default_rng(seed)
    w, s = _pair_world(bar_model, rng, overlap=2e-3)
    data, _ = _collect(w, s, dt=1e-6)
    V = np.concatenate([np.concatenate([s[n].velocity, w._modal[n]["body"].angular_velocity(s[n]), s[n].qdot])
                        for n in ("a", "b")])
    k = len(data["gap"])
    u = _kernels.contact_velocities(V, data["ptr"], data["off"], data["nd"], data["jptr"], data["J"])
    vn = np.einsum("ij,ij->i", u, data["normal"])
    target = vn + rng.choice([-1.0, 1.0], k) * rng.uniform(0.0, 0.5, k)  # half above the velocity (approaching)
    mu = rng.choice([0.0, 0.5], k)
    lam_n = np.where(rng.uniform(size=k) < 0.2, rng.uniform(0, 1e-3, k), 0.0)
    lam_t = np.zeros((k, 3))
    runs = []
    for solve in ("kernel", "reference"):
        V1, ln, lt = V.copy(), lam_n.copy(), lam_t.copy()
        if solve == "kernel":
            sw = _kernels.sequential_impulses(V1, data["ptr"], data["off"], data["nd"], data["jptr"], data["J"],
                                              data["WJt"], data["K"], data["normal"], target, mu, 10, ln, lt, 1e-6,
                                              np.zeros(k, dtype=np.int64))  # one island: the shared stop
        else:
            sw = _reference_sweeps(V1, data, data["K"], target, mu, 10, ln, lt, 1e-6)
        runs.append((V1, ln, lt, sw))
    (V1, ln1, lt1, sw1), (V2, ln2, lt2, sw2) = runs
    assert sw1 == sw2 and 2 <= sw1
    assert 0.2 * k < np.count_nonzero(ln1 == 0.0) < k  # both kinds of contact at the end
    assert np.allclose(V1, V2, rtol=1e-9, atol=1e-9 * np.abs(V2).max())
    assert np.allclose(ln1, ln2, rtol=1e-9, atol=1e-9 * ln2.max())
    assert np.allclose(lt1, lt2, rtol=1e-9, atol=1e-9 * ln2.max())


def _momenta(w, s):
    p, L = np.zeros(3), np.zeros(3)
    for b in w.bodies:
        a, b_ = w.momentum(s, b.name)
        p += a
        L += b_
    return p, L


def _thrown_bars(bar_model, rng, *, inward: float, jitter: float, spin: float) -> list:
    """Five bars on a helix around the origin, randomly turned, thrown towards it (``-inward * position`` plus
    ``jitter`` random [m/s]) and spinning (``spin`` random [rad/s]), drawn from ``rng``."""
    bodies = []
    for i in range(5):
        axis = rng.normal(size=3)
        pos = 0.09 * np.array([np.cos(1.3 * i), np.sin(1.3 * i), 0.6 * (i - 2)])
        bodies.append(mw.Modal(bar_model, name=f"b{i}", position=pos,
                               orientation=quat_from_axis_angle(axis / np.linalg.norm(axis), rng.uniform(0, 3)),
                               velocity=-inward * pos + jitter * rng.normal(size=3),
                               angular_velocity=spin * rng.normal(size=3)))
    return bodies


def test_a_pile_of_modal_bodies_conserves_momentum_and_never_gains_energy(bar_model):
    """Five bars thrown at each other without gravity or obstacles: only body-body impulses act, so the total linear
    and angular momentum stay what they were (to rounding) and the total energy never rises (beyond the free step's
    own energy error: never above the free step's); their surfaces never cross."""
    rng = np.random.default_rng(3)
    bodies = _thrown_bars(bar_model, rng, inward=4.0, jitter=0.1, spin=1.0)
    # the free step keeps the energy only to ~1e-9 of itself per step (the rigid rotation step), so each step is
    # compared with the free step of the same start state (a world without contact)
    free = mw.World(bodies=bodies)
    w = mw.World(bodies=bodies, effects=[Contact(restitution=0.5, friction=0.4, margin=2e-3)])
    s = w.state()
    p0, L0 = _momenta(w, s)
    E0 = sum(w.energy(s, b.name)["total"] for b in bodies)
    scale_p = sum(np.linalg.norm(w.momentum(s, b.name)[0]) for b in bodies)
    scale_L = sum(np.linalg.norm(w.momentum(s, b.name)[1]) for b in bodies) + scale_p * 0.3
    touched = 0
    E_prev = E0
    for _ in range(250):
        fs = s.copy()
        free.step(fs, fs, None, 1e-3)
        E_free = sum(free.energy(fs, b.name)["total"] for b in bodies)
        r = w.step(s, s, None, 1e-3)
        touched += r.contacts.get("solid", 0)
        for a, b, J, L in r.exchanged:
            assert np.all(np.isfinite(J)) and np.all(np.isfinite(L))
        p, L = _momenta(w, s)
        assert np.linalg.norm(p - p0) <= 1e-12 * scale_p
        assert np.linalg.norm(L - L0) <= 1e-12 * scale_L
        E = sum(w.energy(s, b.name)["total"] for b in bodies)
        assert E <= max(E_prev, E_free) + 1e-12 * E0
        E_prev = E
    assert touched > 100
    assert E_prev < E0  # restitution 0.5: the impacts lost energy
    assert w.intersections(s) == []


def test_a_stack_on_the_ground_settles_without_energy_gain_or_crossing(bar_model):
    """Three bars dropped on each other onto the ground (body-body and body-ground contacts in the one solve): the
    total energy (kinetic, elastic, gravity) never rises by more than the rounding of the step, and no surfaces
    cross at any step."""
    bodies = [mw.Modal(bar_model, name=f"b{i}", position=(0.01 * i, 0.0, 0.03 + 0.055 * i)) for i in range(3)]
    w = mw.World(bodies=bodies, obstacles=[mw.Ground(0.0)], effects=[Gravity(), Contact(friction=0.5)])
    s = w.state()
    E_prev = sum(w.energy(s, b.name)["total"] for b in bodies)
    m_g_h = sum(w._modal[b.name]["body"].mass for b in bodies) * 9.81 * 0.2
    pairs = 0
    for i in range(300):
        r = w.step(s, s, None, 1e-3)
        pairs += len(r.exchanged)
        E = sum(w.energy(s, b.name)["total"] for b in bodies)
        assert E <= E_prev + 1e-9 * m_g_h, i
        E_prev = E
        if i % 10 == 9:
            assert w.intersections(s) == [], i
    assert pairs > 0


# ------------------------------------------------------------ carried over from runtime.pairs.ContactGroup's tests
def _two_blocks(bar_model, *, gravity=False, spin=0.3, offset=(0.03, 0.02), e=0.5, mu=0.4, **pos):
    """Two steel blocks (0.2 x 0.1 x 0.05 m) flying at each other, the upper one turned about z by 0.7 rad."""
    za, zb = pos.get("za", 0.0), pos.get("zb", 0.09)
    va, vb = pos.get("va", 0.5), pos.get("vb", -0.5)
    a = mw.Modal(bar_model, name="a", position=(0.0, 0.0, za), velocity=(0.0, 0.0, va), angular_velocity=(spin, 0, 0))
    b = mw.Modal(bar_model, name="b", position=(offset[0], offset[1], zb), velocity=(0.0, 0.0, vb),
                 orientation=quat_from_axis_angle([0, 0, 1], 0.7), angular_velocity=(0.0, -spin, 0.0))
    effects = [Contact(restitution=e, friction=mu)] + ([Gravity()] if gravity else [])
    return mw.World(bodies=[a, b], obstacles=[mw.Ground(0.0)] if gravity else [], effects=effects)


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2])
def test_every_body_body_impulse_conserves_momentum_and_the_reported_exchange(bar_model, dt):
    """No gravity, no obstacles: between the two spinning blocks only their contact acts, so the total linear momentum
    is the same after every step to rounding, and the momentum each block gained is what the step report says the
    other gave it; the angular momentum about the origin too (touching contacts act on both blocks at one point; at
    the largest dt a speculative contact beside an edge may not, see ``modal_contacts``).
    The impacts dissipate (e = 0.5) and the blocks bounce apart. (They do not ring here: modes with omega dt above
    world.SLOW take no part in the velocity-level contact, and this bar's lowest is 5.4 at dt = 1e-4.)"""
    w = _two_blocks(bar_model)
    s = w.state()
    mass = w._modal["a"]["body"].mass
    P0, L0 = _momenta(w, s)
    scale_p = mass * 0.5
    scale_l = scale_p * 0.2
    E0 = sum(w.energy(s, n)["total"] for n in ("a", "b"))
    touched = 0
    for _ in range(int(0.3 / dt)):
        pa0 = mass * s["a"].velocity.copy()
        r = w.step(s, s, None, dt)
        P, L = _momenta(w, s)
        assert np.abs(P - P0).max() <= 1e-12 * scale_p
        # exact while impulses act on touching contacts; at dt = 1e-2 the blocks close 1 cm per step and a
        # speculative contact farther than the margin beside an edge acts on each body at its own point
        assert np.abs(L - L0).max() <= (1e-12 if dt <= 1e-3 else 1e-3) * scale_l
        got = sum((J if a == "a" else -J) for a, b, J, _ in r.exchanged) if r.exchanged else np.zeros(3)
        assert np.allclose(mass * s["a"].velocity - pa0, got, rtol=0, atol=1e-12 * scale_p)
        touched += bool(r.exchanged)
    assert touched > 0
    assert sum(w.energy(s, n)["total"] for n in ("a", "b")) < E0
    assert s["a"].velocity[2] < 0.0 < s["b"].velocity[2]  # they bounced apart


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_blocks_dropped_on_each_other_do_not_interpenetrate(bar_model, dt):
    """With gravity and the ground in the one solve, the upper block lands on the lower one and both come to rest: no
    vertex of one ends deeper inside the other's box than half the contact margin (the skin the solve keeps) plus
    both deformation bounds, none below the ground by more than the skin, and no triangles cross."""
    from modalfem.runtime.contact import deformation_bound

    w = _two_blocks(bar_model, gravity=True, spin=0.0, offset=(0.02, 0.01), e=0.2, mu=0.5, za=0.025, zb=0.1, va=0.0,
                    vb=0.0)
    s = w.state()
    body = w._modal["a"]["body"]
    half = 0.5 * np.array([0.2, 0.1, 0.05])
    skin = 0.5 * Contact().margin

    def depth(p, q):
        x = body.positions(s[p], precise=True)
        local = (x - s[q].position) @ s[q].rotation()
        return float(np.min(half - np.abs(local), axis=1).max())

    for _ in range(int(0.6 / dt)):
        w.step(s, s, None, dt)
        slack = skin + 2 * max(deformation_bound(body, s[n].q) for n in ("a", "b"))
        assert depth("a", "b") <= slack and depth("b", "a") <= slack
        for n in ("a", "b"):
            assert body.positions(s[n], precise=True)[:, 2].min() >= -skin
        assert w.intersections(s) == []
    assert s["b"].position[2] > s["a"].position[2] + 0.04  # stacked
    assert abs(s["b"].velocity[2]) < 0.05


@pytest.mark.parametrize("slack", [None, 0.5])
def test_the_coherent_pair_search_finds_what_a_fresh_brute_force_search_finds(bar_model, monkeypatch, slack):
    """Temporal coherence (``_coherent_kernels.coherent_pairs``: a pair's tree walk reused while its bodies move less
    than a slack) changes nothing: at every step of five bars thrown at each other and ringing (their modal
    coordinates set each step to move vertices by up to ~2 mm, more than the slack, so shape changes alone must
    trigger new walks), the vertex-face and edge-edge contacts are exactly those of ``all_pairs`` (every pair's
    trees walked afresh), in the same order; walks are reused and redone. At the World's slack (``slack`` None:
    ``modal_contacts.SLACK``) and at 0.5 of the margin (its value before 2026-11), where this scene reuses a walk for
    over half its pair searches."""
    from modalfem.world import _coherent_kernels as CK
    from modalfem.world import _solid_kernels as SK
    from modalfem.world import modal_contacts as MC

    rng = np.random.default_rng(5)
    bodies = _thrown_bars(bar_model, rng, inward=0.5, jitter=0.02, spin=0.2)
    w = mw.World(bodies=bodies, effects=[Contact(restitution=0.5, friction=0.4, margin=2e-3)])
    s = w.state()
    body = w._modal["b0"]["body"]
    r = body.mode_count
    amp = 1.5e-3 / np.abs(body.shapes).max() / np.sqrt(r)
    phase = rng.uniform(0, 2 * np.pi, size=(5, r))
    coherent = CK.coherent_pairs
    seen = {"walks": 0, "pairs": 0, "contacts": 0}

    def checked(*a):
        out = coherent(*a)
        # all_pairs takes the same arguments less the slack (4), radius, q, qoff, nm, amp (11-15) and the cache
        ref = SK.all_pairs(*a[:4], *a[5:11], *a[16:23], *a[37:])
        for x, y in zip(out[0] + out[1], ref[0] + ref[1]):
            assert x.shape == y.shape and np.array_equal(x, y)
        seen["walks"] += out[2]
        seen["pairs"] += len(a[0])
        seen["contacts"] += len(out[0][0]) + len(out[1][0])
        return out

    monkeypatch.setattr(CK, "coherent_pairs", checked)
    if slack is not None:
        monkeypatch.setattr(MC, "SLACK", slack)
    for k in range(200):
        for i, b in enumerate(bodies):  # ringing: each mode at its own phase, a period of ~600 steps
            s[b.name].q[:] = amp * np.sin(0.01 * k + phase[i])
        w.step(s, s, None, 1e-3)
    assert seen["contacts"] > 1000
    assert 0 < seen["walks"] < (seen["pairs"] if slack is None else 0.5 * seen["pairs"])


@pytest.mark.parametrize("slack", [None, 0.5])
def test_the_coherent_pair_search_walks_again_when_shape_or_turn_alone_moves_the_bodies(bar_model, monkeypatch,
                                                                                        slack):
    """Two crossed bars, 2 mm into each other's margin: first only ringing (their centres and axes fixed, modal
    coordinates moving vertices by up to ~6 mm), then only turning (b about its own centre, ~0.2 mm per step at its
    ends). Each alone is enough to bring features within reach that were beyond the last walk's radius: the
    contacts found stay exactly those of a fresh walk at every step, and new walks happen in both phases (at the
    World's slack, ``slack`` None, and at 0.5 of the margin, its value before 2026-11, where most walks are reused)."""
    from modalfem.runtime.rotation import quat_multiply
    from modalfem.world import _coherent_kernels as CK
    from modalfem.world import _solid_kernels as SK
    from modalfem.world import modal_contacts as MC

    if slack is not None:
        monkeypatch.setattr(MC, "SLACK", slack)

    rng = np.random.default_rng(7)
    w, s = _pair_world(bar_model, rng, overlap=2e-3)
    r = w._modal["a"]["body"].mode_count
    amp = 6e-3 / np.abs(w._modal["a"]["body"].shapes).max() / np.sqrt(r)
    phase = rng.uniform(0, 2 * np.pi, size=(2, r))
    coherent = CK.coherent_pairs
    walks = []

    def checked(*a):
        out = coherent(*a)
        ref = SK.all_pairs(*a[:4], *a[5:11], *a[16:23], *a[37:])  # as the test above
        for x, y in zip(out[0] + out[1], ref[0] + ref[1]):
            assert x.shape == y.shape and np.array_equal(x, y)
        walks.append(out[2])
        return out

    monkeypatch.setattr(CK, "coherent_pairs", checked)
    q0 = s["b"].orientation.copy()
    found = 0
    for k in range(300):
        if k < 150:
            for i, n in enumerate(("a", "b")):
                s[n].q[:] = amp * np.sin(0.02 * k + phase[i])
        else:
            s["b"].orientation[:] = quat_multiply(quat_from_axis_angle([0.3, 0.2, 1.0], 2e-3 * (k - 150)), q0)
        data, _ = _collect(w, s)
        found += 0 if data is None else len(data["gap"])
    assert len(walks) == 300 and found > 300
    assert sum(walks[1:150]) >= 3 and sum(walks[150:]) >= 3
    assert sum(walks) < (300 if slack is None else 150)


def test_speed_bound_holds_for_every_surface_point_whatever_its_direction(bar_model):
    """The speed bound of ``velocity_blocks`` (the reach of the pair search) is at least every surface vertex's
    deformation speed |(Phi qdot)_i| (a 3-vector norm; a bound from the largest single component undercuts it by up
    to sqrt(3) when a vertex moves along a diagonal)."""
    rng = np.random.default_rng(7)
    w, s = _pair_world(bar_model, rng, overlap=0.0)
    for n in ("a", "b"):
        s[n].velocity[:] = 0.0
        s[n].angular_momentum[:] = 0.0
    g = {n: np.zeros(3) for n in w._fast.names}
    _, speed = w._fast.velocity_blocks(s.bodies, g, 1e-3)
    for i, n in enumerate(w._fast.names):
        body = w._modal[n]["body"]
        u = (s[n].qdot @ body.shapes_t).reshape(-1, 3)
        norms = np.sqrt((u ** 2).sum(1))
        assert norms.max() > 1.05 * np.abs(u).max()  # the draw moves some vertex off the axes
        assert speed[i] >= norms.max() * (1 - 1e-12)
        assert speed[i] <= norms.max() * (1 + 1e-12)  # and no looser than that here (v = w = g = 0)
