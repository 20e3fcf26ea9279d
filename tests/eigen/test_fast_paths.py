"""The small- and mid-size fast paths of ``modes`` (AMD ordering, two MKL threads) give the reference
path's modes: same certificate, frequencies within the pairs' own error bounds.

Reference path: parallel METIS ordering on one thread (the default before the fast paths). The bound is
computed from each solve's pairs, not fixed: for an M-normalised pair (lam, x) of the pencil (K, M) with
residual r = K x - lam M x, some eigenvalue lies within ||r||_{M^-1} of lam (Kato / Bauer-Fike for a
symmetric-definite pencil), and r itself is computed with a rounding error below
sqrt(row nnz) eps || |K| |x| + |lam| |M| |x| ||_{M^-1}; two solves of the same eigenvalue therefore differ
by at most the sum of their two bounds.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from modalfem.eigen import pardiso
from modalfem.modes import modes

needs_pardiso = pytest.mark.skipif(not pardiso.have_pardiso(), reason="MKL PARDISO not loadable here")


def _bounds(res, K, M) -> np.ndarray:
    """Per deformation mode: ||r||_{M^-1} plus the rounding bound of r (see module doc) [rad^2/s^2]."""
    free = ~res.fixed_dofs
    Kf, Mf = sp.csr_matrix(K)[free][:, free], sp.csr_matrix(M)[free][:, free]
    X = res.shapes[free]
    lam = res.eigenvalues
    R = Kf @ X - (Mf @ X) * lam
    lu = splu(Mf.tocsc())
    eps = np.finfo(float).eps * np.sqrt(float(np.max(np.diff(Kf.indptr))))
    E = eps * (abs(Kf) @ np.abs(X) + (abs(Mf) @ np.abs(X)) * np.abs(lam))
    m_inv_norm = [np.sqrt(max(float(v @ lu.solve(v)), 0.0)) for v in (*R.T, *E.T)]
    k = len(lam)
    return np.asarray(m_inv_norm[:k]) + np.asarray(m_inv_norm[k:])


def _solve(mesh, steel, fixed, monkeypatch, *, ordering_amd: bool, threads: bool):
    with monkeypatch.context() as m:
        m.setattr(pardiso, "AMD_BELOW", 10**9 if ordering_amd else 0)
        m.setattr(pardiso, "SERIAL_BELOW", 0 if threads else 10**9)
        m.setattr(pardiso, "busy_elsewhere", lambda samples=5: 0.0)  # threaded even on a busy machine
        return modes(mesh, steel, k=8, degree=2, fixed=fixed, backend="skfem", solver="block")


@needs_pardiso
@pytest.mark.parametrize("fixed", ["x0", None], ids=["clamped", "free"])
@pytest.mark.parametrize("ordering_amd, threads", [(True, False), (False, True), (True, True)],
                         ids=["amd", "threads", "amd+threads"])
def test_fast_path_gives_the_reference_modes(make_box, steel, assemble_km, monkeypatch, fixed, ordering_amd,
                                             threads):
    mesh = make_box((1.0, 0.1, 0.1), (20, 2, 2))  # 3,075 P2 DOFs: above the node-grouped ordering's size
    ref = _solve(mesh, steel, fixed, monkeypatch, ordering_amd=False, threads=False)
    fast = _solve(mesh, steel, fixed, monkeypatch, ordering_amd=ordering_amd, threads=threads)
    name = fast.info["solver_info"]["pardiso_ordering"]
    assert name.startswith("amd" if ordering_amd else "metis-parallel")
    assert ref.info["solver_info"]["pardiso_ordering"].startswith("metis-parallel")
    for res in (ref, fast):
        assert res.certificate.passed, res.certificate.to_dict()
    assert fast.rigid_mode_count == ref.rigid_mode_count == (6 if fixed is None else 0)
    assert fast.certificate.inertia_count - fast.certificate.computed_below_shift == 0
    assert fast.certificate.pairs == ref.certificate.pairs
    K, M = assemble_km(mesh, steel, degree=2)
    allowed = _bounds(ref, K, M) + _bounds(fast, K, M)
    assert np.all(np.abs(fast.eigenvalues - ref.eigenvalues) <= allowed), (fast.eigenvalues - ref.eigenvalues, allowed)


def test_small_problem_runs_its_dense_work_on_one_openblas_thread(beam, steel, monkeypatch):
    """Below PARDISO's one-thread size the shift estimate and the labels hold OpenBLAS on one thread
    (and give the previous count back afterwards); above it they leave OpenBLAS alone."""
    import sys

    from modalfem.eigen.blas_threads import openblas_threads

    if not openblas_threads():
        pytest.skip("no OpenBLAS loaded in this process")
    mm = sys.modules["modalfem.modes"]
    seen = []
    real = mm._labels

    def spy(*args, **kwargs):
        seen.append(openblas_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(mm, "_labels", spy)
    before = openblas_threads()
    modes(beam, steel, k=3, fixed="x0", backend="skfem")
    assert seen[-1] == [1] * len(before) and openblas_threads() == before
    monkeypatch.setattr(pardiso, "SERIAL_BELOW", 0)  # now "large": OpenBLAS keeps its count
    modes(beam, steel, k=3, fixed="x0", backend="skfem")
    assert seen[-1] == before
