"""OpenBLAS is held on one thread inside ``one_openblas_thread`` and restored after."""

from __future__ import annotations

import pytest

from modalfem.eigen.blas_threads import one_openblas_thread, openblas_threads


def test_one_thread_inside_and_the_previous_count_after():
    before = openblas_threads()
    if not before:
        pytest.skip("no OpenBLAS loaded in this process")
    with one_openblas_thread():
        assert all(n == 1 for n in openblas_threads())
    assert openblas_threads() == before


def test_the_count_is_restored_when_the_block_raises():
    before = openblas_threads()
    with pytest.raises(RuntimeError), one_openblas_thread():
        raise RuntimeError("solver failed")
    assert openblas_threads() == before
