"""Implicit backward Euler for tetrahedral soft bodies: ``TetState``, ``TetControl``, ``TetSolver``.

One step minimises the incremental potential (Newton with a backtracking line search)

    E(x) = 1/(2 h^2) |x - x_n - h v_n|_M^2 + Phi(x) + 1/(2 h) |x - x_n|_D^2,

``Phi`` the elastic energy plus the opt-in potentials, ``D = alpha M + beta K(x_n)`` Rayleigh damping;
then ``v_{n+1} = (x_{n+1} - x_n) / h``. ``newton_max=1`` is the classic linearised step from ``x_n``
(Baraff-Witkin); full Newton starts at the predicted ``x_n + h (v_n + dv_prev)`` when its potential is lower
(``dv_prev`` the previous step's velocity change), and an iteration that follows a small full step reuses
that step's matrix (``REUSE_BELOW``). ``integrator="bdf2"`` (optional, second order, much less numerical
damping) uses the same potential with ``h -> 2h/3``, ``x_n -> (4 x_n - x_{n-1}) / 3`` and
``v_n -> (4 v_n - v_{n-1}) / 3`` once a previous step of the same dt is known (backward Euler before).
Newton uses the exact element Hessians and falls back to ones projected to positive semi-definite
(the system matrix ``M / h^2 + H`` then SPD) when a solve meets negative curvature (``projection``). Solved
by CG with a two-level preconditioner (default, ``modalfem.tet.precond``), Jacobi-PCG, or SuperLU.
Pinned (``Pins``) and scripted (``TetControl``) vertices are eliminated (identity rows).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from modalfem.errors import InputError, SimulationError
from modalfem.tet.assembly import HessianPattern
from modalfem.tet.energies import (
    VolumeBarrierDensity,
    element_forces_and_hessians,
    element_hessians,
    first_piola,
)
from modalfem.tet.kinematics import scatter_vertices, svd_rv_of_positions
from modalfem.tet.model import TetModel
from modalfem.tet.precond import Preconditioner, TwoLevel
from modalfem._threads import serial_blas

__all__ = ["LINEAR_SOLVERS", "StepInfo", "TetControl", "TetSolver", "TetState"]

LINEAR_SOLVERS = ("cg", "splu", "spsolve")
#: a Newton iteration whose full step moved no vertex more than this many times the tolerance is followed by
#: one that reuses its matrix (forces only: no Hessians, no assembly, no preconditioner set-up). The
#: Hessian's change over such a step is O(step), so the reused solve still contracts the error by a factor
#: O(step) per iteration; on the 10k-tet benchmark bar this saves the assembly of the last iteration.
REUSE_BELOW = 300.0


@dataclass
class TetState:
    """Changing state of a tetrahedral body.

    Attributes:
        x: vertex positions (n, 3) [m].
        v: vertex velocities (n, 3) [m/s].
        t: time [s].
        history: ``(x, v, dt)`` of the previous step (used by ``integrator="bdf2"``), or None.
    """

    x: np.ndarray
    v: np.ndarray
    t: float = 0.0
    history: tuple | None = None

    @classmethod
    def at_rest(cls, model: TetModel) -> TetState:
        """The rest configuration with zero velocity at t = 0."""
        return cls(model.rest_points.copy(), np.zeros((model.point_count, 3)), 0.0)

    def copy(self) -> TetState:
        return TetState(self.x.copy(), self.v.copy(), float(self.t), self.history)


@dataclass(frozen=True, eq=False)
class TetControl:
    """Per-step inputs: scripted vertices and where they must be at the end of the step.

    Args:
        vertices: vertex indices (k,).
        positions: their positions at the end of the step (k, 3) [m].
    """

    vertices: np.ndarray
    positions: np.ndarray


@dataclass
class StepInfo:
    """What one step did.

    Attributes:
        newton_iterations: Newton iterations (linear solves) taken, a redone one included.
        linear_iterations: total CG iterations (0 for direct solves).
        converged: the Newton step fell below the tolerance.
        projected: the step fell back to projected element Hessians (``projection="on_demand"``: the exact
            ones were indefinite), or used them throughout (``"always"``).
        assembly_s, solve_s, total_s: wall time [s] in energy/gradient/Hessian evaluation, in linear
            solves, and in the whole step.
    """

    newton_iterations: int = 0
    linear_iterations: int = 0
    converged: bool = False
    predicted: bool = False
    projected: bool = False
    assembly_s: float = 0.0
    solve_s: float = 0.0
    total_s: float = 0.0


def _bad_rows(a: np.ndarray, what: str = "vertex") -> str:
    """"k non-finite values, first at vertex i (row values)" for an (n, 3) array with NaN/inf."""
    bad = ~np.isfinite(a)
    i = int(np.flatnonzero(bad.reshape(len(a), -1).any(axis=1))[0])
    return f"{int(bad.sum())} non-finite values, first at {what} {i}: {np.asarray(a[i]).tolist()}"


def _matvec(A, x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = A x`` for a scipy CSR ``A`` (compiled, rows in parallel); returns ``out``."""
    from modalfem.tet import _kernels

    _kernels.csr_matvec(A.indptr, _kernels.unsigned(A.indices), A.data, x, out)
    return out


def _pcg(A, b: np.ndarray, prec: Preconditioner, rtol: float, maxiter: int, x0: np.ndarray | None = None, *,
         blocked: bool | None = None) -> tuple[np.ndarray, int, bool]:
    """Preconditioned conjugate gradients for ``A x = b`` (scipy CSR ``A``; ``prec`` applies M^-1) from
    ``x0`` (default 0), to ``|r| <= rtol |b|``: compiled (:func:`modalfem.tet._kernels.pcg_twolevel`).

    Returns ``(x, iterations, definite)``; ``definite`` is False when CG stopped at a direction ``p`` with
    ``p^T A p <= 0`` before reaching the tolerance (``A`` is not positive definite). (A 3x3 block-Jacobi
    preconditioner was measured too: the same iteration counts as Jacobi on the benchmark bar.)
    ``blocked``: ``A`` is made of full 3x3 vertex blocks (every ``HessianPattern`` matrix; its products
    then read each column index once per block); None: checked here.
    """
    from modalfem.tet import _kernels

    x = np.zeros(len(b)) if x0 is None else np.array(x0, dtype=float)
    if blocked is None:
        blocked = _kernels.is_blocked3(A.indptr, A.indices)
    it, definite = _kernels.pcg_twolevel(A.indptr, _kernels.unsigned(A.indices), A.data,
                                         np.ascontiguousarray(b, dtype=float), x, x0 is not None, *prec.arrays(),
                                         float(rtol), int(maxiter), bool(blocked))
    return x, int(it), bool(definite)


class TetSolver:
    """Backward Euler for a ``TetModel`` with opt-in effects.

    Args:
        model: the body's fixed data.
        effects: any of ``Gravity``, ``Ground``, ``RayleighDamping``, ``Pins``, ``VolumeSprings``,
            ``VolumeBarrier`` (``modalfem.tet.effects``); only these terms are ever evaluated.
        newton_max: Newton iterations per step, >= 1 (1 = one linearised step).
        tol: Newton stops when the largest vertex update is below ``tol * model.size`` [-].
        linear_solver: ``"cg"`` (preconditioned CG), ``"splu"`` or ``"spsolve"`` (SuperLU).
        preconditioner: for CG, ``"twolevel"`` (Jacobi + rigid motions of ~48 vertex aggregates,
            ``modalfem.tet.precond``; default) or ``"jacobi"``.
        cg_rtol: relative residual of the CG solves [-] (1e-3 keeps the linearised step within ~1 um of
            a 1e-6 solve on the 10k-tet benchmark bar, in ~15 iterations instead of ~30), of the solve
            that can end a Newton step (the first after a step under ``REUSE_BELOW`` x tol, or the only
            one with ``newton_max=1``).
        cg_rtol_far: relative residual of the earlier Newton iterations' solves [-], whose error the
            following iterations correct (inexact Newton); default ``min(30 cg_rtol, 0.03)``. On the 10k-tet
            benchmark bar 0.03 instead of 1e-3 takes ~36 CG iterations per step instead of ~53, with
            the same Newton iterations.
        integrator: ``"backward_euler"`` (default) or ``"bdf2"``.
        projection: ``"on_demand"`` (default): Newton uses the exact element Hessians, and only when a
            solve meets negative curvature (CG finds a direction with ``p^T A p <= 0``) or its result does
            not descend is that iteration, and the rest of the step, redone with projected ones;
            ``"always"``: every element Hessian projected to positive semi-definite. Projection clamps
            the negative geometric stiffness of compressed elements (the inner side of a bent bar), which
            turns Newton's quadratic convergence linear: on the 10k-tet benchmark bar ~3.7 instead of ~4.8
            iterations per step at tol 1e-6, to the same minimiser. The damping matrix ``K(x_n)`` of
            ``RayleighDamping`` is always projected.
        coarse_lag: the two-level preconditioner's coarse space (its sparse products and the inverse
            of the coarse matrix) serves up to this many solves, >= 1; it is rebuilt sooner when the held
            DOFs change or CG needs over 1.5x the iterations of the solve right after the rebuild.
            (A lagged coarse space is still SPD: CG reaches the same tolerance.) Default 6: on the 10k-tet
            benchmark bar (2 solves per step) 36.5 instead of 35.9 CG iterations per step with 4, ~2 ms
            less CPU per step (a rebuild costs about as much as 8 CG iterations).

    Per step the solver caches (results do not depend on the caches beyond CG and Newton tolerance and
    roundoff): the SVD of the last evaluated positions (a step's line search ends where the next step
    starts), the previous step's velocity change (the next step's prediction ``x_n + h (v_n + dv_prev)``:
    Newton's start, or the first CG's for ``newton_max=1``), the last matrix, and the coarse space.

    Raises:
        InputError: unknown effect or solver, bad numbers, pinned vertex out of range.
    """

    def __init__(self, model: TetModel, *, effects=(), newton_max: int = 8, tol: float = 1e-6,
                 linear_solver: str = "cg", cg_rtol: float = 1e-3, cg_rtol_far: float | None = None,
                 integrator: str = "backward_euler",
                 preconditioner: str = "twolevel", coarse_lag: int = 6, projection: str = "on_demand") -> None:
        if preconditioner not in ("twolevel", "jacobi"):
            raise InputError(f"unknown preconditioner {preconditioner!r}; choose 'twolevel' or 'jacobi'")
        if integrator not in ("backward_euler", "bdf2"):
            raise InputError(f"unknown integrator {integrator!r}; choose 'backward_euler' or 'bdf2'")
        self.integrator = integrator
        if linear_solver not in LINEAR_SOLVERS:
            raise InputError(f"unknown linear solver {linear_solver!r}; choose one of {LINEAR_SOLVERS}")
        if int(coarse_lag) < 1:
            raise InputError(f"coarse_lag must be >= 1, got {coarse_lag!r}")
        self.coarse_lag = int(coarse_lag)
        if projection not in ("on_demand", "always"):
            raise InputError(f"unknown projection {projection!r}; choose 'on_demand' or 'always'")
        self.projection = projection
        if int(newton_max) < 1:
            raise InputError(f"newton_max must be >= 1, got {newton_max!r}")
        if not (float(tol) > 0 and float(cg_rtol) > 0):
            raise InputError("tol and cg_rtol must be > 0")
        self.model = model
        self.newton_max = int(newton_max)
        self.tol = float(tol)
        self.cg_rtol = float(cg_rtol)
        self.cg_rtol_far = min(30.0 * self.cg_rtol, 0.03) if cg_rtol_far is None else float(cg_rtol_far)
        if not self.cg_rtol_far > 0:
            raise InputError(f"cg_rtol_far must be > 0, got {cg_rtol_far!r}")
        self.linear_solver = linear_solver
        from modalfem.effects import for_tet

        effects = [for_tet(e) for e in effects]  # modalfem.effects classes are taken too
        self.element_terms, self.vertex_terms, self.damping, pins = [model.density], [], None, []
        for e in effects:
            kind = getattr(e, "kind", None)
            if kind == "element":
                self.element_terms.append(e.density())
            elif kind == "vertex":
                self.vertex_terms.append(e)
            elif kind == "damping":
                if self.damping is not None:
                    raise InputError("give at most one RayleighDamping effect")
                self.damping = e
            elif kind == "pins":
                pins.append(e)
            else:
                raise InputError(f"unknown tet effect {e!r}")
        self.effects = tuple(effects)
        n = model.point_count
        self.fixed = np.zeros(n, dtype=bool)
        self.pin_targets = model.rest_points.copy()
        for p in pins:
            if p.vertices.size and (p.vertices.min() < 0 or p.vertices.max() >= n):
                raise InputError(f"pinned vertex index out of range [0, {n})")
            self.fixed[p.vertices] = True
            if p.positions is not None:
                self.pin_targets[p.vertices] = p.positions
        self.pattern = HessianPattern(model.cells, n)
        self._V = None
        self._grad_t = np.ascontiguousarray(np.moveaxis(model.grad, 0, -1))  # (4, 3, m)
        # DOF of each entry of element forces laid out (4 vertices, 3 components, m)
        force_index = np.moveaxis(3 * model.cells[:, :, None] + np.arange(3), 0, -1).ravel()
        # ... summed per DOF by a compiled gather (the order of np.bincount's scatter: the same sums)
        order = np.argsort(force_index, kind="stable")
        self._force_ptr = np.searchsorted(force_index[order], np.arange(3 * n + 1)).astype(np.int64)
        from modalfem.tet import _kernels

        self._force_order = _kernels.compact_unsigned(order)
        self._svd_cache = None  # (x, (U, s, V)) of the last evaluated positions
        self._previous = None  # (x, velocity change (3n,), h) of the last step
        self._lag = (0, 0, 0)  # coarse space: solves since its rebuild, CG iterations then, last CG iterations
        self.twolevel = TwoLevel(model.rest_points) if preconditioner == "twolevel" and linear_solver == "cg" else None
        self.mass_dofs = np.repeat(model.masses, 3)
        self.barrier = any(isinstance(t, VolumeBarrierDensity) for t in self.element_terms)

    def reset_caches(self) -> None:
        """Forget what earlier steps left (the SVD and its warm start, the previous step's velocity change, the
        lagged coarse space and its CG counts): the next step is then bit for bit a fresh solver's step. A run
        started again from an earlier state calls this (``World.step``): the lagged coarse space and the SVD's warm
        start otherwise change its roundoff (1.5e-10 m in a tet cube under a landing bar after 15 x 10 ms)."""
        self._svd_cache = None
        self._V = None
        self._previous = None
        self._lag = (0, 0, 0)
        if self.twolevel is not None:
            self.twolevel._coarse = None
            self.twolevel.rebuilt = False

    # ------------------------------------------------------------------ energies
    def _elastic(self, x: np.ndarray, order: int, *, upper: bool = False, project: bool = True):
        """Sum of element terms at ``x``: (energy [J], gradient (n, 3) [N] or None, blocks or None).

        ``blocks`` are the projected element Hessians (m, 12, 12), or their upper triangles (78, m) with
        ``upper``; with ``upper`` and not ``project`` the exact (possibly indefinite) Hessians.
        The SVD of the last evaluated ``x`` is kept: a linearised step's line search ends where the next
        step starts, so a step costs one SVD instead of two.
        """
        m = self.model
        cache = self._svd_cache
        if cache is not None and np.array_equal(cache[0], x):
            U, s, V = cache[1]
        else:  # rotations with the element index last, (3, 3, m)
            U, s, V = svd_rv_of_positions(x, m.cells, self._grad_t, self._V)
            self._V = V  # warm start of the next SVD (a cache; results do not depend on it beyond roundoff)
            self._svd_cache = (np.array(x, dtype=float), (U, s, V))
        d = self.element_terms[0].derivs(s, order)
        for t in self.element_terms[1:]:
            d = d + t.derivs(s, order)
        E = float(m.rest_volumes @ d.psi) if np.all(np.isfinite(d.psi)) else math.inf
        if order == 0 or not math.isfinite(E):
            return E, None, None
        if upper:  # forces (and Hessians) in one pass, element index last
            from modalfem.tet import _kernels

            if order >= 2:
                f, H = element_forces_and_hessians(U, V, d, self._grad_t, m.rest_volumes, element_last=True,
                                                   project=project)
            else:
                f, H = np.empty((4, 3, m.cell_count)), None
                _kernels.element_forces(U, V, np.ascontiguousarray(d.d1.T), self._grad_t, m.rest_volumes, f)
            g = np.empty((m.point_count, 3))
            _kernels.gather_sum(self._force_ptr, self._force_order, f.ravel(), g.ravel())
            return E, g, H
        U, V = np.moveaxis(U, -1, 0), np.moveaxis(V, -1, 0)
        P = first_piola(U, V, d.d1)
        f = np.matmul(m.grad, np.swapaxes(P, 1, 2)) * m.rest_volumes[:, None, None]  # V0 P grad_a
        g = scatter_vertices(f, m.cells, m.point_count)
        H = None
        if order >= 2:
            H = element_hessians(U, V, d, m.grad, m.rest_volumes, project=True)
        return E, g, H

    def energies(self, state: TetState) -> dict:
        """Energies [J] of a state and their sum ``total``.

        Keys: ``kinetic``, ``elastic`` (the material energy plus the opt-in volume springs / barrier) and
        one per vertex potential (``gravity``, ``ground``). Damping is dissipative and has no entry.
        """
        m = self.model
        out = {"kinetic": 0.5 * float(m.masses @ np.sum(state.v * state.v, axis=1)),
               "elastic": self._elastic(state.x, 0)[0]}
        for t in self.vertex_terms:
            out[type(t).__name__.lower()] = t.energy(state.x, m.masses)
        out["total"] = sum(out.values())
        return out

    def _incremental(self, x, xn, xhat, h, D, order: int, project: bool = True):
        """Incremental potential at ``x``: (E, gradient (3n,), Hessian data or None); ``project``: element
        Hessians projected to positive semi-definite (else exact)."""
        m = self.model
        dx = (x - xhat).ravel()
        E = 0.5 / h**2 * float(self.mass_dofs @ (dx * dx))
        Ee, ge, He = self._elastic(x, order, upper=True, project=project)
        E += Ee
        if D is not None:
            w = (x - xn).ravel()
            Dw = self.pattern.matrix(D) @ w
            E += 0.5 / h * float(w @ Dw)
        for t in self.vertex_terms:
            E += t.energy(x, m.masses)
        if order == 0 or not math.isfinite(E):
            return E, None, None
        g = self.mass_dofs * dx / h**2 + ge.ravel()
        for t in self.vertex_terms:
            g += t.gradient(x, m.masses).ravel()
        if D is not None:
            g += Dw / h
        if order == 1:
            return E, g, None
        diag = self.mass_dofs / h**2
        for t in self.vertex_terms:
            hd = t.hessian_diagonal(x, m.masses)
            if hd is not None:
                diag = diag + hd.ravel()
        data = self.pattern.assemble(He, diag, upper=True)
        for t in self.vertex_terms:  # a term's couplings between DOFs of one tetrahedron (contact normals)
            entries = t.hessian_entries(x, m.masses) if hasattr(t, "hessian_entries") else None
            if entries is not None:
                np.add.at(data, self.pattern.positions(entries[0], entries[1]), entries[2])
        if D is not None:
            data += D / h
        return E, g, data

    # ------------------------------------------------------------------ step
    def _check(self, state_in: TetState, dt, control) -> tuple[float, np.ndarray, np.ndarray]:
        n = self.model.point_count
        try:
            h = float(dt)
        except (TypeError, ValueError):
            raise SimulationError(f"time step dt must be a number [s], got {dt!r}") from None
        if not (math.isfinite(h) and h > 0):
            raise SimulationError(f"time step dt must be finite and > 0 s, got {dt!r}")
        for name, a in (("positions x", state_in.x), ("velocities v", state_in.v)):
            a = np.asarray(a)
            if a.shape != (n, 3):
                raise SimulationError(f"state {name} must have shape ({n}, 3), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise SimulationError(f"state {name} has {_bad_rows(a)}")
        fixed, targets = self.fixed.copy(), self.pin_targets.copy()
        if control is not None:
            cv = np.asarray(control.vertices)
            try:
                cp = np.asarray(control.positions, dtype=float)
            except (TypeError, ValueError):
                raise SimulationError(f"control positions must be numbers (k, 3) [m], got {control.positions!r}") from None
            if cv.ndim != 1 or (cv.size and not np.issubdtype(cv.dtype, np.integer)):
                raise SimulationError(f"control vertices must be a 1-D array of integer indices, got "
                                      f"shape {cv.shape} of {cv.dtype}")
            if cp.shape != (len(cv), 3):
                raise SimulationError(f"control positions must have shape ({len(cv)}, 3) (one row per control "
                                      f"vertex), got {cp.shape}")
            if cv.size and (cv.min() < 0 or cv.max() >= n):
                out = cv[(cv < 0) | (cv >= n)]
                raise SimulationError(f"control vertex {int(out[0])} out of range [0, {n}) "
                                      f"({len(out)} of {len(cv)} out of range)")
            if not np.all(np.isfinite(cp)):
                raise SimulationError(f"control positions have {_bad_rows(cp, 'row')}")
            fixed[cv] = True
            targets[cv] = cp
        return h, fixed, targets

    @serial_blas
    def step(self, state_in: TetState, state_out: TetState, dt: float, *, control: TetControl | None = None
             ) -> StepInfo:
        """Advance ``state_in`` by ``dt`` [s] into ``state_out`` (may be the same object).

        Raises:
            SimulationError: dt <= 0 or not finite, non-finite state or control, a barrier step starting
                with a non-positive element volume, or a non-finite result.
        """
        t0 = time.perf_counter()
        h, fixed, targets = self._check(state_in, dt, control)
        info = StepInfo()
        x0 = np.asarray(state_in.x, dtype=float).copy()
        v0 = np.asarray(state_in.v, dtype=float).copy()
        hist = state_in.history
        if self.integrator == "bdf2" and hist is not None and abs(hist[2] - h) <= 1e-12 * h:
            # BDF2 as backward Euler with step 2h/3 from the base point (4 x_n - x_{n-1}) / 3
            xn, vn, h_full, h = (4 * x0 - hist[0]) / 3, (4 * v0 - hist[1]) / 3, h, 2 * h / 3
        else:
            xn, vn, h_full = x0, v0, h
        xhat = xn + h * vn
        x = x0.copy()
        x[fixed] = targets[fixed]
        fixed_dofs = np.repeat(fixed, 3)
        D = None
        if self.damping is not None:
            ta = time.perf_counter()
            D = self._damping_data(x0)
            info.assembly_s += time.perf_counter() - ta
        lin_tol = self.tol * self.model.size
        if fixed.all():  # every vertex pinned or scripted: the body follows its pins, nothing to solve
            info.converged = True
        project = info.projected = self.projection == "always"
        iterations = 0
        # the first CG starts from the predicted displacement h (v_n + the previous step's velocity change)
        guess = None
        if not fixed.all():
            guess = -(xhat - x).ravel()  # -(x_n + h v_n - x): the first step is close to it
            prev = self._previous
            if prev is not None and prev[2] == h and np.array_equal(prev[0], x0):
                guess -= h * prev[1]  # and the velocity keeps changing as in the previous step
            guess[fixed_dofs] = 0.0
            if self.newton_max > 1 and np.any(guess):
                # full Newton starts at the prediction when its incremental potential is lower than at x_n
                # (x_n first: the previous step's line search ended there, its SVD is cached; the
                # prediction's SVD then serves the first iteration)
                ta = time.perf_counter()
                xp = x - guess.reshape(-1, 3)
                E_start = self._incremental(x, xn, xhat, h, D, 0)[0]
                if self._incremental(xp, xn, xhat, h, D, 0)[0] < E_start:
                    x, guess = xp, None
                    info.predicted = True
                info.assembly_s += time.perf_counter() - ta
        reuse = False  # this iteration solves with the previous iteration's matrix (see REUSE_BELOW)
        near = False  # the last step was under REUSE_BELOW x tol: this iteration may end the step
        while iterations < (0 if fixed.all() else self.newton_max):
            ta = time.perf_counter()
            E, g, data = self._incremental(x, xn, xhat, h, D, 1 if reuse else 2, project)
            info.assembly_s += time.perf_counter() - ta
            if not math.isfinite(E):
                raise SimulationError("the step starts with a non-positive element volume, which the "
                                      "VolumeBarrier forbids" if self.barrier else "non-finite energy")
            g[fixed_dofs] = 0.0
            ts = time.perf_counter()
            if reuse:
                p, definite = self._resolve(g, info)
            else:
                A = self.pattern.apply_dirichlet(data, fixed_dofs, copy=False)  # data is not used again
                # an iteration that cannot end the step (not after a small step) solves less precisely
                rtol = self.cg_rtol if self.newton_max == 1 or near else self.cg_rtol_far
                p, definite = self._solve(A, g, info, guess if info.newton_iterations == 0 else None, x=x,
                                          free=~fixed_dofs, rtol=rtol)
            p = -p
            info.solve_s += time.perf_counter() - ts
            info.newton_iterations += 1
            slope = float(g @ p)
            if not (definite and slope < 0) and (reuse or not project):
                # the exact Hessians are indefinite here (or the reused matrix does not give a descent
                # direction): redo this iteration with a fresh matrix, projected unless it was the reuse
                project = info.projected = project or not reuse
                reuse = False
                continue
            reused, reuse = reuse, False
            iterations += 1
            ta = time.perf_counter()
            alpha, accepted = 1.0, False
            if slope < 0:
                for _ in range(30):
                    xt = x + alpha * p.reshape(-1, 3)
                    Et = self._incremental(xt, xn, xhat, h, D, 0)[0]
                    if Et <= E + 1e-4 * alpha * slope:
                        accepted = True
                        break
                    alpha *= 0.5
            info.assembly_s += time.perf_counter() - ta
            if not accepted:
                # converged if the step is small, or if its predicted decrease is below the roundoff of E
                # (the line search cannot resolve it: x is a minimiser to machine precision)
                info.converged = (float(np.abs(p).max(initial=0.0)) <= lin_tol
                                  or 0.0 <= -slope <= 64 * np.finfo(float).eps * abs(E))
                break
            x = xt
            step = alpha * float(np.abs(p).max(initial=0.0))
            if step <= lin_tol:
                info.converged = True
                break
            # near the minimiser the Hessian hardly changes: the next iteration solves with this one
            # (its forces only; never twice in a row)
            near = step <= REUSE_BELOW * lin_tol
            reuse = not reused and alpha == 1.0 and near
        if not np.all(np.isfinite(x)):
            raise SimulationError("the step produced non-finite positions")
        state_out.v = (x - xn) / h
        # warm start of the next step's CG, used only if that step starts from these positions with this dt
        self._previous = (x.copy(), (state_out.v - vn).ravel(), h)
        state_out.x = x
        state_out.t = float(state_in.t) + h_full
        state_out.history = (x0, v0, h_full) if self.integrator == "bdf2" else None
        info.total_s = time.perf_counter() - t0
        return info

    def _damping_data(self, x0: np.ndarray) -> np.ndarray:
        """CSR data of the damping matrix ``D = alpha M + beta K(x0)`` (K projected) [kg/s]."""
        diag = float(self.damping.alpha) * self.mass_dofs
        He = None
        if float(self.damping.beta) > 0:
            He = self._elastic(x0, 2, upper=True)[2]
            if He is not None:
                He *= float(self.damping.beta)
        return self.pattern.assemble(He, diag, upper=True)

    def _system_matrix(self, data: np.ndarray, free: np.ndarray | None = None):
        """The Newton system's matrix from its CSR ``data`` on the pattern (``free``: the DOFs not held)."""
        return self.pattern.matrix(data)

    def _blocked(self, A) -> bool | None:
        """``A`` is made of full 3x3 vertex blocks (the pattern's matrix), or None: to be checked."""
        return self.pattern.blocked if A.nnz == self.pattern.nnz else None

    def _solve(self, data: np.ndarray, g: np.ndarray, info: StepInfo, guess: np.ndarray | None = None, *,
               x: np.ndarray | None = None, free: np.ndarray | None = None, rtol: float | None = None
               ) -> tuple[np.ndarray, bool]:
        """``(A^-1 g, definite)``; ``definite`` False when CG met a direction of non-positive curvature."""
        A = self._system_matrix(data, free)
        if self.linear_solver == "cg":
            diag = self.pattern.diagonal(data)
            if self.twolevel is not None:
                # lagged coarse space: rebuilt every `coarse_lag` solves, or sooner when CG slows down
                lag = self._lag
                reuse = lag[0] < self.coarse_lag - 1 and lag[2] <= 1.5 * lag[1] + 2
                prec = self.twolevel.setup(A, diag, x, free, reuse=reuse)
            else:
                prec = Preconditioner(1.0 / diag)
            self._system = (A, prec)
            x, it, definite = _pcg(A, g, prec, self.cg_rtol if rtol is None else rtol, 10 * len(g), guess,
                                   blocked=self._blocked(A))
            info.linear_iterations += it
            if self.twolevel is not None:  # (solves since the rebuild, its iterations, the last iterations)
                self._lag = (0, it, it) if self.twolevel.rebuilt else (self._lag[0] + 1, self._lag[1], it)
            return x, definite
        if self.linear_solver == "splu":
            lu = spla.splu(A.tocsc())
            self._system = (A, lu)
            return lu.solve(g), True
        self._system = (A, None)
        return spla.spsolve(A.tocsc(), g), True

    def _resolve(self, g: np.ndarray, info: StepInfo) -> tuple[np.ndarray, bool]:
        """``_solve`` with the matrix (and preconditioner or factors) of the last ``_solve``."""
        A, prec = self._system
        if self.linear_solver == "cg":
            x, it, definite = _pcg(A, g, prec, self.cg_rtol, 10 * len(g), blocked=self._blocked(A))
            info.linear_iterations += it
            return x, definite
        if self.linear_solver == "splu":
            return prec.solve(g), True
        return spla.spsolve(A.tocsc(), g), True
