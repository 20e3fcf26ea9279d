"""Implicit backward Euler for cloth (Baraff-Witkin): one linearised Newton step per time step.

With lumped masses ``M``, the projected elastic Hessian ``K`` (membrane, bending), the damping
``C = alpha M + beta K + C_wind`` and forces ``f`` at the start of the step, the velocity change solves

    (M + dt C + dt^2 K) dv = dt (f - C v - dt K v)

for the free DOFs; handle vertices get the velocity that brings them to their scripted position at
the end of the step (constraint filtering: their rows and columns are eliminated). The system is SPD.
Two linear solvers: ``"cg"`` (conjugate gradients written here in numpy, preconditioned by the inverses
of the 3x3 diagonal blocks of the vertices (block Jacobi: about 20 % fewer iterations than the scalar
diagonal on cloth), warm start from the previous step's velocity change, relative residual ``cg_rtol``)
and ``"splu"`` (scipy's SuperLU, minimum-degree ordering of A^T + A). The sparsity pattern is built once
(with every vertex's full diagonal block); each step only scatters element blocks into it
(``np.bincount``). Which solver is faster: ``modalfem bench cloth``.

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

#: relative residual of the smoothing solve: it only shapes the collision response (which goes through
#: the collision pipeline again), so a looser tolerance than the implicit step's is enough; the
#: momentum the residual would change is restored exactly
SMOOTH_RTOL = 1e-2

__all__ = ["ImplicitEuler", "LinearSolveInfo", "pcg_filtered", "pcg_jacobi"]


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


def _diagonal_blocks(A) -> np.ndarray:
    """(n, 3, 3) diagonal blocks of the (3n, 3n) sparse ``A``."""
    nb = A.shape[0] // 3
    B = sp.bsr_matrix(A, blocksize=(3, 3))
    B.sum_duplicates()
    rows = np.repeat(np.arange(nb), np.diff(B.indptr))
    on = B.indices == rows
    out = np.zeros((nb, 3, 3))
    out[rows[on]] = B.data[on]
    return out


def _diagonal_preconditioner(A, block: int, blocks: np.ndarray | None = None):
    """``z = P^-1 r`` for the (block) diagonal of SPD ``A``: 1 (scalar Jacobi) or 3 (the inverses of the
    3x3 diagonal blocks, node-major DOFs; ``blocks`` (n, 3, 3) if known, else taken from ``A``)."""
    if block == 1:
        d = A.diagonal()
        inv = 1.0 / np.where(d > 0, d, 1.0)
        return lambda r: inv * r
    if block != 3 or A.shape[0] % 3:
        raise InputError(f"block Jacobi needs block 1 or 3 and a size divisible by it, got {block}, {A.shape}")
    nb = A.shape[0] // 3
    D = np.array(_diagonal_blocks(A) if blocks is None else blocks, dtype=float)
    empty = ~np.any(D != 0, axis=(1, 2))
    D[empty] = np.eye(3)  # a block of zeros (an empty row): any SPD block will do
    inv = sp.bsr_matrix((np.linalg.inv(D), np.arange(nb), np.arange(nb + 1)), shape=A.shape).tocsr()
    return lambda r: inv @ r


def pcg_jacobi(A, b: np.ndarray, *, x0: np.ndarray | None = None, rtol: float = 1e-6, maxiter: int = 1000,
               block: int = 1, blocks: np.ndarray | None = None):
    """(Block) Jacobi-preconditioned conjugate gradients for SPD ``A``, from guess ``x0``; returns
    (x, iterations).

    Converged when ``|b - A x| <= rtol |b|``. ``block`` = 3 preconditions by the inverses of the 3x3
    diagonal blocks (node-major DOFs; ``blocks`` (n, 3, 3): those blocks if known), 1 by the diagonal.

    Raises:
        SolverError: no convergence to ``rtol`` within ``maxiter`` iterations.
    """
    prec = _diagonal_preconditioner(A, block, blocks)
    nb = np.linalg.norm(b)
    if nb == 0.0:
        return np.zeros_like(b), 0
    x = np.zeros_like(b) if x0 is None else x0.copy()
    r = b - A @ x if x0 is not None else b.copy()
    if np.linalg.norm(r) <= rtol * nb:
        return x, 0
    return _pcg_iterate(A, prec, x, r, nb, rtol=rtol, maxiter=maxiter)


def _pcg_iterate(A, prec, x: np.ndarray, r: np.ndarray, nb: float, *, rtol: float, maxiter: int, filt=None):
    """The PCG iterations (preconditioner ``prec``: r -> z) from iterate ``x`` with residual ``r`` (both
    updated in place) until ``|r| <= rtol nb``; ``filt`` projects the directions (``pcg_filtered``: the
    residual stays in its range, so ``filt(prec(r))`` is the symmetric ``S P^-1 S r``), None for plain PCG."""
    c = prec(r) if filt is None else filt(prec(r))
    rz = r @ c
    for k in range(1, maxiter + 1):
        q = A @ c if filt is None else filt(A @ c)
        alpha = rz / (c @ q)
        x += alpha * c
        r -= alpha * q
        if np.linalg.norm(r) <= rtol * nb:
            return x, k
        s = prec(r)
        if filt is not None:
            s = filt(s)
        rz_new = r @ s
        c = s + (rz_new / rz) * c
        rz = rz_new
    raise SolverError(f"cloth CG did not reach relative residual {rtol:g} in {maxiter} iterations")


def pcg_filtered(A, b: np.ndarray, z: np.ndarray, normals: np.ndarray, dofs: np.ndarray, *, rtol: float,
                 maxiter: int, x0: np.ndarray | None = None, block: int = 1, blocks: np.ndarray | None = None):
    """Baraff-Witkin modified PCG: solve ``A y = b`` on the components left free by contact constraints.

    The constrained components are ``n_i . y_i = n_i . z_i`` for the vertices whose DOF triples are
    ``dofs`` (k, 3) with unit normals ``normals`` (k, 3); the filter removes the normal part of the
    search directions and residuals there. ``block``, ``blocks`` as in :func:`pcg_jacobi`. Returns (y,
    iterations).
    """

    def filt(u):
        u = u.copy()
        ui = u[dofs]
        u[dofs] = ui - normals * np.sum(ui * normals, axis=1)[:, None]
        return u

    if block == 3:  # the constrained vertices' blocks projected: S D S + |D| n n^T keeps range(S)
        if blocks is None:
            blocks = _diagonal_blocks(A)
        blocks = np.array(blocks, dtype=float)
        vi = dofs[:, 0] // 3
        S = np.eye(3) - normals[:, :, None] * normals[:, None, :]
        Di = blocks[vi]
        tr = np.trace(Di, axis1=1, axis2=2)[:, None, None] / 3.0
        blocks[vi] = S @ Di @ S + tr * (normals[:, :, None] * normals[:, None, :])
    prec = _diagonal_preconditioner(A, block, blocks)
    y = filt(x0) if x0 is not None else np.zeros_like(b)
    zi = z[dofs]
    y[dofs] += normals * np.sum(zi * normals, axis=1)[:, None]
    nb = np.linalg.norm(filt(b))
    r = filt(b - A @ y)
    if nb == 0.0 or np.linalg.norm(r) <= rtol * nb:
        return y, 0
    return _pcg_iterate(A, prec, y, r, nb, rtol=rtol, maxiter=maxiter, filt=filt)


class _Pattern:
    """CSR pattern of the union of element stencils and the vertices' 3x3 diagonal blocks; scatters
    element blocks by ``np.bincount``."""

    def __init__(self, n: int, stencils: list[np.ndarray]):
        self.n = n
        keys = []
        for verts in stencils:
            k = verts.shape[1]
            dof = (3 * verts[:, :, None] + np.arange(3)).reshape(len(verts), 3 * k)
            keys.append((dof[:, :, None] * (3 * n) + dof[:, None, :]).reshape(-1))
        diag = np.arange(3 * n, dtype=np.int64)
        keys.append(diag * (3 * n) + diag)
        # every vertex's full 3x3 diagonal block is in the pattern (the block Jacobi preconditioner)
        r = (3 * np.arange(n)[:, None, None] + np.arange(3)[:, None]).repeat(3, axis=2)
        dblock = (r * (3 * n) + np.swapaxes(r, 1, 2)).reshape(-1)
        allk = np.concatenate(keys + [dblock])
        uk, inv = np.unique(allk, return_inverse=True)
        self.nnz = len(uk)
        rows, cols = uk // (3 * n), uk % (3 * n)
        self.indptr = np.searchsorted(rows, np.arange(3 * n + 1)).astype(np.int64)
        self.indices = cols.astype(np.int64)
        sizes = np.cumsum([0] + [len(k) for k in keys])
        self.maps = [inv[sizes[i]:sizes[i + 1]] for i in range(len(keys))]
        self.diag = self.maps[-1]
        #: (n, 3, 3) positions of the vertices' diagonal blocks in the data
        self.dblock = inv[sizes[-1]:].reshape(n, 3, 3)
        self.rows = rows
        self._filters: dict = {}

    def csr(self, data: np.ndarray) -> sp.csr_matrix:
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(3 * self.n, 3 * self.n))

    def filter_mask(self, fixed: np.ndarray) -> np.ndarray:
        """Entries (nnz,) bool in a fixed DOF's row or column, except its diagonal (cached per set)."""
        key = fixed.tobytes()
        if key not in self._filters:
            isf = np.zeros(3 * self.n, bool)
            isf[fixed] = True
            mask = isf[self.rows] | isf[self.indices]
            mask[self.diag[fixed]] = False
            self._filters = {key: mask}
        return self._filters[key]

    def data(self, blocks: list, diag: np.ndarray) -> np.ndarray:
        """CSR data (nnz,) of sum of element ``blocks`` (one per stencil, or None) and ``diag`` (3n,)."""
        data = np.bincount(self.maps[-1], weights=diag, minlength=self.nnz)
        for mp, b in zip(self.maps[:-1], blocks):
            if b is not None:
                data += np.bincount(mp, weights=b.reshape(-1), minlength=self.nnz)
        return data



class ImplicitEuler:
    """Backward Euler velocity update for a ``ClothModel`` (see module docstring).

    Args:
        model: the cloth.
        linear_solver: ``"cg"`` (default) or ``"splu"``.
        cg_rtol: CG relative residual.
        cg_maxiter: CG iteration cap.

    Raises:
        InputError: unknown linear solver.
    """

    def __init__(self, model: ClothModel, *, linear_solver: str = "cg", cg_rtol: float = 1e-4, cg_maxiter: int = 2000):
        if linear_solver not in ("cg", "splu"):
            raise InputError(f"linear_solver must be 'cg' or 'splu', got {linear_solver!r}")
        self.model = model
        self.linear_solver = linear_solver
        self.cg_rtol = float(cg_rtol)
        self.cg_maxiter = int(cg_maxiter)
        mesh = model.mesh
        self._pattern = _Pattern(mesh.point_count, [mesh.triangles, mesh.hinges.vertices])
        self._m3 = np.repeat(model.masses, 3)
        self._Kdata = None
        self._last_dv = None

    def stiffness(self, x: np.ndarray) -> sp.csr_matrix:
        """Projected elastic Hessian K (3n, 3n) [N/m] at ``x`` (n, 3) [m]; also kept for ``smooth``."""
        m = self.model
        blocks = [m.membrane.hessian_blocks(x), m.bending.hessian_blocks(x)]
        self._Kdata = self._pattern.data(blocks, np.zeros(len(self._m3)))
        return self._pattern.csr(self._Kdata)

    def _solve(self, data: np.ndarray, b: np.ndarray, fixed: np.ndarray, fixed_value: np.ndarray, guess=None,
               contacts=None, rtol: float | None = None):
        """Solve A y = b (A from pattern ``data``) with y[fixed] = fixed_value (constraint filtering:
        the fixed rows and columns become identity, keeping A SPD) and, for ``contacts`` = (vertex
        indices (k,), unit normals (k, 3), prescribed normal components (k,)), ``n . y_i`` given.
        Returns (y, iterations, seconds, contact impulses (k,) = n . (A y - b)_i)."""
        pat = self._pattern
        y = np.zeros(len(b))
        t0 = time.perf_counter()
        if fixed.size:
            y[fixed] = fixed_value
            b = b - pat.csr(data) @ y
            b[fixed] = fixed_value
            data = np.where(pat.filter_mask(fixed), 0.0, data)
            data[pat.diag[fixed]] = 1.0
        A = pat.csr(data)
        if contacts is not None and len(contacts[0]):
            idx, nrm, un = contacts
            dofs = 3 * idx[:, None] + np.arange(3)
            z = y.copy()
            z[dofs] = nrm * un[:, None]
            if self.linear_solver == "splu":
                # S A S + (I - S) with S = I - n n^T at the contacts: SPD, solution in range(S)
                S = np.tile(np.eye(3), (len(b) // 3, 1, 1))
                S[idx] -= nrm[:, :, None] * nrm[:, None, :]
                Ssp = sp.bsr_matrix((S, np.arange(len(S)), np.arange(len(S) + 1))).tocsr()
                As = (Ssp @ A @ Ssp + sp.identity(len(b)) - Ssp).tocsc()
                y = spla.splu(As, permc_spec="MMD_AT_PLUS_A").solve(Ssp @ (b - A @ z)) + z
                it = 0
            else:
                y, it = pcg_filtered(A, b, z, nrm, dofs, rtol=self.cg_rtol, maxiter=self.cg_maxiter, x0=guess,
                                     block=3, blocks=data[pat.dblock])
            res = (A @ y - b)[dofs]
            return y, it, time.perf_counter() - t0, np.sum(res * nrm, axis=1)
        if self.linear_solver == "splu":
            y = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(b)
            it = 0
        else:
            if guess is not None:
                guess = guess.copy()
                guess[fixed] = fixed_value
            rtol = self.cg_rtol if rtol is None else rtol
            y, it = pcg_jacobi(A, b, x0=guess, rtol=rtol, maxiter=self.cg_maxiter, block=3, blocks=data[pat.dblock])
        return y, it, time.perf_counter() - t0, None

    def step_velocity(self, x, v, forces, dt: float, *, fixed=None, fixed_velocity=None, damping_blocks=None,
                      contacts=None):
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
        mdl = self.model
        t0 = time.perf_counter()
        K = self.stiffness(x)
        Kd = self._Kdata
        f = forces - mdl.membrane.gradient(x) - mdl.bending.gradient(x)
        vf = v.reshape(-1)
        Kv = K @ vf
        a, beta = mdl.mass_damping, mdl.stiffness_damping
        Cv = a * self._m3 * vf + beta * Kv
        data = Kd * (dt * dt + dt * beta) + self._pattern.data([], self._m3 * (1.0 + dt * a))
        if damping_blocks is not None:
            Cw = self._pattern.data([damping_blocks], np.zeros(len(self._m3)))
            Cv = Cv + self._pattern.csr(Cw) @ vf
            data += dt * Cw
        b = dt * (f.reshape(-1) - Cv - dt * Kv)
        t_asm = time.perf_counter() - t0
        fixed = np.zeros(0, np.int64) if fixed is None else np.asarray(fixed, dtype=np.int64)
        fdof = (3 * fixed[:, None] + np.arange(3)).reshape(-1)
        dv_fixed = np.zeros(0) if fixed.size == 0 else (np.asarray(fixed_velocity) - v[fixed]).reshape(-1)
        guess = self._last_dv if self._last_dv is not None and len(self._last_dv) == len(b) else None
        con = None
        if contacts is not None:
            ci, cn, cu = (np.asarray(c, dtype=float) for c in contacts)
            ci = ci.astype(np.int64)
            con = (ci, cn, cu - np.sum(v[ci] * cn, axis=1))  # prescribed normal part of dv
        dv, it, t_sol, imp = self._solve(data, b, fdof, dv_fixed, guess, con)
        self._last_dv = dv
        v_new = v + dv.reshape(-1, 3)
        if not np.all(np.isfinite(v_new)):
            raise SimulationError("cloth velocities became NaN/inf in the implicit step (time step too large?)")
        return v_new, LinearSolveInfo(self.linear_solver, it, t_asm, t_sol, imp)

    def smooth(self, dv: np.ndarray, dt: float, *, strength: float, fixed=None) -> np.ndarray:
        """Smoothed velocity change: solve ``(M + dt * strength * K) dv_s = M dv`` with ``dv_s[fixed] = 0``.

        Args:
            dv: velocity change (n, 3) [m/s] (e.g. collision response minus the implicit prediction).
            dt: time step [s].
            strength: smoothing time beta_s [s] (0: no smoothing).
            fixed: indices of vertices whose change stays 0 (handles).

        Returns:
            dv_s (n, 3) [m/s]; uses the stiffness K of the last ``step_velocity``.
        """
        if strength <= 0 or self._Kdata is None or not np.any(dv):
            return dv
        data = self._Kdata * (dt * strength) + self._pattern.data([], self._m3)
        fixed = np.zeros(0, np.int64) if fixed is None else np.asarray(fixed, dtype=np.int64)
        fdof = (3 * fixed[:, None] + np.arange(3)).reshape(-1)
        y, _, _, _ = self._solve(data, self._m3 * dv.reshape(-1), fdof, np.zeros(fdof.size),
                                 rtol=max(self.cg_rtol, SMOOTH_RTOL))
        y = y.reshape(-1, 3)
        if fixed.size == 0:  # the exact solution keeps the momentum of dv: restore what the residual changed
            m = self.model.masses
            y += (m @ dv - m @ y) / m.sum()
        return y
