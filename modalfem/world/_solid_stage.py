"""The solid contact stage of ``World`` (a mixin): modal bodies against each other and against moving and mesh
obstacles in one compiled sequential-impulse solve (see ``modalfem.world.world`` and ``modalfem.world._kernels``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from modalfem import effects as fx
from modalfem.world import _kernels
from modalfem.world import _solid_kernels as SK
from modalfem.world._shared import _REACTION_KEY, BOUNCE_THRESHOLD, PUSH_OUT, SLOW, packed_states
from modalfem.world.obstacles import Box, TriangleMesh

if TYPE_CHECKING:
    from modalfem.world.world import World, _StepContext


class _SolidStage:
    """``World``'s solid contact stage methods (they read the world's build: ``_modal``, ``_fast`` ...)."""

    def _stage_contacts(self, ctx) -> None:
        """Modal bodies against each other and against moving and mesh obstacles (a tet body meets modal bodies and
        other tet bodies in its implicit step): one compiled sequential-impulse solve (see the module docstring).
        Modal bodies against each other and static planes are found and written by ``modal_contacts.ModalContacts``
        (compiled); the rest by ``_ContactBuilder``, with a box's edges under a body's faces as contacts of their own
        (``_box_edges``, the runtime's). The part of an impulse that holds the step's load acts at the step's middle
        (``_solve``), so a body at rest holds its place at any dt (tests/world/test_world_resting_dt.py)."""
        dt = ctx.dt
        t0 = ctx.state_in.time
        # the modal bodies with contact, all of them in the compiled modal contacts (``self._fast``, made at build
        # whenever there are any; this stage is planned only then); tet bodies meet them in their implicit step
        names = self._modal_contact
        pos = {}
        fast = self._fast
        lay = self._solid_layout()
        seg = lay["seg"]
        gd = {n: self._modal[n]["g"] for n in fast.names}
        # their velocity blocks (v + g dt, w, qdot), one after another in ``seg``'s order, and speed bounds in one call
        packed = packed_states(ctx, fast.names)  # their start states packed (read here and by the modal batch)
        Vf, sf = fast.velocity_blocks(ctx.state_in.bodies, gd, dt, packed)
        V = Vf.copy()  # the solve's, changed in place
        speed = dict(zip(fast.names, sf.tolist()))
        for name in ctx.dV:  # the reaction of tet bodies' contacts with it (``_tet_reaction``)
            if name in seg:
                o, nd = seg[name]
                V[o:o + nd] += ctx.dV[name]

        def where(name):  # world surface of a modal body at the step start, computed once when needed
            x = pos.get(name)
            if x is None:
                x = pos[name] = self._modal[name]["body"].positions(ctx.state_in.bodies[name], precise=True)
            return x

        builder = _ContactBuilder(self, ctx, seg, names)
        # the bodies a moving obstacle touches: it may do work on them, so their islands are exempt from the no-gain
        # rule (``_solve``); the other islands keep it
        driven = np.zeros(len(names), dtype=bool)
        for name, obs in lay["obstacles"]:  # modal bodies: moving obstacles and meshes (all if shared)
            c = None
            for o, tag in obs:
                if (name, tag) in ctx.tet_obstacles:
                    continue
                if c is None:
                    c = self._one(name, fx.Contact)
                x = where(name)
                reach = c.margin + speed[name] * dt
                if o.moving:
                    reach += float(np.linalg.norm(o.path.velocity(t0, dt))) * dt
                if isinstance(o, TriangleMesh):
                    hits = self._obstacle_surf[tag].query(x, o.vertices + o.offset(t0), reach)
                    idx, gap, nrm = hits.point, hits.gap, hits.normal
                else:
                    gap_all, n_all = o.signed_distance(x, t0)
                    idx = np.flatnonzero(gap_all < reach)
                    gap, nrm = gap_all[idx], np.asarray(n_all)[idx]
                edges = None
                if isinstance(o, Box):  # its edges under the body's faces (``_box_edges``)
                    edges = _box_edges(self._modal[name]["body"], ctx.state_in.bodies[name], o, t0, x, idx, reach,
                                       c.margin)
                    if edges is not None and edges[0] is not None:  # vertex contacts left to the edge contacts
                        idx, gap, nrm = idx[edges[0]], gap[edges[0]], nrm[edges[0]]
                if len(idx):
                    builder.obstacle(name, idx, gap, nrm, np.asarray(o.velocity(x[idx], t0, dt)), c, tag=tag)
                    driven[names.index(name)] |= o.moving
                if edges is not None:
                    _, verts, w, e_nrm, e_gap, key = edges
                    p = np.einsum("ka,kad->kd", w, x[verts])
                    builder.obstacle(name, verts, e_gap, e_nrm, np.asarray(o.velocity(p, t0, dt)), c, tag=tag,
                                     weights=w, keys=[(name, "edge", tag) + tuple(k) for k in key.tolist()])
                    driven[names.index(name)] |= o.moving
        # modal bodies against each other and static planes (None: no such contact)
        fdata = fast.collect(ctx.state_in.bodies, lay["vel_off"], speed, dt, lay["index"],
                             ctx.state_in.contacts.get(_FAST_KEY), packed)
        kp = builder.count
        k = kp + (len(fdata["gap"]) if fdata is not None else 0)
        ctx.report.contacts["solid"] = k
        ctx.contacts = {key: v for key, v in ctx.contacts.items() if key[0] == _REACTION_KEY}
        if k == 0:
            return
        data = _merge(builder.arrays() if kp else None, fdata)
        if kp:  # warm start: the impulses these contacts had in the last step
            old_lam = np.zeros((k, 3))
            for c, key in enumerate(builder.keys):
                old = ctx.state_in.contacts.get(key)
                if old is not None:
                    old_lam[c] = old
            if fdata is not None:
                old_lam[kp:] = fdata["warm"]
        else:
            old_lam = fdata["warm"]
        # a body the tet step moved (a tet body's reaction in ``ctx.dV``) was placed by it: no lift (``_solve``)
        lifted = np.array([name not in ctx.dV for name in fast.names])
        g = np.array([gd[n] for n in fast.names], dtype=float)
        start = (lay["soff"], g * dt)
        lam, bounce, sweeps, lam_n = _solve(V, data, old_lam, dt, self._inverse_mass_blocks(start[1]), lifted,
                                            start, driven=driven)
        ctx.report.sweeps = sweeps
        ctx.contacts.update({key: lam[c] for c, key in enumerate(builder.keys) if lam_n[c] > 0.0})
        if fdata is not None:
            fk = fdata["keys"]
            held = lam_n[kp:] > 0.0
            order = np.argsort(fk[held], kind="stable")
            ctx.contacts[_FAST_KEY] = (fk[held][order], lam[kp:][held][order])
        dV = data["dV"]
        # the part of the solve's dv that holds the step's load acts at the step's middle (``_solve``)
        lifts, has = gravity_lifts(dV[lay["soff"][:, None] + np.arange(3)], g, dt)
        dV0 = dV + 0.0  # (what adding no tet reaction gave each body's block: -0 made +0)
        for name in fast.names:  # ``seg``'s bodies, in its order; taken at the step start by the modal step
            o, nd = seg[name]
            d = ctx.dV.get(name)
            ctx.dV[name] = dV0[o:o + nd] if d is None else dV[o:o + nd] + d
        for i in np.flatnonzero(lifted & has).tolist():
            ctx.lift[fast.names[i]] = lifts[i]
        # what each body received from each other body (the other received the opposite), per pair
        uniq, J, L = _kernels.exchanged(data["body"], data["other"], data["point"], lam, len(names))
        if len(uniq):  # per pair sums in contact order
            for i, kk in enumerate(uniq.tolist()):
                ctx.report.exchanged.append((names[kk // len(names)], names[kk % len(names)], J[i], L[i]))
        for name in self._sounds:  # what sounding bodies hear: the modal kick of the contacts that bounced
            if name in seg:
                i = names.index(name)
                sel = np.flatnonzero(bounce & ((data["body"] == i) | (data["other"] == i)))
                if len(sel):
                    dq = builder.modal_change(name, sel[sel < kp], lam) if np.any(sel < kp) else 0.0
                    if fdata is not None and name in fast.names and np.any(sel >= kp):
                        dq = dq + fast.modal_change(name, fdata, sel[sel >= kp] - kp, lam[kp:])
                    ctx.impacts[name] = dq

    def _solid_layout(self) -> dict:
        """The solve's bodies (``self._fast``'s, in its order), made once: ``seg`` {name: (velocity offset, 6 + r)},
        ``soff`` (m,) int64 offsets, ``size`` (m,) int64 block sizes, ``vel_off`` {name: offset}, ``index``
        {name: index in ``self._modal_contact``}, and ``obstacles`` [(name, [(obstacle, its index in
        ``self.obstacles``)])]: each body's obstacles of ``_world_obstacles`` less the static planes of the compiled
        modal contacts (``_fast_planes``)."""
        lay = self.__dict__.get("_solid_lay")
        if lay is None or lay["fast"] is not self._fast or lay["wo"] is not self._world_obstacles or \
                lay["fp"] is not self._fast_planes:
            fast = self._fast
            size = (6 + np.asarray(fast.nm)).astype(np.int64)
            soff = np.concatenate([[0], np.cumsum(size)[:-1]]).astype(np.int64)
            seg = {n: (int(soff[i]), int(size[i])) for i, n in enumerate(fast.names)}
            lay = self._solid_lay = {"fast": fast, "seg": seg, "soff": soff, "size": size,
                                     "vel_off": {n: seg[n][0] for n in fast.names},
                                     "index": {n: self._modal_contact.index(n) for n in fast.names},
                                     "wo": self._world_obstacles, "fp": self._fast_planes, "obstacles": [
                                         (name, [(o, t) for o, t in ((o, self.obstacles.index(o)) for o in obs)
                                                 if t not in self._fast_planes])
                                         for name, obs in self._world_obstacles.items()]}
        return lay

    def _inverse_mass_blocks(self, gdt: np.ndarray) -> tuple:
        """The bodies of the solve (the compiled modal contacts') as arrays for ``_kernels.modal_energy_change``, to
        measure the energy of velocity changes: offsets, sizes, masses [kg], rotations at the step start, body-axes
        inertias [kg m^2] (modal coordinates have unit mass) and shifts ``g dt`` (3,) [m/s], which the solve's
        velocities hold but the energy must not count: a velocity change dv at the step start moves the body by
        ``dv dt`` in the gravity field, which costs ``-m g . dv dt``, so the energy change is
        ``dv . M (V - g dt) + 0.5 dv . M dv`` (and the part of dv that holds the step's load, acting at the step's
        middle, lowers the body: ``gravity_lift``, counted by ``_solve``). ``gdt``: those shifts (m, 3), in
        ``self._fast``'s order."""
        fast = self._fast
        lay = self._solid_layout()
        return lay["soff"], lay["size"], fast.mass, fast.rotations, fast.inertia, gdt


#: the key of the compiled modal contacts' impulses in ``WorldState.contacts``: (sorted int64 keys, (k, 3) [N s])
_FAST_KEY = "modal contacts"


def _merge(a: dict | None, b: dict | None) -> dict:
    """The solve arrays of the Python builder's contacts followed by the compiled modal contacts'."""
    if a is None or b is None:
        return dict(a if b is None else b)
    out = {key: np.concatenate([a[key], b[key]]) for key in (
        "off", "nd", "normal", "gap", "vobs_n", "mu", "restitution", "margin", "body", "other", "point", "J", "WJt")}
    out["ptr"] = np.concatenate([a["ptr"], b["ptr"][1:] + a["ptr"][-1]])
    out["jptr"] = np.concatenate([a["jptr"], b["jptr"] + len(a["J"])])
    out["iterations"] = max(a["iterations"], b["iterations"])
    return out


def _box_edges(body, s, box: Box, t: float, x: np.ndarray, idx: np.ndarray, reach: float, margin: float):
    """Box-edge contacts of modal body ``body`` (state ``s``, surface ``x`` (nv, 3) [m] at time ``t`` [s]) with
    ``box``, as the runtime's (``runtime.contact._with_edges``): where an edge of the box passes under a body face
    within ``reach`` [m], the clipped ends (``_contact_edge_kernels.edge_contacts``) are body points ``sum_a w_a X_a``
    of the face against the plane through the edge point whose normal is the face's outward normal reversed; one per
    body point, none at a vertex with its own contact with the box (``idx`` (k,): the vertex contacts), and the vertex
    contacts at the box's edge (within ``margin`` [m] of two of its face planes) whose vertex is a corner of such a
    face are left to them.

    Returns None (no edge contact; the search runs only when the body's bounding sphere is within ``reach`` of the
    box), else ``(keep (k,) bool or None, vertices (p, 3), weights (p, 3), normals (p, 3), gaps (p,) [m], keys (p, 3)
    int64)``: ``keep`` the vertex contacts kept (None: all), the keys the body points at rest in 1e-6 of the body's
    radius (what names a contact from step to step)."""
    from modalfem.runtime import _contact_edge_kernels as KE
    from modalfem.runtime.contact import (
        _skip,
        deformation_bound,
        left_to_edges,
        near_box_edge,
        unique_edge_points,
        vertex_modes,
    )
    from modalfem.runtime.obstacles import BOX, PARAMS

    q = s.q
    bound = deformation_bound(body, q)
    if float(box.signed_distance(s.position[None, :], t)[0][0]) > body.radius + bound + reach:
        return None
    params = np.zeros((1, PARAMS))
    params[0, 0:3], params[0, 3:6], params[0, 6:15] = box.center + box.offset(t), box.half, box.rotation.reshape(-1)
    og, verts, w, nrm, gap, _ = KE.edge_contacts(np.array([BOX], dtype=np.int64), params, np.array([reach]),
                                                  np.array([margin]), body.rest, vertex_modes(body), q, _skip(body, q),
                                                  s.rotation(), s.position, bound, body.triangles)
    if len(og) == 0:
        return None
    row = np.zeros(len(idx), dtype=np.int64)
    keep = unique_edge_points(body, og, verts, w, row, idx)
    og, verts, w, nrm, gap = og[keep], verts[keep], w[keep], nrm[keep], gap[keep]
    if len(og) == 0:
        return None
    vkeep = None
    near = near_box_edge(np.repeat(params, len(idx), axis=0), np.full(len(idx), margin), x[idx])
    if near.any():
        drop = np.zeros(len(idx), dtype=bool)
        drop[near] = left_to_edges(og, verts, body.vertex_count, row[near], idx[near])
        vkeep = None if not drop.any() else ~drop
    key = np.round(np.einsum("ka,kad->kd", w, body.rest[verts]) / (1e-6 * body.radius)).astype(np.int64)
    return vkeep, verts, w, nrm, gap, key


#: the solve stops once a sweep changes no contact's velocity by more than this fraction of the velocity that
#: closes its skin (half its margin) in one step
VELOCITY_STOP = 1e-2


def _solve(V: np.ndarray, data: dict, warm: np.ndarray, dt: float, blocks: tuple | None,
           lifted: np.ndarray | None = None, start: tuple | None = None, driven: np.ndarray | None = None):
    """The sequential-impulse solve in place on ``V`` from the warm start ``warm`` (k, 3) [N s] (its normal part, and
    its tangential part clamped to the friction disc: ``_kernels.solve_start``); then no gain: the
    kinetic energy change of the impulses ``dV^T M V0 + 0.5 dV^T M dV`` (summed over the bodies, ``blocks`` as
    ``_SolidStage._inverse_mass_blocks``; None: no energy rule) is made <= 0 per island (``islands``: bodies linked by
    body-body contacts; an obstacle links nothing) by scaling the island's impulses back (equal and opposite impulses
    stay so), so no energy moves between bodies that do not touch (one factor for the whole solve let a body at rest
    gain 1.1e-6 J from a drop elsewhere: tests/world/test_world_islands.py). An island holding a body of ``driven``
    (bool per body of ``blocks``: a moving obstacle touches it, and may do work on it) is exempt; the others keep the
    rule (tests/world/test_world_driven_islands.py). Returns
    ``(lam (k, 3), bounce (k,), sweeps, lam_n (k,))`` and leaves ``data["dV"]``.

    The impulses act at the step start and target the end velocity ``vn`` that closes the gap to the skin (or pushes
    out) in a step, ``gap + vn dt`` (``V`` holds the end-of-step velocities ``v + g dt``). That would leave a body
    held against gravity ``g dt^2 / 2`` above the target: the part of a body's dv against gravity up to ``|g| dt``
    (the step's load) acts at the step's middle instead, like a contact force held over the step (as the runtime's
    sustained step, ``runtime.contact``): the modal step moves the body back by ``dt / 2`` of it (``gravity_lift``),
    so a body at rest ends where it began, holding ``m g dt``, and an impact (more than the load) still ends at its
    target. The energy change is then exact: ``f(s) = s work + s^2 quad / 2 - sum_b m_b |g_b| dt / 2 min(max(s a_b,
    0), |g_b| dt)`` for the impulses scaled by s (``a_b`` body b's dv against gravity; the last term the lift's
    potential energy), 0 at rest; f is convex with f(0) = 0, so when f(1) > 1e-12 quad an island's impulses are scaled
    to the largest s with f(s) <= 0 (``_solid_kernels.no_gain_scales``, compiled: f is piecewise quadratic with a
    break where each body's lift reaches its cap; the piece where f turns positive is found at the sorted breaks and
    its quadratic solved; was a numpy bisection, 60 evaluations per island, 1.6-3 ms per step of the pile of 20).
    ``lifted`` (bodies of ``blocks``, bool; None: all): the bodies that take the lift (not those a tet body's implicit
    step placed this step, whose positions it computed with the reaction at the start: lifted, a bar landing across a
    tet cube and a sphere crossed the cube).

    Restitution acts on the approach at the step start (``start``: per body its velocity offset and ``g dt``, taken
    off ``V``; None: the end-of-step approach), as ``runtime.contact``: the end-of-step approach holds the step's ``g
    dt``, so a resting contact with e > 0 was taken as bouncing once ``g dt`` > ``BOUNCE_THRESHOLD`` (dt > 5 ms) and
    the body sank (e = 0.3: 0.11 m into the ground at dt = 1 s; tests/world/test_world_restitution_dt.py).
    """
    ptr, off, nd, jptr, J, WJt = (data[key] for key in ("ptr", "off", "nd", "jptr", "J", "WJt"))
    K = data.get("K")  # the compiled modal contacts' come with their entries
    if K is None:
        K = _kernels.effective_masses(ptr, off, nd, jptr, J, WJt)
    n = data["normal"]
    if start is None:
        soff, gdt = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    else:  # the approach at the step start (without the step's g dt)
        soff, gdt = start
    # warm start, targets, bounces and the warm impulses applied, in one compiled pass
    lam_n, lam_t, target, bounce, V0, min_skin = _kernels.solve_start(
        V, ptr, off, nd, jptr, J, WJt, n, data["vobs_n"], data["gap"], data["margin"], data["restitution"],
        data["mu"], warm, float(dt), PUSH_OUT, BOUNCE_THRESHOLD, soff, gdt)
    vtol = VELOCITY_STOP * min_skin / dt
    # each island (bodies linked by body-body contacts) stops on its own: an island's result is that of solving it alone
    body, other = np.asarray(data["body"], dtype=np.int64), np.asarray(data["other"], dtype=np.int64)
    island = SK.island_labels(body, other, int(max(body.max(), other.max())) + 1)[body]
    sweeps = _kernels.sequential_impulses(V, ptr, off, nd, jptr, J, WJt, K, n, target, data["mu"],
                                          int(data["iterations"]), lam_n, lam_t, vtol, island)
    lam = lam_n[:, None] * n + lam_t
    dV = V - V0
    if blocks is not None:  # the energy change (see above), per island (``islands``), compiled
        m = len(blocks[0])
        scale = SK.no_gain_scales(dV, V0, body, other, *blocks,
                                  np.ones(m, dtype=bool) if lifted is None else np.asarray(lifted, dtype=bool),
                                  np.zeros(m, dtype=bool) if driven is None else np.asarray(driven, dtype=bool))
        if (scale < 1.0).any():  # some island's impulses would add energy: scale them back
            body_scale = np.repeat(scale, blocks[1])  # per velocity (blocks in order, contiguous)
            dV *= body_scale
            lam *= scale[body][:, None]
            V[:] = V0 + dV
    data["dV"] = dV
    return lam, bounce, sweeps, lam_n


def islands(body: np.ndarray, other: np.ndarray, m: int) -> list:
    """The islands of a solve's contacts (``body``, ``other`` (k,): body indices, ``other`` -1 for an obstacle) among
    ``m`` bodies: the connected components of the graph whose edges are the body-body contacts (an obstacle links
    nothing), as sorted int64 index arrays, in order of their first body; bodies with no contact are left out."""
    label = SK.island_labels(np.asarray(body, dtype=np.int64), np.asarray(other, dtype=np.int64), m)
    return [np.flatnonzero(label == r) for r in np.unique(label[label >= 0])]


def gravity_lift(dv: np.ndarray, g: np.ndarray, dt: float) -> np.ndarray | None:
    """The position change [m] of a modal body at the step start for the part of its solve's velocity change
    ``dv`` (3,) [m/s] that holds the step's load (gravity ``g`` (3,) [m/s^2], step ``dt`` [s]): that part,
    ``min(max(dv . up, 0), |g| dt)`` along ``up = -g / |g|``, acts at the step's middle, so the body moves
    ``-dt / 2`` of it (None: none; see ``_solve``)."""
    gn = float(np.sqrt(g @ g)) * dt
    if gn == 0.0:
        return None
    up = -np.asarray(g) * dt / gn
    c = min(max(float(dv @ up), 0.0), gn)
    return None if c == 0.0 else (-0.5 * dt * c) * up


def gravity_lifts(dv: np.ndarray, g: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``gravity_lift`` of m bodies at once (``dv``, ``g`` (m, 3)): their position changes (m, 3) [m] and (m,) bool,
    whether each has one (``gravity_lift`` not None); compiled (``_kernels.gravity_lifts``)."""
    return _kernels.gravity_lifts(np.ascontiguousarray(dv, dtype=float), np.ascontiguousarray(g, dtype=float),
                                  float(dt))


def apply_lift(lift: dict, name: str, position: np.ndarray) -> None:
    """Adds body ``name``'s lift (``lift``: ``_StepContext.lift``, position changes [m] from ``gravity_lift``) to its
    start ``position`` (3,) [m] in place, if it has one: the one place both modal steps (the batch's and the
    per-body one) take it."""
    d = lift.get(name)
    if d is not None:
        position += d


class _ContactBuilder:
    """Entries of the compiled solve (see ``modalfem.world._kernels``) for modal bodies' surface vertices against
    moving and mesh obstacles (the compiled ``modal_contacts.ModalContacts`` writes the contacts between bodies), built
    a batch of contacts at a time: each contact is one entry of 6 + r velocities of its body, so the arrays are
    assembled with numpy, not per contact."""

    def __init__(self, world: World, ctx: _StepContext, seg: dict, names: list) -> None:
        self.w, self.ctx, self.seg, self.names = world, ctx, seg, names
        self.count = 0
        self.n_entries = 0
        self.jlen = 0
        self.batches = []  # per batch: dict of arrays
        self.keys = []  # per contact: what identifies it from step to step (warm start)
        self.iterations = 1
        self._modal_frames = {}

    def _modal_frame(self, name: str):
        f = self._modal_frames.get(name)
        if f is None:
            m = self.w._modal[name]
            s = self.ctx.state_in.bodies[name]
            R = s.rotation()
            Iw_inv = R @ m["body"].inertia_inv @ R.T
            f = (R, Iw_inv, s)
            self._modal_frames[name] = f
        return f

    def _entries_modal(self, name: str, verts: np.ndarray, w: np.ndarray, sign: float):
        """(k,) entries for points sum_j w_j vertex_j of a modal body: J (k, 3, 6 + r), WJt (k, 6 + r, 3), r (k, 3),
        sign R Phi (k, 3, r)."""
        body = self.w._modal[name]["body"]
        R, Iw_inv, s = self._modal_frame(name)
        phi = np.einsum("kj,kjcr->kcr", w, body.vertex_shapes(verts.reshape(-1)).reshape(verts.shape + (3, -1)))
        rest = np.einsum("kj,kjc->kc", w, body.rest[verts])
        r = (rest + np.einsum("kcr,r->kc", phi, s.q)) @ R.T
        k, nm = len(r), body.mode_count
        J = np.zeros((k, 3, 6 + nm))
        J[:, :, 0:3] = np.eye(3)
        S = np.zeros((k, 3, 3))
        S[:, 0, 1], S[:, 0, 2] = -r[:, 2], r[:, 1]
        S[:, 1, 0], S[:, 1, 2] = r[:, 2], -r[:, 0]
        S[:, 2, 0], S[:, 2, 1] = -r[:, 1], r[:, 0]
        J[:, :, 3:6] = -S
        Rphi = np.einsum("ab,kbr->kar", R, phi)
        # modes the step resolves (omega dt <= SLOW) join the contact; faster ones would swing back within the
        # step, so a velocity-level contact cannot predict them: they take no part (the sound still hears
        # them: ``modal_change``)
        J[:, :, 6:] = Rphi * (body.omega * self.ctx.dt <= SLOW)
        WJt = np.transpose(J, (0, 2, 1)).copy()
        WJt[:, 0:3, :] /= body.mass
        WJt[:, 3:6, :] = np.einsum("ab,kbc->kac", Iw_inv, S)  # Iw^-1 (-[r]x)^T = Iw^-1 [r]x
        return sign * J, sign * WJt, r + s.position, sign * Rphi

    def obstacle(self, name, idx, gap, nrm, vobs, contact, tag: int = 0, *, weights=None, keys=None) -> None:
        """Contacts of modal body ``name``'s surface vertices ``idx`` (k,) with obstacle ``tag``: gaps (k,) [m],
        normals (k, 3) out of the obstacle, the obstacle's velocities there (k, 3) [m/s], its ``Contact`` effect.
        With ``weights`` (k, m), ``idx`` (k, m) are the vertices of body points ``sum_a w_a X_a`` (box-edge contacts:
        their rows the weighted sums of the vertices'), and ``keys`` name them from step to step (warm start)."""
        k = len(gap)
        if k == 0:
            return
        o0, _ = self.seg[name]
        if weights is None:
            J, WJt, p, full = self._entries_modal(name, idx[:, None], np.ones((k, 1)), 1.0)
        else:
            J, WJt, p, full = self._entries_modal(name, idx, weights, 1.0)
        nd = J.shape[2]
        nrm = np.asarray(nrm, dtype=float)
        per = 3 * nd  # J data per contact
        self.batches.append({
            "ptr": self.n_entries + np.arange(1, k + 1), "off": np.full(k, o0, dtype=np.int64),
            "nd": np.full(k, nd), "jptr": self.jlen + per * np.arange(k),
            "J": J.reshape(-1), "WJt": WJt.reshape(-1), "normal": nrm.reshape(k, 3),
            "gap": np.asarray(gap, dtype=float), "vobs_n": np.einsum("ij,ij->i", vobs, nrm),
            "mu": np.full(k, contact.friction), "restitution": np.full(k, contact.restitution),
            "margin": np.full(k, contact.margin), "body": np.full(k, self.names.index(name)), "other": np.full(k, -1),
            "point": p, "full": full, "name": name, "first": self.count})
        self.n_entries += k
        self.jlen += per * k
        self.count += k
        self.iterations = max(self.iterations, contact.iterations)
        self.keys.extend(keys if keys is not None else ((name, "obstacle", tag, int(i)) for i in idx))

    def arrays(self) -> dict:
        cat = {key: np.concatenate([bt[key] for bt in self.batches]) for key in (
            "ptr", "off", "nd", "jptr", "J", "WJt", "normal", "gap", "vobs_n", "mu", "restitution", "margin", "body",
            "other", "point")}
        cat["ptr"] = np.concatenate([[0], cat["ptr"]]).astype(np.int64)
        for key in ("off", "nd", "jptr"):
            cat[key] = cat[key].astype(np.int64)
        cat["normal"] = np.ascontiguousarray(cat["normal"])
        cat["iterations"] = self.iterations
        cat["keys"] = self.keys
        return cat

    def modal_change(self, name: str, sel: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """The modal velocity change (r,) the impulses of contacts ``sel`` give every mode of modal body ``name``
        (what its sound hears)."""
        dq = None
        chosen = {int(c) for c in sel}
        for bt in self.batches:
            if bt["name"] != name:
                continue
            rows = [c - bt["first"] for c in range(bt["first"], bt["first"] + len(bt["gap"])) if c in chosen]
            if rows:
                add = np.einsum("kcr,kc->r", bt["full"][rows], lam[np.asarray(rows) + bt["first"]])
                dq = add if dq is None else dq + add
        return dq if dq is not None else np.zeros(self.w._modal[name]["body"].mode_count)
