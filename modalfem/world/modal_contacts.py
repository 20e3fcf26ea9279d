"""The modal part of the World's solid contact solve, compiled: contacts between modal bodies and of modal bodies
with static planes (the ground, box walls), found and turned into solve entries without a Python loop per pair
of vertices or per contact (``modalfem.world._solid_kernels``).

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
from modalfem.world import _solid_kernels as SK
from modalfem.world.proximity import surface_edges

__all__ = ["ModalContacts"]

#: contact kinds in the warm-start keys
_VF, _EE, _PLANE = 0, 1, 2
_FEATURES = 1 << 40  # feature indices (a vertex; an edge pair, mine * (other body's edge count) + other) below this
#: a pair's tree walk keeps the features within its search radius plus this fraction of its margin, and is reused
#: while the bodies move (relative to each other, or in shape) less than what is left of that slack
SLACK = 0.5


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
            List([np.zeros(0)] * (nb * nb)) for _ in range(3))

    def velocity_blocks(self, states: dict, g: dict, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Every body's block ``(v + g dt, w, qdot)`` (6 + r) of the solve's velocities, one after another in
        ``names`` order, and (nb,) bounds of its surface points' speed ``|v| + |w| radius + |g| dt + max_i |(Phi
        qdot)_i|`` [m/s] (``states``: ``{name: runtime.State}``; ``g``: ``{name: gravity (3,) [m/s^2]}``; dt [s])."""
        sts = [states[n] for n in self.names]
        return SK.velocity_blocks(np.array([s.orientation for s in sts]), np.array([s.velocity for s in sts]),
                                  np.array([s.angular_momentum for s in sts]),
                                  np.concatenate([np.zeros(0)] + [s.qdot for s in sts]), self.mask_off, self.nm,
                                  self._inertia_inv, np.array([g[n] for n in self.names], dtype=np.float64),
                                  self._radius, self.phi, self.phi_off, self._voff, float(dt))

    def _masks(self, dt: float) -> np.ndarray:
        if self._mask_dt != dt:
            self.mask = np.concatenate([(b.omega * dt <= self.slow).astype(np.int64) for b in self.bodies])
            self._mask_dt = dt
        return self.mask

    def collect(self, states: dict, vel_off: dict, speed: dict, dt: float, index: dict, warm) -> dict | None:
        """This step's modal contacts and their entries.

        Args:
            states: ``{name: runtime.State}`` at the step start. vel_off: ``{name: offset}`` of each body's block in
                the solve's velocity vector. speed: ``{name: bound of a surface point's speed [m/s]}``.
            dt: step [s]. index: ``{name: index of the body in the solve}`` (for ``body`` / ``other``).
            warm: the last step's ``(keys, impulses)`` of these contacts, or None.

        Returns:
            None without contacts, else the arrays of ``_ContactBuilder.arrays`` (``ptr``, ``off``, ``nd``, ``jptr``,
            ``J``, ``WJt``, ``normal``, ``gap``, ``vobs_n``, ``mu``, ``restitution``, ``margin``, ``body``, ``other``,
            ``point``, ``iterations``) plus ``keys`` (k,) int64 and ``warm`` (k, 3) [N s] start impulses.
        """
        nb = len(self.bodies)
        sts = [states[n] for n in self.names]
        q = np.concatenate([np.zeros(0)] + [s.q for s in sts])
        pos = np.array([s.position for s in sts])
        R, Iw_inv, Xl, X, bound, lo, hi = SK.frames(np.array([s.orientation for s in sts]), pos, q, self.mask_off,
                                                   self.nm, self.phi, self.phi_off, self._rest, self._voff,
                                                   self._inertia_inv)
        reach = np.array([speed[n] for n in self.names]) * dt
        marg = self._marg
        parts = []  # (body_a, verts_a, w_a, body_b, verts_b, w_b, point, normal, gap, kind, feature, other)
        # static planes
        voff = self._voff
        if len(self.plane_d):
            ba, v, p, g = SK.plane_contacts(X, voff, pos, self._radius + bound, marg + reach, self.plane_n, self.plane_d)
            if len(ba):
                k = len(ba)
                va, wa = _one_vertex(v)
                parts.append((ba, va, wa, np.full(k, -1), np.zeros((k, 3), dtype=np.int64), np.zeros((k, 3)),
                              X[voff[ba] + v], self.plane_n[p], g, np.full(k, _PLANE), v, nb + p))
        # body pairs whose boxes meet within the search radius
        mm = np.maximum(marg[:, None], marg[None, :])
        rr = mm + reach[:, None] + reach[None, :]
        meet = np.all((lo[:, None, :] - rr[:, :, None] <= hi[None, :, :])
                      & (lo[None, :, :] - rr[:, :, None] <= hi[:, None, :]), axis=2)
        ia, ib = np.nonzero(np.triu(meet, 1))
        self.walks = 0
        if len(ia):
            (pa, qa, v, tri, wb, g, nrm), (a, b, mine, other, s, tt, ge, ne), self.walks = CK.coherent_pairs(
                ia.astype(np.int64), ib.astype(np.int64), rr[ia, ib], mm[ia, ib], SLACK * mm[ia, ib], X, Xl, voff, R,
                pos, bound, self._radius, q, self._qoff, self.nm, self._amp, lo, hi,
                self._tris, self._toff, self._edges, self._eoff, self._adj, self._meta, self._qsnap, *self._cache,
                *self._treelists)
            if len(v):
                k = len(v)
                va, wa = _one_vertex(v)
                parts.append((pa, va, wa, qa, self._tris[self._toff[qa] + tri], wb, X[voff[pa] + v], nrm, g,
                              np.full(k, _VF), v, qa))
            if len(mine):
                k = len(mine)
                ea, eb = self._edges[self._eoff[a] + mine], self._edges[self._eoff[b] + other]
                va = np.zeros((k, 3), dtype=np.int64)
                va[:, :2] = ea
                wa = np.zeros((k, 3))
                wa[:, 0], wa[:, 1] = 1.0 - s, s
                vb = np.zeros((k, 3), dtype=np.int64)
                vb[:, :2] = eb
                wb = np.zeros((k, 3))
                wb[:, 0], wb[:, 1] = 1.0 - tt, tt
                pa_ = X[voff[a] + ea[:, 0]] * wa[:, :1] + X[voff[a] + ea[:, 1]] * wa[:, 1:2]
                pb_ = X[voff[b] + eb[:, 0]] * wb[:, :1] + X[voff[b] + eb[:, 1]] * wb[:, 1:2]
                # the edge pair in the key (an edge may touch several of the other body's edges: one key each)
                feat = mine * (self._eoff[b + 1] - self._eoff[b]) + other
                parts.append((a, va, wa, b, vb, wb, 0.5 * (pa_ + pb_), ne, ge, np.full(k, _EE), feat, b))
        if not parts:
            return None
        cols = [np.concatenate([p[j] for p in parts]) for j in range(12)]
        body_a, verts_a, w_a, body_b, verts_b, w_b, point, normal, gap, kind, feat, other = cols
        body_a = body_a.astype(np.int64)
        body_b = body_b.astype(np.int64)
        vel = np.array([vel_off[n] for n in self.names], dtype=np.int64)
        # the rigid lever arms: one world point for both sides of a contact whose gap is within its margin (touching
        # or inside: exact linear and angular momentum); a speculative contact farther apart has no friction (it is
        # not touching yet) and acts on body b at the foot of a's point on b's tangent plane when that is within the
        # margin of b's closest point (a's point minus a multiple of the normal: the normal impulse's moment is the
        # same at both, so momentum stays exact), else at b's closest point itself (at a's point the far body
        # would be turned about a point off its surface: at dt = 0.1 s bars then tunnelled; the angular momentum
        # then changes by (x_a - x_b) x impulse)
        pb = np.zeros_like(point)
        pair = body_b >= 0
        for j in range(3):
            pb[pair] += w_b[pair, j:j + 1] * X[voff[body_b[pair]] + verts_b[pair, j]]
        far = pair & (gap > np.maximum(marg[body_a], marg[np.maximum(body_b, 0)]))
        foot = point - normal * np.einsum("ij,ij->i", point - pb, normal)[:, None]
        lateral = np.sqrt(np.einsum("ij,ij->i", foot - pb, foot - pb))
        point_b = np.where(far[:, None], np.where((lateral <= marg[body_a])[:, None], foot, pb), point)
        ptr, off, nd, jptr, J, WJt = SK.rows(body_a, np.ascontiguousarray(verts_a, dtype=np.int64), w_a, body_b,
                                             np.ascontiguousarray(verts_b, dtype=np.int64), w_b,
                                             np.ascontiguousarray(point), np.ascontiguousarray(point_b), R, Iw_inv, pos, self.mass, self.nm,
                                             self.phi_off, self.phi, self.mask_off, self._masks(dt), vel)
        k = len(gap)
        cont = self.contacts
        fr = np.array([c.friction for c in cont])
        rs = np.array([c.restitution for c in cont])
        pair = body_b >= 0
        bb = np.where(pair, body_b, body_a)
        mu = np.where(pair, np.sqrt(fr[body_a] * fr[bb]), fr[body_a]) * ~far
        e = np.where(pair, np.minimum(rs[body_a], rs[bb]), rs[body_a])
        margin = np.where(pair, np.maximum(marg[body_a], marg[bb]), marg[body_a])
        keys = (((body_a * (nb + len(self.plane_d)) + other) * 3 + kind) * _FEATURES + feat).astype(np.int64)
        lam0 = np.zeros((k, 3))
        if warm is not None and len(warm[0]):
            wk, wl = warm
            j = np.minimum(np.searchsorted(wk, keys), len(wk) - 1)
            hit = wk[j] == keys
            lam0[hit] = wl[j[hit]]
        names_idx = np.array([index[n] for n in self.names], dtype=np.int64)
        return {"ptr": ptr, "off": off, "nd": nd, "jptr": jptr, "J": J, "WJt": WJt,
                "normal": np.ascontiguousarray(normal, dtype=np.float64), "gap": gap.astype(np.float64),
                "vobs_n": np.zeros(k), "mu": mu, "restitution": e, "margin": margin,
                "body": names_idx[body_a], "other": np.where(pair, names_idx[bb], -1), "point": point,
                "iterations": max(c.iterations for c in cont), "keys": keys, "warm": lam0,
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


def _one_vertex(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contacts at single vertices ``v`` (k,) in the three-slot layout of the solve's rows: vertex ids (k, 3)
    (``v`` then 0) and weights (k, 3) (1 then 0)."""
    va = np.zeros((len(v), 3), dtype=np.int64)
    va[:, 0] = v
    wa = np.zeros((len(v), 3))
    wa[:, 0] = 1.0
    return va, wa
