"""Tet bodies that may touch in a step, stepped as one implicit system (``World._stage_tet_step``).

Their vertices are stacked (body after body) into one ``TetModel`` whose elements keep each body's own material,
energy and effects (gravity, wind, damping, pins: each acting on its body's slice), and one backward Euler step
minimises the sum of their incremental potentials plus the penalty energy of their contacts with each other, the
obstacles and the modal bodies (``tetcontact.PenaltyContacts``). A contact between two of them is one row with up
to four stacked vertices and signed weights that sum to zero (a vertex of one body on a face of the other: ``1,
-b_0, -b_1, -b_2``; an edge on an edge: ``1 - s, s, -(1 - t), -t``), so its gap is the two sides' relative
position along the normal: its forces on the two bodies are equal and opposite (the momentum they exchange sums to
zero), and the step's incremental potential, which holds the penalty, is minimised with both bodies' elasticity:
contact cannot store energy the step does not count.

The penalty Hessian couples vertices of two bodies, which share no tetrahedron: those entries are kept outside
the element sparsity pattern and added to the Newton system's matrix (``JointTetSolver._system_matrix``).
"""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp

from modalfem.mesh.core import Mesh
from modalfem.tet.energies import SigmaDerivs
from modalfem.tet.model import TetModel
from modalfem.world.tetcontact import CoupledTetSolver, PenaltyContacts

__all__ = ["CREASE", "JointTetSolver", "pair_contacts", "touching"]

#: a vertex closest to an edge or corner of the other body meets, besides the face there it will be most in front
#: of, the faces within ~25 degrees of that one (their normals' cosine at least this): a stiff cube's corner over the
#: crease between two faces of a soft block met only one and crossed the other at 3-10 ms steps
CREASE = 0.9


class _StackedDensity:
    """The members' element terms, each on its own range of the stacked elements."""

    def __init__(self, ranges: list, terms: list) -> None:
        self.ranges, self.terms = ranges, terms

    def derivs(self, s: np.ndarray, order: int = 2) -> SigmaDerivs:
        parts = []
        for (a, b), terms in zip(self.ranges, self.terms):
            d = terms[0].derivs(s[a:b], order)
            for t in terms[1:]:
                d = d + t.derivs(s[a:b], order)
            parts.append(d)

        def cat(name):
            v = [getattr(p, name) for p in parts]
            return None if any(x is None for x in v) else np.concatenate(v)

        return SigmaDerivs(cat("psi"), cat("d1"), cat("d2"), cat("twist"), cat("flip"))


class _Slice:
    """A member's vertex term (gravity, wind) on its slice ``a:b`` of the stacked vertices."""

    kind = "vertex"

    def __init__(self, term, a: int, b: int, n: int) -> None:
        self.term, self.a, self.b, self.n = term, a, b, n

    def energy(self, x: np.ndarray, masses: np.ndarray) -> float:
        return self.term.energy(x[self.a:self.b], masses[self.a:self.b])

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        g = np.zeros((self.n, 3))
        g[self.a:self.b] = self.term.gradient(x[self.a:self.b], masses[self.a:self.b])
        return g

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray):
        h = self.term.hessian_diagonal(x[self.a:self.b], masses[self.a:self.b])
        if h is None:
            return None
        out = np.zeros((self.n, 3))
        out[self.a:self.b] = h
        return out


class _SplitPenalty:
    """The group's ``PenaltyContacts`` as a term of the joint step: its Hessian entries between two bodies (no
    common tetrahedron) go to the solver's extra entries instead of the element pattern."""

    kind = "vertex"

    def __init__(self, penalty, solver) -> None:
        self.penalty, self.solver = penalty, solver

    @property
    def inertia(self):
        return self.penalty.inertia

    def energy(self, x, masses):
        return self.penalty.energy(x, masses)

    def gradient(self, x, masses):
        return self.penalty.gradient(x, masses)

    def hessian_diagonal(self, x, masses):
        return None

    def hessian_entries(self, x, masses):
        entries = self.penalty.hessian_entries(x, masses)
        owner = self.solver.owner
        if entries is None:
            self.solver.extra = None
            return None
        r, c, v = entries
        cross = owner[r // 3] != owner[c // 3]
        self.solver.extra = (r[cross], c[cross], v[cross]) if cross.any() else None
        keep = ~cross
        return r[keep], c[keep], v[keep]

    def hessian_low_rank(self, x, masses):
        return self.penalty.hessian_low_rank(x, masses)


class JointTetSolver(CoupledTetSolver):
    """One implicit step over several tet bodies (see the module docstring).

    Args:
        solvers: the members' own solvers (their models, effects, pins, Newton and linear-solver settings).
        penalty: the group's ``PenaltyContacts`` over the stacked vertices.

    Attributes:
        offsets: the first stacked vertex of each member (len(solvers) + 1,).
    """

    def __init__(self, solvers: list, penalty) -> None:
        models = [s.model for s in solvers]
        counts = [m.point_count for m in models]
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        n = int(self.offsets[-1])
        # rest points side by side (the two-level preconditioner's aggregates never join two bodies); shape gradients
        # and masses are the members' own
        pts, shift = [], 0.0
        for m in models:
            lo, hi = m.mesh.bounds
            pts.append(m.rest_points + np.array([shift - lo[0], 0.0, 0.0]))
            shift += float(hi[0] - lo[0]) + 2.0 * max(mm.size for mm in models)
        cells = np.concatenate([m.cells + o for m, o in zip(models, self.offsets[:-1])])
        mesh = Mesh(np.concatenate(pts), cells)
        model = TetModel(mesh, models[0].material, models[0].energy, np.concatenate([m.grad for m in models]),
                         np.concatenate([m.rest_volumes for m in models]), np.concatenate([m.masses for m in models]))
        m_cells = np.concatenate([[0], np.cumsum([m.cell_count for m in models])])
        model.__dict__["density"] = _StackedDensity(list(itertools.pairwise(m_cells)),
                                                    [list(s.element_terms) for s in solvers])
        model.__dict__["size"] = max(m.size for m in models)  # the tolerances' length scale: the largest body
        self.owner = np.repeat(np.arange(len(models)), counts)
        self.extra = None
        terms = []
        for s, a, b in zip(solvers, self.offsets[:-1], self.offsets[1:]):
            terms += [_Slice(t, int(a), int(b), n) for t in s.vertex_terms if not isinstance(t, PenaltyContacts)]
        self.penalty = penalty
        terms.append(_SplitPenalty(penalty, self))
        ref = solvers[0]
        lin = "cg" if any(s.linear_solver == "cg" for s in solvers) else ref.linear_solver
        super().__init__(model, effects=terms, newton_max=max(s.newton_max for s in solvers),
                         tol=min(s.tol for s in solvers), linear_solver=lin, cg_rtol=min(s.cg_rtol for s in solvers))
        self.element_terms = [model.density]  # the members' extra element terms are in the stacked density
        self.barrier = any(s.barrier for s in solvers)
        self.fixed = np.concatenate([s.fixed for s in solvers])
        self.pin_targets = np.concatenate([s.pin_targets for s in solvers])
        self._members = solvers
        self._m_cells = m_cells
        if any(s.damping is not None for s in solvers):
            self.damping = True  # per member: ``_damping_data``

    def step(self, state_in, state_out, dt, *, control=None):
        """``CoupledTetSolver.step``; with contacts between the members, up to ``coupled_newton_max`` Newton iterations
        as with a moving body (the step's energy, and the momentum the members exchange, are honest once it has
        converged: at 0.1 s steps 8 iterations left the cube on the foam short of it)."""
        n = self.newton_max
        if self.penalty.count:
            self.newton_max = max(n, self.coupled_newton_max)
        try:
            return super().step(state_in, state_out, dt, control=control)
        finally:
            self.newton_max = n

    def _damping_data(self, x0: np.ndarray) -> np.ndarray:
        """``D = alpha M + beta K(x0)`` with each member's alpha [1/s] and beta [s] on its vertices and elements."""
        alpha = np.zeros(len(self.mass_dofs))
        beta = np.zeros(self.model.cell_count)
        for s, a, b, ca, cb in zip(self._members, self.offsets[:-1], self.offsets[1:], self._m_cells[:-1],
                                   self._m_cells[1:]):
            if s.damping is not None:
                alpha[3 * a:3 * b] = float(s.damping.alpha)
                beta[ca:cb] = float(s.damping.beta)
        He = None
        if beta.any():
            He = self._elastic(x0, 2, upper=True)[2]
            if He is not None:
                He = He * beta[None, :]
        return self.pattern.assemble(He, alpha * self.mass_dofs, upper=True)

    def _system_matrix(self, data: np.ndarray, free: np.ndarray | None = None):
        A = self.pattern.matrix(data)
        if self.extra is None:
            return A
        r, c, v = self.extra
        if free is not None:
            held = ~free[r] | ~free[c]
            v = np.where(held, 0.0, v)
        return (A + sp.csr_matrix((v, (r, c)), shape=A.shape)).tocsr()


def touching(names: list, boxes: dict) -> list:
    """Groups of bodies (lists of names, in the order of ``names``) whose boxes ``(lo (3,), hi (3,))`` [m] overlap,
    transitively; a body without a box (no contact) or overlapping none is a group alone."""
    root = {n: n for n in boxes}

    def find(n):
        while root[n] != n:
            n = root[n]
        return n

    keys = list(boxes)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            if np.all(boxes[a][0] <= boxes[b][1]) and np.all(boxes[b][0] <= boxes[a][1]):
                root[find(a)] = find(b)
    groups = {}
    for n in names:
        groups.setdefault(find(n) if n in root else n, []).append(n)
    return list(groups.values())


def pair_owners(solver, penalty, rows: np.ndarray) -> tuple:
    """Which members a group's contacts ``rows`` (penalty indices, contacts between members) join: ``owner``
    (k, 4) the member of each of a contact's vertices (-1: no vertex), ``first`` (k,) the member of its first
    vertex and ``other`` (k,) the other member it touches. ``solver``: the group's ``JointTetSolver``."""
    owner = np.where(penalty.verts[rows] >= 0, solver.owner[penalty.vid[rows]], -1)
    first = owner[:, 0]
    other = np.where(owner != first[:, None], owner, -1).max(1)
    return owner, first, other


def between(first: np.ndarray, other: np.ndarray, a: int, b: int) -> np.ndarray:
    """Indices of the contacts (``pair_owners``' ``first``, ``other``) joining members ``a`` and ``b``."""
    return np.flatnonzero(((first == a) & (other == b)) | ((first == b) & (other == a)))


def pair_contacts(members: list, x: np.ndarray, r: float, edge_align: float, u: np.ndarray | None = None) -> tuple:
    """The contacts of a group's tet bodies with each other within ``r`` [m] at stacked positions ``x`` (n, 3) [m]:
    each body's surface vertices on the other's faces within ``r`` whose closest point to them is inside the face,
    and for a vertex closest to an edge or corner, on the face there it will be most in front of after the predicted
    motion ``u`` (n, 3) [m] (default none) with the faces nearly coplanar with it (normals' cosine at least
    ``CREASE``), and its edges on the other's edges where the line between their
    closest points is within ~60 degrees of the other surface's outward side (the cosine at least ``edge_align``).

    Args:
        members: ``(entry, first stacked vertex)`` per body; an entry holds the body's ``surface`` (mesh vertex ids),
            ``triangles`` (surface-local), ``proximity`` (``SurfaceProximity``) and ``edges`` (``EdgeProximity``).

    Returns:
        Stacked vertex ids (k, 4), signed weights (k, 4) (the point on the first body minus the one on the other:
        they sum to zero) and the other surface's outward normals (k, 3).
    """
    V, W, N = [np.zeros((0, 4), np.int64)], [np.zeros((0, 4))], [np.zeros((0, 3))]
    u = np.zeros_like(x) if u is None else u
    for i, (ta, oa) in enumerate(members):
        sa = ta["surface"] + oa
        xa = x[sa]
        for tb, ob in members[i + 1:]:
            sb = tb["surface"] + ob
            xb = x[sb]
            lo = np.maximum(xa.min(0), xb.min(0)) - r
            hi = np.minimum(xa.max(0), xb.max(0)) + r
            if np.any(lo > hi):
                continue
            for sv, xp, tq, sq, xq in ((sa, xa, tb, sb, xb), (sb, xb, ta, sa, xa)):
                near = np.flatnonzero(np.all((xp >= lo) & (xp <= hi), axis=1))
                if not len(near):
                    continue
                h = tq["proximity"].query(xp[near], xq, r, every=True)  # normal: out of q's face
                if len(h.point):
                    # each point on the faces whose closest point to it is inside them, and on one face of each
                    # edge or corner it is closest to: the one it will be most in front of after the predicted
                    # motion (any face of a convex edge separates; this one lets it slide past: a vertex rising
                    # past the other body's bottom edge, held "below" its bottom face, pushed the two apart),
                    # with the faces nearly coplanar with that one (a crease: a stiff cube's corner over the
                    # crease between two triangles of a soft block met only one and crossed the other)
                    T = tq["triangles"][h.triangle]
                    inside = h.bary.min(1) > 1e-6
                    ahead = h.gap + np.einsum("kd,kd->k", u[sv[near[h.point]]] - np.einsum(
                        "kj,kjd->kd", h.bary, u[sq[T]]), h.normal)
                    # (among the faces it is in front of at the start: a face it is behind does not separate)
                    score = np.where(h.gap >= 0.0, ahead, -1e300 * (1.0 - h.gap))
                    new = np.r_[True, h.point[1:] != h.point[:-1]]
                    grp = np.cumsum(new) - 1
                    top = np.maximum.reduceat(score, np.flatnonzero(new))[grp]
                    pick = np.flatnonzero(score == top)
                    best = np.empty(grp[-1] + 1, np.int64)
                    best[grp[pick]] = pick  # (one per point: the last of ties)
                    coplanar = np.einsum("kd,kd->k", h.normal, h.normal[best[grp]]) >= CREASE
                    ok = (inside & (h.gap >= 0.0)) | coplanar
                    V.append(np.column_stack([sv[near[h.point[ok]]], sq[T[ok]]]))
                    W.append(np.column_stack([np.ones(int(ok.sum())), -h.bary[ok]]))
                    N.append(h.normal[ok])
            e = ta["edges"].edges
            a0, a1 = xa[e[:, 0]], xa[e[:, 1]]
            sel = np.flatnonzero(np.all((np.minimum(a0, a1) <= hi) & (np.maximum(a0, a1) >= lo), axis=1))
            if not len(sel):
                continue
            h = tb["edges"].query(a0[sel], a1[sel], xb, r)  # normal: from b's edge to a's
            if len(h.mine):
                side = tb["edges"].sides(xb, h.other)
                side /= np.maximum(np.linalg.norm(side, axis=1), 1e-300)[:, None]
                ok = np.einsum("ij,ij->i", h.normal, side) >= edge_align
                if ok.any():
                    E = tb["edges"].edges[h.other[ok]]
                    V.append(np.column_stack([sa[e[sel[h.mine[ok]]]], sb[E]]))
                    W.append(np.column_stack([1.0 - h.s[ok], h.s[ok], h.t[ok] - 1.0, -h.t[ok]]))
                    N.append(h.normal[ok])
    return np.concatenate(V).astype(np.int64), np.concatenate(W), np.concatenate(N)
