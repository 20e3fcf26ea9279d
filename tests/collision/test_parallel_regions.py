"""Parallel regions the pipeline's per-call kernels start (issue 20): a region started after serial Python waits for
the pool's sleeping workers (~33 us on an idle 2-vCPU host), so passes too small to pay for it run serially and no
kernel starts hidden regions (numba makes each np.zeros or array expression of a parallel=True function a loop of its
own). Counted with ``modalfem.bench.threads_bench.count_launches`` in a fresh child, at the 64x64 pile's sizes."""

from __future__ import annotations

import subprocess
import sys

import pytest

from modalfem._threads import threading_layer

CHILD = """
import numpy as np
from modalfem.bench import threads_bench
count = threads_bench.count_launches()
from modalfem.collision import _ccd_kernels as ck, _distance_kernels as dk, _pair_kernels as pk
from modalfem.collision._stages import PIPELINE_DEPTH
from modalfem.collision.ccd import MAX_INTERVALS

rng = np.random.default_rng(0)
N = 4096 + 200  # the pile's cloth vertices and a few obstacle ones
X0 = rng.standard_normal((N, 3)); V = rng.standard_normal((N, 3)); X1 = X0 + 0.01 * V
lo, hi = np.minimum(X0, X1) - 1e-3, np.maximum(X0, X1) + 1e-3
q = rng.integers(0, N, (20000, 4)).astype(np.int32)
B = np.zeros(0, bool); I = np.zeros(0, np.int64); mov = np.ones(N, bool)
gone = rng.random(N) < 0.1
diag, gap = ck.diagonal_intervals(X0, X1), ck.diagonal_gap(X0, X1, 1e-4)
segs = [(True, q, gone, B), (True, q[:300].copy(), B, B), (False, q[5000:], B, mov)]
cases = [
    ("trajectory_diagonals", lambda: ck.trajectory_diagonals(X0, V, 0.01, 1e-4)),
    ("diagonal_gap", lambda: ck.diagonal_gap(X0, X1, 1e-4)),
    ("outgrown", lambda: pk.outgrown(X0, V, 0.01, 5e-5, lo, hi, V, np.inf, 4096)),
    ("rows_nonzero", lambda: pk.rows_nonzero(V)),
    ("obstacle_vertex_hits", lambda: dk.obstacle_vertex_hits(False, X0, V, 0.01, np.array([0, 0, 1.0]),
                                                             np.array([-5.0, -5.0]), 0.0, 1e-4)),
    ("ccd_block", lambda: ck.ccd_block(True, X0, X1, q, B, B, mov, I, 1e-4, PIPELINE_DEPTH, MAX_INTERVALS, diag,
                                       gap)),
    ("ccd_segments", lambda: ck.ccd_segments(segs, X0, X1, mov, I, 1e-4, PIPELINE_DEPTH, MAX_INTERVALS, diag, gap)),
]
for name, f in cases:
    f()
    c = count[0]
    f()
    print(name, count[0] - c)
"""


def test_the_pipeline_kernels_start_one_region_or_none():
    if threading_layer() != "tbb":
        pytest.skip("the counter wraps the TBB layer's launch")
    p = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=900, check=True)
    got = dict(line.split() for line in p.stdout.strip().splitlines())
    assert got == {"trajectory_diagonals": "0", "diagonal_gap": "0", "outgrown": "0", "rows_nonzero": "0",
                   "obstacle_vertex_hits": "0", "ccd_block": "1", "ccd_segments": "1"}
