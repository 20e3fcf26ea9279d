"""The package's thread count (``modalfem.threads``): default, environment variable, Python call, errors."""

from __future__ import annotations

import os
import subprocess
import sys

import numba
import pytest

import modalfem
from modalfem._threads import chunk_bounds, chunk_count, thread_count, threading_layer
from modalfem.errors import InputError


def _child(code: str, **env) -> subprocess.CompletedProcess:
    full = {k: v for k, v in os.environ.items() if k != "MODALFEM_THREADS"}
    full.update(env)
    return subprocess.run([sys.executable, "-c", code], env=full, capture_output=True, text=True, timeout=120)


def test_default_is_every_core_and_the_environment_variable_sets_it():
    code = ("import modalfem, numba, os; "
            "print(modalfem.threads(), numba.get_num_threads(), len(os.sched_getaffinity(0)))")
    p = _child(code)
    assert p.returncode == 0, p.stderr
    count, numba_count, cores = map(int, p.stdout.split())
    assert count == numba_count == min(cores, numba.config.NUMBA_NUM_THREADS)
    p = _child(code, MODALFEM_THREADS="1")
    assert p.returncode == 0, p.stderr
    assert p.stdout.split()[:2] == ["1", "1"]


def test_a_bad_environment_value_is_one_clear_line():
    p = _child("import modalfem.cloth._kernels", MODALFEM_THREADS="two")
    assert p.returncode != 0
    assert "MODALFEM_THREADS must be a whole number >= 1, got 'two'" in p.stderr.strip().splitlines()[-1]


def test_set_threads_checks_its_argument_and_thread_count_restores():
    before = modalfem.threads()
    for bad in (0, -1, 1.5, "2", True, numba.config.NUMBA_NUM_THREADS + 1):
        with pytest.raises(InputError, match="thread count must be"):
            modalfem.set_threads(bad)
    assert modalfem.threads() == before
    with thread_count(1):
        assert modalfem.threads() == 1 and numba.get_num_threads() == 1
    assert modalfem.threads() == before and numba.get_num_threads() == before
    assert modalfem.set_threads(1) == 1
    assert modalfem.set_threads(None) == before


def test_the_threading_layer_is_a_thread_safe_one_where_it_exists():
    layer = threading_layer()
    assert layer in ("tbb", "omp", "workqueue")
    from modalfem._threads import _has_omp, _preload_tbb

    if _preload_tbb():
        assert layer == "tbb"
    elif _has_omp():
        assert layer == "omp"


@numba.njit
def _bounds(n, min_chunk):
    k = chunk_count(n, min_chunk)
    out = []
    for c in range(k):
        out.append(chunk_bounds(n, k, c))
    return out


@pytest.mark.parametrize("n, min_chunk", [(0, 4), (3, 4), (10, 4), (1000, 7), (10**6, 256)])
def test_chunks_cover_the_range_in_order_and_do_not_depend_on_threads(n, min_chunk):
    bounds = _bounds(n, min_chunk)
    assert 1 <= len(bounds) <= 64
    assert bounds[0][0] == 0 and bounds[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(bounds, bounds[1:]))
    assert all(hi - lo >= min(min_chunk, n) for lo, hi in bounds)
    with thread_count(1):
        assert _bounds(n, min_chunk) == bounds
