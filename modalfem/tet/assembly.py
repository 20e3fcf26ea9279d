"""Sparse assembly of 12x12 element blocks on a sparsity pattern computed once (CSR, node-major DOFs).

The pattern holds every coupling of the mesh plus the full diagonal. ``assemble`` scatters element
values to a precomputed CSR position per element entry (one ``np.bincount``, or for upper triangles a
compiled, parallel gather over the upper positions that writes each sum and its transpose; no COO -> CSR
conversion per step); Dirichlet
rows/columns are replaced by the identity through a mask on ``data``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["HessianPattern"]


class HessianPattern:
    """CSR pattern of a (3n x 3n) matrix assembled from tetrahedra.

    Args:
        cells: tetrahedra (m, 4).
        n: number of vertices.
    """

    def __init__(self, cells: np.ndarray, n: int) -> None:
        N = 3 * n
        dofs = (3 * cells[:, :, None] + np.arange(3)).reshape(-1, 12)
        rows = np.concatenate([np.repeat(dofs, 12, axis=1).ravel(), np.arange(N)])
        cols = np.concatenate([np.tile(dofs, (1, 12)).ravel(), np.arange(N)])
        keys, inv = np.unique(rows * np.int64(N) + cols, return_inverse=True)
        inv = inv.ravel()
        self.shape = (N, N)
        self.keys = keys
        self.nnz = len(keys)
        self.indices = (keys % N).astype(np.int32)
        self.rows = (keys // N).astype(np.int64)
        self.indptr = np.searchsorted(self.rows, np.arange(N + 1)).astype(np.int32)
        self.element_index = inv[: 144 * len(cells)]
        # upper triangles (78, m) of the element blocks, element index last: each entry's CSR position (upper
        # or lower: an element's local order is not the global one), and the transpose permutation
        iu = np.triu_indices(12)
        self.upper_index = np.ascontiguousarray(self.element_index.reshape(-1, 12, 12)[:, iu[0], iu[1]].T).ravel()
        self.transpose = np.searchsorted(keys, (keys % N) * np.int64(N) + keys // N)
        # the same scatter as a gather, symmetrised in the same pass: each position of the upper triangle
        # (diagonal included) sums, in a fixed order, the element entries landing on it or on its transpose,
        # and writes both (one compiled pass over the positions, in parallel, no write conflicts)
        from modalfem.tet import _kernels

        upper = np.flatnonzero(self.rows <= self.indices)
        rank = np.empty(self.nnz, dtype=np.int64)
        rank[upper] = np.arange(len(upper))
        rank[self.transpose[upper]] = np.arange(len(upper))
        target = rank[self.upper_index]
        order = np.argsort(target, kind="stable")
        self._gather_ptr = np.searchsorted(target[order], np.arange(len(upper) + 1)).astype(np.int64)
        # unsigned (no wrap-around test per access in numba), 32-bit when they fit (half the index traffic)
        self._gather_order = _kernels.compact_unsigned(order)
        self._owner = _kernels.compact_unsigned(upper)
        self._mirror = _kernels.compact_unsigned(self.transpose[upper])
        self.diag_index = inv[144 * len(cells):]
        self._cells = len(cells)
        self._order_em = None

        #: full 3x3 vertex blocks (every vertex in a tetrahedron): the CG's products read them by blocks
        self.blocked = bool(_kernels.is_blocked3(self.indptr, self.indices))
        self._dirichlet = None  # (fixed mask, zeroed positions, diagonal positions) of the last call

    def assemble(self, blocks: np.ndarray | None = None, diag: np.ndarray | None = None, *,
                 upper: bool = False) -> np.ndarray:
        """CSR ``data`` (nnz,) from symmetric element blocks and a diagonal (3n,) (either may be None).

        Args:
            blocks: element matrices (m, 12, 12), or with ``upper`` their upper triangles (78, m) in the
                order of ``np.triu_indices(12)`` (``element_hessians(..., upper=True)``; about half the
                scatter work): C-ordered, or the transposed view of an (m, 78) array (what
                ``element_hessians`` returns; read element by element, no copy).
            diag: added to the diagonal (3n,).
            upper: the layout of ``blocks``.
        """
        if blocks is None:
            data = np.zeros(self.nnz)
        elif upper:
            from modalfem.tet import _kernels

            data = np.empty(self.nnz)
            blocks = np.asarray(blocks, dtype=float)
            if blocks.T.flags.c_contiguous and not blocks.flags.c_contiguous:  # an (m, 78) array's view
                values, order = blocks.T.ravel(), self._element_major_order()
            else:
                values, order = np.ascontiguousarray(blocks).ravel(), self._gather_order
            _kernels.assemble_upper(self._gather_ptr, order, values, self._owner, self._mirror, data)
        else:
            data = np.bincount(self.element_index, weights=blocks.ravel(), minlength=self.nnz)
        if diag is not None:
            data[self.diag_index] += diag
        return data

    def _element_major_order(self) -> np.ndarray:
        """The gather order for upper triangles stored (m, 78) (element index first), made once."""
        if self._order_em is None:
            k, e = np.divmod(self._gather_order.astype(np.int64), self._cells)
            from modalfem.tet import _kernels

            self._order_em = _kernels.compact_unsigned(e * 78 + k)
        return self._order_em

    def positions(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """CSR positions of entries ``(rows, cols)`` (DOF indices); every entry must be in the pattern (two DOFs
        of one tetrahedron, or a diagonal one)."""
        key = np.asarray(rows, dtype=np.int64) * np.int64(self.shape[0]) + np.asarray(cols, dtype=np.int64)
        pos = np.searchsorted(self.keys, key)
        if len(key) and (pos.max() >= self.nnz or np.any(self.keys[np.minimum(pos, self.nnz - 1)] != key)):
            raise ValueError("Hessian entries outside the sparsity pattern (DOFs of no common tetrahedron)")
        return pos

    def apply_dirichlet(self, data: np.ndarray, fixed: np.ndarray, *, copy: bool = True) -> np.ndarray:
        """``data`` with rows and columns of DOFs ``fixed`` (3n,) bool replaced by the identity: a copy, or
        ``data`` itself changed with ``copy=False``."""
        out = data.copy() if copy else data
        if fixed.any():
            cached = self._dirichlet
            if cached is None or not np.array_equal(cached[0], fixed):  # positions of the last mask are kept
                zero = np.flatnonzero(fixed[self.rows] | fixed[self.indices])
                cached = self._dirichlet = (fixed.copy(), zero, self.diag_index[fixed])
            out[cached[1]] = 0.0
            out[cached[2]] = 1.0
        return out

    def diagonal(self, data: np.ndarray) -> np.ndarray:
        """Diagonal (3n,) of the matrix with values ``data``."""
        return data[self.diag_index]

    def matrix(self, data: np.ndarray) -> sp.csr_matrix:
        """The scipy CSR matrix with values ``data``."""
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)
