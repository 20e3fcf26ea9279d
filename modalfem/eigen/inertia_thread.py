"""The certificate's Sylvester count on a second PARDISO handle, computed while the solves run.

The inertia count needs an LDL^T of K - sigma M with sigma above the wanted eigenvalues: a second
numeric factorisation as costly as the first (2-3 s at 139,587 P2 DOFs), which the shift-invert
solves do not need. It needs sigma, i.e. approximate eigenvalues, but not converged ones: sigma is
the midpoint of a clear gap of the spectrum (``certify.choose_inertia_shift``), and the block
Krylov-Schur iteration has its Ritz values to ~1e-4 relative long before its vectors reach 1e-12.

``ConcurrentInertia`` therefore

1. analyses a twin handle (same pattern and ordering, symbolic phase only) on a background thread
   when created;
2. watches the Ritz values (``monitor``, called by ``block_krylov_schur`` after each block): once every
   computed pair's residual estimate is below ``TRIGGER_RTOL``, it places sigma and factorises
   K - sigma M on the twin, on one MKL thread, while the main thread goes on solving on one thread
   (measured at 139,587 DOFs: a numeric factorisation is compute-bound and a triangular solve
   memory-bound, so the two overlap well: 8.2 s for factor + 13 block solves + inertia against
   9.8 s one after the other);
3. ``count(lam)`` checks the early sigma against the converged eigenvalues: it must fall in the gap
   the converged eigenvalues would choose, with a clear margin; otherwise (or if the trigger never
   fired) the twin is factorised again at the converged sigma. The count is the same proof either
   way: negative pivots of an unperturbed LDL^T of K - sigma M.

A factor with diagonal pivots of an indefinite matrix is trusted only if a solve's backward error
is at most ``scipy_solver._FACTOR_BACKWARD_TOL``; else it is redone with Bunch-Kaufman pivots.
"""

from __future__ import annotations

import queue
import threading

import numpy as np

from modalfem.errors import SolverError

__all__ = ["TRIGGER_RTOL", "ConcurrentInertia", "pardiso_inertia"]

#: relative residual estimate every computed Ritz pair must reach before sigma is placed
TRIGGER_RTOL = 1e-2
#: the early sigma must stay at least this far (relative) from every converged eigenvalue
SIGMA_MARGIN = 1e-3


def pardiso_inertia(factor, K, M, sigma: float) -> int | None:
    """Negative pivots of an LDL^T of K - sigma M, numerically refactorising ``factor`` (a
    ``PardisoLDLT`` analysed on this pattern); None when the count is not proven (another pattern,
    perturbed or zero pivots, or a diagonal-pivot factor with a poor backward error)."""
    from modalfem.eigen.scipy_solver import _FACTOR_BACKWARD_TOL, _backward_error

    A = (K - sigma * M).tocsr()
    A.sort_indices()
    if not factor.same_pattern(A):
        return None
    factor.refactor(A.data)
    if factor.pivoting_used == "diagonal" and _backward_error(A, factor.solve) > _FACTOR_BACKWARD_TOL:
        factor.pivoting = "bunch-kaufman"
        factor.refactor()
    neg, zero, _ = factor.inertia
    return None if factor.perturbed_pivots or zero else int(neg)


class ConcurrentInertia:
    """Sylvester count of K - sigma M on a twin of ``factor``, overlapping the solves (module doc).

    Args:
        factor: the ``PardisoLDLT`` of K - shift M used for the solves (analysed; may be factorised
            after this object is made).
        K, M: free-DOF stiffness [N/m] and mass [kg], scipy CSR (n, n).
        nev: wanted eigenpairs (rigid included); shift: the solves' shift [rad^2/s^2] (< 0).
    """

    def __init__(self, factor, K, M, *, nev: int, shift: float) -> None:
        self._factor, self._K, self._M = factor, K, M
        self._nev, self._shift = int(nev), float(shift)
        self._jobs: queue.Queue = queue.Queue()
        self._results: dict[float, int | None] = {}
        self._error: BaseException | None = None
        self._main_threads = factor.threads
        #: sigma placed from the Ritz values during the solves (None until the trigger fires)
        self.early_sigma: float | None = None
        self._thread = threading.Thread(target=self._work, name="modalfem-inertia", daemon=True)
        self._thread.start()

    def _floor(self) -> float:
        from modalfem.eigen.scipy_solver import ZERO_RTOL

        return ZERO_RTOL * abs(self._shift)

    def _work(self) -> None:
        twin = None
        try:
            twin = self._factor.twin(threads=1, pivoting="diagonal")
            while True:
                sigma = self._jobs.get()
                if sigma is None:
                    return
                try:
                    self._results[sigma] = pardiso_inertia(twin, self._K, self._M, sigma)
                finally:
                    self._factor.threads = self._main_threads
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread by count()
            self._error = exc
        finally:
            if twin is not None:
                twin.close()

    def _submit(self, sigma: float) -> None:
        self._factor.threads = 1  # the twin factorises on one thread while the main one solves on one
        self._jobs.put(float(sigma))

    def monitor(self, theta: np.ndarray, rel: np.ndarray) -> None:
        """Block Krylov-Schur hook: place sigma and start the twin factorisation once every computed
        Ritz pair is within ``TRIGGER_RTOL`` (theta are Ritz values of (K - shift M)^-1 M)."""
        if self.early_sigma is not None or len(theta) <= self._nev or not np.all(rel <= TRIGGER_RTOL):
            return
        from modalfem.eigen.certify import choose_inertia_shift

        with np.errstate(divide="ignore"):
            lam = np.sort(self._shift + 1.0 / np.asarray(theta, dtype=float))
        try:
            sigma = choose_inertia_shift(lam, self._nev, floor=self._floor())
        except SolverError:
            return
        self.early_sigma = sigma
        self._submit(sigma)

    def count(self, lam: np.ndarray) -> tuple[int | None, float]:
        """(count, sigma) for the converged eigenvalues ``lam`` (ascending): the count at the early
        sigma when it sits in the gap the converged eigenvalues choose, else at that gap's sigma.
        count is None when no proven count could be made (the caller falls back)."""
        from modalfem.eigen.certify import choose_inertia_shift

        lam = np.asarray(lam, dtype=float)
        final = choose_inertia_shift(lam, self._nev, floor=self._floor())
        sigma = final
        early = self.early_sigma
        if early is not None:
            same_gap = np.searchsorted(lam, early) == np.searchsorted(lam, final)
            margin = np.min(np.abs(lam - early)) / max(abs(early), np.finfo(float).tiny)
            if same_gap and margin >= SIGMA_MARGIN:
                sigma = early
        if sigma != early:
            self._submit(sigma)
        self._jobs.put(None)
        self._thread.join()
        self._factor.threads = self._main_threads
        if self._error is not None:
            if isinstance(self._error, SolverError):
                raise self._error
            raise SolverError(f"inertia count failed: {type(self._error).__name__}: {self._error}")
        return self._results.get(sigma), float(sigma)

    def close(self) -> None:
        """Stop the worker (idempotent); the twin's memory is released."""
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join()
        self._factor.threads = self._main_threads
