"""The tet stage's contacts (a mixin of ``World``, through ``_TetStage``): each step's penalty contacts of a tet
body (or a group of them) with the obstacles, with the modal bodies' surfaces as moving obstacles at their predicted
free step end (tet vertices on modal faces, modal vertices on tet faces, edges on edges), and with the other bodies of
its group; a modal body's static planes solved in the same step (``_modal_planes``). What acts on the bodies after
the step (reactions, friction, restitution) is in ``_tet_response``; the step itself in ``_tet_stage``."""

from __future__ import annotations

import numpy as np

from modalfem.errors import SimulationError
from modalfem.world._shared import _REACTION_KEY
from modalfem.world._solid_stage import _box_edges
from modalfem.world.obstacles import Box, TriangleMesh
from modalfem.world.proximity import EdgeProximity
from modalfem.world.tetcontact import STIFFNESS

#: a tet body's penalty contacts with one modal body hold its approach within a 1 / DEPTH_SHARE part of the skin
#: (their stiffness summed at least ``DEPTH_SHARE (travel + |g| dt^2) / dhat`` times its mass / dt^2)
DEPTH_SHARE = 4.0
#: a tet edge meets a modal edge in a tet step only where the line between their closest points is within ~60
#: degrees of the modal surface's outward side at its edge (the cosine at least this): the contact's sign (which
#: side the tet edge must stay on) is read from that side, and it is ill-defined where they are near perpendicular
#: (a foam vertex on a steel bar's edge, between its two foam edges in line: two contacts with opposite normals,
#: which no stiffness could satisfy; the step ended with +1.3 J in them at dt = 7 ms). Closest points near an edge's
#: end are kept: a foam edge folding round the bar's corner, 0.6 mm from the end of the bar's 50 mm edge, crossed
#: it at 5 and 20 ms when the pairs within 5 % of an end were left out
EDGE_ALIGN = 0.5
#: the slip speed [m/s] below which a contact between two tet bodies stepped together sticks (their friction in the
#: implicit step, ``PenaltyContacts.set_friction``: a slip below ``FRICTION_SLIP dt`` per step is elastic)
FRICTION_SLIP = 1e-4


def _top_speed(s) -> float:
    """The fastest vertex's speed [m/s] of tet state ``s`` (0 without vertices)."""
    return float(np.sqrt(np.einsum("ij,ij->i", s.v, s.v)).max()) if len(s.v) else 0.0


def _tet_reach(vmax: float, margin: float, dt: float) -> float:
    """How far [m] a tet body whose fastest vertex moves at ``vmax`` [m/s] may meet something in a step of ``dt``
    [s]: its contact's skin ``margin`` [m] twice, twice that vertex's travel and gravity's ``g dt^2``."""
    return margin + margin + 2.0 * vmax * dt + 9.81 * dt * dt


def _opposed(V, W, P, N, g0, xv, bodies: list, first: int, dhat: float) -> np.ndarray:
    """Which of the modal contacts ``first:first + len(bodies)`` (of one modal body each, ``bodies``) contradict
    another: the same body, the same tet vertex the heaviest in both, normals more than 120 degrees apart and
    planes leaving that vertex less than two skins (their gaps at the start positions ``xv`` (c, 4, 3) summed
    below ``2 dhat``), so one of them ends inside its skin whatever the step does. Of each such pair the one
    further behind its plane at the step start (smaller ``g0``) is marked. Where a bar's corner meets a foam
    vertex dragged under it, the bar vertex on the foam face (the face's normal) and the bar edge on the foam
    edge (the edge's outward side) pushed that vertex opposite ways: 1.67 J stored in them in one 1.7 ms
    sub-step of tests/world/test_tet_squeeze.py at 5 ms (step 29)."""
    rows = np.arange(first, first + len(bodies))
    out = np.zeros(len(rows), dtype=bool)
    if len(rows) < 2:
        return out
    top = V[rows, np.argmax(W[rows], axis=1)]
    gap = np.einsum("cd,cd->c", np.einsum("cj,cjd->cd", W[rows], xv[rows]) - P[rows], N[rows])
    order = np.argsort(top, kind="stable")
    cut = np.flatnonzero(np.diff(top[order])) + 1
    for grp in np.split(order, cut):
        for a in range(len(grp)):
            for b in grp[a + 1:]:
                i, j = grp[a], b
                if (bodies[i] == bodies[j] and float(N[rows[i]] @ N[rows[j]]) < -0.5
                        and gap[i] + gap[j] < 2.0 * dhat):
                    out[i if g0[rows[i]] < g0[rows[j]] else j] = True
    return out


def _contacts_of(modal: list, body: str) -> np.ndarray:
    """Indices (int64, in order) of a tet body's modal contacts ``modal`` ((body, ids, weights) each) with ``body``."""
    return np.array([i for i, (b, _, _) in enumerate(modal) if b == body], dtype=np.int64)



class _TetContacts:
    """``World``'s methods that set a tet step's penalty contacts (they read the world's build: ``_tet``,
    ``_modal``, ``_tet_modal``, ``obstacles`` ...)."""

    def _tet_contacts(self, ctx, name: str, s, t: dict | None = None) -> list:
        """Set this step's penalty contacts of tet body ``name`` (start state ``s``) with the obstacles and with
        the modal bodies' surfaces, the latter as moving obstacles at their predicted step end (tet vertices on
        modal faces, modal vertices on tet faces), so the tet's elasticity and these contacts are solved together
        in its implicit step; the modal bodies take the reaction (``_tet_reaction``). Returns the obstacle of
        each contact (for its friction, ``_tet_friction``; None: a contact between two tet bodies). ``t``: a group
        of tet bodies stepped together (``_tet_group``; ``s`` their stacked state), whose contacts with each other
        follow the obstacles' and the modal bodies' (``_tet_pair_contacts``)."""
        t = self._tet[name] if t is None else t
        c = t["contact"]
        dt, t1 = ctx.dt, ctx.state_in.time + ctx.dt
        dhat = c.margin
        sv = t["surface"]
        xs = s.x[sv]
        vmax = _top_speed(s)
        reach = _tet_reach(vmax, c.margin, dt)
        verts, ws, ps, ns, p0s, touched = [], [], [], [], [], []
        t["modal_ends"] = {}  # modal body -> its free step end (surface, centre of mass): the reaction's arms

        def add(ids, w, p, n, p0, o):  # (up to 4 vertices per contact: two tet bodies' in a group)
            verts.append(np.column_stack([ids, -np.ones((len(ids), 4 - ids.shape[1]), np.int64)]) if ids.ndim == 2
                         else np.column_stack([ids, -np.ones((len(ids), 3), np.int64)]))
            ws.append(np.column_stack([w, np.zeros((len(w), 4 - w.shape[1]))]))
            ps.append(p)
            ns.append(n)
            p0s.append(p if p0 is None else p0)
            touched.extend(o.points() if isinstance(o, _ModalSurface) else [o] * len(p))

        for o in self.obstacles:
            # a moving obstacle's tangent planes are found where the vertices are relative to it at the step start
            # and carried by its travel ``d`` in the step (a vertex at rest on it is then pushed along with it): read
            # at the step end, a box rising half its height in a step (1 m/s, 50 ms) put a tet cube resting on it
            # under its middle, its bottom face the closest, and the cube fell through it
            d = o.offset(t1) - o.offset(ctx.state_in.time) if o.moving else None
            te = t1 if d is None else ctx.state_in.time
            r = reach + (0.0 if d is None else float(np.linalg.norm(d)))
            if isinstance(o, TriangleMesh):
                Vo = o.vertices + o.offset(te)
                h = self._obstacle_surf[self.obstacles.index(o)].query(xs, Vo, r)
                if len(h.point):
                    p = np.einsum("kj,kjd->kd", h.bary, Vo[o.triangles[h.triangle]])
                    add(sv[h.point][:, None], np.ones((len(p), 1)), p if d is None else p + d, h.normal, p, o)
            else:
                gap, n = o.signed_distance(xs, te)
                idx = np.flatnonzero(gap < r)
                if len(idx):
                    n = np.asarray(n)[idx]
                    p = xs[idx] - gap[idx, None] * n
                    add(sv[idx][:, None], np.ones((len(idx), 1)), p if d is None else p + d, n, p, o)
                if isinstance(o, Box):  # its edges on the tet's edges, its corners on the tet's faces
                    for ids, w, p, n in self._tet_box_rows(o, t, xs, te, r):
                        add(ids, w, p if d is None else p + d, n, p, o)
        n_obstacle = len(touched)
        # each obstacle contact's travel [m] in the step (0: a static obstacle), for the work the obstacle does
        # (``_TetStage._tet_step_work``)
        t["obstacle_travel"] = np.array([o.offset(t1) - o.offset(ctx.state_in.time) if o.moving else np.zeros(3)
                                         for o in touched]).reshape(-1, 3)
        modal = []  # per modal contact: (body, modal vertex ids (3,), weights (3,))
        ends = {}  # modal body -> (its free end state, how far its surface travels in the step [m])
        x1s = {}  # modal body -> its surface at the step start and at its free end
        for m in self._tet_modal.get(name, ()):
            x0, x1, end = self._modal_prediction(ctx, m)
            travel = float(np.sqrt(np.einsum("ij,ij->i", x1 - x0, x1 - x0)).max())
            ends[m] = (end, travel)
            t["modal_ends"][m] = (x1, end.position)
            x1s[m] = (x0, x1)
            r = reach + travel + c.margin
            lo, hi = x1.min(0) - r, x1.max(0) + r
            if np.any(lo > xs.max(0)) or np.any(hi < xs.min(0)):
                continue
            tri = self._tris[m]
            h = self._surf[m].query(xs, x1, r)  # tet vertices on the modal faces (normal: out of the modal body)
            if len(h.point):
                T = tri[h.triangle]
                add(sv[h.point][:, None], np.ones((len(h.point), 1)), np.einsum("kj,kjd->kd", h.bary, x1[T]),
                    h.normal, np.einsum("kj,kjd->kd", h.bary, x0[T]), _ModalSurface(m, x0, x1, T, h.bary))
                modal.extend((m, T[i], h.bary[i]) for i in range(len(T)))
            h = t["proximity"].query(x1, xs, r)  # modal vertices on the tet faces (normal: out of the tet)
            if len(h.point):
                T = t["triangles"][h.triangle]
                ids = np.column_stack([h.point, h.point, h.point])
                one = np.tile([1.0, 0.0, 0.0], (len(h.point), 1))
                add(sv[T], h.bary, x1[h.point], -h.normal, x0[h.point], _ModalSurface(m, x0, x1, ids, one))
                modal.extend((m, ids[i], one[i]) for i in range(len(ids)))
            # tet edges on modal edges near each other (surfaces resting on each other, where an edge can cross a
            # face with every vertex outside: a soft tet's edge folding round the modal body's edge in a large
            # step), within what both travel in the step
            e = t["edges"].edges
            h = self._edges[m].query(xs[e[:, 0]], xs[e[:, 1]], x1, r)
            if len(h.mine):  # normals well out of the modal surface (else the contact's sign is ill-defined)
                side = self._edges[m].sides(x1, h.other)
                side /= np.maximum(np.linalg.norm(side, axis=1), 1e-300)[:, None]
                ok = np.einsum("ij,ij->i", h.normal, side) >= EDGE_ALIGN
                h = type(h)(h.mine[ok], h.other[ok], h.s[ok], h.t[ok], h.gap[ok], h.normal[ok])
            if len(h.mine):
                E = self._edges[m].edges[h.other]
                ids = np.column_stack([E, E[:, 0]])
                wm = np.column_stack([1.0 - h.t, h.t, np.zeros(len(h.t))])
                add(sv[e[h.mine]], np.column_stack([1.0 - h.s, h.s]), np.einsum("kj,kjd->kd", wm, x1[ids]),
                    h.normal, np.einsum("kj,kjd->kd", wm, x0[ids]), _ModalSurface(m, x0, x1, ids, wm))
                modal.extend((m, ids[i], wm[i]) for i in range(len(ids)))
        if "members" in t:  # the group's bodies with each other: relative positions (signed weights), plane at 0
            pv, pw, pn = self._tet_pair_contacts(t, s, reach + c.margin, dt * s.v)
            if len(pv):
                verts.append(pv)
                ws.append(pw)
                ps.append(np.zeros((len(pv), 3)))
                ns.append(pn)
                p0s.append(ps[-1])
                touched.extend([None] * len(pv))
        t["modal_contacts"] = (n_obstacle, modal)
        pen = t["penalty"]
        if not verts:
            pen.set(np.zeros((0, 4), np.int64), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), dhat)
            return []
        V, W = np.concatenate(verts), np.concatenate(ws)
        vid = np.where(V >= 0, V, 0)
        P, N, P0 = np.concatenate(ps), np.concatenate(ns), np.concatenate(p0s)
        # a contact with an obstacle already inside the skin at the step start is held where it is: a push out of
        # the skin would throw a body placed on the ground. Not with a modal body: its weight on a few vertices
        # would sink it by its force / stiffness every step (~0.1 mm per step for a 8 kg bar on a soft block)
        g0 = np.einsum("cd,cd->c", np.einsum("cj,cjd->cd", W, s.x[vid]) - P0, N)
        rows = np.arange(len(g0))
        # two tet bodies of a group: never held inside the skin (a resting pair crept through the surface, which
        # with a tet body is a crossing): their penalty is the same potential at every step, ``dhat`` off the surface
        pair = rows >= n_obstacle + len(modal)
        hold = rows < n_obstacle
        # a modal (or tet-tet) contact whose point is more than a skin behind the other surface at the step start is
        # the wrong feature (a tet vertex under a thin bell's rim closest to its inner wall: 2.8 mm "behind" it;
        # pushed out of it in one step, that was +9.6 mJ in the landing step of tutorials/world.py), not a
        # crossing: the surfaces are intersection-free at every step end
        keep = (rows < n_obstacle) | (g0 >= -dhat)
        keep[n_obstacle:n_obstacle + len(modal)] &= ~_opposed(V, W, P, N, g0, s.x[vid], [b for b, _, _ in modal],
                                                              n_obstacle, dhat)
        if not keep.all():
            sel = np.flatnonzero(keep[n_obstacle:n_obstacle + len(modal)])
            modal = [modal[i] for i in sel]
            t["modal_contacts"] = (n_obstacle, modal)
            touched = [o for o, kk in zip(touched, keep) if kk]
            V, W, vid, P, N, g0, hold, pair = (V[keep], W[keep], vid[keep], P[keep], N[keep], g0[keep], hold[keep],
                                               pair[keep])
        P = P - np.where(hold, dhat - np.clip(g0, 0.0, dhat), 0.0)[:, None] * N
        m = t["masses"][vid]
        inv = np.where((V >= 0) & np.isfinite(m), W**2 / np.where(np.isfinite(m), m, 1.0), 0.0).sum(1)
        k = np.where(inv > 0, STIFFNESS / np.where(inv > 0, inv, 1.0) / dt**2, 0.0)
        last = self._last_force(ctx, name, t, "obstacle force")  # [N] by vertex, last step
        if last is not None and n_obstacle:  # (a soft body's vertices bear the weight of what rests on it too)
            k[:n_obstacle] = np.maximum(k[:n_obstacle], DEPTH_SHARE * last[V[:n_obstacle, 0]] / dhat)
        last = self._last_force(ctx, name, t, "pair force") if pair.any() else None
        if last is not None:  # the same for the group's bodies resting on each other (by the contact's first vertex)
            k[pair] = np.maximum(k[pair], DEPTH_SHARE * last[V[pair, 0]] / dhat)
        # each modal body's rigid displacement by the reaction is solved with the tet (``tetcontact``): no explicit
        # limit on the stiffness; its contacts share the body's weight and hold its approach (the tet's too) in a
        # part of the skin: at least DEPTH_SHARE (approach + |g| dt^2) / dhat times its mass / dt^2, summed
        bodies, arms, inertia, planes = np.full(len(k), -1, np.int64), np.zeros((len(k), 6)), [], []
        for b in self._tet_modal.get(name, ()):
            sel = n_obstacle + _contacts_of(modal, b)
            if not len(sel):
                continue
            body, (end, travel) = self._modal[b]["body"], ends[b]
            R = ctx.state_in.bodies[b].rotation()
            S = np.zeros((6, 6))
            S[:3, :3] = body.mass * np.eye(3)
            S[3:, 3:] = R @ body.inertia @ R.T
            approach = travel + vmax * dt + float(np.linalg.norm(self._modal[b]["g"])) * dt * dt
            last = ctx.state_in.contacts.get((_REACTION_KEY, name, "force"), {}).get(b, 0.0)  # [N]
            force = max(approach * body.mass / dt**2, last)
            share = DEPTH_SHARE * force / dhat / len(sel)
            k[sel] = np.maximum(k[sel], share)
            arms[sel] = np.column_stack([N[sel], np.cross(P[sel] - end.position, N[sel])])
            bodies[sel] = len(inertia)
            planes.append(self._modal_planes(ctx, b, len(inertia), x1s[b], end, travel, dhat, share))
            inertia.append(S / dt**2)
        t["modal_planes"] = (len(k), [p for p in planes if p is not None])
        if t["modal_planes"][1]:  # after every other row (a group's pair rows are read from the modal ones on)
            rows = t["modal_planes"][1]
            V = np.concatenate([V] + [-np.ones((len(r[1]), V.shape[1]), np.int64) for r in rows])
            W = np.concatenate([W] + [np.zeros((len(r[1]), W.shape[1])) for r in rows])
            P, N, k, arms = (np.concatenate([a] + [r[i] for r in rows]) for i, a in ((2, P), (3, N), (4, k), (5, arms)))
            bodies = np.concatenate([bodies] + [np.full(len(r[1]), r[0][1]) for r in rows])
        pen.set(V, W, P, N, k, dhat, bodies=bodies, arms=arms, inertia=inertia)
        if pair.any() and c.friction > 0:
            # the group's bodies rub on each other inside the step (a lagged potential: the normal forces at the start),
            # so a body resting on another on a slope sticks: friction applied to the end velocities alone let the
            # step's tangential push move it every step (a cube on a cube on foam crept ~1 mm/s at 10 ms steps).
            # Below a slip of eps per step a contact sticks elastically
            rows = np.flatnonzero(pair)
            eps = max(FRICTION_SLIP * dt, 10.0 * t["solver"].tol * t["solver"].model.size)
            pen.set_friction(rows, c.friction * pen.forces(s.x)[rows], s.x, eps)
        return touched

    def _tet_box_rows(self, o: Box, t: dict, xs: np.ndarray, te: float, r: float) -> list:
        """Contacts of a tet body's surface (vertices ``xs`` (n, 3) [m], build entry ``t``) with box ``o`` at time
        ``te`` [s] within ``r`` [m], besides its vertices' (``_tet_contacts``): the box's 12 edges on the tet's surface
        edges (a tet edge's point closest to a box edge kept in front of the plane through the box edge's closest point
        whose normal is the line between them; only where that line is in the box edge's own region, in front of both
        its faces, and the tet edge at most a skin behind it) and the box's 8 corners on the tet's faces (the face's
        points kept off the corner, along the face normal). Without them a box's edge crossing a tet cube's edge went
        10 mm into the cube at 10 ms steps, no tet vertex inside the box (tests/world/test_tet_box_edges.py). Returns
        ``[(tet vertex ids (k, m), weights (k, m), plane points (k, 3), normals (k, 3) out of the box)]``, each part
        non-empty."""
        boxes = self.__dict__.setdefault("_tet_boxes", {})
        V, F = o.surface(te)
        prox = boxes.get(id(o))
        if prox is None:  # (the box's own edges: its faces' diagonals are flat, not edges)
            edges = EdgeProximity(F, V)
            side = np.linalg.norm(edges.sides(V, np.arange(len(edges.edges))), axis=1)
            prox = boxes[id(o)] = (edges, side < 1.9)
        edges, real = prox
        out = []
        sv, e = t["surface"], t["edges"].edges
        h = edges.query(xs[e[:, 0]], xs[e[:, 1]], V, r)  # ("mine": the tet's edges; "other": the box's)
        if len(h.mine):
            # in the edge's own region (in front of both its faces): there the box's closest point to the tet edge's
            # is on the box edge, so the plane is a tangent plane of the box, as a vertex's closest face is (without
            # this rule, pairs beside the box, carried by its travel, flung the tet cube at 20 ms steps: +78 J); and at
            # most a skin behind it: a tet edge further in is in the box, which its faces push out (the box edges across
            # the box, 5 cm away, flung it too)
            ok = real[h.other] & (h.gap > -t["contact"].margin)
            for j in range(2):
                f = F[edges.adjacent[h.other, j]]
                nf = np.cross(V[f[:, 1]] - V[f[:, 0]], V[f[:, 2]] - V[f[:, 0]])
                nf /= np.linalg.norm(nf, axis=1)[:, None]
                ok &= np.einsum("ij,ij->i", h.normal, nf) >= 0.0
            if ok.any():
                E = edges.edges[h.other[ok]]
                tb = h.t[ok][:, None]
                out.append((sv[e[h.mine[ok]]], np.column_stack([1.0 - h.s[ok], h.s[ok]]),
                            V[E[:, 0]] + tb * (V[E[:, 1]] - V[E[:, 0]]), h.normal[ok]))
        h = t["proximity"].query(V, xs, r)  # the box's corners on the tet's faces (normal: out of the tet)
        if len(h.point):
            out.append((sv[t["triangles"][h.triangle]], h.bary, V[h.point], -h.normal))
        return out

    def _modal_prediction(self, ctx, name: str):
        """World surface vertices (n, 3) [m] of modal body ``name`` at the step start and at its free step end (its
        own step without contacts: gravity, spin, modes, strikes), and that end state: the moving obstacle a tet
        body's step meets. The body's displacement by the tet's reaction is an unknown of that step
        (``tetcontact``), so the reaction's impulse at the step start moves it exactly as solved."""
        m = self._modal[name]
        body, s = m["body"], ctx.state_in.bodies[name]
        x0 = np.array(body.positions(s, precise=True), dtype=np.float64)
        ctl = self._strike_control(ctx, name)
        p = s.copy()
        try:
            m["solver"].step(s, p, ctl, None, ctx.dt)
        except SimulationError as exc:
            raise SimulationError(f"modal body {name!r}: {exc}") from None
        return x0, np.array(body.positions(p, precise=True), dtype=np.float64), p

    def _modal_planes(self, ctx, b: str, index: int, xs: tuple, end, travel: float, dhat: float, k: float):
        """Contacts of modal body ``b`` (its ``index`` among the moving bodies of a tet step) with the static
        obstacles (the ground and planes, spheres, boxes, triangle meshes), solved in the tet step with its rigid
        displacement: its surface ``xs`` (start, free end) vertices within ``travel`` [m] plus twice ``dhat`` [m] of
        an obstacle at the free end, each on the obstacle's tangent plane there (its signed distance and normal; a
        mesh's closest triangle), held ``dhat`` off it (or at its start gap, when inside the skin then) with
        stiffness ``k`` [N/m]. Without them a bar landing on a tet cube and the ground in one 10 ms step took the
        ground's impulse (5.7 rad/s) after the tet step had placed it on the cube: it ended turned 3.6 degrees, 7.4
        mm from that pose, across the cube; across a tet cube and a box, alike (the box's edges under the body's
        faces too, as the solid solve's: ``_solid_stage._box_edges``). A moving obstacle's rows are found where the body
        is relative to it at the step start and carried by its travel in the step (a box's edges too: acting after the
        tet step, a box's edge rising 0.5 m/s between a bar's vertices tipped the bar through a tet cube at 20 ms).
        Returns ``((b, index), body point vertex ids (r, 3), plane rows' p, n, k, arms, body point weights (r, 3))``
        or None (``PenaltyContacts`` rows without tet vertices: the depth is ``target gap - gap - a . u``)."""
        x0, x1 = xs
        t0, t1 = ctx.state_in.time, ctx.state_in.time + ctx.dt
        ids, w, P, N = [], [], [], []
        for i, o in enumerate(self.obstacles):
            n_rows = len(ids)
            if o.moving:  # found where the body is relative to it at the step start, carried by its travel d
                d = o.offset(t1) - o.offset(t0)
                r = travel + float(np.linalg.norm(d)) + 2.0 * dhat
                if isinstance(o, TriangleMesh):
                    h = self._obstacle_surf[i].query(x0, o.vertices + o.offset(t0), r)
                    idx, gap0, n = h.point, h.gap, h.normal
                else:
                    gap0, n = o.signed_distance(x0, t0)
                    idx = np.flatnonzero(gap0 < r)
                    gap0, n = gap0[idx], np.broadcast_to(np.asarray(n, np.float64), x0.shape)[idx]
                gap = gap0 + np.einsum("kd,kd->k", x1[idx] - x0[idx] - d, n)  # at the free end
            elif isinstance(o, TriangleMesh):  # each vertex on its closest triangle's plane (the same at the start)
                h = self._obstacle_surf[i].query(x1, o.vertices, travel + 2.0 * dhat)
                idx, gap, n = h.point, h.gap, h.normal
                gap0 = gap + np.einsum("kd,kd->k", x0[idx] - x1[idx], n)
            else:
                gap, n = o.signed_distance(x1, t1)
                idx = np.flatnonzero(gap < travel + 2.0 * dhat)
                gap, n = gap[idx], np.broadcast_to(np.asarray(n, np.float64), x1.shape)[idx]
                gap0 = o.signed_distance(x0[idx], t0)[0] if len(idx) else gap
            if isinstance(o, Box) and not o.moving:  # its edges under the body's faces at the free end, as the solid
                # solve's (a moving box's vertex rows alone)
                edges = _box_edges(self._modal[b]["body"], end, o, t1, x1, idx, travel + 2.0 * dhat, dhat)
                if edges is not None:
                    if edges[0] is not None:  # (vertex contacts left to the edge contacts)
                        idx, gap, n, gap0 = idx[edges[0]], gap[edges[0]], n[edges[0]], gap0[edges[0]]
                    _, ev, ew, en, eg, _ = edges  # body points sum_a w_a X_a against the edge's plane
                    ids.append(ev)
                    w.append(ew)
                    P.append((eg + dhat - np.clip(eg + np.einsum("kd,kd->k", np.einsum(
                        "ka,kad->kd", ew, x0[ev] - x1[ev]), en), 0.0, dhat))[:, None] * en)
                    N.append(-en)
            elif isinstance(o, Box):  # a moving box's edges: found where the body is relative to it at the step
                # start (as its vertex rows), their gaps at the free end with the box carried by its travel d
                edges = _box_edges(self._modal[b]["body"], ctx.state_in.bodies[b], o, t0, x0, idx, r, dhat)
                if edges is not None:
                    if edges[0] is not None:  # (vertex contacts left to the edge contacts)
                        idx, gap, n, gap0 = idx[edges[0]], gap[edges[0]], n[edges[0]], gap0[edges[0]]
                    _, ev, ew, en, eg, _ = edges  # eg: the gaps at the start
                    end_gap = eg + np.einsum("kd,kd->k", np.einsum("ka,kad->kd", ew, x1[ev] - x0[ev]) - d, en)
                    ids.append(ev)
                    w.append(ew)
                    P.append((end_gap + dhat - np.clip(eg, 0.0, dhat))[:, None] * en)
                    N.append(-en)
            if not o.moving and (len(idx) or len(ids) > n_rows):
                # solved here, with the tet step: the solid stage leaves it out for this body (solved again there,
                # without the tet body in its solve, it turned a bar lying across a soft tet cube on a static
                # ridge into the cube: 16-26 crossing triangle pairs per 20 ms step)
                ctx.tet_obstacles.add((b, i))
            if not len(idx):
                continue
            target = np.clip(gap0, 0.0, dhat)  # (inside the skin: held there)
            ids.append(np.repeat(idx[:, None], 3, 1))
            w.append(np.tile([1.0, 0.0, 0.0], (len(idx), 1)))
            P.append((gap + dhat - target)[:, None] * n)  # d = dhat + p . (-n) = target - gap
            N.append(-n)
        if not ids:
            return None
        ids, w, P, N = np.concatenate(ids), np.concatenate(w), np.concatenate(P), np.concatenate(N)
        arms = np.column_stack([N, np.cross(np.einsum("ka,kad->kd", w, x1[ids]) - end.position, N)])
        return (b, index), ids, P, N, np.full(len(ids), float(k)), arms, w

    def _tet_pair_contacts(self, t: dict, s, r: float, u: np.ndarray) -> tuple:
        """The contacts of a group's tet bodies with each other within ``r`` [m] at the start ``s`` (stacked), ``u``
        (n, 3) [m] the predicted motion: ``tetgroup.pair_contacts``, edges on edges as ``EDGE_ALIGN``."""
        from modalfem.world.tetgroup import pair_contacts

        return pair_contacts([(self._tet[n], o) for n, o in t["members"]], s.x, r, EDGE_ALIGN, u)

    def _last_force(self, ctx, name: str, t: dict, kind: str):
        """The last step's contact force [N] by vertex of ``kind`` (``"obstacle force"``, ``"pair force"``), for a
        group stacked from its members' (zero where a member has none); None without any."""
        if "members" not in t:
            return ctx.state_in.contacts.get((_REACTION_KEY, name, kind))
        parts = [ctx.state_in.contacts.get((_REACTION_KEY, n, kind)) for n, _ in t["members"]]
        if all(p is None for p in parts):
            return None
        return np.concatenate([np.zeros(self.by_name[n].model.point_count) if p is None else p
                               for p, (n, _) in zip(parts, t["members"])])


class _ModalSurface:
    """A point of a modal body's surface as a tet contact's obstacle (for friction): its velocity over the step
    from the start to the predicted end positions."""

    def __init__(self, name: str, x0: np.ndarray, x1: np.ndarray, ids: np.ndarray, w: np.ndarray) -> None:
        self.name = name
        self.d = np.einsum("kj,kjd->kd", w, x1[ids] - x0[ids])  # displacement over the step [m]

    def points(self) -> list:
        return [_ModalPoint(d) for d in self.d]

class _ModalPoint:
    def __init__(self, d: np.ndarray) -> None:
        self.d = d

    def velocity(self, x, t: float, dt: float) -> np.ndarray:
        return self.d[None] / dt
