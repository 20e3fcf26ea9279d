"""Comparing approximate modes with reference modes: frequency error, MAC, mode matching.

The modal assurance criterion of two shapes ``a``, ``b`` is ``MAC = (a^T W b)^2 / ((a^T W a)(b^T W b))``
with ``W`` the mass matrix M [kg] (mass-weighted, the energy-consistent choice) or the identity
(plain). It is 1 for parallel shapes and 0 for W-orthogonal ones, and does not depend on the sign
or scale of either shape. Approximate modes are matched to reference modes by MAC (an optimal
one-to-one assignment maximising the summed MAC), so mode swaps between close frequencies are not
counted as frequency errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = ["ModeComparison", "compare_modes", "frequency_errors", "mac_matrix", "match_modes"]


def frequency_errors(f_approx, f_ref) -> np.ndarray:
    """Relative frequency errors ``(f_approx - f_ref) / f_ref`` [-] of equal-length arrays [Hz or rad/s]."""
    a = np.asarray(f_approx, dtype=np.float64)
    r = np.asarray(f_ref, dtype=np.float64)
    if a.shape != r.shape:
        raise InputError(f"frequency arrays differ in shape: {a.shape} vs {r.shape}")
    if np.any(r == 0):
        raise InputError("reference frequencies must be non-zero (compare deformation modes only)")
    return (a - r) / r


def mac_matrix(A: np.ndarray, B: np.ndarray, *, M=None) -> np.ndarray:
    """MAC of every pair of columns: (k_a, k_b) in [0, 1].

    Args:
        A: shapes (N, k_a) (node-major DOFs).
        B: shapes (N, k_b) on the same DOFs.
        M: optional mass matrix (N, N) [kg] (dense or scipy.sparse); None for the plain MAC.

    Raises:
        InputError: row counts differ, or a shape is zero.
    """
    A = np.asarray(A, dtype=np.float64).reshape(len(A), -1)
    B = np.asarray(B, dtype=np.float64).reshape(len(B), -1)
    if A.shape[0] != B.shape[0]:
        raise InputError(f"shapes have different DOF counts: {A.shape[0]} vs {B.shape[0]}")
    MB = B if M is None else M @ B
    MA = A if M is None else M @ A
    cross = A.T @ MB
    na = np.einsum("ij,ij->j", A, MA)
    nb = np.einsum("ij,ij->j", B, MB)
    if np.any(na <= 0) or np.any(nb <= 0):
        raise InputError("MAC of a zero shape (or a mass matrix that is not positive) is undefined")
    return np.clip(cross**2 / np.outer(na, nb), 0.0, 1.0)


def match_modes(mac: np.ndarray) -> np.ndarray:
    """For each reference mode (column of ``mac``), the approximate mode (row) assigned to it.

    Optimal one-to-one assignment maximising the total MAC (``scipy.optimize.linear_sum_assignment``);
    needs at least as many approximate as reference modes.
    """
    from scipy.optimize import linear_sum_assignment

    mac = np.asarray(mac, dtype=np.float64)
    if mac.shape[0] < mac.shape[1]:
        raise InputError(f"need at least as many approximate modes ({mac.shape[0]}) as reference modes ({mac.shape[1]})")
    rows, cols = linear_sum_assignment(-mac)
    out = np.empty(mac.shape[1], dtype=np.int64)
    out[cols] = rows
    return out


@dataclass(frozen=True)
class ModeComparison:
    """Approximate modes against reference modes, matched by MAC.

    Attributes:
        matched: index of the approximate mode matched to each reference mode (n,).
        mac: MAC of each matched pair (n,) [-].
        frequency_error: relative frequency error of each matched pair (n,) [-].
        mass_weighted: True when the MAC used the mass matrix.
    """

    matched: np.ndarray
    mac: np.ndarray
    frequency_error: np.ndarray
    mass_weighted: bool

    @property
    def max_frequency_error(self) -> float:
        """Largest |relative frequency error| [-]."""
        return float(np.max(np.abs(self.frequency_error)))

    @property
    def min_mac(self) -> float:
        """Smallest MAC of a matched pair [-]."""
        return float(np.min(self.mac))


def compare_modes(f_approx, shapes_approx, f_ref, shapes_ref, *, M=None, count: int | None = None) -> ModeComparison:
    """Match the first ``count`` reference modes to approximate ones by MAC and compare them.

    Args:
        f_approx: approximate frequencies (k_a,) [Hz] (or rad/s, same unit as f_ref).
        shapes_approx: approximate shapes (N, k_a) on the reference DOFs.
        f_ref: reference frequencies (k_r,).
        shapes_ref: reference shapes (N, k_r).
        M: optional mass matrix (N, N) [kg] for the mass-weighted MAC.
        count: reference modes to compare (default all k_r; at most k_a).

    Returns:
        ``ModeComparison``.
    """
    f_approx = np.asarray(f_approx, dtype=np.float64)
    f_ref = np.asarray(f_ref, dtype=np.float64)
    count = len(f_ref) if count is None else int(count)
    if not 1 <= count <= min(len(f_ref), len(f_approx)):
        raise InputError(f"count must be in [1, {min(len(f_ref), len(f_approx))}], got {count}")
    shapes_ref = np.asarray(shapes_ref)[:, :count]
    mac = mac_matrix(shapes_approx, shapes_ref, M=M)
    matched = match_modes(mac)
    return ModeComparison(
        matched=matched,
        mac=mac[matched, np.arange(count)],
        frequency_error=frequency_errors(f_approx[matched], f_ref[:count]),
        mass_weighted=M is not None,
    )
