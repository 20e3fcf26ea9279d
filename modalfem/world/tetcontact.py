"""Contact of tet bodies with obstacles inside their implicit step: a one-sided quadratic penalty per contact.

Each contact says "the point ``sum_j w_j x_j`` of the tet body stays at least ``dhat`` [m] on the free side of
the plane through ``p`` with normal ``n``": energy ``0.5 k (dhat - g)^2`` for ``g = (sum_j w_j x_j - p) . n <
dhat``, zero beyond (the World uses one vertex per contact against obstacles and modal faces, a tet face's point
(three vertices) against a modal vertex, a tet edge's point (two) against a modal edge). The planes are the obstacles'
surfaces at the step end, linearised at the closest points found at the step start. The stiffness of a
contact is ``STIFFNESS m_eff / dt^2`` (m_eff its effective mass ``1 / sum_j w_j^2 / m_j``): the implicit step
then stops an approach within the step, at any dt, and a body resting on it compresses the skin ``dhat`` by
``m g dt^2 / STIFFNESS`` per vertex's share of the weight. A contact already inside the skin at the step start
is held there (its plane shifted to the start depth): a body placed on the ground is not thrown off. A resting
body creeps into the skin by ``g dt^2 / STIFFNESS`` per step down to the surface, and rests ~``g dt^2 /
STIFFNESS`` (0.3 um at dt = 1 ms) below it. A modal body's surface is such an obstacle too, moving, at its
predicted step end; a contact with it is not held (the weight of the modal body on a few vertices would sink it
by force / stiffness every step); a contact's stiffness shares the modal body's mass too (at least ``STIFFNESS M /
(c dt^2)`` for its c contacts: its weight, not the light tet vertices', loads them), and the stiffness of one
modal body's contacts summed is capped by ``M / dt^2``, since it takes their reaction explicitly. Tet bodies meet each other in the World's solid contact solve.
"""

from __future__ import annotations

import numpy as np

__all__ = ["STIFFNESS", "PenaltyContacts"]

#: penalty stiffness in units of m_eff / dt^2 [-]
STIFFNESS = 36.0


class PenaltyContacts:
    """The tet solver's vertex term for this step's contacts (``kind = "vertex"``); empty until ``set``."""

    kind = "vertex"

    def __init__(self, n: int) -> None:
        self.n = n
        self.set(np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0.0)

    def set(self, verts: np.ndarray, w: np.ndarray, p: np.ndarray, n: np.ndarray, k: np.ndarray, dhat: float) -> None:
        """Contacts: tet vertex ids (c, 3) (-1: unused, weight 0), weights (c, 3), plane points (c, 3) [m],
        unit normals (c, 3), stiffnesses (c,) [N/m], skin ``dhat`` [m]."""
        self.verts, self.w = verts, w
        self.vid = np.where(verts >= 0, verts, 0)
        self.p, self.nrm, self.k, self.dhat = p, n, k, float(dhat)

    @property
    def count(self) -> int:
        return len(self.k)

    def _depth(self, x: np.ndarray) -> np.ndarray:
        pt = np.einsum("cj,cjd->cd", self.w, x[self.vid])
        return np.maximum(self.dhat - np.einsum("cd,cd->c", pt - self.p, self.nrm), 0.0)

    def forces(self, x: np.ndarray) -> np.ndarray:
        """Contact force magnitudes (c,) [N] along the normals at positions ``x``."""
        return self.k * self._depth(x) if self.count else np.zeros(0)

    def energy(self, x: np.ndarray, masses: np.ndarray) -> float:
        if not self.count:
            return 0.0
        return 0.5 * float(self.k @ self._depth(x) ** 2)

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        g = np.zeros((self.n, 3))
        if self.count:
            f = self.k * self._depth(x)  # force along +n on the point
            for j in range(3):
                np.add.at(g, self.vid[:, j], -(f * self.w[:, j])[:, None] * self.nrm)
        return g

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray | None:
        return None  # all of it in ``hessian_entries``

    def hessian_entries(self, x: np.ndarray, masses: np.ndarray):
        """The exact Hessian of the active contacts, ``k (w w^T) (x) (n n^T)``, as DOF entries (rows, cols, values)
        (the vertices of one contact share a tetrahedron: a surface triangle's or edge's)."""
        if not self.count:
            return None
        act = np.flatnonzero(self._depth(x) > 0)
        if not len(act):
            return None
        k, w, n, v = self.k[act], self.w[act], self.nrm[act], self.vid[act]
        used = self.verts[act] >= 0
        rows, cols, vals = [], [], []
        for i in range(3):
            for j in range(3):
                sel = used[:, i] & used[:, j]
                if not sel.any():
                    continue
                kij = k[sel] * w[sel, i] * w[sel, j]
                nn = n[sel][:, :, None] * n[sel][:, None, :]  # (c, 3, 3)
                r = 3 * v[sel, i][:, None, None] + np.arange(3)[None, :, None] + 0 * np.arange(3)[None, None, :]
                c = 3 * v[sel, j][:, None, None] + np.arange(3)[None, None, :] + 0 * np.arange(3)[None, :, None]
                rows.append(r.ravel())
                cols.append(c.ravel())
                vals.append((kij[:, None, None] * nn).ravel())
        return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
