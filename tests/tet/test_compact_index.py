"""The tet solver's gathers index through 32-bit unsigned arrays when the indices fit
(``_kernels.compact_unsigned``), 64-bit otherwise, and give the bits of the 64-bit gathers."""

import numpy as np
import pytest

from modalfem._threads import thread_count
from modalfem.material import Material
from modalfem.mesh import box
from modalfem.tet import _kernels as K
from modalfem.tet.assembly import HessianPattern
from modalfem.tet.effects import Gravity
from modalfem.tet.model import tet_model
from modalfem.tet.solver import TetSolver


def test_compact_unsigned_picks_the_narrowest_width_that_holds_the_indices():
    small = np.array([0, 5, 2**32 - 1], dtype=np.int64)
    got = K.compact_unsigned(small)
    assert got.dtype == np.uint32
    np.testing.assert_array_equal(got.astype(np.int64), small)
    big = np.array([3, 2**32], dtype=np.int64)
    got = K.compact_unsigned(big)
    assert got.dtype == np.uint64
    np.testing.assert_array_equal(got.astype(np.int64), big)
    assert K.compact_unsigned(np.zeros(0, dtype=np.int64)).size == 0
    with pytest.raises(ValueError):
        K.compact_unsigned(np.array([1, -1]))


def test_pattern_and_force_gathers_use_32_bit_indices_with_the_bits_of_64_bit_ones():
    mesh = box(size=(0.3, 0.1, 0.1), cells=(6, 2, 2))
    pat = HessianPattern(mesh.cells, mesh.point_count)
    solver = TetSolver(tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0)), effects=[Gravity()])
    for a in (pat._gather_order, pat._owner, pat._mirror, pat._element_major_order(), solver._force_order):
        assert a.dtype == np.uint32
    rng = np.random.default_rng(7)
    em = rng.standard_normal((mesh.cell_count, 78))
    f = rng.standard_normal(4 * 3 * mesh.cell_count)
    wide = [x.astype(np.uint64) for x in (pat._element_major_order(), pat._owner, pat._mirror, solver._force_order)]
    for t in (1, 2):
        with thread_count(t):
            ref = np.empty(pat.nnz)
            K.assemble_upper(pat._gather_ptr, wide[0], em.ravel(), wide[1], wide[2], ref)
            got = pat.assemble(em.T, None, upper=True)
            np.testing.assert_array_equal(got, ref)
            g_ref = np.empty(3 * mesh.point_count)
            K.gather_sum(solver._force_ptr, wide[3], f, g_ref)
            g = np.empty(3 * mesh.point_count)
            K.gather_sum(solver._force_ptr, solver._force_order, f, g)
            np.testing.assert_array_equal(g, g_ref)
