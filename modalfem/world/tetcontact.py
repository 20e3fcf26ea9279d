"""Contact of tet bodies inside their implicit step: a one-sided quadratic penalty per contact, with the rigid
motion of the modal bodies they touch solved together with the tet's positions.

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
STIFFNESS`` (0.3 um at dt = 1 ms) below it.

A modal body's surface is such an obstacle too, at its free step end (its own step without contacts), and it
moves with the reaction: the body's rigid displacement ``u = (t, theta)`` (6,) [m, rad] from its free end (the
impulse ``M u / dt`` at its step start) is an unknown of the same step. The step minimises, over the tet
positions ``x`` and every touched modal body's ``u``, the tet's incremental potential plus
``sum_b 0.5 u_b^T S_b u_b + sum_c 0.5 k_c (d_c(x) + a_c . u_b)_+^2``, with ``S_b = diag(M, M, M, I_world) /
dt^2``, ``d_c = dhat - g_c`` and ``a_c = (n_c, r_c x n_c)`` (``r_c`` the contact's arm from the body's centre
of mass). ``u`` is eliminated exactly inside the penalty term (a 6-unknown convex problem per body, solved to
its active set), so the tet solver sees a function of ``x`` alone whose Hessian is the penalty's sparse part
minus a rank-6 part per body, ``V S^-1 V^T`` (``CoupledTetSolver`` solves with it by the Woodbury identity:
one extra linear solve per rank). The contact is then as stiff as wanted whatever the mass ratio: a 8 kg bar
on 1 g foam vertices does not take their reaction explicitly (which capped the stiffness at M / dt^2 and let it
sink through the skin at dt >= 5 ms). A contact with a moving body stiffens over its first ``SMOOTH dhat`` of
depth (C2 energy), and its stiffness is the World's to choose (``World._tet_contacts``: the body's weight and
approach held in a quarter of the skin, stiffened and redone when deeper). The body's modes are not in ``u``
(they take their part of the reaction after the step). Tet bodies that may touch are stepped as one system
(``tetgroup``): a contact between two of them is a row of up to four stacked vertices with signed weights summing to
zero and its plane at 0 (the two points' relative position), and their friction a lagged potential of the step
(``set_friction``).
"""

from __future__ import annotations

import numpy as np

from modalfem.tet.solver import TetSolver
from modalfem.world import _tet_kernels

__all__ = ["STIFFNESS", "CoupledTetSolver", "PenaltyContacts"]

#: penalty stiffness in units of m_eff / dt^2 [-]
STIFFNESS = 36.0
#: a contact with a moving body stiffens over its first ``SMOOTH * dhat`` of depth (C2 energy: Newton's
#: active set changes smoothly; with the plain quadratic, steps where many contacts let go cycled)
SMOOTH = 0.25


def _psi(z: np.ndarray, k: np.ndarray, e: np.ndarray):
    """Penalty energy, force and stiffness at depths ``z`` [m]: ``0.5 k z^2`` where ``e == 0``; else C2,
    ``k z^3 / (6 e)`` below ``e`` [m] and ``k (z^2 / 2 - e z / 2 + e^2 / 6)`` beyond (compiled:
    ``_tet_kernels.penalty``)."""
    f64 = np.float64
    return _tet_kernels.penalty(np.ascontiguousarray(z, f64), np.ascontiguousarray(k, f64),
                                np.ascontiguousarray(e, f64))


class PenaltyContacts:
    """The tet solver's vertex term for this step's contacts (``kind = "vertex"``); empty until ``set``."""

    kind = "vertex"

    def __init__(self, n: int) -> None:
        self.n = n
        self.set(np.zeros((0, 3), np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0.0)

    def set(self, verts: np.ndarray, w: np.ndarray, p: np.ndarray, n: np.ndarray, k: np.ndarray, dhat: float, *,
            bodies: np.ndarray | None = None, arms: np.ndarray | None = None, inertia: list | None = None) -> None:
        """Contacts: tet vertex ids (c, k) (-1: unused, weight 0; k <= 4), weights (c, k), plane points (c, 3) [m],
        unit normals (c, 3), stiffnesses (c,) [N/m], skin ``dhat`` [m]; optionally the moving body of each
        contact, ``bodies`` (c,) (-1: an obstacle, else an index into ``inertia``), its ``arms`` ``a_c`` (c, 6)
        [-, m] and each body's ``S_b`` (6, 6) [kg/s^2, kg m^2/s^2]."""
        self.verts, self.w = verts, w
        self.vid = np.where(verts >= 0, verts, 0)
        self.p, self.nrm, self.k, self.dhat = p, n, k, float(dhat)
        c = len(k)
        self.bodies = np.full(c, -1, np.int64) if bodies is None else np.asarray(bodies, np.int64)
        self.arms = np.zeros((c, 6)) if arms is None else arms
        self.inertia = list(inertia or [])
        self.groups = [np.flatnonzero(self.bodies == b) for b in range(len(self.inertia))]
        self.eps = np.where(self.bodies >= 0, SMOOTH * self.dhat, 0.0)
        self.u = [np.zeros(6) for _ in self.inertia]
        self._cache = None
        self.fric = None

    def set_friction(self, rows: np.ndarray, bound: np.ndarray, x0: np.ndarray, eps: float) -> None:
        """Coulomb friction of contacts ``rows`` inside the step, as a lagged dissipative potential (IPC's, Li et
        al. 2020): ``bound`` (k,) [N] the largest friction force ``mu lambda`` (lambda the normal force at the step
        start), ``x0`` (n, 3) [m] the start positions and ``eps`` [m] the tangential displacement below which the
        contact sticks elastically (``f0``: ``y^2 / eps - y^3 / (3 eps^2) + eps / 3`` below ``eps``, ``y`` beyond, of
        the tangential displacement ``y`` of the contact's point over the step)."""
        rows = np.asarray(rows, np.int64)
        keep = bound > 0
        rows, bound = rows[keep], np.asarray(bound, float)[keep]
        if not len(rows):
            self.fric = None
            return
        n = self.nrm[rows]
        P = np.eye(3)[None] - n[:, :, None] * n[:, None, :]  # tangent projectors (k, 3, 3)
        start = np.einsum("cj,cjd->cd", self.w[rows], x0[self.vid[rows]])
        self.fric = (rows, bound, P, start, float(eps))

    def _slip(self, x: np.ndarray):
        rows, _, P, start, _ = self.fric
        u = np.einsum("cab,cb->ca", P, np.einsum("cj,cjd->cd", self.w[rows], x[self.vid[rows]]) - start)
        return u, np.sqrt(np.einsum("ca,ca->c", u, u))

    def friction_energy(self, x: np.ndarray) -> float:
        """The friction potential [J] at ``x`` (zero without ``set_friction``)."""
        if self.fric is None:
            return 0.0
        bound, eps = self.fric[1], self.fric[4]
        _, y = self._slip(x)
        f0 = np.where(y < eps, y * y / eps - y**3 / (3 * eps * eps) + eps / 3, y)
        return float(bound @ f0)

    def friction_forces(self, x: np.ndarray):
        """``(rows, F (k, 3) [N])``: the friction force on each friction contact's point at ``x`` (against its slip)."""
        rows, bound, _, _, eps = self.fric
        u, y = self._slip(x)
        f1y = np.where(y < eps, 2.0 / eps - y / (eps * eps), 1.0 / np.maximum(y, 1e-300))  # f1(y) / y
        return rows, -(bound * f1y)[:, None] * u

    @property
    def count(self) -> int:
        return len(self.k)

    def _solve(self, x: np.ndarray) -> np.ndarray:
        """Depths (c,) [m] at ``x`` with each body's displacement ``u_b`` minimising its part of the energy
        (kept in ``self.u``)."""
        if self._cache is not None and np.array_equal(self._cache[0], x):
            return self._cache[1]
        pt = np.einsum("cj,cjd->cd", self.w, x[self.vid])
        d = self.dhat - np.einsum("cd,cd->c", pt - self.p, self.nrm)
        depth = np.maximum(d, 0.0)
        for b, sel in enumerate(self.groups):
            if len(sel):
                self.u[b] = _minimise(self.inertia[b], self.arms[sel], self.k[sel], self.eps[sel], d[sel], self.u[b])
                depth[sel] = np.maximum(d[sel] + self.arms[sel] @ self.u[b], 0.0)
        self._cache = (np.array(x), depth)
        return depth

    def keep_first(self, n: int, x: np.ndarray) -> None:
        """Drop every contact after the first ``n``, keeping the bodies' displacements and the depths at ``x``
        (n, 3) [m] solved with all of them (what the step ended with)."""
        depth = self._solve(x)[:n].copy() if self.count else np.zeros(0)
        u, fric = self.u, self.fric
        self.set(self.verts[:n], self.w[:n], self.p[:n], self.nrm[:n], self.k[:n], self.dhat, bodies=self.bodies[:n],
                 arms=self.arms[:n], inertia=self.inertia)
        self.u, self.fric = u, fric
        self._cache = (np.array(x), depth)

    def depths(self, x: np.ndarray) -> np.ndarray:
        """Depths (c,) [m] of the contacts into their skins at ``x`` (the bodies at their displacements)."""
        return self._solve(x) if self.count else np.zeros(0)

    def stiffen(self, factor: np.ndarray) -> None:
        """Multiply the stiffnesses by ``factor`` (c,) [-]."""
        self.k = self.k * factor
        self._cache = None

    def forces(self, x: np.ndarray) -> np.ndarray:
        """Contact force magnitudes (c,) [N] along the normals at positions ``x`` (the bodies at their
        displacements ``self.u``)."""
        return _psi(self._solve(x), self.k, self.eps)[1] if self.count else np.zeros(0)

    def energy(self, x: np.ndarray, masses: np.ndarray | None = None) -> float:
        """The penalty energy [J] plus the moving bodies' inertia terms ``0.5 u^T S u``."""
        if not self.count:
            return 0.0
        e = float(_psi(self._solve(x), self.k, self.eps)[0].sum()) + self.friction_energy(x)
        return e + sum(0.5 * float(u @ S @ u) for u, S in zip(self.u, self.inertia))

    def penalty_energy(self, x: np.ndarray) -> float:
        """The energy [J] stored in the contacts at ``x`` (at most ``F^2 / 2k`` each)."""
        return float(_psi(self._solve(x), self.k, self.eps)[0].sum()) if self.count else 0.0

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        if not self.count:
            return np.zeros((self.n, 3))
        fw = -self.forces(x)[:, None] * self.w  # (c, k): the force along +n on the point, by vertex weight
        idx = self.vid.ravel()  # (bincount adds in index order, as np.add.at, and is ~10x faster)
        g = np.column_stack([np.bincount(idx, weights=(fw * self.nrm[:, d:d + 1]).ravel(), minlength=self.n)
                             for d in range(3)])
        if self.fric is not None:
            rows, F = self.friction_forces(x)
            gw = -self.w[rows][:, :, None] * F[:, None, :]  # (k, K, 3)
            ids = self.vid[rows].ravel()
            g += np.column_stack([np.bincount(ids, weights=gw[:, :, d].ravel(), minlength=self.n) for d in range(3)])
        return g

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray | None:
        return None  # all of it in ``hessian_entries``

    def hessian_entries(self, x: np.ndarray, masses: np.ndarray):
        """The Hessian of the active contacts with the bodies held, ``k (w w^T) (x) (n n^T)``, as DOF entries
        (rows, cols, values) (the vertices of one contact share a tetrahedron: a surface triangle's or edge's)."""
        if not self.count:
            return None
        stiff = _psi(self._solve(x), self.k, self.eps)[2]
        act = np.flatnonzero(stiff > 0)
        out = _tet_kernels.penalty_hessian(stiff, self.verts, self.w, self.nrm) if len(act) else None
        if self.fric is None:
            return out
        # friction: ``bound f1(y) / y`` times the tangent projector (positive semi-definite; IPC's Hessian without its
        # negative part), by vertex weights
        rows, bound, P, _, eps = self.fric
        _, y = self._slip(x)
        c = bound * np.where(y < eps, 2.0 / eps - y / (eps * eps), 1.0 / np.maximum(y, 1e-300))
        V, W = self.verts[rows], self.w[rows]
        blk = c[:, None, None, None, None] * (W[:, :, None, None, None] * W[:, None, :, None, None]) * P[:, None, None]
        ok = (V[:, :, None] >= 0) & (V[:, None, :] >= 0)  # (k, K, K)
        r = 3 * V[:, :, None, None, None] + np.arange(3)[None, None, None, :, None]
        cc = 3 * V[:, None, :, None, None] + np.arange(3)[None, None, None, None, :]
        r, cc = np.broadcast_to(r, blk.shape), np.broadcast_to(cc, blk.shape)
        m = np.broadcast_to(ok[:, :, :, None, None], blk.shape)
        fr, fc, fv = r[m].astype(np.int64), cc[m].astype(np.int64), blk[m]
        if out is None:
            return fr, fc, fv
        return np.concatenate([out[0], fr]), np.concatenate([out[1], fc]), np.concatenate([out[2], fv])

    def hessian_low_rank(self, x: np.ndarray, masses: np.ndarray):
        """What eliminating the bodies' displacements takes off the Hessian: ``(V (3n, 6 B), S (6 B, 6 B))`` with
        the Hessian ``hessian_entries - V S^-1 V^T`` (V the cross derivatives x-u of the active contacts, S the
        u-u block, block diagonal); None without moving bodies in contact."""
        if not self.inertia:
            return None
        stiff = _psi(self._solve(x), self.k, self.eps)[2]
        V, S, nonzero = _tet_kernels.penalty_low_rank(stiff, self.verts, self.w, self.nrm, self.arms, self.bodies,
                                                      np.array(self.inertia, dtype=np.float64), self.n)
        return (V, S) if nonzero else None


def _minimise(S: np.ndarray, A: np.ndarray, k: np.ndarray, e: np.ndarray, d: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``argmin_u 0.5 u^T S u + sum psi(d + A u)`` (convex, S SPD; ``psi`` of ``_psi``): Newton with a
    backtracking line search, from ``u``, until the step is below roundoff of ``u`` (compiled:
    ``_tet_kernels.minimise``)."""
    f64 = np.float64
    return _tet_kernels.minimise(*(np.ascontiguousarray(a, f64) for a in (S, A, k, e, d, u)))


class CoupledTetSolver(TetSolver):
    """``TetSolver`` whose vertex terms may take a low-rank part off the Hessian (``hessian_low_rank``:
    ``H = A - V S^-1 V^T``, the elimination of extra unknowns such as a touching modal body's rigid motion); the
    Newton systems are solved by the Woodbury identity ``H^-1 g = A^-1 g + Z (S - V^T Z)^-1 V^T A^-1 g``,
    ``Z = A^-1 V`` (one solve with A per column of V, with A's preconditioner or factors)."""

    _low = None
    _wood = None
    _lu = None
    #: relative residual of the solves ``Z = A^-1 V`` [-]: ``S - V^T Z`` subtracts nearly equal terms when the
    #: contacts are much stiffer than the body's inertia, so Z must be tighter than the Newton solves
    low_rank_rtol = 1e-10
    #: with CG, systems of at most this many unknowns solve ``Z`` and the Newton step with one sparse LU of A
    #: instead (exact; on a 75-vertex foam block cheaper than the tight CG solves; the Newton step's CG skipped:
    #: bar on foam at 1 ms, tet step 10.1 -> 7.4 ms CPU, 3.3 -> 3.05 Newton iterations per step)
    direct_below = 3000

    #: Newton iterations allowed in a step with a moving body in contact: its energy is honest only once the
    #: step has converged (steps where many contacts let go at once took up to 18 on a foam block under a
    #: steel bar; left at 8, such steps gained up to 0.1 J)
    coupled_newton_max = 60

    def step(self, state_in, state_out, dt, *, control=None):
        n = self.newton_max
        if any(getattr(t, "inertia", None) for t in self.vertex_terms):
            self.newton_max = max(n, self.coupled_newton_max)
        try:
            return super().step(state_in, state_out, dt, control=control)
        finally:
            self.newton_max = n

    def _incremental(self, x, xn, xhat, h, D, order: int, project: bool = True):
        out = super()._incremental(x, xn, xhat, h, D, order, project)
        if order >= 2 and out[2] is not None:
            parts = [t.hessian_low_rank(x, self.model.masses) for t in self.vertex_terms
                     if hasattr(t, "hessian_low_rank")]
            parts = [p for p in parts if p is not None]
            if not parts:
                self._low = None
            elif len(parts) == 1:
                self._low = parts[0]
            else:
                r = np.cumsum([0] + [p[1].shape[0] for p in parts])
                S = np.zeros((r[-1], r[-1]))
                for p, a, b in zip(parts, r[:-1], r[1:]):
                    S[a:b, a:b] = p[1]
                self._low = (np.hstack([p[0] for p in parts]), S)
        return out

    def _woodbury(self, y: np.ndarray) -> np.ndarray:
        V, _, Z, T = self._wood
        return y + Z @ np.linalg.solve(T, V.T @ y)

    def _solve(self, data, g, info, guess=None, *, x=None, free=None, rtol=None):
        low, self._wood, self._lu = self._low, None, None
        if low is not None and self.linear_solver == "cg" and len(g) <= self.direct_below:
            # one sparse LU (symmetric ordering: ~25 % faster) serves Z = A^-1 V and A^-1 g: no CG (an indefinite
            # A is then caught by the Newton loop's descent test, as with linear_solver="splu")
            import scipy.sparse.linalg as spla

            A = self._system_matrix(data, free)
            self._system = (A, None)
            self._lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A")
            y, definite = self._lu.solve(g), True
        else:
            y, definite = super()._solve(data, g, info, guess, x=x, free=free, rtol=rtol)
        if low is None:
            return y, definite
        V, S = low
        if free is not None:
            V = V * free[:, None]
        if self._lu is not None:
            Z = self._lu.solve(V)
        elif self.linear_solver == "cg":
            Z = np.empty_like(V)
            rtol, self.cg_rtol = self.cg_rtol, min(self.cg_rtol, self.low_rank_rtol)
            try:
                for i in range(V.shape[1]):
                    Z[:, i], ok = super()._resolve(V[:, i], info)
                    definite = definite and ok
            finally:
                self.cg_rtol = rtol
        else:  # factors: exact
            Z = np.column_stack([super()._resolve(V[:, i], info)[0] for i in range(V.shape[1])])
        T = S - V.T @ Z
        self._wood = (V, S, Z, T)
        return self._woodbury(y), definite

    def _resolve(self, g, info):
        y, definite = (self._lu.solve(g), True) if self._lu is not None else super()._resolve(g, info)
        if self._wood is None:
            return y, definite
        return self._woodbury(y), definite
