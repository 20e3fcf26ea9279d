"""The shift estimate's trial fields: admissible (zero on held DOFs), distance factors against brute
force (one distance field per distinct held-node set), and a Ritz value bounding lambda_1 from above."""

import importlib

import numpy as np
import pytest
import scipy.linalg as sl

from modalfem import STEEL
from modalfem.backends.skfem import assemble
from modalfem.constraints import Fix, fixed_mask
from modalfem.mesh import box

modes_module = importlib.import_module("modalfem.eigen.shift")
restrict = importlib.import_module("modalfem.modes").restrict


@pytest.fixture(scope="module")
def beam():
    return box(size=(1.0, 0.2, 0.2), cells=(6, 2, 2))


@pytest.mark.parametrize(
    "spec",
    ["x0", [Fix("x0", components="x"), Fix("x1", components="yz")], [Fix("x0", components="xy"), Fix("x1", components="z")]],
)
def test_fields_vanish_on_held_dofs_and_use_each_components_distance(beam, spec):
    degree = 2
    fixed = fixed_mask(beam, degree, spec)
    B = modes_module._trial_fields(beam, degree, fixed)
    p = beam.dof_points(degree)
    lo, hi = beam.bounds
    L = float(np.max(hi - lo))
    npoly = B.shape[1] // 3
    held = fixed.reshape(-1, 3)
    U = B.reshape(len(p), 3, B.shape[1])
    for c in range(3):
        cols = slice(c * npoly, (c + 1) * npoly)
        # other components' columns are zero on this component's rows
        assert not np.any(np.delete(U[:, c, :], np.arange(B.shape[1])[cols], axis=1))
        np.testing.assert_array_equal(U[held[:, c], c, cols], 0.0)  # admissible
        brute = np.min(np.linalg.norm(p[:, None, :] - p[held[:, c]][None, :, :], axis=2), axis=1) / L
        # the constant polynomial column is the distance factor itself
        np.testing.assert_allclose(U[:, c, c * npoly], brute, rtol=1e-12, atol=1e-15)


def test_ritz_value_bounds_the_first_eigenvalue_from_above(beam):
    degree = 1
    fixed = fixed_mask(beam, degree, "x0")
    K, M = assemble(beam, STEEL, degree=degree)
    free = ~fixed
    K_ff, M_ff = restrict(K, free), restrict(M, free)
    shift, theta = modes_module.estimate_shift(beam, degree, fixed, K_ff, M_ff, rigid_count=0)
    lam1 = sl.eigh(K_ff.toarray(), M_ff.toarray(), eigvals_only=True, subset_by_index=[0, 0])[0]
    assert lam1 <= theta * (1 + 1e-10)  # min-max: a Ritz value is an upper bound
    assert shift == pytest.approx(-modes_module.SHIFT_FRACTION * theta)
