"""The pipeline's per-call set-up and selections as compiled parallel passes (issue 20): the same bits as the numpy
expressions and serial loops they replace, on one and two threads, with inputs spanning several chunks."""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem._threads import thread_count
from modalfem.collision import _ccd_kernels, _pair_kernels

THREADS = (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,)


def _trajectories(N: int, seed: int):
    rng = np.random.default_rng(seed)
    X0 = rng.standard_normal((N, 3)) * np.array([0.5, 2.0, 0.1])
    V = rng.standard_normal((N, 3))
    if N:
        X0[N // 3, 1] = -7.5  # the largest coordinate in a middle chunk
    return X0, V


def test_trajectory_diagonals_give_the_bits_of_the_three_steps_it_fuses():
    dt, eta = 1e-2, 1e-4
    # serial below SERIAL_VERTICES (8192), parallel chunks above: the same chunks either way
    for N in (0, 1, 1023, 5000, _ccd_kernels.SERIAL_VERTICES - 1, _ccd_kernels.SERIAL_VERTICES + 4000):
        X0, V = _trajectories(N, N)
        X1 = X0 + dt * V  # the numpy expression ccd_hits used
        want_diag = _ccd_kernels.diagonal_intervals(X0, X1)
        scale = max(np.abs(X0).max(initial=0.0), np.abs(X1).max(initial=0.0))
        want_gap = eta * math.sqrt(3.0) * (1.0 + 1e-9) + _ccd_kernels.ROUNDING * 3.0 * scale
        for t in THREADS:
            with thread_count(t):
                got_x1, got_diag, got_gap = _ccd_kernels.trajectory_diagonals(X0, V, dt, eta)
                gap = _ccd_kernels.diagonal_gap(X0, X1, eta)
            assert np.array_equal(got_x1, X1)
            assert np.array_equal(got_diag, want_diag)
            assert got_gap == want_gap and gap == want_gap


def test_outgrown_matches_numpy_on_any_thread_count():
    """The dirty vertices of the pipeline's candidate refresh: trajectory out of its box, or (swept culling) the
    end position moved by more than eta since the pairs were found -- the numpy expressions _stages used, with
    both tests on and the velocity test off (vtol = inf), and the counts among the first n and in all."""
    dt, grow, eta = 1e-2, 2e-4, 1e-4
    for N in (5000, _pair_kernels.OUTGROWN_SERIAL + 3000):  # the serial pass and the parallel one
        _check_outgrown(N, dt, grow, eta)


def _check_outgrown(N, dt, grow, eta):
    X0, V = _trajectories(N, 1)
    V[11, 0] = 0.0  # see the bound below
    X1 = X0 + dt * V
    lo, hi = np.minimum(X0, X1) - 1e-3, np.maximum(X0, X1) + 1e-3
    V2 = V.copy()
    V2[::7] *= 1.3  # some trajectories leave their boxes
    rng = np.random.default_rng(3)
    Vc = V2.copy()
    moved = rng.random(len(V2)) < 0.05
    # a single component changed by 2 eta / dt (dirty) or 0.5 eta / dt (clean), inside the box either way
    Vc[moved, rng.integers(0, 3, moved.sum())] += np.where(rng.random(moved.sum()) < 0.5, 2.0, 0.5) * eta / dt
    # the bound itself is clean (dt |dV| > eta): a component whose change times dt rounds to eta exactly
    x = eta / dt
    while dt * x < eta:
        x = np.nextafter(x, np.inf)
    while dt * x > eta:
        x = np.nextafter(x, -np.inf)
    Vc[11] = V2[11]  # 11 is inside its box (V2[::7] only are scaled)
    Vc[11, 0] = x
    assert dt * abs(V2[11, 0] - Vc[11, 0]) == eta
    n = 3100  # the cloth vertices: a count over a prefix that ends inside a chunk
    Vc[n, 1] += 3.0 * eta / dt  # the first vertex after the prefix is dirty
    X1b = X0 + dt * V2
    box = ((np.minimum(X0, X1b) - grow < lo) | (np.maximum(X0, X1b) + grow > hi)).any(axis=1)
    vel = dt * np.abs(V2 - Vc).max(axis=1) > eta
    assert 0 < box.sum() < len(box) and 0 < (vel & ~box).sum() < moved.sum() and not (box | vel)[11] and vel[n]
    for vtol, want in ((eta, box | vel), (np.inf, box)):
        for t in THREADS:
            with thread_count(t):
                got_x1, got, head, total = _pair_kernels.outgrown(X0, V2, dt, grow, lo, hi, Vc, vtol, n)
            assert np.array_equal(got_x1, X1b) and np.array_equal(got, want)
            assert head == want[:n].sum() and total == want.sum()


def test_select_pairs_keeps_the_pairs_in_order_on_any_thread_count():
    rng = np.random.default_rng(5)
    N = 3000
    for k in (0, 5, 2047, 20000, 40000):  # serial below two chunks of SELECT_CHUNK, parallel at 40000
        q = np.stack([rng.choice(N, 4, replace=False) for _ in range(k)]).astype(np.int32) if k else \
            np.zeros((0, 4), dtype=np.int32)
        stamp = np.where(rng.random(N) < 0.05, 3, 0).astype(np.int64)
        only = rng.random(N) < 0.1
        for epoch, st, fl in ((1, stamp, only), (1, stamp, np.zeros(0, bool)), (3, stamp, only),
                              (0, np.zeros(0, np.int64), only)):
            alive = np.ones(k, bool) if len(st) == 0 else (st[q] <= epoch).all(axis=1)
            keep = alive & (fl[q].any(axis=1) if len(fl) else True)
            for t in THREADS:
                with thread_count(t):
                    got = _pair_kernels.select_pairs(q, st, epoch, fl)
                assert got.dtype == q.dtype
                assert np.array_equal(got, q[keep])


def test_flagged_triangles_and_nonzero_rows_match_numpy_on_any_thread_count():
    rng = np.random.default_rng(6)
    tris = rng.integers(0, 4000, size=(9000, 3))
    flags = rng.random(4000) < 0.02
    for k in (6000, _pair_kernels.ROWS_SERIAL + 5000):  # serial below ROWS_SERIAL, parallel chunks above
        dV = np.where(rng.random((k, 3)) < 0.1, rng.standard_normal((k, 3)), 0.0)
        dV[1, 2] = -0.0  # a negative zero is no change
        dV[2, 0] = np.nan
        dV[-3] = 0.0
        dV[-2, 2] = 1e-300
        dV[-1] = (0.0, 2.0, 0.0)  # the last row counts
        for t in THREADS:
            with thread_count(t):
                assert np.array_equal(_pair_kernels.flagged_triangles(flags, tris), flags[tris].any(axis=1))
                assert np.array_equal(_pair_kernels.rows_nonzero(dV), (dV != 0).any(axis=1))
                assert _pair_kernels.rows_nonzero(np.zeros((0, 3))).shape == (0,)
