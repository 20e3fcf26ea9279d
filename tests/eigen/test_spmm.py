"""spmm: MKL's sparse-times-dense product against a dense reference, and the SciPy fallbacks."""

import numpy as np
import pytest
import scipy.sparse as sp

from modalfem.eigen import spmm as spmm_module
from modalfem.eigen.pardiso import have_pardiso
from modalfem.eigen.spmm import spmm

needs_mkl = pytest.mark.skipif(not have_pardiso(), reason="MKL not loadable here")


def random_csr(m: int, n: int, density: float, seed: int) -> sp.csr_matrix:
    """Random CSR with some empty rows (rows 0 and m // 2 cleared) and unsorted-free canonical form."""
    A = sp.random(m, n, density=density, format="lil", random_state=seed)
    A[0, :] = 0.0
    A[m // 2, :] = 0.0
    A = A.tocsr()
    A.eliminate_zeros()
    return A


def with_int64_indices(A):
    B = A.copy()
    B.indices, B.indptr = B.indices.astype(np.int64), B.indptr.astype(np.int64)
    return B


def reference(A, X):
    return A.toarray() @ X


def _counted(monkeypatch):
    """Count the MKL calls (the wrapped mkl_sparse_d_mm)."""
    funcs = spmm_module._funcs()
    calls = []

    def mm(*args):
        calls.append(1)
        return funcs[1](*args)

    monkeypatch.setattr(spmm_module, "_funcs", lambda: (funcs[0], mm, funcs[2], funcs[3]))
    return calls


@needs_mkl
@pytest.mark.parametrize("k", [None, 1, 4, 14])
@pytest.mark.parametrize("order", ["C", "F"])
def test_mkl_product_matches_dense(k, order, monkeypatch):
    calls = _counted(monkeypatch)
    A = random_csr(300, 200, 0.05, seed=1)
    rng = np.random.default_rng(2)
    X = rng.standard_normal(200 if k is None else (200, k))
    X = np.asfortranarray(X) if order == "F" else X
    Y = spmm(A, X)
    assert calls, "the MKL kernel was not used"
    assert Y.shape == ((300,) if k is None else (300, k)) and Y.flags.c_contiguous
    ref = reference(A, X)
    np.testing.assert_allclose(Y, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    np.testing.assert_allclose(Y, A @ X, rtol=0, atol=1e-13 * np.abs(ref).max())  # SciPy: same to roundoff


@needs_mkl
def test_mkl_product_on_a_strided_view_and_a_symmetric_fe_like_matrix(monkeypatch):
    calls = _counted(monkeypatch)
    n = 500
    t = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")
    rng = np.random.default_rng(3)
    X = rng.standard_normal((n, 12))[:, ::3]  # non-contiguous view
    np.testing.assert_allclose(spmm(t, X), reference(t, X), rtol=0, atol=1e-13)
    assert calls


@pytest.mark.parametrize(
    "make",
    [
        lambda A: A.tocsc(),  # not CSR
        lambda A: A.astype(np.float32),  # not float64
        lambda A: with_int64_indices(A),  # 64-bit indices (MKL's LP64 interface takes 32-bit)
        lambda A: A.toarray(),  # dense
        lambda A: sp.csr_matrix(A.shape),  # no entries
    ],
)
def test_what_mkl_cannot_take_goes_to_scipy(make, monkeypatch):
    monkeypatch.setattr(spmm_module, "_funcs", lambda: pytest.fail("MKL used for unsupported input"))
    A0 = random_csr(40, 30, 0.2, seed=4)
    A = make(A0)
    X = np.random.default_rng(5).standard_normal((30, 3))
    np.testing.assert_allclose(spmm(A, X), np.asarray(A @ X), rtol=1e-6)


def test_without_mkl_scipy_computes_the_product(monkeypatch):
    monkeypatch.setattr(spmm_module, "_funcs", lambda: False)
    A = random_csr(50, 50, 0.1, seed=6)
    X = np.random.default_rng(7).standard_normal((50, 2))
    np.testing.assert_allclose(spmm(A, X), reference(A, X), rtol=0, atol=1e-13)
