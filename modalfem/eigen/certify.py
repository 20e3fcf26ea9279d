"""Certification logic shared by all solvers: the inertia shift, degenerate pairs, the Certificate.

The solvers compute the numbers (residuals, M-orthonormality, a Sylvester inertia count of
K - sigma M); this module only decides where sigma goes and whether the numbers prove the result.

Tolerances (relative eigenvalue gaps, ``gap = (lam_{i+1} - lam_i) / lam_{i+1}``):

* ``PAIR_RTOL = 1e-5``: two consecutive deformation modes closer than this are reported as a
  degenerate pair. On a mesh with the body's symmetry (a square beam meshed symmetrically) the two
  bending planes differ only by solver error; at the default residual tolerance 1e-10 an eigenvalue
  is accurate to ~1e-10 relative, so 1e-5 leaves 5 decades of margin. Physically distinct modes that
  close (1000 Hz vs 1000.005 Hz) cannot be told apart in any measurement, while discretization alone
  splits the pair on a mesh WITHOUT the symmetry by ~1e-3 (P2, a coarse square beam on plain Kuhn
  tetrahedra) and ~2e-1 (P1), so such a near-pair is (correctly) not reported.
* ``CLEAR_GAP = 1e-3``: the inertia shift is placed in the first gap at or above the nev-th
  eigenvalue that is at least this wide, so it never splits a (near-)degenerate cluster and
  K - sigma M stays far from singular (its smallest |eigenvalue| is >= CLEAR_GAP / 2 * lam relative).
"""

from __future__ import annotations

import numpy as np

from modalfem.errors import SolverError
from modalfem.result import Certificate

__all__ = [
    "CLEAR_GAP",
    "FLOOR_FACTOR",
    "ORTHONORMALITY_TOL",
    "PAIR_RTOL",
    "build_certificate",
    "choose_inertia_shift",
    "degenerate_pairs",
]

PAIR_RTOL = 1e-5
CLEAR_GAP = 1e-3
ORTHONORMALITY_TOL = 1e-8
#: the residual bound is raised to FLOOR_FACTOR x the roundoff floor of the residual itself
FLOOR_FACTOR = 10.0


def _rel_gaps(lam: np.ndarray, floor: float) -> np.ndarray:
    lam = np.asarray(lam, dtype=float)
    return np.diff(lam) / np.maximum(np.maximum(np.abs(lam[1:]), np.abs(lam[:-1])), floor)


def choose_inertia_shift(eigenvalues, nev: int, *, floor: float = 0.0, complete: bool = False) -> float:
    """Shift sigma [rad^2/s^2] for the Sylvester count: between the nev-th and a later eigenvalue.

    sigma is the midpoint of the first gap ``(lam[j], lam[j+1])``, ``j >= nev - 1``, whose relative
    width is at least ``CLEAR_GAP``; if no computed gap is that wide, the widest one is used.

    Args:
        eigenvalues: computed lambda (m,) [rad^2/s^2], ascending, m > nev.
        nev: number of wanted eigenvalues (rigid included).
        floor: eigenvalue scale [rad^2/s^2] under which gaps are measured absolutely (so that gaps
            among near-zero rigid eigenvalues are not inflated); 0 uses pure relative gaps.
        complete: ``eigenvalues`` is the whole spectrum (a dense solve of a tiny problem). Then, if
            no gap above the nev-th is clear, sigma goes above the largest eigenvalue (every
            eigenvalue lies below it, which the count proves just as well).

    Returns:
        sigma, with lam[nev - 1] < sigma < lam[m - 1].

    Raises:
        SolverError: fewer than nev + 1 eigenvalues, or every gap above nev is below ``PAIR_RTOL``
            (a cluster too wide for the computed eigenvalues to bracket).
    """
    lam = np.asarray(eigenvalues, dtype=float)
    top = float(lam[-1] + max(abs(lam[-1]), np.finfo(float).tiny)) if lam.size else 0.0
    if complete and lam.ndim == 1 and len(lam) == nev >= 1:
        return top
    if lam.ndim != 1 or len(lam) < nev + 1 or nev < 1:
        raise SolverError(
            f"the inertia check needs at least nev + 1 = {nev + 1} computed eigenvalues, got {lam.size}"
        )
    gaps = _rel_gaps(lam, max(floor, np.finfo(float).tiny))[nev - 1 :]
    wide = np.flatnonzero(gaps >= CLEAR_GAP)
    j = int(wide[0]) if len(wide) else int(np.argmax(gaps))
    if complete and not len(wide):
        return top
    if gaps[j] < PAIR_RTOL:
        raise SolverError(
            f"cannot place the inertia shift: eigenvalues {nev}..{len(lam)} form one cluster "
            f"(largest relative gap {gaps.max():.1e}); ask for more modes"
        )
    j += nev - 1
    return float(0.5 * (lam[j] + lam[j + 1]))


def degenerate_pairs(eigenvalues, *, rtol: float = PAIR_RTOL) -> tuple[tuple[int, int], ...]:
    """Index pairs (i, i + 1) of consecutive eigenvalues with relative gap < ``rtol``.

    A cluster of three reports (i, i+1) and (i+1, i+2). Use on deformation eigenvalues (> 0).
    """
    lam = np.asarray(eigenvalues, dtype=float)
    if len(lam) < 2:
        return ()
    gaps = _rel_gaps(lam, np.finfo(float).tiny)
    return tuple((int(i), int(i) + 1) for i in np.flatnonzero(gaps < rtol))


def build_certificate(
    raw,
    rigid_count: int,
    nev: int,
    *,
    tol: float = 1e-10,
    keep: int | None = None,
    residual_floor=None,
    rigid_coupling: float = 0.0,
) -> Certificate:
    """Turn a solver's numbers into a ``Certificate``.

    Args:
        raw: ``RawModes`` from a solver (ascending eigenvalues, rigid ones first).
        rigid_count: r, the number of leading eigenpairs that are rigid-body modes.
        nev: number of wanted eigenpairs (rigid included); the certificate covers ``raw``'s first nev.
        tol: residual bound for ``passed`` (relative, see ``RawModes.residuals``).
        keep: deformation modes reported (default nev - rigid_count); pairs are searched among them.
        residual_floor: optional per-pair roundoff floor (m,) of the residual, eps * || |K| |x| || / ||K x||.
            Computing K x - lambda M x in double precision cannot go below it (thin plates and slender
            beams reach 1e-8..1e-6: lambda_max / lambda_1 ~ 1e10), so the bound used is
            max(tol, FLOOR_FACTOR * max floor over the reported deformation modes): the pairs are then
            exact for a relative perturbation of K of a few eps, the best double precision can prove.
        rigid_coupling: max_j ||Z^T M x_j|| of the reported deformation modes against the M-orthonormal
            rigid fields Z (0 when they are exactly M-orthogonal); must be <= ``ORTHONORMALITY_TOL``.

    Returns:
        The Certificate: passed = all residuals <= tol, orthonormality <= 1e-8, and the Sylvester count
        at ``raw.inertia_shift`` equals the number of computed eigenvalues below it (none missed).
    """
    lam = np.asarray(raw.eigenvalues, dtype=float)
    res = np.asarray(raw.residuals, dtype=float)
    r = int(rigid_count)
    k = nev - r if keep is None else int(keep)
    deform = res[r : r + k]
    rigid = res[:r]
    if residual_floor is not None and k > 0:
        floor = float(np.max(np.asarray(residual_floor, dtype=float)[r : r + k]))
        if np.isfinite(floor):
            tol = max(float(tol), FLOOR_FACTOR * floor)
    below = int(np.sum(lam < raw.inertia_shift))
    count_ok = raw.inertia_count is not None and int(raw.inertia_count) == below
    passed = bool(
        len(lam) >= nev
        and np.all(np.isfinite(res[:nev]))
        and np.all(deform <= tol)
        and np.all(rigid <= tol)
        and np.isfinite(raw.orthonormality_error)
        and raw.orthonormality_error <= ORTHONORMALITY_TOL
        and count_ok
        and np.isfinite(rigid_coupling)
        and rigid_coupling <= ORTHONORMALITY_TOL
    )
    return Certificate(
        residuals=deform,
        rigid_residuals=rigid,
        orthonormality_error=float(raw.orthonormality_error),
        inertia_shift=float(raw.inertia_shift),
        inertia_count=int(raw.inertia_count),
        computed_below_shift=below,
        pairs=degenerate_pairs(lam[r : r + k]),
        tolerance=float(tol),
        passed=passed,
        rigid_coupling=float(rigid_coupling),
    )
