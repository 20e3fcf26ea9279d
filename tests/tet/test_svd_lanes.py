"""The SVD kernels sweep SVD_LANES elements side by side (SIMD lanes, ``_kernels._svd_lanes``): each element's
result must be the bits of the element-by-element one-sided Jacobi (``_kernels._svd_element``), for ordinary,
cold-started, degenerate (rank 0 and 1), extreme-scaled (squares out of range: the ``math.hypot`` path) and
non-finite deformation gradients, for every lane count and on 1 and 2 threads."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet import _kernels
from modalfem.tet import kinematics as kin
from modalfem.tet.model import tet_model
from modalfem._threads import thread_count


@numba.njit
def _one_by_one(Ft, V0t, warm, U, s, V):
    AV = np.empty((6, 3))
    F = np.empty((3, 3))
    for e in range(Ft.shape[2]):
        for i in range(3):
            for j in range(3):
                F[i, j] = Ft[i, j, e]
        _kernels._svd_element(e, F, V0t, warm, U, s, V, AV)


def _reference(Ft, V0t):
    m = Ft.shape[2]
    U, V, s = np.empty((3, 3, m)), np.empty((3, 3, m)), np.empty((m, 3))
    _one_by_one(Ft, U if V0t is None else V0t, V0t is not None, U, s, V)
    return U, s, V


def _positions():
    mesh = box(size=(0.8, 0.3, 0.2), cells=(16, 6, 4))  # 2304 tets: chunks of 128 and a last partial batch
    model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    rng = np.random.default_rng(5)
    X = model.rest_points
    bent = X + 0.02 * rng.standard_normal(X.shape)
    degenerate = bent.copy()
    degenerate[:60] = degenerate[60]  # collapsed elements (F = 0 or of rank 1)
    flat = bent.copy()
    flat[:, 2] = 0.0  # every element flat (rank <= 2)
    line = np.outer(np.arange(len(X)), [1.0, 2.0, 3.0]) * 1e-3  # rank <= 1 everywhere
    nan = bent.copy()
    nan[rng.random(len(X)) < 0.02, 1] = np.nan
    cases = {"rest": X, "bent": bent, "degenerate": degenerate, "flat": flat, "line": line, "nan": nan,
             "tiny": bent * 1e-150, "huge": bent * 1e150, "random": rng.standard_normal(X.shape)}
    return model, cases


@pytest.mark.parametrize("lanes", [1, 3, _kernels.SVD_LANES])
def test_svd_lanes_equal_the_element_by_element_sweeps(lanes):
    model, cases = _positions()
    gt = np.ascontiguousarray(np.moveaxis(model.grad, 0, -1))
    threads = (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,)
    for name, x in cases.items():
        Ft = kin.deformation_gradient_t(x, model.cells, gt)
        cold = _reference(Ft, None)
        warm_start = np.ascontiguousarray(np.roll(cold[2], 1, axis=2))  # a neighbour's V: several sweeps
        for V0 in (None, warm_start):
            ref = cold if V0 is None else _reference(Ft, V0)
            m = model.cell_count
            for t in threads:
                with thread_count(t):
                    U, V, s = np.empty((3, 3, m)), np.empty((3, 3, m)), np.empty((m, 3))
                    _kernels.svd_of_positions(x, model.cells, gt, U if V0 is None else V0, V0 is not None, U, s, V,
                                              lanes)
                    got = (U, s, V)
                    U2, V2, s2 = np.empty((3, 3, m)), np.empty((3, 3, m)), np.empty((m, 3))
                    _kernels.svd_rv(Ft, U2 if V0 is None else V0, V0 is not None, U2, s2, V2, lanes)
                for a, b, c in zip(got, (U2, s2, V2), ref):
                    np.testing.assert_array_equal(a, c, err_msg=f"{name}, lanes {lanes}, {t} threads")
                    np.testing.assert_array_equal(b, c, err_msg=f"{name}, lanes {lanes}, {t} threads (svd_rv)")
