"""expand_components = restrict(kron(S, I3), free), built directly (checked against scipy's kron)."""

import numpy as np
import pytest
import scipy.sparse as sp

from modalfem.backends._sparse import expand_components
from modalfem.modes import restrict


def _random_symmetric(n: int, density: float, seed: int) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, random_state=rng, format="csr")
    A = (A + A.T + sp.identity(n)).tocsr()
    A.data[::7] = 0.0  # explicit zeros are structural entries and must survive
    A.sort_indices()
    return A


def _reference(S, free):
    full = sp.kron(S, sp.identity(3, format="csr"), format="csr")
    return full if free is None else restrict(full, free)


def _same(A, B):
    A, B = sp.csr_matrix(A), sp.csr_matrix(B)
    B = B.copy()
    B.sort_indices()
    assert A.shape == B.shape
    assert A.has_sorted_indices
    np.testing.assert_array_equal(A.indptr, B.indptr)
    np.testing.assert_array_equal(A.indices, B.indices)
    np.testing.assert_array_equal(A.data, B.data)


@pytest.mark.parametrize("kind", ["all", "whole_nodes", "scattered", "none"])
def test_expand_components_matches_kron_then_restrict(kind):
    S = _random_symmetric(40, 0.15, seed=1)
    rng = np.random.default_rng(2)
    if kind == "all":
        free = None
    elif kind == "whole_nodes":
        free = np.repeat(rng.random(40) > 0.3, 3)
    elif kind == "scattered":
        free = rng.random(120) > 0.3
    else:
        free = np.zeros(120, dtype=bool)
    _same(expand_components(S, free), _reference(S, free))


def test_expand_components_sorts_unsorted_input_and_keeps_it_unchanged():
    S = _random_symmetric(25, 0.2, seed=3)
    U = S.copy()
    U.indices = U.indices.copy()
    for i in range(U.shape[0]):  # reverse each row's order
        a, b = U.indptr[i], U.indptr[i + 1]
        U.indices[a:b] = U.indices[a:b][::-1]
        U.data[a:b] = U.data[a:b][::-1]
    U.has_sorted_indices = False
    before = U.indices.copy()
    _same(expand_components(U), _reference(S, None))
    np.testing.assert_array_equal(U.indices, before)
