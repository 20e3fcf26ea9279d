"""The modal part of the World's solid contact solve, compiled: contacts between modal bodies and of modal bodies
with static planes (the ground, box walls), found and turned into solve entries without a Python loop per pair
of vertices or per contact (``modalfem.world._solid_kernels``, ``_coherent_kernels``, ``_contact_rows``).

Per step: every body's deformed surface (body axes and world), a body-level broad phase (world boxes grown by the
search radius), then per pair of bodies whose boxes meet the compiled vertex-face search both ways and the
edge-edge search, and one compiled call writing every contact's Jacobian entries. The contacts found are the same
as ``proximity.SurfaceProximity`` / ``EdgeProximity`` find (same distances and selection; the trees are walked in
rest axes with boxes grown by the deformation bound instead of being refitted); both sides of a body-body contact
take the impulse at the same world point when they touch (gap within the margin), so it conserves linear and
angular momentum exactly; a speculative contact farther apart acts at each body's own surface point.
"""

from __future__ import annotations

import numpy as np

from modalfem.collision.bvh import BroadPhaseBVH
from modalfem.world import _coherent_kernels as CK
from modalfem.world import _contact_rows as CR
from modalfem.world import _solid_kernels as SK
from modalfem.world._shared import pack_states
from modalfem.world.proximity import surface_edges

__all__ = ["ModalContacts"]

#: a pair's tree walk keeps the features within its search radius plus this fraction of its margin, and is reused
#: while the bodies move (relative to each other, or in shape) less than what is left of that slack. Small: in a
#: moving pile a walk is due every step or two whatever the slack, and its cost grows fast with the radius
#: (benchmark pile, coherent_pairs per step over 600 steps: slack 0.05 5.3 ms, 0.1 5.0, 0.15 5.3, 0.25 5.6, 0.5 6.3,
#: 0.75 7.5; 1.0 and above were worse still: 1.0 14.0 vs 11.9 ms at 0.5, 4.0 49 ms before the one-pass walk)
SLACK = 0.15


class ModalContacts:
    """Compiled contact search and entries for the modal bodies of a World's solid solve.

    Args:
        bodies: ``{name: runtime.ModalBody}`` of the modal bodies with contact, in the solve's order.
        contacts: ``{name: effects.Contact}`` of those bodies.
        planes: static planes as ``(tag, normal (3,), offset [m])`` with ``normal . x = offset`` on the plane
            (outward unit normal); ``tag`` names the obstacle in the warm-start keys.
        slow: modes with ``omega dt`` above this take no part in the contact (as the Python builder).
    """

    def __init__(self, bodies: dict, contacts: dict, planes: list, *, slow: float) -> None:
        self.names = list(bodies)
        self.index = {n: i for i, n in enumerate(self.names)}  # a body's index in ``names``
        self.bodies = [bodies[n] for n in self.names]
        self.contacts = [contacts[n] for n in self.names]
        self.slow = float(slow)
        self.planes = planes
        self.plane_n = np.array([p[1] for p in planes], dtype=np.float64).reshape(-1, 3)
        self.plane_d = np.array([p[2] for p in planes], dtype=np.float64)
        self.plane_tag = np.array([p[0] for p in planes], dtype=np.int64)
        self.trees, self.etrees, self.edges, self.adj = [], [], [], []
        for b in self.bodies:
            t = BroadPhaseBVH(b.triangles, b.rest)
            t.refit(b.rest, margin=0.0)
            self.trees.append(t)
            e, adj = surface_edges(b.triangles)
            et = BroadPhaseBVH(np.ascontiguousarray(np.column_stack([e[:, 0], e[:, 1], e[:, 1]])), b.rest)
            et.refit(b.rest, margin=0.0)
            self.etrees.append(et)
            self.edges.append(np.ascontiguousarray(e))
            self.adj.append(np.ascontiguousarray(adj))
        nm = np.array([b.mode_count for b in self.bodies], dtype=np.int64)
        self.nm = nm
        self.phi = np.concatenate([np.moveaxis(b._modes3, 0, -1).astype(np.float64).reshape(-1)
                                   for b in self.bodies]) if len(self.bodies) else np.zeros(0)
        sizes = np.array([b._modes3.size for b in self.bodies], dtype=np.int64)
        self.phi_off = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.mask_off = np.concatenate([[0], np.cumsum(nm)[:-1]]).astype(np.int64)
        self.mass = np.array([b.mass for b in self.bodies], dtype=np.float64)
        self._friction = np.array([c.friction for c in self.contacts], dtype=np.float64)
        self._restitution = np.array([c.restitution for c in self.contacts], dtype=np.float64)
        self._iterations = max([c.iterations for c in self.contacts] + [1])
        self.rotations = np.zeros((len(self.bodies), 3, 3))  # the bodies' rotations at the last ``collect``
        self.inertia = np.array([b.inertia for b in self.bodies], dtype=np.float64).reshape(-1, 3, 3)  # body axes
        self._mask_dt = None
        self._voff = np.concatenate([[0], np.cumsum([b.vertex_count for b in self.bodies])]).astype(np.int64)
        self._tris = np.concatenate([b.triangles for b in self.bodies]) if self.bodies else np.zeros((0, 3), int)
        self._toff = np.concatenate([[0], np.cumsum([len(b.triangles) for b in self.bodies])]).astype(np.int64)
        self._edges = np.concatenate(self.edges) if self.bodies else np.zeros((0, 2), int)
        self._eoff = np.concatenate([[0], np.cumsum([len(e) for e in self.edges])]).astype(np.int64)
        self._adj = np.concatenate(self.adj) if self.bodies else np.zeros((0, 2), int)
        self._treelists = _tree_lists(self.trees) + _tree_lists(self.etrees)
        self.mask = np.zeros(int(nm.sum()), dtype=np.int64)
        # temporal coherence of the pair search (``_coherent_kernels.coherent_pairs``): each mode's largest vertex
        # displacement per unit coordinate, the bodies' rest radii, and the cache of every pair's last walk
        self._amp = np.concatenate([np.zeros(0)] + [
            np.sqrt(np.einsum("mvc,mvc->mv", b._modes3, b._modes3, dtype=np.float64)).max(1) for b in self.bodies
            if b.mode_count])
        self._qoff = self.mask_off
        self._radius = np.array([b.radius for b in self.bodies], dtype=np.float64)
        self._rest = np.concatenate([np.zeros((0, 3))] + [np.asarray(b.rest, dtype=np.float64) for b in self.bodies])
        self._marg = np.array([c.margin for c in self.contacts], dtype=np.float64)
        self._inertia_inv = np.array([b.inertia_inv for b in self.bodies], dtype=np.float64).reshape(-1, 3, 3)
        self.walks = 0  # pairs whose trees the last ``collect`` walked (the others reused their last walk)
        self.reset_coherence()

    def reset_coherence(self) -> None:
        """Forget every pair's last tree walk (the next ``collect`` walks every pair whose bodies' boxes meet)."""
        from numba.typed import List

        nb = len(self.bodies)
        self._meta = np.zeros((nb * nb, CK.META))
        self._qsnap = np.zeros((nb * nb, 4, max([int(v) for v in self.nm] + [1])))
        empty = np.zeros(0, dtype=np.int64)
        self._cache = tuple(List([empty] * (nb * nb)) for _ in range(6)) + tuple(
            List([np.zeros(0)] * (nb * nb)) for _ in range(3)) + tuple(
            List([np.zeros((0, 4))] * (nb * nb)) for _ in range(2)) + (List([np.zeros((0, 7))] * (nb * nb)),)

    def velocity_blocks(self, states: dict, g: dict, dt: float, packed: tuple | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Every body's block ``(v + g dt, w, qdot)`` (6 + r) of the solve's velocities, one after another in
        ``names`` order, and (nb,) bounds of its surface points' speed ``|v| + |w| radius + |g| dt + max_i |(Phi
        qdot)_i|`` [m/s] (``states``: ``{name: runtime.State}``; ``g``: ``{name: gravity (3,) [m/s^2]}``; dt [s];
        ``packed``: ``_shared.pack_states(states, names)``, or None)."""
        pos, vel, L, quat, q, qdot = pack_states(states, self.names) if packed is None else packed
        return SK.velocity_blocks(quat, vel, L, qdot, self.mask_off, self.nm,
                                  self._inertia_inv, np.array([g[n] for n in self.names], dtype=np.float64),
                                  self._radius, self.phi, self.phi_off, self._voff, float(dt))

    def _masks(self, dt: float) -> np.ndarray:
        if self._mask_dt != dt:
            self.mask = np.concatenate([(b.omega * dt <= self.slow).astype(np.int64) for b in self.bodies])
            self._mask_dt = dt
        return self.mask

    def collect(self, states: dict, vel_off: dict, speed: dict, dt: float, index: dict, warm,
                packed: tuple | None = None) -> dict | None:
        """This step's modal contacts and their entries.

        Args:
            states: ``{name: runtime.State}`` at the step start. vel_off: ``{name: offset}`` of each body's block in
                the solve's velocity vector. speed: ``{name: bound of a surface point's speed [m/s]}``.
            dt: step [s]. index: ``{name: index of the body in the solve}`` (for ``body`` / ``other``).
            warm: the last step's ``(keys, impulses)`` of these contacts, or None.
            packed: ``_shared.pack_states(states, names)``, or None.

        Returns:
            None without contacts, else the arrays of ``_ContactBuilder.arrays`` (``ptr``, ``off``, ``nd``, ``jptr``,
            ``J``, ``WJt``, ``normal``, ``gap``, ``vobs_n``, ``mu``, ``restitution``, ``margin``, ``body``, ``other``,
            ``point``, ``iterations``) plus ``keys`` (k,) int64 and ``warm`` (k, 3) [N s] start impulses.
        """
        pos, _, _, quat, q, _ = pack_states(states, self.names) if packed is None else packed
        R, Iw_inv, Xl, X, bound, lo, hi = SK.frames(quat, pos, q, self.mask_off,
                                                   self.nm, self.phi, self.phi_off, self._rest, self._voff,
                                                   self._inertia_inv)
        self.rotations = R
        reach = np.array([speed[n] for n in self.names]) * dt
        marg = self._marg
        empty_i, empty_v, empty_n = np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros((0, 3))
        plane = (empty_i, empty_i, empty_i, empty_v)
        vf = (empty_i, empty_i, empty_i, empty_i, empty_n, empty_v, empty_n)
        ee = (empty_i, empty_i, empty_i, empty_i, empty_v, empty_v, empty_v, empty_n)
        # static planes
        voff = self._voff
        if len(self.plane_d):
            plane = SK.plane_contacts(X, voff, pos, self._radius + bound, marg + reach, self.plane_n, self.plane_d)
        # body pairs whose boxes meet within the search radius
        ia, ib, rr, mm = CK.box_pairs(lo, hi, marg, reach)
        self.walks = 0
        if len(ia):
            vf, ee, self.walks = CK.coherent_pairs(
                ia, ib, rr, mm, SLACK * mm, X, Xl, voff, R,
                pos, bound, self._radius, q, self._qoff, self.nm, self._amp, lo, hi,
                self._tris, self._toff, self._edges, self._eoff, self._adj, self._meta, self._qsnap, *self._cache,
                *self._treelists)
        if len(plane[0]) + len(vf[0]) + len(ee[0]) == 0:
            return None
        wk, wl = warm if warm is not None and len(warm[0]) else (empty_i, empty_n)
        (ptr, off, nd, jptr, J, WJt, K, normal, gap, mu, e, margin, body, other, point, keys, lam0, body_a, verts_a,
         w_a, body_b, verts_b, w_b) = CR.assemble(
            *plane, *vf, *ee, X, voff, self._tris, self._toff, self._edges, self._eoff, self.plane_n, marg,
            self._friction, self._restitution, R, Iw_inv, pos, self.mass, self.nm, self.phi_off, self.phi,
            self.mask_off, self._masks(dt), np.array([vel_off[n] for n in self.names], dtype=np.int64),
            np.array([index[n] for n in self.names], dtype=np.int64), wk, wl)
        return {"ptr": ptr, "off": off, "nd": nd, "jptr": jptr, "J": J, "WJt": WJt, "K": K, "normal": normal,
                "gap": gap, "vobs_n": np.zeros(len(gap)), "mu": mu, "restitution": e, "margin": margin, "body": body,
                "other": other, "point": point, "iterations": self._iterations, "keys": keys, "warm": lam0,
                "_modal": (body_a, verts_a, w_a, body_b, verts_b, w_b, R)}

    def modal_change(self, name: str, data: dict, sel: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """The modal velocity change (r,) that the impulses ``lam`` (k, 3) [N s] of contacts ``sel`` (indices into
        ``data``, this object's contacts) give every mode of body ``name`` (what its sound hears)."""
        i = self.names.index(name)
        b = self.bodies[i]
        body_a, verts_a, w_a, body_b, verts_b, w_b, R = data["_modal"]
        dq = np.zeros(b.mode_count)
        for bod, verts, w, sign in ((body_a, verts_a, w_a, 1.0), (body_b, verts_b, w_b, -1.0)):
            s = sel[bod[sel] == i]
            if len(s):
                phi = np.einsum("kj,kjcr->kcr", w[s], b.vertex_shapes(verts[s].reshape(-1)).reshape(len(s), 3, 3, -1))
                dq += sign * np.einsum("ab,kbr,ka->r", R[i], phi, lam[s])
        return dq


def _tree_lists(trees: list) -> tuple:
    """The arrays of rest-surface trees as numba typed lists (P, lo, hi, nonempty, slot_tri, slot lo, slot hi)."""
    from numba.typed import List

    out = []
    for get in (lambda t: t.lo, lambda t: t.hi, lambda t: t.nonempty, lambda t: t.slot_tri, lambda t: t._slo,
                lambda t: t._shi):
        lst = List()
        for t in trees:
            lst.append(np.ascontiguousarray(get(t)))
        out.append(lst)
    return (np.array([t.P for t in trees], dtype=np.int64),) + tuple(out)

