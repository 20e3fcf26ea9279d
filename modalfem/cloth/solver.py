"""Implicit backward Euler for cloth (Baraff-Witkin): one linearised Newton step per time step.

With lumped masses ``M``, the projected elastic Hessian ``K`` (membrane, bending), the damping
``C = alpha M + beta K + C_wind`` and forces ``f`` at the start of the step, the velocity change solves

    (M + dt C + dt^2 K) dv = dt (f - C v - dt K v)

for the free DOFs; handle vertices get the velocity that brings them to their scripted position at
the end of the step, and contact vertices the normal velocity of their obstacle (constraint filtering:
per vertex a projection ``S_i`` on the free components, ``0`` for a handle, ``I - n n^T`` for a contact,
and the system ``S A S`` on range(S) is SPD). Two linear solvers: ``"cg"`` (the filtered conjugate
gradients of ``modalfem.cloth._sgs_kernels.pcg_sgs`` or ``_kernels.pcg``, compiled, warm start from the previous
step's velocity change, relative residual ``cg_rtol``) and ``"splu"`` (scipy's SuperLU on ``S A S + I - S``,
minimum-degree ordering of A^T + A). The CG preconditioner (``cg_preconditioner``) is by default symmetric block
Gauss-Seidel (:mod:`modalfem.cloth._sgs_kernels`: Eisenstat's trick makes an iteration cost about one matrix
product) in a block multicolour order (``"sgs-blocks"``: groups of 256 consecutive vertices coloured, two colours
of stripes on a grid, the groups of a colour swept in parallel, vertex order inside a group). In vertex order
(``"sgs"``) the sweeps are serial; it takes about as many iterations (64x64 pile: 39.2 against 39.7 per step) and
needs no gather of the matrix into the order nor the extra parallel launches: on the pile's step-60 system
(Intel Xeon, 2 cores free) a solve takes 10.0-10.3 ms on one thread and the same on two, the block multicolour
one 11.6-11.9 ms on one thread and 7.7-8.0 on two; whole pile steps 61-68 replayed (34 paired runs, 2 cores free,
median ms/step) 132.8 -> 136.1 on one thread, 100.3 -> 98.8 on two (1.32x -> 1.38x). In a vertex multicolour
order (``"sgs-colours"``, 7 colours) it takes 49.2 (a sweep carries a correction only as many vertices far as
there are colours). The orders are fixed by the pattern, so every choice gives the same bits on any thread count.
Per step on the 64x64 pile (80 steps, one thread) SGS in vertex order took 38.0 iterations against the multilevel
preconditioner's 53.3 (drape 64x64: 37.0 against 56.8; the twist without collisions 23.5 against 25.4), and needs
no setup of levels (the smoothing solve keeps the multilevel one: ``SMOOTH_PRECONDITIONER``); its sweeps do not
reach a free-floating stiff sheet's global modes as well (a synthetic ``M + 1e-4 K`` on 24x24 vertices without
constraints, random right-hand side: 49 against 35 iterations). The other, ``"multilevel"``, is additive: block Jacobi (the
inverses of the vertices' projected 3x3 diagonal blocks) plus, on a hierarchy of vertex aggregates
(greedy aggregation of the matrix graph, repeated until at most ``COARSEST`` aggregates remain, built
once), block Jacobi of each level's Galerkin matrix for piecewise-constant translations and a direct
solve on the coarsest level. The slow, smooth modes that block Jacobi leaves to CG are the levels'
work: on the 64x64 pile it takes 58 iterations instead of 94 (implicit step, 1e-4) and 64 instead of
~135 (smoothing, 1e-2; it now stops at 0.1, ``SMOOTH_RTOL``) for about the cost of one matrix product each. Matrices live in a 3x3-block
sparse pattern built once (every vertex's diagonal block included); each step the triangles' blocks are
computed in parallel and every matrix block gathers its element sub-blocks (parallel over block rows, the
additions of a serial scatter in its order: the same bits on any thread count). Which solver is faster: ``modalfem bench cloth``.

``smooth`` is the post-collision smoothing: a velocity change ``dv`` (from the collision pipeline) is
replaced by the solution of ``(M + dt beta_s K) dv_s = M dv`` (CG to ``SMOOTH_RTOL``; without fixed
vertices the momentum of ``dv`` is then restored exactly). Rigid translations lie in the null space
of ``K``, so the smoothing keeps the linear momentum of ``dv``; it spreads the jump over neighbours
the way the cloth's own stiffness would. The caller re-checks the smoothed velocities for collisions.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from modalfem.cloth.model import ClothModel
from modalfem.errors import InputError, SimulationError, SolverError
from modalfem._threads import serial_blas

#: relative residual of the smoothing solve: it only shapes the collision response (which goes through
#: the collision pipeline again), so a looser tolerance than the implicit step's is enough; the
#: momentum the residual would change is restored exactly. On the 64x64 pile at step 60 (one collision
#: response): 0.1 takes 33 CG iterations (1e-2: 60, converged: 276) and its smoothed change is within
#: 3.5 % (L2; 5 % in the largest entry, 3.4 % of the thickness over the step) of the converged one; over
#: the whole pile 31 instead of 55 iterations per step, no more impact-zone vertices in the re-check,
#: 0 intersections; started from the last step's smoothed change (``smooth``), 27.7 instead of 31.2
SMOOTH_RTOL = 0.1
#: CG preconditioner of the smoothing solve. Symmetric Gauss-Seidel takes fewer iterations there too (64x64 pile:
#: 19.4 against 27.9 per step; drape 12.3 against 22.0), but at ``SMOOTH_RTOL`` the two leave differently shaped
#: errors in the smoothed response, and the twist test (8x8, two turns, dt = 1/50; tests/cloth/test_scenes.py) then
#: reaches at t = 1.84 s a state whose impact zone (between the two handles) does not resolve even in eighth steps,
#: with either preconditioner for the implicit step. Not a property of one preconditioner: in sibling twists (7-10
#: vertices per side, 1.8-2.2 turns) the multilevel smoothing failed once (9x9, t = 1.52 s) and SGS never (5 runs).
#: Kept multilevel until the impact zones between handles are robust. Re-measured with the multicolour orders (one
#: thread, loaded machine): pile 64x64 smoothing iterations per step multilevel 27.9, "sgs" 23.8, "sgs-blocks" 23.5,
#: "sgs-colours" 29.3, smoothing CPU per step within the load's noise of each other (10.8-11.9 ms; "sgs-colours" 14.3);
#: the twist test now passes with each, and in the sibling twists (8x8 2.2 turns, 9x9, 10x10, 8x8 1.8, 7x7 2.0) each
#: fails about as often (multilevel 7x7; "sgs" 8x8 2.2; "sgs-colours" 8x8 2.2 and 9x9): no reason to change then.
#: Tried "sgs-blocks" for two threads (the multilevel CG's level corrections run serially every iteration, its
#: Galerkin matrices in at most 4 chunks every call; the SGS sweeps in parallel, no setup; an SGS order also forms
#: the matrix directly in its order, ``SweepOrder.solve_shifted``): whole 64x64 pile on one thread (CPU, loaded
#: machine) 28.4 -> 24.5 smoothing iterations per step, CPU per step within the load's noise, 0 intersections; but
#: the pile's step-61 smoothing system, fastest of 829 interleaved calls on a loaded machine (load 3-4, Intel
#: Xeon), took 9.52 / 7.12 ms (1 / 2 threads, multilevel with its level set-up) against 9.16 / 8.02 (sgs-blocks).
#: Kept multilevel until a quiet two-core measurement shows the change pays.
SMOOTH_PRECONDITIONER = "multilevel"

__all__ = ["ImplicitEuler", "LinearSolveInfo", "pcg_constrained"]


@dataclass(frozen=True)
class LinearSolveInfo:
    """What one linear solve cost.

    Attributes:
        method: ``"cg"`` or ``"splu"``.
        iterations: CG iterations (0 for splu).
        assemble_seconds: time to build the matrix [s].
        solve_seconds: time to solve [s].
        contact_impulses: normal impulse [N s] each contact constraint applied over the step (> 0
            pushes the vertex away from the obstacle, < 0 held it on: release it next step).
    """

    method: str
    iterations: int
    assemble_seconds: float
    solve_seconds: float
    contact_impulses: np.ndarray | None = None


class _Pattern:
    """3x3-block sparse pattern (block CSR over vertices) of the union of element stencils and the
    vertices' diagonal blocks; ``maps[s]`` (m, k, k) are the block positions of stencil ``s``'s elements."""

    def __init__(self, n: int, stencils: list[np.ndarray]):
        self.n = n
        keys = [(v[:, :, None].astype(np.int64) * n + v[:, None, :]).reshape(-1) for v in stencils]
        diag = np.arange(n, dtype=np.int64) * (n + 1)
        uk, inv = np.unique(np.concatenate(keys + [diag]), return_inverse=True)
        self.nnzb = len(uk)
        rows = uk // n
        self.indptr = np.searchsorted(rows, np.arange(n + 1)).astype(np.int64)
        self.indices = (uk % n).astype(np.int64)
        sizes = np.cumsum([0] + [len(k) for k in keys])
        self.maps = [inv[sizes[i]:sizes[i + 1]].reshape(s.shape[0], s.shape[1], s.shape[1])
                     for i, s in enumerate(stencils)]
        #: (n,) position of each vertex's diagonal block
        self.diag = np.ascontiguousarray(inv[sizes[-1]:])
        #: the element sub-blocks each block gathers (``_kernels.gather_stiffness``), in element order: for the
        #: triangles (stencil 0, 9x9 blocks) ``(ptr (nnzb + 1,), flat offsets)``, for the hinges (stencil 1,
        #: Gauss-Newton factors ``g`` (h, 12)) ``(ptr, hinge, offsets (., 2) of g_a and g_b)``
        #: per stencil, the element corners each vertex gathers (``_energy_kernels.gather_rows``): ``(ptr (n + 1,),
        #: ids k e + a)`` in element order
        self.rows = []
        for v in stencils:
            flat = np.asarray(v, dtype=np.int64).reshape(-1)
            order = np.argsort(flat, kind="stable").astype(np.int64)
            self.rows.append((np.searchsorted(flat[order], np.arange(n + 1)).astype(np.int64), order))
        self.gathers = []
        for s, mp in enumerate(self.maps):
            k = mp.shape[1] if mp.ndim == 3 else 0
            flat = mp.reshape(-1)
            order = np.argsort(flat, kind="stable").astype(np.int64)  # ids k^2 e + k a + b, e ascending
            ptr = np.searchsorted(flat[order], np.arange(self.nnzb + 1)).astype(np.int64)
            e, ab = np.divmod(order, max(k * k, 1))
            a, b = np.divmod(ab, max(k, 1))
            if s == 0:
                self.gathers.append((ptr, np.ascontiguousarray(81 * e + 27 * a + 3 * b)))
            else:
                self.gathers.append((ptr, np.ascontiguousarray(e), np.ascontiguousarray(
                    np.stack([3 * k * e + 3 * a, 3 * k * e + 3 * b], axis=1))))

    def zeros(self) -> np.ndarray:
        return np.zeros((self.nnzb, 3, 3))

    def add_diagonal(self, data: np.ndarray, d: np.ndarray) -> None:
        """``data += diag(d)`` for ``d`` (3n,) (node-major)."""
        d = d.reshape(-1, 3)
        for c in range(3):
            data[self.diag, c, c] += d[:, c]

    def csr(self, data: np.ndarray) -> sp.csr_matrix:
        return sp.bsr_matrix((data, self.indices, self.indptr), shape=(3 * self.n, 3 * self.n)).tocsr()


def _constraints(n: int, fixed, fixed_values, contacts):
    """Per-vertex constraint arrays for ``_kernels.pcg``: kind (n,) int8, normal (n, 3), prescribed part
    z (n, 3) (fixed values and normal components); contact normals are normalised."""
    kind = np.zeros(n, np.int8)
    normal = np.zeros((n, 3))
    z = np.zeros((n, 3))
    if contacts is not None and len(contacts[0]):
        idx = np.asarray(contacts[0], dtype=np.int64)
        nrm = np.asarray(contacts[1], dtype=float)
        nrm = nrm / np.linalg.norm(nrm, axis=1)[:, None]
        kind[idx] = 1
        normal[idx] = nrm
        z[idx] = nrm * np.asarray(contacts[2], dtype=float)[:, None]
    if fixed is not None and len(fixed):
        idx = np.asarray(fixed, dtype=np.int64)
        kind[idx] = 2
        z[idx] = np.asarray(fixed_values, dtype=float).reshape(-1, 3)
    return kind, normal, z


def _project(kind: np.ndarray, normal: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``S u`` (n, 3) per vertex."""
    out = u.copy()
    out[kind == 2] = 0.0
    c = kind == 1
    out[c] -= normal[c] * np.sum(u[c] * normal[c], axis=1)[:, None]
    return out


#: aggregation stops once a level has at most this many aggregates (its 3x as many DOFs are solved directly)
COARSEST = 64


class _Levels:
    """Aggregation levels of a block pattern for the multilevel preconditioner of ``_kernels.pcg``: greedy
    aggregation of the vertex graph, repeated on the graph of the aggregates until at most ``COARSEST``
    remain. Built once per pattern. ``agg`` (n,): each vertex's level-0 aggregate; aggregates of all levels
    numbered together, level ``l`` from ``off[l]``; ``up``: each aggregate's parent on the next level."""

    def __init__(self, indptr: np.ndarray, indices: np.ndarray):
        from modalfem.cloth import _kernels

        n = len(indptr) - 1
        maps, counts = [], []
        gp, gi = indptr, indices
        while n > 1:
            a, k = _kernels.aggregate(gp, gi)
            if k == n:  # no edges left (separate pieces): one aggregate of everything, the global translations
                a, k = np.zeros(n, np.int64), 1
            maps.append(a)
            counts.append(k)
            if k <= COARSEST:
                break
            rows = np.repeat(np.arange(n), np.diff(gp))
            keys = np.unique(a[rows] * k + a[gi])
            gp = np.searchsorted(keys // k, np.arange(k + 1)).astype(np.int64)
            gi = (keys % k).astype(np.int64)
            n = k
        self.off = np.cumsum([0] + counts).astype(np.int64)
        self.agg = maps[0].astype(np.int64) if maps else np.zeros(len(indptr) - 1, np.int64)
        self.up = np.concatenate([m + o for m, o in zip(maps[1:], self.off[1:-1])] + [np.zeros(0)]).astype(np.int64)

    def inverses(self, indptr, indices, data, kind, normal):
        """(Dinv, Cinv) for ``_kernels.pcg``: inverses of the levels' diagonal blocks and of the coarsest
        matrix (regularised by 1e-10 of its mean diagonal: see ``_kernels.level_matrices``)."""
        from modalfem.cloth import _kernels

        if len(self.off) < 2:
            return np.zeros((0, 3, 3)), np.zeros((0, 0))
        Dinv, C = _kernels.level_matrices(indptr, indices, data, kind, normal, self.agg, self.up, self.off)
        d = np.diagonal(C)
        scale = d.mean() if np.any(d > 0) else 1.0
        C[np.diag_indices_from(C)] += 1e-10 * scale + (d == 0) * scale
        return Dinv, np.linalg.inv(C)


class _Shifted:
    """The block matrix ``scale K + diag(d)`` (``K`` (nnzb, 3, 3) on a pattern, ``d`` (n, 3)), formed where a solve
    takes it: a block multicolour SGS solve forms it directly in its order (``SweepOrder.solve_shifted``)."""

    def __init__(self, K: np.ndarray, indptr: np.ndarray, diag: np.ndarray, scale: float, d: np.ndarray):
        self.K, self.indptr, self.diag, self.scale, self.d = K, indptr, diag, float(scale), d

    def data(self) -> np.ndarray:
        from modalfem.cloth import _kernels

        out = np.empty_like(self.K)
        _kernels.scale_plus_diagonal(self.K, self.indptr, self.diag, self.scale, self.d, out)
        return out


def _solve_cg(indptr, indices, data, diag, b, kind, normal, z, guess, rtol: float, maxiter: int,
              levels):
    """Filtered PCG: the multilevel preconditioner on ``levels`` (``_Levels``), or symmetric block Gauss-Seidel in
    vertex order (None) or in a ``_sgs_kernels.SweepOrder``; ``data`` the block matrix or a ``_Shifted`` one."""
    from modalfem.cloth import _kernels, _sgs_kernels

    y = z + (_project(kind, normal, guess) if guess is not None else 0.0)
    shifted = isinstance(data, _Shifted)
    if shifted and not isinstance(levels, _sgs_kernels.SweepOrder):
        data, shifted = data.data(), False
    if shifted:
        it, res = levels.solve_shifted(data.K, data.scale, data.d, kind, normal, b, y, float(rtol), int(maxiter))
    elif isinstance(levels, _sgs_kernels.SweepOrder):
        it, res = levels.solve(data, kind, normal, b, y, float(rtol), int(maxiter))
    elif levels is None:
        it, res = _sgs_kernels.pcg_sgs(indptr, indices, data, diag, kind, normal, b, y, float(rtol), int(maxiter))
    else:
        Dinv, Cinv = levels.inverses(indptr, indices, data, kind, normal)
        it, res = _kernels.pcg(indptr, indices, data, diag, kind, normal, b, y, float(rtol), int(maxiter), levels.agg,
                               levels.up, levels.off, Dinv, Cinv)
    if it < 0:
        raise SolverError(f"cloth CG did not reach relative residual {rtol:g} in {maxiter} iterations "
                          f"(reached {res:.2g})")
    return y, it


#: the CG preconditioners: symmetric block Gauss-Seidel with its sweeps in vertex order (serial), in a block
#: multicolour order (groups of consecutive vertices coloured, a colour's groups in parallel) or in a vertex
#: multicolour order (a colour's vertices in parallel); block Jacobi plus additive aggregation levels
PRECONDITIONERS = ("sgs", "sgs-blocks", "sgs-colours", "multilevel")
_SWEEPS = {"sgs": "natural", "sgs-blocks": "blocks", "sgs-colours": "colours"}


def _check_preconditioner(name) -> None:
    if name not in PRECONDITIONERS:
        raise InputError(f"CG preconditioner must be one of {', '.join(map(repr, PRECONDITIONERS))}, got {name!r}")


def _preconditioner_setup(name: str, indptr, indices, diag):
    """What ``_solve_cg`` takes as ``levels`` for the preconditioner ``name`` (built once per pattern)."""
    from modalfem.cloth import _sgs_kernels

    if name == "multilevel":
        return _Levels(indptr, indices)
    if name == "sgs":
        return None
    return _sgs_kernels.SweepOrder(indptr, indices, diag, _SWEEPS[name])


def pcg_constrained(A, b: np.ndarray, *, fixed=None, fixed_values=None, contacts=None, x0=None,
                    rtol: float = 1e-6, maxiter: int = 1000, preconditioner: str = "sgs-blocks"):
    """Filtered preconditioned conjugate gradients (the ``"cg"`` solver of ``ImplicitEuler``) for a sparse SPD
    ``A`` (3n, 3n).

    Solves ``A y = b`` on the free components: the vertices ``fixed`` (k,) have ``y_i = fixed_values``
    (k, 3); for ``contacts`` = (indices (c,), unit normals (c, 3), values (c,)), ``n . y_i`` is prescribed.
    Converged when ``|S (b - A y)| <= rtol |b'|`` (``b'``: ``S (b - A z)`` with the fixed values in the
    fixed rows, the right-hand side once the constrained components are eliminated; ``z``: the prescribed
    part).

    Args:
        A: SPD sparse matrix (3n, 3n), node-major DOFs.
        b: right-hand side (3n,).
        fixed, fixed_values, contacts: the constraints.
        x0: start (3n,) (its constrained components are replaced).
        rtol: relative residual.
        maxiter: iteration cap.
        preconditioner: one of ``PRECONDITIONERS``: ``"sgs-blocks"`` (default: symmetric block Gauss-Seidel in a
            block multicolour order, parallel sweeps, ``_sgs_kernels``), ``"sgs"`` (in vertex order, serial sweeps),
            ``"sgs-colours"`` (in a vertex multicolour order) or ``"multilevel"`` (block Jacobi plus additive
            aggregation levels, ``_kernels.pcg``).

    Returns:
        (y (3n,), iterations).

    Raises:
        InputError: a size not divisible by 3, or an unknown preconditioner.
        SolverError: no convergence within ``maxiter``.
    """
    if A.shape[0] % 3 or A.shape[0] != A.shape[1]:
        raise InputError(f"pcg_constrained needs a square matrix of size 3n, got {A.shape}")
    _check_preconditioner(preconditioner)
    n = A.shape[0] // 3
    B = sp.bsr_matrix(sp.csr_matrix(A), blocksize=(3, 3))  # SPD: every diagonal block is present
    B.sum_duplicates()
    B.sort_indices()
    rows = np.repeat(np.arange(n), np.diff(B.indptr))
    diag = np.empty(n, np.int64)
    on = np.flatnonzero(B.indices == rows)
    diag[rows[on]] = on
    kind, normal, z = _constraints(n, fixed, fixed_values, contacts)
    guess = None if x0 is None else np.asarray(x0, dtype=float).reshape(n, 3)
    ip, ind = B.indptr.astype(np.int64), B.indices.astype(np.int64)
    y, it = _solve_cg(ip, ind, np.ascontiguousarray(B.data, float), diag, np.asarray(b, dtype=float).reshape(n, 3),
                      kind, normal, z, guess, rtol, maxiter,
                      _preconditioner_setup(preconditioner, ip, ind, diag))
    return y.reshape(-1), it


class ImplicitEuler:
    """Backward Euler velocity update for a ``ClothModel`` (see module docstring).

    Args:
        model: the cloth.
        linear_solver: ``"cg"`` (default) or ``"splu"``.
        cg_rtol: CG relative residual.
        cg_maxiter: CG iteration cap.
        cg_preconditioner: ``"sgs-blocks"`` (default: symmetric block Gauss-Seidel in a block multicolour order,
            parallel sweeps), ``"sgs"`` (the same in vertex order, serial sweeps), ``"sgs-colours"`` (in a vertex
            multicolour order) or ``"multilevel"`` (block Jacobi plus aggregation levels); see the module docstring.

    Raises:
        InputError: unknown linear solver or preconditioner.
    """

    def __init__(self, model: ClothModel, *, linear_solver: str = "cg", cg_rtol: float = 1e-4, cg_maxiter: int = 2000,
                 cg_preconditioner: str = "sgs-blocks"):
        if linear_solver not in ("cg", "splu"):
            raise InputError(f"linear_solver must be 'cg' or 'splu', got {linear_solver!r}")
        _check_preconditioner(cg_preconditioner)
        self.cg_preconditioner = cg_preconditioner
        self.model = model
        self.linear_solver = linear_solver
        self.cg_rtol = float(cg_rtol)
        self.cg_maxiter = int(cg_maxiter)
        mesh = model.mesh
        self._pattern = _Pattern(mesh.point_count, [mesh.triangles, mesh.hinges.vertices])
        self._setups = {}  # per preconditioner, its levels or sweep order (built on first use)
        self._m3 = np.repeat(model.masses, 3)
        self._Kdata = None
        self._mblocks = None
        self._mgrads = None
        self._m_ones = np.ones(len(mesh.triangles))
        self._last_dv = None
        self._last_smooth = None  # the last smoothed change: the next smoothing solve's start
        #: CG iterations of the last ``smooth`` call
        self.smooth_iterations = 0

    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        """Projected elastic Hessian K (3n, 3n) [N/m] at ``x`` (n, 3) [m]; also kept for ``smooth``."""
        self._stiffness_data(x)
        return self._pattern.csr(self._Kdata)

    def _stiffness_data(self, x: np.ndarray, bending_factors=None) -> np.ndarray:
        """K's block data (nnzb, 3, 3): the triangles' blocks computed in parallel, then gathered per block in
        parallel (``_kernels.gather_stiffness``: the sums of a serial scatter, in its order). ``bending_factors``:
        ``Bending.gauss_newton_factors(x)`` if already computed."""
        from modalfem.cloth import _energy_kernels, _kernels

        m, pat = self.model, self._pattern
        if self._mblocks is None:
            self._mblocks = np.empty((len(pat.maps[0]), 9, 9))
            self._mgrads = np.empty((len(pat.maps[0]), 3, 3))
        # the membrane gradient's terms in the same pass (``_membrane_gradient``)
        _energy_kernels.membrane_hessian_and_gradient(*m.membrane._args(x), True, self._mblocks, self._mgrads)
        if not len(pat.maps[1]):
            w, g = np.zeros(0), np.zeros((0, 12))
        else:
            w, g = m.bending.gauss_newton_factors(x) if bending_factors is None else bending_factors
        data = np.empty((pat.nnzb, 3, 3))
        _kernels.gather_stiffness(pat.indptr, *pat.gathers[0], self._mblocks, *pat.gathers[1],
                                  np.ascontiguousarray(w, dtype=float), np.ascontiguousarray(g, dtype=float), data)
        self._Kdata = data
        return data

    def _gather_rows(self, stencil: int, values: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(n, 3): each vertex's sum of ``w[e] * values[e, a]`` over the corners ``a`` it is of the stencil's
        elements ``e`` (values (m, k, 3)), in element order (a serial scatter's bits), vertices in parallel."""
        from modalfem.cloth import _energy_kernels

        ptr, src = self._pattern.rows[stencil]
        out = np.empty((self._pattern.n, 3))
        k = values.shape[1]
        _energy_kernels.gather_rows(ptr, src, np.ascontiguousarray(values.reshape(-1, 3), dtype=float),
                                    np.ascontiguousarray(w, dtype=float), k, out)
        return out

    def _scale_plus_diagonal(self, K: np.ndarray, scale: float, d: np.ndarray) -> np.ndarray:
        """``scale K + diag(d)`` (block data; ``d`` (3n,) node-major)."""
        from modalfem.cloth import _kernels

        pat = self._pattern
        out = np.empty_like(K)
        _kernels.scale_plus_diagonal(K, pat.indptr, pat.diag, float(scale), np.ascontiguousarray(d.reshape(-1, 3)),
                                     out)
        return out

    def _matvec(self, data: np.ndarray, u: np.ndarray) -> np.ndarray:
        from modalfem.cloth import _kernels

        out = np.empty((self._pattern.n, 3))
        _kernels.bsr_matvec(self._pattern.indptr, self._pattern.indices, data, np.ascontiguousarray(u), out)
        return out

    def _solve(self, data: np.ndarray, b: np.ndarray, kind: np.ndarray, normal: np.ndarray, z: np.ndarray,
               guess=None, rtol: float | None = None, preconditioner: str | None = None):
        """Solve ``A y = b`` (A from the pattern ``data``, b (n, 3)) on the free components with the
        prescribed part ``z`` (n, 3) (``_constraints``); CG with ``preconditioner`` (default
        ``cg_preconditioner``). Returns (y (n, 3), iterations, seconds)."""
        pat = self._pattern
        t0 = time.perf_counter()
        if self.linear_solver == "splu":
            A = pat.csr(data.data() if isinstance(data, _Shifted) else data)
            S = np.tile(np.eye(3), (pat.n, 1, 1))
            S[kind == 2] = 0.0
            c = kind == 1
            S[c] -= normal[c][:, :, None] * normal[c][:, None, :]
            Ssp = sp.bsr_matrix((S, np.arange(pat.n), np.arange(pat.n + 1))).tocsr()
            As = (Ssp @ A @ Ssp + sp.identity(3 * pat.n) - Ssp).tocsc()
            rhs = Ssp @ (b.reshape(-1) - A @ z.reshape(-1))
            y = spla.splu(As, permc_spec="MMD_AT_PLUS_A").solve(rhs).reshape(-1, 3) + z
            return y, 0, time.perf_counter() - t0
        rtol = self.cg_rtol if rtol is None else rtol
        y, it = _solve_cg(pat.indptr, pat.indices, data, pat.diag, b, kind, normal, z, guess, rtol, self.cg_maxiter,
                          self._setup(preconditioner or self.cg_preconditioner))
        return y, it, time.perf_counter() - t0

    @property
    def _levels(self) -> _Levels:
        """The multilevel preconditioner's aggregation levels on this cloth's pattern."""
        return self._setup("multilevel")

    def _setup(self, name: str):
        """The levels or sweep order of the preconditioner ``name`` on this cloth's pattern (cached)."""
        _check_preconditioner(name)
        if name not in self._setups:
            pat = self._pattern
            self._setups[name] = _preconditioner_setup(name, pat.indptr, pat.indices, pat.diag)
        return self._setups[name]

    @serial_blas
    def step_velocity(self, x, v, forces, dt: float, *, fixed=None, fixed_velocity=None, damping_blocks=None,
                      contacts=None, friction=None):
        """Velocities at the end of a backward Euler step, before collisions.

        Args:
            x: positions (n, 3) [m] at the start of the step.
            v: velocities (n, 3) [m/s] at the start of the step.
            forces: external forces (n, 3) [N] (gravity, wind, ...), excluding elastic and damping ones.
            dt: time step [s] > 0.
            fixed: indices (k,) of vertices with prescribed velocity (handles).
            fixed_velocity: their velocities (k, 3) [m/s] over the step.
            damping_blocks: extra per-triangle damping blocks (m, 9, 9) [kg/s] (``df/dv = -C``), e.g. wind.
            contacts: ``(indices (k,), unit normals (k, 3), normal velocities (k,) [m/s])``: vertices resting
                on an obstacle, whose end-of-step velocity along ``n`` is prescribed (Baraff-Witkin
                constraint filtering; tangential motion stays free). Not for handle vertices.
            friction: ``(mu [-], obstacle surface velocities (k, 3) [m/s], v_eps [m/s])`` for the contacts:
                Coulomb friction inside the solve as a tangential damping of each contact vertex towards its
                obstacle's velocity, ``k_i P_t`` added to its diagonal block with ``k_i = mu J_i / max(|v_t|,
                v_eps)`` [kg] (``J_i = max(0, m_i dv_n - b_i . n)`` [N s], the impulse that holds the vertex
                alone on the obstacle this step; ``v_t`` its tangential velocity relative to the obstacle at the
                start): alone, a vertex's tangential speed shrinks by ``k/(m + k)``, an impulse of at most ``mu
                J``, never reversed; with its neighbours, the sheet's stiffness shares it. Backward Euler damping
                only removes energy (a friction pass after the solve stopped vertices one by one against their
                neighbours and the shear came back as elastic energy).

        Returns:
            ``(v_new (n, 3) [m/s], LinearSolveInfo)``.

        Raises:
            SimulationError: dt <= 0 or non-finite inputs.
            SolverError: CG failure.
        """
        if not (np.isfinite(dt) and dt > 0):
            raise SimulationError(f"time step must be finite and > 0 s, got {dt!r}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v)) and np.all(np.isfinite(forces))):
            raise SimulationError("cloth state or forces hold NaN/inf before the step")
        from modalfem.cloth import _kernels

        mdl, pat = self.model, self._pattern
        t0 = time.perf_counter()
        v = np.asarray(v, dtype=float)
        wg_b, w_b, g_b = mdl.bending.angle_factors(x)  # one evaluation of the dihedral angles
        Kd = self._stiffness_data(x, (w_b, g_b.reshape(-1, 12)))  # also the membrane gradient's terms
        grad_m = self._gather_rows(0, self._mgrads, self._m_ones)
        grad_b = self._gather_rows(1, g_b, wg_b) if len(wg_b) else np.zeros_like(grad_m)
        f = forces - grad_m - grad_b
        Kv = self._matvec(Kd, v)
        a, beta = mdl.mass_damping, mdl.stiffness_damping
        m = mdl.masses[:, None]
        Cv = a * m * v + beta * Kv
        data = self._scale_plus_diagonal(Kd, dt * dt + dt * beta, self._m3 * (1.0 + dt * a))
        if damping_blocks is not None:
            Cw = pat.zeros()
            _kernels.scatter_blocks(Cw, pat.maps[0], np.ascontiguousarray(damping_blocks, dtype=float), 1.0)
            Cv = Cv + self._matvec(Cw, v)
            data += dt * Cw
        b = dt * (f - Cv - dt * Kv)
        t_asm = time.perf_counter() - t0
        con = None
        if contacts is not None:
            ci = np.asarray(contacts[0], dtype=np.int64)
            cn = np.asarray(contacts[1], dtype=float)
            con = (ci, cn, np.asarray(contacts[2], dtype=float) - np.sum(v[ci] * cn, axis=1))  # normal part of dv
        if con is not None and friction is not None and friction[0] > 0 and len(con[0]):
            data, b = self._friction(data, b, v, con, friction)
        fixed = np.zeros(0, np.int64) if fixed is None else np.asarray(fixed, dtype=np.int64)
        dv_fixed = np.zeros((0, 3)) if fixed.size == 0 else np.asarray(fixed_velocity, dtype=float) - v[fixed]
        kind, normal, z = _constraints(pat.n, fixed, dv_fixed, con)
        guess = self._last_dv if self._last_dv is not None and self._last_dv.shape == b.shape else None
        dv, it, t_sol = self._solve(data, b, kind, normal, z, guess)
        imp = None
        if con is not None:
            ci = con[0]
            imp = np.sum((self._matvec(data, dv) - b)[ci] * normal[ci], axis=1)
        self._last_dv = dv
        v_new = v + dv
        if not np.all(np.isfinite(v_new)):
            raise SimulationError("cloth velocities became NaN/inf in the implicit step (time step too large?)")
        return v_new, LinearSolveInfo(self.linear_solver, it, t_asm, t_sol, imp)

    def _friction(self, data: np.ndarray, b: np.ndarray, v: np.ndarray, con, friction):
        """The system ``(data, b)`` with the contacts' Coulomb friction as tangential damping (``step_velocity``)."""
        mu, vo, v_eps = float(friction[0]), np.asarray(friction[1], dtype=float), float(friction[2])
        ci, cn, dvn = con
        cn = cn / np.linalg.norm(cn, axis=1)[:, None]
        m = self.model.masses[ci]
        J = np.maximum(0.0, m * dvn - np.sum(b[ci] * cn, axis=1))
        rel = v[ci] - vo
        vt = rel - cn * np.sum(rel * cn, axis=1)[:, None]
        k = mu * J / np.maximum(np.linalg.norm(vt, axis=1), v_eps)
        Pt = np.eye(3)[None] - cn[:, :, None] * cn[:, None, :]
        data[self._pattern.diag[ci]] += k[:, None, None] * Pt  # data and b are this step's own arrays
        b = b.copy()
        b[ci] -= k[:, None] * vt
        return data, b

    @serial_blas
    def smooth(self, dv: np.ndarray, dt: float, *, strength: float, fixed=None) -> np.ndarray:
        """Smoothed velocity change: solve ``(M + dt * strength * K) dv_s = M dv`` with ``dv_s[fixed] = 0``
        (CG from the last call's answer: in a resting pile the contact response changes little from step to step).

        Args:
            dv: velocity change (n, 3) [m/s] (e.g. collision response minus the implicit prediction).
            dt: time step [s].
            strength: smoothing time beta_s [s] (0: no smoothing).
            fixed: indices of vertices whose change stays 0 (handles).

        Returns:
            dv_s (n, 3) [m/s]; uses the stiffness K of the last ``step_velocity``.
        """
        self.smooth_iterations = 0
        if strength <= 0 or self._Kdata is None or not np.any(dv):
            return dv
        pat = self._pattern
        data = _Shifted(self._Kdata, pat.indptr, pat.diag, dt * strength, self._m3.reshape(-1, 3))
        fixed = np.zeros(0, np.int64) if fixed is None else np.asarray(fixed, dtype=np.int64)
        kind, normal, z = _constraints(pat.n, fixed, np.zeros((fixed.size, 3)), None)
        m = self.model.masses
        last = self._last_smooth
        y, self.smooth_iterations, _ = self._solve(data, m[:, None] * dv, kind, normal, z,
                                                   guess=last if last is not None and last.shape == dv.shape else None,
                                                   rtol=max(self.cg_rtol, SMOOTH_RTOL),
                                                   preconditioner=SMOOTH_PRECONDITIONER)
        self._last_smooth = y.copy()
        if fixed.size == 0:  # the exact solution keeps the momentum of dv: restore what the residual changed
            y += (m @ dv - m @ y) / m.sum()
        return y
