"""The tet stage of ``World`` (a mixin): each tet body's build and implicit step with its contacts as penalty terms
(retried stiffer when too deep, never ending with more energy), groups of tet bodies stepped together, what the next
step reads, the surfaces the deformable pipeline's reaction meets (``_surface_now``), tet self-collision and tet wind
(see ``modalfem.world.world``). The contacts are set in ``_tet_contacts`` (``_TetContacts``); the reactions,
friction and restitution after the step are in ``_tet_response`` (``_TetResponse``)."""

from __future__ import annotations

import numpy as np

from modalfem import effects as fx
from modalfem.errors import SimulationError
from modalfem.runtime.effects import windward_pressure
from modalfem.world import _tet_kernels
from modalfem.world._shared import _REACTION_KEY, _vertex
from modalfem.world._tet_contacts import FRICTION_SLIP, _contacts_of, _tet_reach, _TetContacts, _top_speed  # noqa: F401
from modalfem.world._tet_response import _TetResponse
from modalfem.world.bodies import Tet
from modalfem.world.pair_restitution import pair_restitution
from modalfem.world.proximity import EdgeProximity, SurfaceProximity
from modalfem.world.tetcontact import CoupledTetSolver, PenaltyContacts

#: a tet step whose contacts (with obstacles or modal bodies) end deeper than this part of the skin is redone with them
#: stiffer (up to TET_RETRIES times), so no contact ends beyond the skin
MAX_DEPTH = 0.5
TET_RETRIES = 6


class _TetStage(_TetContacts, _TetResponse):
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
                if kept is not None and energy - self._tet_step_work(t, out) > kept[2]:
                    out, t["penalty"].k = kept[0], kept[1]
                    t["penalty"].stiffen(np.ones(len(kept[1])))  # (drops the cached depths)
                    break
                pen = t["penalty"]
                if attempt == TET_RETRIES or not (pen.depths(out.x) > MAX_DEPTH * pen.dhat).any():
                    break
                # (plus the work its too-deep contacts' forces do holding their points a quarter skin deep instead: a
                # body its first attempt sank into the ground ends higher, and heavier by that, when held)
                d = pen.depths(out.x)
                lift = float(np.sum(np.where(d > MAX_DEPTH * pen.dhat, pen.forces(out.x) * (d - 0.25 * pen.dhat), 0.0)))
                e_end = self._tet_end_energy(ctx, name, t, out) if energy is None else energy
                kept = (out, pen.k.copy(), lift + e_end - self._tet_step_work(t, out))
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

    @staticmethod
    def _tet_step_work(t: dict, out) -> float:
        """The work [J] the moving obstacles do on a tet step ``out`` of body or group ``t``: each obstacle contact's
        penalty force at the step end (held over the step) along its normal times the obstacle's travel in the step
        (``t["obstacle_travel"]``, set by ``_tet_contacts``). A retry is compared with the attempt it redoes by its end
        energy less this work: a box pushing harder on the retry does more work on it."""
        pen = t["penalty"]
        d = t.get("obstacle_travel")
        if d is None or not len(d) or not d.any():
            return 0.0
        n = len(d)
        f = pen.forces(out.x)[:n]
        return float(f @ np.einsum("cd,cd->c", pen.nrm[:n], d))

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
