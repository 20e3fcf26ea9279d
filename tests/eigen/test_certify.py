"""Certificate logic: inertia shift placement, degenerate pairs, passed/failed decisions."""

from dataclasses import replace

import numpy as np
import pytest

from modalfem.constraints import fixed_mask
from modalfem.eigen.base import RawModes
from modalfem.eigen.certify import (
    PAIR_RTOL,
    build_certificate,
    choose_inertia_shift,
    degenerate_pairs,
)
from modalfem.eigen.scipy_solver import solve_scipy
from modalfem.errors import SolverError


def test_shift_never_splits_a_cluster():
    lam = np.array([0.0, 1.0, 2.0, 2.0 * (1 + 1e-9), 5.0, 9.0])
    s = choose_inertia_shift(lam, 3)  # nev-th eigenvalue is half of a degenerate pair
    assert lam[3] < s < lam[4] and s == pytest.approx(3.5 + 1e-9)
    assert lam[1] < choose_inertia_shift(lam, 2) < lam[2]


def test_shift_errors():
    with pytest.raises(SolverError, match="nev \\+ 1"):
        choose_inertia_shift([1.0, 2.0], 2)
    with pytest.raises(SolverError, match="cluster"):
        choose_inertia_shift([1.0, 2.0, 2.0, 2.0], 2)


def test_pairs_tolerance():
    lam = np.array([100.0, 100.0 * (1 + 1e-9), 200.0, 200.0 * (1 + 1e-3), 300.0, 300.0, 300.0])
    assert degenerate_pairs(lam) == ((0, 1), (4, 5), (5, 6))
    assert 1e-6 <= PAIR_RTOL <= 1e-4


@pytest.fixture(scope="module")
def cantilever_raw(beam, steel, assemble_km):
    K, M = assemble_km(beam, steel, degree=2)
    free = ~fixed_mask(beam, 2, "x0")
    K, M = K[free][:, free].tocsr(), M[free][:, free].tocsr()
    import scipy.linalg as sl

    ref = sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    raw = solve_scipy(K, M, nev=8, shift=-1e6)
    absK = abs(K)
    floor = np.finfo(float).eps * np.linalg.norm(absK @ np.abs(raw.vectors), axis=0) / np.linalg.norm(
        K @ raw.vectors, axis=0
    )
    return raw, ref, floor


def test_certificate_passes_and_matches_dense_count(cantilever_raw):
    raw, ref, floor = cantilever_raw
    cert = build_certificate(raw, 0, 8, tol=1e-10, residual_floor=floor)
    assert cert.passed, cert.to_dict()
    assert cert.max_residual < 1e-9 and cert.orthonormality_error < 1e-12
    assert cert.inertia_count == int(np.sum(ref < cert.inertia_shift)) == cert.computed_below_shift
    assert cert.missed_count == 0
    # the square beam's bending planes (symmetric mesh) pair up; torsion/axial do not. The dense
    # reference resolves a gap only to ~eps * lambda_max (1e-4 rad^2/s^2 here, ~1e-9 relative to
    # lambda_1), hence 1e-7.
    assert cert.pairs == ((0, 1), (2, 3), (6, 7))
    assert np.all(np.diff(ref[:8])[[0, 2, 6]] / ref[[1, 3, 7]] < 1e-7)
    assert np.all(np.diff(ref[:8])[[1, 3, 4, 5]] / ref[[2, 4, 5, 6]] > 1e-2)


def test_missed_eigenvalue_fails(cantilever_raw):
    raw, _, floor = cantilever_raw
    assert build_certificate(raw, 0, 8, tol=1e-10, residual_floor=floor).passed
    keep = np.delete(np.arange(len(raw.eigenvalues)), 3)  # drop one computed pair below the shift
    missed = replace(raw, eigenvalues=raw.eigenvalues[keep], vectors=raw.vectors[:, keep], residuals=raw.residuals[keep])
    cert = build_certificate(missed, 0, 8, tol=1e-10, residual_floor=np.delete(floor, 3))
    assert not cert.passed and cert.missed_count == 1


def test_bad_residual_or_orthonormality_fails(cantilever_raw):
    raw, _, _ = cantilever_raw
    assert not build_certificate(replace(raw, residuals=raw.residuals * 1e4), 0, 8, tol=1e-10).passed
    assert not build_certificate(replace(raw, orthonormality_error=1e-6), 0, 8, tol=1e-10).passed
    res = raw.residuals.copy()
    res[2] = np.nan
    assert not build_certificate(replace(raw, residuals=res), 0, 8, tol=1e-10).passed


def test_residual_floor_raises_the_bound():
    raw = RawModes(
        eigenvalues=np.array([1.0, 2.0, 3.0]), vectors=np.eye(3), residuals=np.array([1e-8, 1e-9, 1e-9]),
        orthonormality_error=0.0, inertia_shift=2.5, inertia_count=2,
    )
    assert not build_certificate(raw, 0, 2, tol=1e-10).passed
    cert = build_certificate(raw, 0, 2, tol=1e-10, residual_floor=np.array([2e-9, 1e-10, 1e-10]))
    assert cert.passed and cert.tolerance == pytest.approx(2e-8)
