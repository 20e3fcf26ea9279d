"""Two-level preconditioner for the SPD step systems of ``TetSolver``: Jacobi plus a coarse correction
on the 6 rigid motions of each spatial aggregate of vertices (additive, so it stays SPD for CG).

``M^-1 r = D^-1 r + P (P^T A P)^-1 P^T r``. The vertices are grouped by a uniform grid over the rest
bounding box into about ``aggregates`` groups; ``P`` (3n x 6g) holds, per group, the three translations
and the three infinitesimal rotations about the group's current centroid (held DOFs zeroed). The
coarse matrix is dense, Cholesky-factorised and inverted per rebuild. On the benchmark bar (10k tets,
dt = 1/30 s) it cuts Jacobi-PCG from ~160 to ~30 iterations and halves the solve time.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from modalfem.errors import InputError

__all__ = ["Preconditioner", "TwoLevel"]


class Preconditioner:
    """``r -> inv * r + P Ac_inv P^T r`` (Jacobi alone without ``P``), callable, and in the form the compiled
    CG (:func:`modalfem.tet._kernels.pcg_twolevel`) takes: :meth:`arrays`.

    Args:
        inv: inverse diagonal (N,).
        P: prolongation (N, c), CSR (or None).
        Ac_inv: inverse coarse matrix (c, c), exactly symmetric (or None).
        groups: ``(ptr, rows)`` with P: the rows of group ``g`` are ``rows[ptr[g]:ptr[g + 1]]`` (every row
            once, a vertex's three together), and P is in :class:`TwoLevel`'s layout (row ``3v + k``: the
            translation ``k`` and the two rotations other than ``k`` of the vertex's group, in that order;
            what the compiled CG's restriction reads).

    Raises:
        InputError: ``P`` without ``Ac_inv`` or ``groups``.
    """

    def __init__(self, inv: np.ndarray, P: sp.csr_matrix | None = None, Ac_inv: np.ndarray | None = None,
                 groups: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        from modalfem.tet import _kernels

        self.inv = np.ascontiguousarray(inv, dtype=float)
        if P is None:
            empty_i = np.zeros(1, dtype=np.int64)
            self._arrays = (self.inv, empty_i, empty_i, np.zeros(0), np.zeros((0, 0)), empty_i, empty_i)
        else:
            if groups is None or Ac_inv is None:
                raise InputError("a coarse part needs its inverse coarse matrix and the groups of TwoLevel's P")
            self._arrays = (self.inv, P.indptr, _kernels.unsigned(P.indices), P.data, np.ascontiguousarray(Ac_inv),
                            np.asarray(groups[0], dtype=np.int64), _kernels.unsigned(np.asarray(groups[1], dtype=np.int64)))
        self.P, self.Ac_inv = P, Ac_inv
        self._Pt = None

    @property
    def Pt(self) -> sp.csr_matrix | None:
        """``P^T`` (CSR; made on first use: the compiled CG restricts with ``P`` itself)."""
        if self._Pt is None and self.P is not None:
            self._Pt = self.P.T.tocsr()
        return self._Pt

    def arrays(self) -> tuple:
        """``(inv, P indptr, indices, data, Ac_inv, group ptr, group rows)``."""
        return self._arrays

    def __call__(self, r: np.ndarray) -> np.ndarray:
        out = self.inv * r
        if self.P is not None:
            out += self.P @ (self.Ac_inv @ (self.Pt @ r))
        return out


class TwoLevel:
    """Aggregation of vertices (fixed) and the per-solve preconditioner.

    Args:
        rest_points: rest vertex positions (n, 3) [m].
        aggregates: target number of vertex groups (at most n / 16; the coarse space has 6 per group).
    """

    def __init__(self, rest_points: np.ndarray, *, aggregates: int = 48) -> None:
        X = np.asarray(rest_points, dtype=float)
        n = len(X)
        lo, hi = X.min(axis=0), X.max(axis=0)
        ext = np.maximum(hi - lo, 1e-12 * max(float(np.max(hi - lo)), 1e-300))
        groups = max(1, min(int(aggregates), n // 16))  # at least ~16 vertices per group
        side = float(np.prod(ext) / groups) ** (1 / 3)
        cells = np.maximum(1, np.rint(ext / side)).astype(np.int64)
        key = np.minimum(np.floor((X - lo) / ext * cells).astype(np.int64), cells - 1)
        _, agg = np.unique(key, axis=0, return_inverse=True)
        self.agg = agg.ravel()
        self.count = int(self.agg.max()) + 1
        self.n = n
        # CSR of P built directly: row 3 i + k holds the translation k and the two rotations a != k of
        # vertex i's group (component k of e_k x r is zero, so it is not stored)
        g6 = 6 * self.agg
        cols = np.empty((n, 3, 3), dtype=np.int32)
        for k, (a, b) in enumerate(((1, 2), (0, 2), (0, 1))):
            cols[:, k, 0] = g6 + k
            cols[:, k, 1] = g6 + 3 + a
            cols[:, k, 2] = g6 + 3 + b
        self._indices = cols.ravel()
        self._indptr = (3 * np.arange(3 * n + 1)).astype(np.int32)
        self._mass = np.bincount(self.agg, minlength=self.count).astype(float)
        # the DOFs of each group in increasing order (the rows of P whose columns are that group's)
        by_group = np.argsort(self.agg, kind="stable")
        self._group_rows = (3 * by_group[:, None] + np.arange(3)).ravel().astype(np.int64)
        self._group_ptr = 3 * np.searchsorted(self.agg[by_group], np.arange(self.count + 1)).astype(np.int64)
        self._coarse = None  # (free mask, P, inverse coarse matrix) of the last setup
        self.rebuilt = False  # whether the last setup made a new coarse space

    def prolongation(self, x: np.ndarray, free: np.ndarray) -> sp.csr_matrix:
        """P (3n, 6g) at positions ``x`` (n, 3) [m]; rows of held DOFs (``free`` False) are zero."""
        c = np.stack([np.bincount(self.agg, weights=x[:, k], minlength=self.count) for k in range(3)], axis=1)
        r = x - c[self.agg] / self._mass[self.agg, None]
        vals = np.empty((self.n, 3, 3))  # (vertex, component k, [translation, rotation a, rotation b])
        vals[:, :, 0] = 1.0
        vals[:, 0, 1], vals[:, 0, 2] = r[:, 2], -r[:, 1]  # e_y x r, e_z x r: x components
        vals[:, 1, 1], vals[:, 1, 2] = -r[:, 2], r[:, 0]  # e_x x r, e_z x r: y components
        vals[:, 2, 1], vals[:, 2, 2] = r[:, 1], -r[:, 0]  # e_x x r, e_y x r: z components
        vals *= free.reshape(self.n, 3, 1)
        return sp.csr_matrix((vals.ravel(), self._indices, self._indptr), shape=(3 * self.n, 6 * self.count))

    def setup(self, A: sp.csr_matrix, diag: np.ndarray, x: np.ndarray, free: np.ndarray, *, reuse: bool = False):
        """The preconditioner ``r -> M^-1 r`` for matrix ``A`` at positions ``x``; Jacobi if the coarse
        matrix cannot be factorised.

        With ``reuse`` the coarse part (``P`` and the factorised ``P^T A P``) of the previous call is kept
        if it was made for the same held DOFs (a lagged coarse space: still SPD, so CG still converges to
        the same tolerance; only the Jacobi part follows ``A``). This saves the two sparse products and
        the factorisation, which cost as much as several CG iterations.
        """
        inv = 1.0 / diag
        coarse = self._coarse
        self.rebuilt = not (reuse and coarse is not None and np.array_equal(coarse[0], free))
        if self.rebuilt:
            coarse = self._coarse = (free.copy(), *self._coarse_space(A, x, free))
        _, P, Ac_inv = coarse
        if Ac_inv is None:
            return Preconditioner(inv)
        return Preconditioner(inv, P, Ac_inv, (self._group_ptr, self._group_rows))

    def _coarse_space(self, A: sp.csr_matrix, x: np.ndarray, free: np.ndarray):
        """``(P, (P^T A P)^-1 or None)``.

        ``P^T A P`` is formed by a compiled kernel (:func:`modalfem.tet._kernels.galerkin`, groups in
        parallel; ~4x faster than SciPy's two sparse products). The coarse matrix is inverted explicitly
        from its Cholesky factor (LAPACK ``potri``): one dense matrix-vector product per CG iteration
        instead of two triangular solves (about 3x faster at the ~300 coarse DOFs here; the inverse costs
        about one factorisation more per rebuild).
        """
        from modalfem.tet import _kernels

        P = self.prolongation(x, free)
        A = A.tocsr()
        Ac = np.zeros((6 * self.count, 6 * self.count))
        _kernels.galerkin(A.indptr, _kernels.unsigned(A.indices), np.ascontiguousarray(A.data, dtype=float),
                          P.indptr, _kernels.unsigned(P.indices), P.data, self._group_ptr, self._group_rows, Ac)
        d = np.diag(Ac).copy()
        dmax = max(float(d.max(initial=0.0)), 1e-300)
        empty = d <= 1e-14 * dmax
        Ac[empty, empty] = 1.0
        Ac[np.diag_indices_from(Ac)] += 1e-10 * dmax  # dependent columns (collinear groups) stay factorisable
        # LAPACK directly, in place (the factor's lower triangle is left as it was: potri reads the upper)
        c, info = sla.lapack.dpotrf(Ac, lower=False, clean=False, overwrite_a=True)
        if info != 0:
            return P, None
        Ac_inv, info = sla.lapack.dpotri(c, lower=False, overwrite_c=True)
        if info != 0:
            return P, None
        _kernels.mirror_upper(Ac_inv)  # exactly symmetric (the compiled CG reads it by columns)
        return P, Ac_inv.T  # potri's Fortran-ordered result, as the C-ordered array the CG was compiled for
