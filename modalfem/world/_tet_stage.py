"""The tet stage of ``World`` (a mixin): each tet body's implicit step with its contacts as penalty terms (the
obstacles, the modal bodies' surfaces as moving obstacles, other tet bodies stepped together in a group), its
restitution and friction, the reactions on the modal bodies, and tet self-collision (see ``modalfem.world.world``)."""

from __future__ import annotations

import math

import numpy as np

from modalfem import effects as fx
from modalfem.errors import SimulationError
from modalfem.runtime.effects import windward_pressure
from modalfem.world import _tet_kernels
from modalfem.world._shared import _REACTION_KEY, SLOW, _vertex
from modalfem.world.bodies import Tet
from modalfem.world.obstacles import Plane, TriangleMesh
from modalfem.world.pair_restitution import pair_restitution
from modalfem.world.proximity import EdgeProximity, SurfaceProximity
from modalfem.world.tetcontact import STIFFNESS, CoupledTetSolver, PenaltyContacts
from modalfem.world.tetgroup import between, pair_owners

#: a tet body's penalty contacts with one modal body hold its approach within a 1 / DEPTH_SHARE part of the skin
#: (their stiffness summed at least ``DEPTH_SHARE (travel + |g| dt^2) / dhat`` times its mass / dt^2)
DEPTH_SHARE = 4.0
#: a tet step whose contacts (with obstacles or modal bodies) end deeper than this part of the skin is redone with them
#: stiffer (up to TET_RETRIES times), so no contact ends beyond the skin
MAX_DEPTH = 0.5
TET_RETRIES = 6
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


def _contacts_of(modal: list, body: str) -> np.ndarray:
    """Indices (int64, in order) of a tet body's modal contacts ``modal`` ((body, ids, weights) each) with ``body``."""
    return np.array([i for i, (b, _, _) in enumerate(modal) if b == body], dtype=np.int64)


class _TetStage:
    """``World``'s tet stage methods (they read the world's build: ``_tet``, ``_modal``, ``_groups`` ...)."""

    def _build_tet(self, b: Tet, eff: list) -> dict:
        from modalfem import tet
        from modalfem.mesh.surface import boundary_surface
        from modalfem.tet import effects as te

        inner, names = [], []
        wind = None
        for e in eff:
            if isinstance(e, fx.Gravity):
                inner.append(te.Gravity(e.g))
            elif isinstance(e, fx.Damping):
                inner.append(te.RayleighDamping(e.alpha, e.beta))
            elif isinstance(e, fx.Wind):
                wind = _TetWind(e)
                inner.append(wind)
            else:
                continue
            names.append(e.name)
        if b.pins is not None and len(b.pins):
            p = b.model.rest_points[b.pins] + (0.0 if b.position is None else b.position)
            inner.append(tet.Pins(b.pins, p))
        contact = self._one(b.name, fx.Contact)
        penalty = None
        if contact is not None:
            penalty = PenaltyContacts(b.model.point_count)
            inner.append(penalty)
            names.append("contact")
        solver = (tet.TetSolver if penalty is None else CoupledTetSolver)(
            b.model, effects=inner, newton_max=b.newton_max, linear_solver=b.linear_solver)
        surf = boundary_surface(b.model.mesh)
        if wind is not None:
            wind.bind(surf)
        masses = b.model.masses.copy()
        if b.pins is not None:
            masses[b.pins] = np.inf
        tris = np.ascontiguousarray(surf.triangles)
        out = {"solver": solver, "effects": tuple(names), "surface": surf.mesh_vertices, "triangles": tris,
               "wind": wind, "masses": masses, "penalty": penalty, "contact": contact, "pipeline": None,
               "proximity": SurfaceProximity(tris, surf.vertices), "edges": EdgeProximity(tris, surf.vertices)}
        sc = self._one(b.name, fx.SelfCollision)
        if sc is not None:
            from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline

            out["pipeline"] = CollisionPipeline(tris, config=CollisionConfig(
                thickness=self._thickness(b.name), friction=0.0 if contact is None else contact.friction))
            names.append("self-collision")
            out["effects"] = tuple(names)
        return out

    def _stage_tet_step(self, ctx) -> None:
        from modalfem.tet import TetControl, TetState

        dt = ctx.dt
        for key in [k for k in ctx.contacts if k[0] == _REACTION_KEY]:  # this step's are set below
            del ctx.contacts[key]
        starts = {}
        for name, t in self._tet.items():
            s = ctx.state_in.bodies[name].copy()
            for p, J in self._strikes(ctx, name):
                i = _vertex(name, p, len(s.x))
                if np.isfinite(t["masses"][i]):
                    s.v[i] += J / t["masses"][i]
            if t["wind"] is not None:
                t["wind"].update(s.x, s.v, ctx.state_in.time)
            starts[name] = s
        for names in self._tet_groups(ctx, starts):
            if len(names) == 1:
                name = names[0]
                t, s = self._tet[name], starts[name]
                ctl = TetControl(*ctx.control.scripted[name]) if name in ctx.control.scripted else None
            else:  # tet bodies that may touch in this step: one implicit step over their stacked vertices
                name, t = self._tet_group(names)
                s = TetState(np.concatenate([starts[n].x for n in names]), np.concatenate([starts[n].v for n in names]),
                             starts[names[0]].t)
                ctl = None
                if any(n in ctx.control.scripted for n in names):
                    cv, cp = zip(*[(np.asarray(ctx.control.scripted[n][0]) + o, np.asarray(ctx.control.scripted[n][1]))
                                   for n, o in t["members"] if n in ctx.control.scripted])
                    ctl = TetControl(np.concatenate(cv), np.concatenate(cp))
            obstacles = self._tet_contacts(ctx, name, s, t) if t["penalty"] is not None else None
            out, kept = s.copy(), None
            for attempt in range(TET_RETRIES + 1):
                try:
                    t["solver"].step(s, out, dt, control=ctl)
                except SimulationError as exc:
                    raise SimulationError(f"tet body {name!r}: {exc}") from None
                if obstacles is None:
                    break
                # a stiffened retry must not end with more energy than the attempt it redoes: where a soft vertex is
                # wedged between contacts pushing it opposite ways (foam between the ground and a heavy bar's
                # tilted face), stiffening them in turn flung it ~9 cm in one 5 ms step and stored +23 J in them
                energy = self._tet_end_energy(ctx, name, t, out) if kept is not None else None
                if kept is not None and energy > kept[2]:
                    out, t["penalty"].k = kept[0], kept[1]
                    t["penalty"].stiffen(np.ones(len(kept[1])))  # (drops the cached depths)
                    break
                pen = t["penalty"]
                if attempt == TET_RETRIES or not (pen.depths(out.x) > MAX_DEPTH * pen.dhat).any():
                    break
                kept = (out, pen.k.copy(), self._tet_end_energy(ctx, name, t, out) if energy is None else energy)
                self._tet_too_deep(pen, out.x)
                out = s.copy()
            if obstacles is not None:
                self._modal_planes_reaction(ctx, t, out)
                group = (t,) if "members" in t else ()  # (a body alone: looked up by name)
                self._tet_reaction(ctx, name, out, *group)
                self._tet_friction(ctx, name, out, obstacles, *group)
                if "members" not in t:
                    self._tet_restitution(ctx, name, s, out)
                else:
                    self._group_restitution(ctx, t, s, out)
                    pair_restitution(self, ctx, t, s, out, _REACTION_KEY)  # tet-tet (pair_restitution.py)
                self._tet_record(ctx, name, t, out)
            if len(names) == 1:
                ctx.out.bodies[name] = out
                ctx.start[name] = s  # the start the step used (strikes applied)
                ctx.done.add(name)
                continue
            for (n, o), a, b in zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:]):
                ctx.out.bodies[n] = TetState(out.x[a:b].copy(), out.v[a:b].copy(), out.t)
                ctx.start[n] = starts[n]
                ctx.done.add(n)

    def _tet_end_energy(self, ctx, name: str, t: dict, out) -> float:
        """The energy [J] a tet step ``out`` of ``name`` (a body or a group ``t``) ends with, to compare attempts of
        one step: its bodies' (kinetic, elastic, vertex potentials), its penalty contacts' and the kinetic energy of
        the modal bodies it pushes (their start velocity plus gravity's and the reaction's in the step)."""
        from modalfem.tet import TetState

        def own(e):  # (a body's solver holds its penalty contacts as a vertex term: counted once, below)
            return e["total"] - e.get(type(pen).__name__.lower(), 0.0)

        pen = t["penalty"]
        if "members" in t:
            e = sum(own(self._tet[n]["solver"].energies(TetState(out.x[a:b], out.v[a:b], out.t)))
                    for (n, _), a, b in zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:]))
        else:
            e = own(t["solver"].energies(out))
        e += pen.penalty_energy(out.x)  # (also sets pen.u, the modal bodies' displacements, for these positions)
        modal = t["modal_contacts"][1]
        touched = [b for b in self._tet_modal.get(name, ()) if len(_contacts_of(modal, b))]
        for b, u, S in zip(touched, pen.u, pen.inertia):
            body, st = self._modal[b]["body"], ctx.state_in.bodies[b]
            V = np.concatenate([st.velocity + np.asarray(self._modal[b]["g"]) * ctx.dt, body.angular_velocity(st)])
            V = V + u / ctx.dt
            e += 0.5 * ctx.dt**2 * float(V @ S @ V)
        return e

    def _group_restitution(self, ctx, t: dict, s, out) -> None:
        """``_tet_restitution`` of each member of a group with the modal bodies it touches: its own vertices (views
        into the group's states, changed in place), its contacts with them, the energy stored in its own
        elasticity and in the contacts of its vertices."""
        from modalfem.tet import TetState

        pen = t["penalty"]
        n_obstacle, modal = t["modal_contacts"]
        if not modal:
            return
        owner = t["solver"].owner[pen.vid[:, 0]]
        f = pen.forces(out.x)
        psi = _tet_kernels.penalty(pen.depths(out.x), pen.k, pen.eps)[0]
        for i, ((n, _), a, b) in enumerate(zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:])):
            rows = n_obstacle + np.flatnonzero(owner[n_obstacle:n_obstacle + len(modal)] == i)
            view = {"masses": t["masses"][a:b], "solver": self._tet[n]["solver"], "contact": self._tet[n]["contact"],
                    "modal_contacts": (0, [modal[r - n_obstacle] for r in rows]),
                    "penalty": _MemberContacts(f[rows], pen.nrm[rows], float(psi[owner == i].sum()))}
            self._tet_restitution(ctx, n, TetState(s.x[a:b], s.v[a:b], s.t), TetState(out.x[a:b], out.v[a:b], out.t),
                                  view)

    def _tet_groups(self, ctx, starts: dict) -> list:
        """The tet bodies in groups stepped together (``tetgroup.touching``): those with contact whose surfaces'
        boxes, each grown by what it may travel in the step plus its margins, overlap; every other body alone."""
        from modalfem.world.tetgroup import touching

        boxes = {}
        for n, t in self._tet.items():
            if t["penalty"] is None:
                continue
            s = starts[n]
            xs = s.x[t["surface"]]
            r = _tet_reach(_top_speed(s), t["contact"].margin, ctx.dt)
            boxes[n] = (xs.min(0) - r, xs.max(0) + r)
        return touching(list(self._tet), boxes)

    def _tet_group(self, names: list) -> tuple:
        """``(key, entry)`` of the tet bodies ``names`` stepped as one (made once per set of bodies): an entry like
        a tet body's (stacked vertices, surfaces, masses; one ``JointTetSolver`` and ``PenaltyContacts``) with
        ``members``: (name, first stacked vertex) each. Its contact takes the largest margin and the smallest
        friction and restitution of its members'."""
        key = "+".join(names)
        g = self._groups.get(key)
        if g is not None:
            return key, g
        import dataclasses

        from modalfem.world.tetgroup import JointTetSolver

        ts = [self._tet[n] for n in names]
        n_total = sum(self.by_name[n].model.point_count for n in names)
        pen = PenaltyContacts(n_total)
        solver = JointTetSolver([t["solver"] for t in ts], pen)
        offs = solver.offsets[:-1]
        surface = np.concatenate([t["surface"] + o for t, o in zip(ts, offs)])
        s_off = np.concatenate([[0], np.cumsum([len(t["surface"]) for t in ts])])
        tris = np.concatenate([t["triangles"] + o for t, o in zip(ts, s_off[:-1])])
        rest = np.concatenate([self.by_name[n].model.rest_points[t["surface"]] for n, t in zip(names, ts)])
        cs = [t["contact"] for t in ts]
        contact = dataclasses.replace(cs[0], margin=max(c.margin for c in cs), friction=min(c.friction for c in cs),
                                      restitution=min(c.restitution for c in cs))
        g = {"solver": solver, "penalty": pen, "masses": np.concatenate([t["masses"] for t in ts]), "surface": surface,
             "triangles": tris, "contact": contact, "wind": None, "pipeline": None,
             "proximity": SurfaceProximity(tris, rest), "edges": EdgeProximity(tris, rest),
             "members": [(n, int(o)) for n, o in zip(names, offs)]}
        self._groups[key] = g
        self._tet_modal[key] = list(self._modal_contact)
        return key, g

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

    def _tet_record(self, ctx, name: str, t: dict, out) -> None:
        """Keep what the next step and ``energy`` read: the energy stored in the penalty contacts, the forces by
        vertex of the obstacles' and of the group's bodies on each other (per member body in a group; a
        contact's energy counts for the body of its first vertex)."""
        pen = t["penalty"]
        n_obstacle, modal = t["modal_contacts"]
        f = pen.forces(out.x)
        n = len(out.x)
        start = n_obstacle + len(modal)
        obstacle = np.bincount(pen.verts[:n_obstacle, 0], weights=f[:n_obstacle], minlength=n)
        pair = np.bincount(pen.verts[start:, 0], weights=f[start:], minlength=n)
        if "members" not in t:
            ctx.contacts[(_REACTION_KEY, name)] = pen.penalty_energy(out.x)
            ctx.contacts[(_REACTION_KEY, name, "obstacle force")] = obstacle
            return
        psi = _tet_kernels.penalty(pen.depths(out.x), pen.k, pen.eps)[0]
        first = np.bincount(t["solver"].owner[pen.vid[:, 0]], weights=psi, minlength=len(t["members"]))
        for i, ((m, _), a, b) in enumerate(zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:])):
            ctx.contacts[(_REACTION_KEY, m)] = float(first[i])
            ctx.contacts[(_REACTION_KEY, m, "obstacle force")] = obstacle[a:b]
            ctx.contacts[(_REACTION_KEY, m, "pair force")] = pair[a:b]

    def _surface_now(self, ctx, name: str) -> np.ndarray:
        """World surface vertices of a body: at the step end if it has stepped, else at the start."""
        if name in self._modal:
            st = ctx.out.bodies[name] if name in ctx.done else ctx.state_in.bodies[name]
            return self._modal[name]["body"].positions(st, precise=True)
        st = ctx.out.bodies[name] if name in ctx.done else ctx.state_in.bodies[name]
        return st.x[self._tet[name]["surface"]]

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
            r = reach + (0.0 if not o.moving else float(np.linalg.norm(o.path.velocity(ctx.state_in.time, dt))) * dt)
            if isinstance(o, TriangleMesh):
                Vo = o.vertices + o.offset(t1)
                h = self._obstacle_surf[self.obstacles.index(o)].query(xs, Vo, r)
                if len(h.point):
                    p = np.einsum("kj,kjd->kd", h.bary, Vo[o.triangles[h.triangle]])
                    add(sv[h.point][:, None], np.ones((len(p), 1)), p, h.normal, None, o)
            else:
                gap, n = o.signed_distance(xs, t1)
                idx = np.flatnonzero(gap < r)
                if len(idx):
                    n = np.asarray(n)[idx]
                    add(sv[idx][:, None], np.ones((len(idx), 1)), xs[idx] - gap[idx, None] * n, n, None, o)
        n_obstacle = len(touched)
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

    def _modal_planes(self, ctx, b: str, index: int, xs: tuple, end, travel: float, dhat: float, k: float):
        """Contacts of modal body ``b`` (its ``index`` among the moving bodies of a tet step) with the static
        planes (the ground), solved in the tet step with its rigid displacement: its surface ``xs`` (start, free
        end) within ``travel`` [m] plus twice ``dhat`` [m] of a plane at the free end, each held ``dhat`` off it
        (or at its start gap, when inside the skin then) with stiffness ``k`` [N/m]. Without them a bar landing on
        a tet cube and the ground in one 10 ms step took the ground's impulse (5.7 rad/s) after the tet step had
        placed it on the cube: it ended turned 3.6 degrees, 7.4 mm from that pose, across the cube. Returns
        ``((b, index), vertex ids, plane rows' p, n, k, arms)`` or None (``PenaltyContacts`` rows without tet
        vertices: the depth is ``target gap - gap - a . u``)."""
        x0, x1 = xs
        t0, t1 = ctx.state_in.time, ctx.state_in.time + ctx.dt
        ids, P, N = [], [], []
        for o in self.obstacles:
            if not isinstance(o, Plane) or o.moving:
                continue
            gap, n = o.signed_distance(x1, t1)
            idx = np.flatnonzero(gap < travel + 2.0 * dhat)
            if not len(idx):
                continue
            n = np.broadcast_to(np.asarray(n, np.float64), x1.shape)[idx]
            target = np.clip(o.signed_distance(x0[idx], t0)[0], 0.0, dhat)  # (inside the skin: held there)
            ids.append(idx)
            P.append((gap[idx] + dhat - target)[:, None] * n)  # d = dhat + p . (-n) = target - gap
            N.append(-n)
        if not ids:
            return None
        ids, P, N = np.concatenate(ids), np.concatenate(P), np.concatenate(N)
        arms = np.column_stack([N, np.cross(x1[ids] - end.position, N)])
        return (b, index), ids, P, N, np.full(len(ids), float(k)), arms

    def _modal_planes_reaction(self, ctx, t: dict, out) -> None:
        """The static planes' impulses on the modal bodies from their rows in a tet step (``_modal_planes``), at
        the end positions ``out.x``, given as the tet reaction is (at the step start, arms at the free end); the
        rows are then dropped from the penalty (its depths and the bodies' displacements kept), so what follows
        sees the tet's own contacts alone (the planes' rows hold no tet vertex)."""
        n0, rows = t.get("modal_planes", (0, []))
        if not rows:
            return
        pen = t["penalty"]
        f = pen.forces(out.x)
        o = n0
        for (b, _), ids, _, N, _, _ in rows:
            ff, o = f[o:o + len(ids)], o + len(ids)
            on = ff > 0
            if on.any():
                one = np.tile([1.0, 0.0, 0.0], (int(on.sum()), 1))
                J = -(ff[on] * ctx.dt)[:, None] * N[on]
                self._modal_impulses(ctx, b, np.repeat(ids[on][:, None], 3, 1), one, J, "", t["modal_ends"].get(b),
                                     report=False)
        pen.keep_first(n0, out.x)
        t["modal_planes"] = (n0, [])

    def _tet_restitution(self, ctx, name: str, s, out, t: dict | None = None) -> None:
        """Restitution between tet body ``name`` (start ``s``, end ``out``) and the modal bodies it meets, on the
        bodies' relative motion (Poisson): an impact starts when their contacts first push (the relative velocity
        ``v0`` of the tet's centre of mass and the modal body noted); while the pair approaches, the normal impulse
        adds up (``J_c``); when it stops approaching, the pair takes ``e J_c`` more, equal and opposite, through the
        tet's centre of mass (all its vertices alike: no strain) and the modal body's. Capped so that the relative
        motion's kinetic energy after it, plus what the tet stored in the impact (elastic, contact, vibration), is at
        most ``e^2`` times the impact's ``mu v0^2 / 2`` (mu the reduced mass): the energy the implicit step's
        damping took is given back, never more; the elasticity of a soft body returns what it stored itself. When
        the contacts let go, the pair is topped up once more, to ``e v0`` apart under the same cap: at steps much
        shorter than the impact, the tet's elastic return after the end of compression takes many steps, and the
        implicit step's damping of it (0.19 v0 of the rebound of a stiff block at dt = 0.1 ms) is given back too.
        ``t``: a member of a group's view (``_group_restitution``; ``s`` and ``out`` its slices of the group's)."""
        t = self._tet[name] if t is None else t
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        m = t["masses"]
        if not modal or not np.all(np.isfinite(m)):
            return
        pen = t["penalty"]
        f = pen.forces(out.x)[n_obstacle:]
        M = float(m.sum())
        Vt = m @ out.v / M
        en = t["solver"].energies(out)
        stored = en["elastic"] + pen.penalty_energy(out.x) + en["kinetic"] - 0.5 * M * float(Vt @ Vt)
        for b in self._tet_modal[name]:
            sel = _contacts_of(modal, b)
            J = ((f[sel] * ctx.dt)[:, None] * pen.nrm[n_obstacle + sel]).sum(0) if len(sel) else np.zeros(3)
            key = (_REACTION_KEY, name, "impact", b)
            rec = ctx.state_in.contacts.get(key)
            if not np.any(J) and rec is None:
                continue
            mb = self._modal[b]
            cb = self._one(b, fx.Contact)
            e = t["contact"].restitution if cb is None else min(t["contact"].restitution, cb.restitution)
            sb = ctx.state_in.bodies[b]
            Vb = sb.velocity + mb["g"] * ctx.dt + (ctx.dV[b][:3] if b in ctx.dV else 0.0)
            if rec is None:  # the impact starts: the relative velocity and the tet's stored energy before it
                V0 = m @ s.v / M
                e0 = t["solver"].energies(s)
                rec = (V0 - sb.velocity, e0["elastic"] + e0["kinetic"] - 0.5 * M * float(V0 @ V0), np.zeros(3), False)
            v_start, stored0, Jc, done = rec
            Jc = Jc + J
            ended = not np.any(J)  # the contacts let go: the impact's record is not carried on
            if not ended:
                ctx.contacts[key] = (v_start, stored0, Jc, done)
            nJ = float(np.linalg.norm(Jc))
            if (done and not ended) or e <= 0 or nJ == 0:
                continue
            nh = Jc / nJ  # on the tet, out of the modal body
            vn = float((Vt - Vb) @ nh)
            if vn < 0:  # still approaching
                continue
            mu = 1.0 / (1.0 / M + 1.0 / mb["body"].mass)
            v0 = max(-float(v_start @ nh), 0.0)
            vmax = math.sqrt(max(e * e * v0 * v0 - 2.0 * max(stored - stored0, 0.0) / mu, 0.0))
            lam = max(0.0, mu * (vmax - vn) if ended else min(e * nJ, mu * (vmax - vn)))
            if not ended:
                ctx.contacts[key] = (v_start, stored0, Jc, True)
            if lam == 0:
                continue
            out.v += lam * nh / M
            dV = np.zeros(6 + mb["body"].mode_count)
            dV[:3] = -lam * nh / mb["body"].mass
            ctx.dV[b] = ctx.dV[b] + dV if b in ctx.dV else dV
            ctx.report.exchanged.append((b, name, -lam * nh, np.cross(sb.position, -lam * nh)))

    @staticmethod
    def _tet_too_deep(pen, x: np.ndarray) -> bool:
        """True, and the contacts that ended deeper than ``MAX_DEPTH`` of the skin stiffened to end at a quarter of
        it (their force held), when the step is to be redone."""
        depth = pen.depths(x)
        over = depth > MAX_DEPTH * pen.dhat
        if not over.any():
            return False
        pen.stiffen(np.where(over, depth / (0.25 * pen.dhat), 1.0))
        return True

    def _tet_reaction(self, ctx, name: str, out, t: dict | None = None) -> None:
        """The modal bodies take the opposite of the impulses the tet body's penalty contacts with them gave it in
        its implicit step (``f dt`` along the normal at each contact's modal point): generalised velocity changes
        at the step start (``ctx.dV``, merged with the solid solve's), reported in ``StepReport.exchanged``. Their
        rigid part is the body's displacement solved in the step (``tetcontact``) over dt. ``t``: a group's entry
        (``_tet_group``; the impulses reported as from the member body each contact's vertices belong to)."""
        t = self._tet[name] if t is None else t
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        if not modal:
            return
        pen = t["penalty"]
        f = pen.forces(out.x)[n_obstacle:]
        J = -(f * ctx.dt)[:, None] * pen.nrm[n_obstacle:]  # on the modal body
        ctx.contacts[(_REACTION_KEY, name, "force")] = {  # [N] by body: the next step's stiffness holds it
            b: float(f[_contacts_of(modal, b)].sum()) for b in self._tet_modal[name]}
        for b in self._tet_modal[name]:
            sel = _contacts_of(modal, b)
            sel = sel[f[sel] > 0]
            for src, part in self._by_member(t, name, n_obstacle + sel):
                part = part - n_obstacle
                ids = np.array([modal[i][1] for i in part])
                w = np.array([modal[i][2] for i in part])
                self._modal_impulses(ctx, b, ids, w, J[part], src, t.get("modal_ends", {}).get(b))

    def _by_member(self, t: dict, name: str, rows: np.ndarray) -> list:
        """``(body, rows)``: the contact ``rows`` (penalty indices) by the tet body of their first vertex (a group's
        members; else ``name``), bodies without rows left out."""
        if not len(rows):
            return []
        if "members" not in t:
            return [(name, rows)]
        owner = t["solver"].owner[t["penalty"].vid[rows, 0]]
        return [(n, rows[owner == i]) for i, (n, _) in enumerate(t["members"]) if np.any(owner == i)]

    def _modal_impulses(self, ctx, b: str, ids: np.ndarray, w: np.ndarray, J: np.ndarray, src: str,
                        end: tuple | None = None, report: bool = True) -> np.ndarray:
        """Impulses ``J`` (k, 3) [N s] on modal body ``b`` at its surface points ``sum_j w_j vertex_j`` (ids, w
        (k, 3)) at the step start, from body ``src``: added to ``ctx.dV[b]`` (rigid: v, omega; the modes the
        step resolves, as ``_ContactBuilder``), and reported as exchanged. ``end``: ``(surface (n, 3) [m], centre of
        mass (3,) [m])`` of the body's free step end, the pose a tet step solved its rigid displacement about
        (``_tet_contacts``): the torques then take their arms there, so the body turns by the rotation that step
        solved (with the arms at the start, a steel bar turning 12 degrees per 20 ms step on a tet cube turned
        ~2.4 degrees away from it, 2.7 mm at its ends, and crossed the cube). ``report``: False for a static
        obstacle's impulses (``_modal_planes``; not an exchange between bodies)."""
        body = self._modal[b]["body"]
        s = ctx.state_in.bodies[b]
        R = s.rotation()
        phi = np.einsum("kj,kjcr->kcr", w, body.vertex_shapes(ids.reshape(-1)).reshape(ids.shape + (3, -1)))
        if end is None:
            rest = np.einsum("kj,kjc->kc", w, body.rest[ids])
            r = (rest + np.einsum("kcr,r->kc", phi, s.q)) @ R.T
        else:
            r = np.einsum("kj,kjd->kd", w, end[0][ids]) - end[1]
        Jsum = J.sum(0)
        L = np.cross(r, J).sum(0)
        dq = np.einsum("kcr,kc->r", np.einsum("ab,kbr->kar", R, phi), J) * (body.omega * ctx.dt <= SLOW)
        dV = np.concatenate([Jsum / body.mass, R @ body.inertia_inv @ R.T @ L, dq])
        ctx.dV[b] = ctx.dV[b] + dV if b in ctx.dV else dV
        if report:
            ctx.report.exchanged.append((b, src, Jsum, np.cross(r + s.position, J).sum(0)))
        return dV

    def _tet_friction(self, ctx, name: str, out, obstacles: list, t: dict | None = None) -> None:
        """Coulomb friction of the tet's penalty contacts: the tangential velocity of a contact's point relative to
        the obstacle's (or modal body's) surface shrinks by at most ``mu f dt / m_eff`` (f the penalty force at the
        step end), the change spread over the point's vertices by their weights; a modal body takes the opposite
        impulse. The end velocities change, not the end positions: friction moving single vertices by ``dt dv``
        stored the shear against their neighbours as elastic energy (a steel bar landing on a soft block with
        friction 0.5 gained ~5 mJ per 1 ms step, 2.4 % of the scene's energy); the tet's next implicit step takes
        the slowed vertices with its elasticity. A group's bodies (``t``, ``_tet_group``) rub on each other alike,
        each contact's impulses equal and opposite on the two (signed weights); what each received from the other,
        with the penalty's impulses, is reported in ``StepReport.exchanged``."""
        t = self._tet[name] if t is None else t
        pen = t["penalty"]
        mu = t["contact"].friction
        if not pen.count:
            return
        f = pen.forces(out.x)
        act = np.flatnonzero(f > 0)
        ctx.report.contacts["tet"] = ctx.report.contacts.get("tet", 0) + len(act)
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        start = n_obstacle + len(modal)  # the group's bodies with each other from here
        J = np.zeros((pen.count, 3))
        if pen.fric is not None:  # rubbing inside the step: not again here; its impulses for the report
            rows, F = pen.friction_forces(out.x)
            J[rows] = F * ctx.dt
            act = np.setdiff1d(act, rows)
        if mu > 0:
            J = J + self._tet_friction_pass(ctx, name, out, obstacles, t, f, act, mu)
        if "members" in t and start < pen.count:
            self._pair_exchange(ctx, t, out, f, J, start)

    def _pair_exchange(self, ctx, t: dict, out, f: np.ndarray, J: np.ndarray, start: int) -> None:
        """Report what each body of a group received from each other (the penalty's ``f dt n`` and the friction
        impulse ``J`` of the contacts from ``start``, spread by their signed weights): one entry per ordered pair
        of members in contact, each side summed on its own vertices."""
        pen = t["penalty"]
        rows = np.arange(start, pen.count)
        rows = rows[(f[rows] > 0) | np.any(J[rows] != 0.0, axis=1)]
        if not len(rows):
            return
        imp = (f[rows] * ctx.dt)[:, None] * pen.nrm[rows] + J[rows]  # on the point (sum_j w_j x_j)
        owner, first, other = pair_owners(t["solver"], pen, rows)  # (k, 4), (k,), (k,)
        names = [n for n, _ in t["members"]]
        for a in range(len(names)):
            for b in range(len(names)):
                sel = between(first, other, a, b)
                if a == b or not len(sel):
                    continue
                on_a = np.where(owner[sel] == a, pen.w[rows[sel]], 0.0)  # (k, 4): the weights of a's vertices
                Jv = on_a[:, :, None] * imp[sel][:, None, :]  # (k, 4, 3) on each of a's vertices
                x = out.x[pen.vid[rows[sel]]]
                ctx.report.exchanged.append((names[a], names[b], Jv.sum((0, 1)), np.cross(x, Jv).sum((0, 1))))

    def _tet_friction_pass(self, ctx, name: str, out, obstacles: list, t: dict, f: np.ndarray, act: np.ndarray,
                           mu: float) -> np.ndarray:
        """The friction of ``_tet_friction`` (``mu`` > 0): end velocities changed in place; the impulses (c, 3)."""
        pen = t["penalty"]
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        # the obstacles' surface velocities at the contacts' points (the positions do not change below), per
        # obstacle at once; a modal body's point moves as predicted over the step
        vo = np.zeros((pen.count, 3))
        extra = np.zeros(pen.count)  # [1/kg]: a modal body's translation takes the opposite impulse
        pt = np.einsum("cj,cjd->cd", pen.w, out.x[pen.vid])
        if n_obstacle:
            ob = act[act < n_obstacle]
            for o in {id(obstacles[c]): obstacles[c] for c in ob}.values():
                sel = np.array([c for c in ob if obstacles[c] is o], dtype=np.int64)
                vo[sel] = np.asarray(o.velocity(pt[sel], ctx.state_in.time, ctx.dt))
        md = act[(act >= n_obstacle) & (act < n_obstacle + len(modal))]
        if len(md):
            vo[md] = np.array([obstacles[c].velocity(None, 0.0, ctx.dt) for c in md]).reshape(-1, 3)
            inv_mass = {b: 1.0 / self._modal[b]["body"].mass for b in self._tet_modal[name]}
            extra[md] = [inv_mass[modal[c - n_obstacle][0]] for c in md]
        # in contact order, each contact seeing the velocities the ones before left (compiled)
        J = _tet_kernels.friction(act.astype(np.int64), pen.verts, pen.w, t["masses"], extra, out.v, vo,
                                  pen.nrm, f, float(mu), float(ctx.dt))
        back = {}  # modal body -> contacts with an impulse: the opposite impulses, given once per body below
        for c in md[np.any(J[md] != 0.0, axis=1)] if len(md) else ():
            back.setdefault(modal[c - n_obstacle][0], []).append(c)
        for mb, cs in back.items():
            for src, part in self._by_member(t, name, np.array(cs, dtype=np.int64)):
                self._modal_impulses(ctx, mb, np.array([modal[c - n_obstacle][1] for c in part]),
                                     np.array([modal[c - n_obstacle][2] for c in part]), -J[part], src,
                                     t.get("modal_ends", {}).get(mb))
        return J

    def _kick(self, ctx, kind: str, other: str, data, J: np.ndarray) -> None:
        """Impulse ``J`` (3,) [N s] on solid body ``other`` at its contact point, at its step end (see
        ``_reaction``): a modal body's rigid motion, a tet body's vertices by their weights."""
        ids, w, pt = data
        if kind == "modal":
            st = ctx.out.bodies[other]
            st.velocity += J / self._modal[other]["body"].mass
            st.angular_momentum += np.cross(pt - st.position, J)
            return
        t = self._tet[other]
        vid = t["surface"][np.asarray(ids)]  # surface-local -> mesh vertex ids
        m = t["masses"][vid]
        dv = np.where(np.isfinite(m), 1.0, 0.0)[:, None] * (w / np.where(np.isfinite(m), m, 1.0))[:, None] * J
        ctx.out.bodies[other].v[vid] += dv

    def _stage_tet_self(self, ctx) -> None:
        dt = ctx.dt
        for name, t in self._tet.items():
            if t["pipeline"] is None:
                continue
            x0 = ctx.start[name].x
            out = ctx.out.bodies[name]
            sv = t["surface"]
            v = (out.x[sv] - x0[sv]) / dt
            v_new, stats = t["pipeline"].resolve(x0[sv], v, t["masses"][sv], dt, t=ctx.state_in.time)
            if stats.unresolved:
                raise SimulationError(f"tet body {name!r}: self-collision left {stats.unresolved} colliding pairs")
            out.v[sv] += v_new - v
            out.x[sv] = x0[sv] + dt * v_new


class _MemberContacts:
    """A group member's contacts with the modal bodies, as ``_tet_restitution`` reads them: their forces [N] and
    normals at the step end, and the energy [J] stored in the contacts of its vertices."""

    def __init__(self, f: np.ndarray, nrm: np.ndarray, stored: float) -> None:
        self.f, self.nrm, self.stored = f, nrm, stored

    def forces(self, x: np.ndarray) -> np.ndarray:
        return self.f

    def penalty_energy(self, x: np.ndarray) -> float:
        return self.stored


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


class _TetWind:
    """Wind on a tet body's surface: pressure ``0.5 rho C s^2`` on the faces the air meets, held over a step
    (a vertex load of the implicit step, updated at each step start)."""

    kind = "vertex"

    def __init__(self, wind: fx.Wind) -> None:
        self.wind = wind
        self.f = None

    def bind(self, surf) -> None:
        self.surface_vertices = surf.mesh_vertices
        self.triangles = surf.triangles

    def update(self, x: np.ndarray, v: np.ndarray, t: float) -> None:
        sv = self.surface_vertices
        xs, vs = x[sv], v[sv]
        T = self.triangles
        a = xs[T[:, 0]]
        cr = np.cross(xs[T[:, 1]] - a, xs[T[:, 2]] - a)
        w_rel = self.wind.at(xs[T].mean(axis=1), t) - vs[T].mean(axis=1)
        F = windward_pressure(cr, w_rel, self.wind.density, self.wind.drag)  # the modal runtime's law
        f = np.zeros((len(x), 3))
        for k in range(3):
            np.add.at(f, sv[T[:, k]], F / 3.0)
        self.f = f

    def energy(self, x: np.ndarray, masses: np.ndarray) -> float:
        return -float(np.sum(self.f * x))

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        return -self.f

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray):
        return None
