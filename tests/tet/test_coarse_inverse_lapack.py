"""The two-level preconditioner's coarse inverse from LAPACK potrf/potri in place, made symmetric by
``_kernels.mirror_upper``: the bits of the SciPy recipe it replaced (cho_factor, potri, two np.triu),
exactly symmetric and C-ordered."""

import numpy as np
import scipy.linalg as sla

from modalfem.backends.skfem import assemble
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet import _kernels
from modalfem.tet.precond import TwoLevel


def test_mirror_upper_copies_the_upper_triangle_onto_the_lower_for_both_layouts():
    rng = np.random.default_rng(11)
    for order in ("C", "F"):
        a = np.asarray(rng.standard_normal((7, 7)), order=order)
        up = np.triu(a)
        _kernels.mirror_upper(a)
        np.testing.assert_array_equal(a, up + np.triu(up, 1).T)


def test_coarse_inverse_has_the_bits_of_cho_factor_and_potri():
    mesh = box(size=(0.4, 0.1, 0.1), cells=(8, 2, 2))
    K, M = assemble(mesh, Material(E=1e6, nu=0.3, rho=1000.0), degree=1)
    A = (K + 900.0 * M).tocsr()
    free = np.ones(3 * mesh.point_count, dtype=bool)
    free[:12] = False
    tl = TwoLevel(mesh.points, aggregates=6)
    x = mesh.points + 1e-3 * np.random.default_rng(5).standard_normal(mesh.points.shape)
    P, inv = tl._coarse_space(A, x, free)
    Ac = (P.T @ (A @ P)).toarray()
    d = np.diag(Ac).copy()
    dmax = d.max()
    empty = d <= 1e-14 * dmax
    Ac[empty, empty] = 1.0
    Ac[np.diag_indices_from(Ac)] += 1e-10 * dmax
    # the recipe before (on the compiled Galerkin product's matrix: rebuild it as TwoLevel does)
    Ag = np.zeros_like(Ac)
    _kernels.galerkin(A.indptr, _kernels.unsigned(A.indices), A.data, P.indptr, _kernels.unsigned(P.indices),
                      P.data, tl._group_ptr, tl._group_rows, Ag)
    dg = np.diag(Ag).copy()
    eg = dg <= 1e-14 * dg.max()
    Ag[eg, eg] = 1.0
    Ag[np.diag_indices_from(Ag)] += 1e-10 * dg.max()
    c, _ = sla.cho_factor(Ag, lower=False, check_finite=False)
    ci, info = sla.lapack.dpotri(c, lower=False)
    assert info == 0
    ref = np.triu(ci)
    ref += np.triu(ci, 1).T
    np.testing.assert_array_equal(inv, ref)
    assert inv.flags.c_contiguous
    np.testing.assert_array_equal(inv, inv.T)
    # and it is the inverse (to the conditioning of the coarse matrix times eps)
    err = np.abs(inv @ Ac - np.eye(len(Ac))).max()
    assert err <= 64 * np.linalg.cond(Ac) * np.finfo(float).eps
