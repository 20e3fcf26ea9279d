"""Contact between modal bodies (and with static obstacles) in one compiled sequential-impulse solve.

``ContactGroup(solvers, obstacles=...)`` holds several modal bodies (one ``ModalSolver`` each) and
``step(states, dt)`` advances all their ``State``s together by dt [s]:

1. loads: each solver's load effects (gravity, wind, ...) held over the step, as in ``ModalSolver.step``;
2. free motion of every body over the first half step (``ModalSolver.advance_free``: exact modes, exact
   centre of mass);
3. contacts at mid-step: surface vertices within ``margin`` + what the body can travel in dt of an
   obstacle (the compiled candidates of ``runtime.contact``), and for every pair of bodies whose
   bounding spheres come that close, the vertices of each body against the deformed surface triangles of
   the other (the collision module's BVH, ``collision.bvh.BroadPhaseBVH``, refitted to the deformed world
   triangles, and its compiled point-triangle distances): the closest point, the gap [m] (negative inside,
   by the side of the closest triangle; on a shared edge or corner outside if one of the tied triangles
   says so) and the normal pointing out of the other body;
4. one solve over all contacts of the group (``_contact_kernels.solve``, matrix-free, O(6 + r) per
   contact and sweep), the impulse acting at mid-step like a force held over the step (the runtime's
   sustained solve): the velocities seen are the end-of-step ones and a contact ``gap`` apart may close
   it by the step's end (**speculative contacts**, Catto: nothing tunnels, nothing stops early); a contact
   touching (``gap <= |vn| dt / 2``) and approaching faster than ``bounce_threshold`` bounces with
   restitution e (of its mid-step approach speed); Coulomb friction on the disc ``mu lambda_n``. A
   body-body impulse acts on both bodies at the same world point (the touching vertex), with equal and
   opposite signs, on their rigid and modal velocities (side b's modal velocity is that of the closest
   point on its triangle): every body-body impulse conserves linear and angular momentum exactly, to
   rounding;
5. no solve adds energy: the kinetic + modal energy change of the impulses, ``dV^T W^-1 V + 0.5 dV^T W^-1
   dV`` summed over the group, is made <= 0 by scaling the impulses back when an unconverged or frictional
   solve would add some (scaling keeps every impulse equal and opposite);
6. free motion over the second half step;
7. position correction without velocity change: the two bodies of a pair with a vertex more than
   ``tolerance`` [m] (and at most 2 ``margin``) inside the other are translated apart along the contact
   normal, each by its share ``m_other / (m_a + m_b)`` (the pair's centre of mass does not move, so
   neither the linear momentum nor the gravitational energy changes; the angular momentum about the
   origin changes by ``d x mu (v_a - v_b)``, d the shift: reported in ``GroupReport.separated``); a vertex
   inside an obstacle is pushed out as in ``contact.push_out``.

Why speculative contacts and not the single-body event machinery (impacts at their predicted time,
sustained sub-steps, friction stops): splitting the step at every impact of every body would serialise the
whole group on its earliest event (20 bodies in a pile have several events per step), and the energy guard
would redo the whole group's step; the speculative solve has one solve per step whatever happens, at the
cost of restitution being applied to the mid-step approach speed (off by up to the relative load's
a dt / 2) and of a vertex ending at most the (unconverged, rotating, deforming) remainder inside, which the
position correction removes beyond ``tolerance``.

Contract for a caller (the World): ``step(states, dt)`` changes the given states in place (all-or-nothing:
on an error every state is restored); it returns a ``GroupReport`` with the contacts and the impulses
exchanged between bodies in this step. Control inputs are not taken here: apply impulses to the states
before the call (``ModalSolver.apply_impulse``). Surfaces are the bodies' vertices and triangles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from modalfem.errors import InputError, SimulationError
from modalfem.runtime.integrator import check_dt
from modalfem.runtime.state import restore, snapshot

__all__ = ["ContactGroup", "GroupReport", "step_group"]


@dataclass
class GroupReport:
    """What one ``ContactGroup.step`` did.

    Attributes:
        contacts: number of contacts in the solve (obstacle + body-body).
        pair_contacts: number of body-body contacts.
        exchanged: list of ``(a, b, J, L)``: body indices a < b, the total impulse J (3,) [N s] body a received
            from body b in this step (b received -J) and its moment about the world origin L (3,) [N m s].
        obstacle_impulse: (bodies, 3) total impulses [N s] from the obstacles.
        separated: list of (a, b, depth [m]) pairs translated apart by the position correction.
    """

    contacts: int = 0
    pair_contacts: int = 0
    exchanged: list = field(default_factory=list)
    obstacle_impulse: np.ndarray | None = None
    separated: list = field(default_factory=list)


class ContactGroup:
    """Several modal bodies in contact with each other and with static obstacles.

    Args:
        solvers: one ``ModalSolver`` per body (its load effects are applied by ``step``; its own
            ``Obstacles`` effects are not used here: give the group's obstacles below).
        obstacles: an ``Obstacles`` effect (planes, ground, spheres, boxes) touched by every body, or None.
        restitution: e in [0, 1] of body-body impacts.
        friction: Coulomb coefficient >= 0 of body-body contacts.
        margin: contacts are gathered within this distance [m] (plus what the bodies travel in dt).
        iterations: sweeps of the solve.
        bounce_threshold: body-body impacts slower than this [m/s] do not bounce.
        modal: include the modes in the contact response (impacts ring the bodies).
        tolerance: vertices deeper than this [m] inside another body are separated by the position
            correction (default: margin / 10).

    Raises:
        InputError: no solvers, a bad coefficient.
    """

    def __init__(self, solvers, *, obstacles=None, restitution: float = 0.3, friction: float = 0.5,
                 margin: float = 1e-3, iterations: int = 10, bounce_threshold: float = 0.05, modal: bool = True,
                 tolerance: float | None = None) -> None:
        self.solvers = list(solvers)
        if not self.solvers:
            raise InputError("ContactGroup needs at least one ModalSolver")
        if not 0.0 <= restitution <= 1.0:
            raise InputError(f"restitution must be in [0, 1], got {restitution!r}")
        if not (np.isfinite(friction) and friction >= 0.0):
            raise InputError(f"friction must be finite and >= 0, got {friction!r}")
        if not (np.isfinite(margin) and margin > 0.0):
            raise InputError(f"margin must be finite and > 0 [m], got {margin!r}")
        if int(iterations) < 1:
            raise InputError(f"iterations must be >= 1, got {iterations!r}")
        if obstacles is not None and not hasattr(obstacles, "kinds"):
            raise InputError("obstacles must be an Obstacles effect (rt.Obstacles([...])) or None")
        self.obstacles = obstacles
        self.restitution, self.friction = float(restitution), float(friction)
        self.margin, self.iterations = float(margin), int(iterations)
        self.bounce_threshold, self.modal = float(bounce_threshold), bool(modal)
        self.tolerance = 0.1 * self.margin if tolerance is None else float(tolerance)
        self._bvh = [None] * len(self.solvers)
        sizes = [6 + (s.body.mode_count if self.modal else 0) for s in self.solvers]
        self._msz = np.array(sizes, dtype=np.int64)
        self._off = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self._M = max(sizes)

    # ------------------------------------------------------------------ helpers
    def _tree(self, i: int):
        if self._bvh[i] is None:
            from modalfem.collision.bvh import BroadPhaseBVH

            body = self.solvers[i].body
            self._bvh[i] = BroadPhaseBVH(body.triangles, body.rest, leaf_size=8)
        return self._bvh[i]

    def _loads(self, solver, state, h):
        from modalfem.runtime.solver import Loads

        if not solver._load_effects:
            return None
        loads = Loads(solver.body.mode_count)
        for e in solver._load_effects:
            if not getattr(e, "state_dependent", False):
                e.loads(solver, state, h, loads)
        return loads

    # ------------------------------------------------------------------ step
    def step(self, states, dt: float) -> GroupReport:
        """Advance every state by dt [s] in place with contact (see the module docstring).

        Args:
            states: one ``State`` per solver, in the same order.
            dt: step [s], finite and > 0.

        Returns:
            ``GroupReport``.

        Raises:
            SimulationError: dt not finite or <= 0, the wrong number of states, or a state that became
                non-finite (every state is then restored).
        """
        h = check_dt(dt)
        states = list(states)
        if len(states) != len(self.solvers):
            raise SimulationError(f"step needs {len(self.solvers)} states (one per solver), got {len(states)}")
        saved = [snapshot(s) for s in states]
        try:
            report = self._step(states, h)
            for s in states:
                s.check_finite()
        except BaseException:
            for s, sv in zip(states, saved):
                restore(s, sv)
            raise
        return report

    def _step(self, states, h: float) -> GroupReport:
        from modalfem.runtime import _contact_kernels as K
        from modalfem.runtime.contact import (
            Contacts,
            deformation_bound,
            local_positions,
            push_out,
        )

        nb = len(self.solvers)
        bodies = [s.body for s in self.solvers]
        loads = [self._loads(sv, st, h) for sv, st in zip(self.solvers, states)]
        accel = [np.zeros(3) if ld is None else ld.force / b.mass for ld, b in zip(loads, bodies)]
        for sv, st, ld in zip(self.solvers, states, loads):  # free first half
            sv.advance_free(st, ld, 0.5 * h)
        R = [st.rotation() for st in states]
        Iw_inv = [r @ b.inertia_inv @ r.T for r, b in zip(R, bodies)]
        speed = np.array([float(np.linalg.norm(st.velocity)) + float(np.linalg.norm(w @ st.angular_momentum)) * b.radius
                          for st, w, b in zip(states, Iw_inv, bodies)]) + np.array([np.linalg.norm(a) for a in accel]) * h
        reach = self.margin + 2.0 * speed * h
        report = GroupReport(obstacle_impulse=np.zeros((nb, 3)))
        # ---- contact lists: (side a body, vertex, side b body or -1, triangle, bary, normal, gap, point)
        parts = []
        if self.obstacles is not None:
            ob = self.obstacles
            for i, (b, st) in enumerate(zip(bodies, states)):
                vs, og = K.candidates(ob.kinds, ob.params, b.rest, R[i], st.position, deformation_bound(b, st.q),
                                      np.full(len(ob.kinds), reach[i]))
                if not len(vs):
                    continue
                x = K.world_positions(local_positions(b, st.q, vs), R[i], st.position)
                gap, nrm = K.gaps_of(x, og, ob.kinds, ob.params)
                sel = gap < reach[i]
                if sel.any():
                    k = int(sel.sum())
                    parts.append((np.full(k, i), vs[sel], np.full(k, -1), np.full(k, -1), np.zeros((k, 3)), nrm[sel],
                                  gap[sel], x[sel]))
        world: dict = {}
        centre = np.array([st.position for st in states])
        radius = np.array([b.radius for b in bodies]) + np.array([deformation_bound(b, st.q) for b, st in zip(bodies, states)])
        dist = np.linalg.norm(centre[:, None, :] - centre[None, :, :], axis=2)
        ia, ib = np.nonzero(np.triu(dist < radius[:, None] + radius[None, :] + reach[:, None] + reach[None, :], 1))
        close = []
        if len(ia):  # bounding spheres overlap: compare the deformed surfaces' boxes
            for i in sorted(set(ia.tolist()) | set(ib.tolist())):
                b, st = bodies[i], states[i]
                world[i] = K.world_positions(local_positions(b, st.q, np.arange(b.vertex_count)), R[i], st.position)
            box = {i: (x.min(axis=0), x.max(axis=0)) for i, x in world.items()}
            for a, b in zip(ia.tolist(), ib.tolist()):
                r = reach[a] + reach[b]
                if np.all(box[a][0] - r <= box[b][1]) and np.all(box[b][0] - r <= box[a][1]):
                    close.append((a, b))
            for i in sorted({i for p in close for i in p}):
                self._tree(i).refit_boxes(world[i])
            for a, b in close:
                for va, vb in ((a, b), (b, a)):
                    part = self._pair_contacts(va, vb, world, box, reach)
                    if part is not None:
                        parts.append(part)
        k = sum(len(p[0]) for p in parts)
        report.contacts = k
        if k:
            self._solve(states, bodies, R, Iw_inv, accel, parts, h, report)
        # ---- free second half
        for sv, st, ld in zip(self.solvers, states, loads):
            sv.advance_free(st, ld, 0.5 * h)
        # ---- position correction: out of the obstacles first, then pairs apart (bodies on an obstacle stay)
        grounded = np.zeros(nb, dtype=bool)
        if self.obstacles is not None:
            ob = self.obstacles
            dummy = Contacts(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64),
                             [ob])
            for i, (sv, st, a) in enumerate(zip(self.solvers, states, accel)):
                push_out(sv, st, dummy, accel=a)
                if parts:
                    vs, _ = K.candidates(ob.kinds, ob.params, bodies[i].rest, st.rotation(), st.position,
                                         deformation_bound(bodies[i], st.q), np.full(len(ob.kinds), self.margin))
                    grounded[i] = len(vs) > 0
        touching = sorted({(int(min(p[0][0], p[2][0])), int(max(p[0][0], p[2][0]))) for p in parts if p[2][0] >= 0})
        if touching:
            self._separate(states, bodies, touching, report, grounded, accel)
        for st in states:
            st.time += h
        return report

    def _pair_contacts(self, a: int, b: int, world, box, reach):
        """Vertices of body a near the deformed surface of body b (within ``margin`` + both bodies' travel
        [m]; ``box`` the bodies' world boxes): (ba, vertex, bb, triangle, bary, normal, gap, point) or None.
        The normal points out of b (towards a)."""
        from modalfem.runtime import _pair_kernels as PK

        r = float(reach[a] + reach[b] - self.margin)
        t = self._tree(b)
        vertex, tri, bary, nrm, gap, point = PK.pair_contacts(
            world[a], np.asarray(box[b][0], dtype=np.float64), np.asarray(box[b][1], dtype=np.float64), r, t.P, t.lo,
            t.hi, t.nonempty, t.slot_tri, t._slo, t._shi, world[b], self.solvers[b].body.triangles, 1e-9)
        k = len(vertex)
        if not k:
            return None
        return (np.full(k, a), vertex, np.full(k, b), tri, bary, nrm, gap, point)

    def _solve(self, states, bodies, R, Iw_inv, accel, parts, h, report) -> None:
        from modalfem.runtime import _contact_kernels as K
        from modalfem.runtime.contact import vertex_modes

        ba, vert, bb, tri, bary, n, gap, point = (np.concatenate([p[i] for p in parts]) for i in range(8))
        n = np.ascontiguousarray(n)
        k = len(ba)
        M = self._M
        J = np.zeros((k, 3, M))
        WJ = np.zeros((k, 3, M))
        Jb = np.zeros((k, 3, M))
        WJb = np.zeros((k, 3, M))
        modal = np.full(k, self.modal)
        for i, (b, st) in enumerate(zip(bodies, states)):
            sel = np.flatnonzero(ba == i)
            if len(sel):  # side a: the vertex itself
                loc = (point[sel] - st.position) @ R[i]  # body axes, from the centre of mass
                K.rows(vert[sel], loc, modal[sel], vertex_modes(b), R[i], b.mass, Iw_inv[i], int(self._msz[i]), J, WJ, sel)
            sel = np.flatnonzero(bb == i)
            if len(sel):  # side b: rigid at the same world point, modal at the closest point of its triangle
                loc = (point[sel] - st.position) @ R[i]
                corners = b.triangles[tri[sel]]
                K.rows(corners[:, 0], loc, np.zeros(len(sel), dtype=bool), vertex_modes(b), R[i], b.mass, Iw_inv[i],
                       int(self._msz[i]), Jb, WJb, sel)
                if self._msz[i] > 6:
                    phi = np.einsum("kc,rkcd->krd", bary[sel], b._modes3[:, corners, :].astype(np.float64))
                    Jb[sel, :, 6:self._msz[i]] = np.einsum("ab,krb->kar", R[i], phi)
                    WJb[sel, :, 6:self._msz[i]] = Jb[sel, :, 6:self._msz[i]]
        V = np.concatenate([np.concatenate([st.velocity, Iw_inv[i] @ st.angular_momentum, st.qdot[:self._msz[i] - 6]])
                            for i, st in enumerate(states)])
        acc = np.array(accel)
        arel = acc[ba] - np.where((bb >= 0)[:, None], acc[np.maximum(bb, 0)], 0.0)
        shift = np.ascontiguousarray(0.5 * h * arel)  # the solve sees the end-of-step velocities
        an = np.einsum("ij,ij->i", n, arel)
        off, msz = self._off, self._msz
        u0 = K.contact_velocities(ba, bb, J, Jb, V, off, msz)  # mid-step velocities now
        vn0 = np.einsum("ij,ij->i", n, u0)
        # end gap gap + (h/2) u_end_n - a_n h^2 / 8 >= 0 (as the runtime's sustained solve)
        target = 0.25 * h * an - 2.0 * gap / h
        obstacle = bb < 0
        e = np.full(k, self.restitution)
        mu = np.full(k, self.friction)
        thr = np.full(k, self.bounce_threshold)
        if self.obstacles is not None:
            e[obstacle], mu[obstacle] = self.obstacles.restitution, self.obstacles.friction
            thr[obstacle] = self.obstacles.bounce_threshold
        touching = gap <= -0.5 * vn0 * h
        bounce = touching & (vn0 < -thr) & (e > 0)
        target = np.where(bounce, np.maximum(target, -e * vn0), target)
        V0 = V.copy()
        lam = np.zeros((k, 3))
        jt = np.zeros((k, 3))
        lam_n = np.zeros(k)
        K.solve(ba, bb, J, WJ, Jb, WJb, V, off, msz, n, np.ascontiguousarray(target), mu, shift,
                self.iterations, lam, jt, lam_n, True)
        # energy of the impulses, summed over the bodies (W^-1 V = (m v, L, qdot) per body)
        dV = V - V0
        work = quad = 0.0
        for i, (b, st) in enumerate(zip(bodies, states)):
            o, m = off[i], msz[i]
            dv, dw, dq = dV[o:o + 3], dV[o + 3:o + 6], dV[o + 6:o + m]
            Iw = R[i] @ b.inertia @ R[i].T
            work += b.mass * float(dv @ V0[o:o + 3]) + float(dw @ st.angular_momentum) + float(dq @ V0[o + 6:o + m])
            quad += b.mass * float(dv @ dv) + float(dw @ (Iw @ dw)) + float(dq @ dq)
        scale = 1.0
        if work + 0.5 * quad > 1e-12 * quad:
            scale = min(1.0, -2.0 * (1.0 - 1e-9) * work / quad) if work < 0.0 and quad > 0.0 else 0.0
            dV *= scale
            lam *= scale
        for i, (b, st) in enumerate(zip(bodies, states)):
            o, m = off[i], msz[i]
            st.velocity += dV[o:o + 3]
            st.angular_momentum += R[i] @ (b.inertia @ (R[i].T @ dV[o + 3:o + 6]))
            if m > 6:
                st.qdot[:m - 6] += dV[o + 6:o + m]
        report.pair_contacts = int((bb >= 0).sum())
        if report.pair_contacts:
            pairs = bb >= 0
            lo, hi = np.minimum(ba, bb)[pairs], np.maximum(ba, bb)[pairs]
            sgn = np.where(ba[pairs] == lo, 1.0, -1.0)[:, None]
            Jl = sgn * lam[pairs]
            Ll = np.cross(point[pairs], Jl)
            key = lo * len(bodies) + hi
            for kk in np.unique(key):
                s = key == kk
                report.exchanged.append((int(kk // len(bodies)), int(kk % len(bodies)), Jl[s].sum(axis=0),
                                         Ll[s].sum(axis=0)))
        if obstacle.any():
            np.add.at(report.obstacle_impulse, ba[obstacle], lam[obstacle])

    @staticmethod
    def _pay_lift(st, body, accel, d) -> None:
        """Take the potential energy gained by moving ``st`` by d [m] in the load field from its kinetic energy."""
        gain = _lift_cost(body, accel, d)
        if gain <= 0.0:
            return
        kinetic = body.kinetic_energy_rigid(st) + 0.5 * float(st.qdot @ st.qdot)
        scale = float(np.sqrt(max(0.0, 1.0 - gain / kinetic))) if kinetic > 0.0 else 0.0
        st.velocity *= scale
        st.angular_momentum *= scale
        st.qdot *= scale

    def _separate(self, states, bodies, pairs, report, grounded, accel, passes: int = 2) -> None:
        """Translate pairs with a vertex deeper than ``tolerance`` inside the other apart (see the module
        docstring). A body touching an obstacle (``grounded``) is not moved when the other one is free: the
        free one moves the whole way; the potential energy this lift adds in the load field is taken from
        the kinetic energy of the lifted body (as ``contact.push_out`` does). A body moved in a pass is
        checked against its other partners in the next pass."""
        from modalfem.runtime import _contact_kernels as K
        from modalfem.runtime.contact import local_positions

        todo = list(pairs)
        for _ in range(passes):
            world, box, moved = {}, {}, set()
            for i in sorted({i for p in todo for i in p}):
                st = states[i]
                world[i] = K.world_positions(local_positions(bodies[i], st.q, np.arange(bodies[i].vertex_count)),
                                             st.rotation(), st.position)
                box[i] = (world[i].min(axis=0), world[i].max(axis=0))
                self._tree(i).refit_boxes(world[i])
            reach = np.full(len(bodies), 1.5 * self.margin)  # query half-size 2 margin: deeper vertices not judged
            again = []
            for a, b in todo:
                if a in moved or b in moved:
                    again.append((a, b))
                    continue
                depth, normal = 0.0, None
                for va, vb, sgn in ((a, b, 1.0), (b, a, -1.0)):
                    part = self._pair_contacts(va, vb, world, box, reach)
                    if part is None:
                        continue
                    gap, nrm = part[6], part[5]
                    j = int(np.argmin(gap))
                    if -gap[j] > depth:
                        depth, normal = -gap[j], sgn * nrm[j]
                if normal is None or depth <= self.tolerance:
                    continue
                ma, mb = bodies[a].mass, bodies[b].mass
                shift = (depth - 0.5 * self.tolerance) * normal
                wa = 0.0 if grounded[a] and not grounded[b] else (1.0 if grounded[b] and not grounded[a]
                                                                   else mb / (ma + mb))
                for i, d in ((a, wa * shift), (b, -(1.0 - wa) * shift)):
                    states[i].position += d
                    if grounded[a] != grounded[b]:  # the pair's centre of mass moves: pay its lift
                        self._pay_lift(states[i], bodies[i], accel[i], d)
                report.separated.append((a, b, float(depth)))
                moved |= {a, b}
                again.append((a, b))
            todo = again
            if not moved:
                break


def _lift_cost(body, accel, d) -> float:
    return -body.mass * float(np.asarray(accel) @ d)


def step_group(solvers, states, dt: float, **options) -> GroupReport:
    """One-shot ``ContactGroup(solvers, **options).step(states, dt)`` (builds the BVHs every call: for a
    simulation keep one ``ContactGroup``)."""
    return ContactGroup(solvers, **options).step(states, dt)

