"""The tet stage's response on the bodies after a tet step (a mixin of ``World``, through ``_TetStage``): the
modal bodies' reactions to the penalty contacts they shared with the tet (``_tet_reaction``, the static planes'
rows ``_modal_planes_reaction``, both through ``_modal_impulses``), Coulomb friction of the tet's contacts and the
impulses a group's bodies exchanged (``_tet_friction``), and restitution between a tet body and the modal bodies it
meets (``_tet_restitution``, per member of a group ``_group_restitution``). The contacts are set in
``_tet_contacts``; the step itself in ``_tet_stage``."""

from __future__ import annotations

import math

import numpy as np

from modalfem import effects as fx
from modalfem.world import _tet_kernels
from modalfem.world._shared import _REACTION_KEY, SLOW
from modalfem.world._tet_contacts import _contacts_of
from modalfem.world.tetgroup import between, pair_owners


class _TetResponse:
    """``World``'s methods that act on the bodies after a tet step (they read the world's build and ``ctx``)."""

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

    def _modal_planes_reaction(self, ctx, t: dict, out) -> None:
        """The static obstacles' impulses on the modal bodies from their rows in a tet step (``_modal_planes``), at
        the end positions ``out.x``, given as the tet reaction is (at the step start, arms at the free end); the
        rows are then dropped from the penalty (its depths and the bodies' displacements kept), so what follows
        sees the tet's own contacts alone (the planes' rows hold no tet vertex)."""
        n0, rows = t.get("modal_planes", (0, []))
        if not rows:
            return
        pen = t["penalty"]
        f = pen.forces(out.x)
        o = n0
        for (b, _), ids, _, N, _, _, w in rows:
            ff, o = f[o:o + len(ids)], o + len(ids)
            on = ff > 0
            if on.any():
                J = -(ff[on] * ctx.dt)[:, None] * N[on]
                self._modal_impulses(ctx, b, ids[on], w[on], J, "", t["modal_ends"].get(b), report=False)
        pen.keep_first(n0, out.x)
        t["modal_planes"] = (n0, [])

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

    def _by_member(self, t: dict, name: str, rows: np.ndarray) -> list:
        """``(body, rows)``: the contact ``rows`` (penalty indices) by the tet body of their first vertex (a group's
        members; else ``name``), bodies without rows left out."""
        if not len(rows):
            return []
        if "members" not in t:
            return [(name, rows)]
        owner = t["solver"].owner[t["penalty"].vid[rows, 0]]
        return [(n, rows[owner == i]) for i, (n, _) in enumerate(t["members"]) if np.any(owner == i)]

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


class _MemberContacts:
    """A group member's contacts with the modal bodies, as ``_tet_restitution`` reads them: their forces [N] and
    normals at the step end, and the energy [J] stored in the contacts of its vertices."""

    def __init__(self, f: np.ndarray, nrm: np.ndarray, stored: float) -> None:
        self.f, self.nrm, self.stored = f, nrm, stored

    def forces(self, x: np.ndarray) -> np.ndarray:
        return self.f

    def penalty_energy(self, x: np.ndarray) -> float:
        return self.stored
