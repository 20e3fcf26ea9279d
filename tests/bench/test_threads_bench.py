"""``modalfem bench threads``: Amdahl's serial fraction and the section's table and verdicts (synthetic
runs: the child processes are the cloth and tet benches' own, tested there)."""

from __future__ import annotations

import pytest

from modalfem.bench.threads_bench import SECTION, amdahl, render


@pytest.mark.parametrize("t1, t2, s, at16", [(100.0, 60.0, 0.2, 4.0), (100.0, 50.0, 0.0, 16.0),
                                              (100.0, 110.0, 1.0, 1.0), (80.0, 60.0, 0.5, 32 / 17)])
def test_amdahl_serial_fraction_and_16_core_speed_up(t1, t2, s, at16):
    got_s, got_16 = amdahl(t1, t2, 2)
    assert got_s == pytest.approx(s, abs=1e-12) and got_16 == pytest.approx(at16, rel=1e-12)


def _run(ms, **extra):
    return {"ms_per_step": ms, "cpu_ms_per_step": ms, "load": (0.5, 0.7), **extra}


def test_section_reports_both_counts_the_stages_and_the_goals():
    shares = {"implicit": 0.5, "broad_phase": 0.3}
    cloth = {1: [_run(120.0, shares=shares, intersections=0), _run(110.0, shares=shares, intersections=0)],
             2: [_run(70.0, shares={"implicit": 0.4, "broad_phase": 0.3}, intersections=0)]}
    tet = {1: [_run(60.0)], 2: [{"error": "timeout after 9 s", "load": (1, 1)}, _run(32.0)]}
    text = render(cloth, tet, 2, command="cmd", date="today", machine="CPU X", layer="tbb",
                  cloth_label="pile", tet_label="bar")
    assert text.startswith(SECTION) and "CPU X" in text and "`tbb`" in text
    assert "| pile | 1 | 110.0 | 9.09 |" in text  # the faster of the two 1-thread runs
    assert "| pile | 2 | 70.0 | 14.29 | 70.0 | 1.57x | 0.27 |" in text  # s = 2 * 70 / 110 - 1
    assert "| bar | 2 | 32.0 | 31.25 | 32.0 | 1.88x | 0.07 |" in text
    assert "| implicit | 55.0 | 28.0 | 1.96x |" in text
    assert "one thread): 9.09 steps/s, **not met**" in text
    assert "two threads): 1.57x, **not met**" in text
    assert "Tet goal (>= 30 steps/s on two threads): 31.2 steps/s, **met**" in text


def test_parallel_kernels_are_recognised_in_a_profile():
    from modalfem.bench.threads_bench import _is_parallel
    from modalfem.collision import _bvh_kernels
    from modalfem.tet import _kernels

    assert _is_parallel(_kernels.__file__, "hessians_upper") and _is_parallel(_bvh_kernels.__file__, "traverse")
    assert _is_parallel(_kernels.__file__.replace("tet", "cloth"), "pcg")  # calls the parallel CG passes
    from modalfem.cloth import _sgs_kernels

    assert _is_parallel(_sgs_kernels.__file__, "pcg_sgs_ordered")  # calls the parallel sweeps
    assert not _is_parallel(_sgs_kernels.__file__, "greedy_colours")  # compiled, serial
    assert not _is_parallel(_bvh_kernels.__file__, "refit_triangles")  # compiled, serial
    assert not _is_parallel(_kernels.__file__, "unsigned")  # plain Python
    assert not _is_parallel("/usr/lib/python3/dist-packages/numpy/core/numeric.py", "array_equal")


def test_profile_lines_give_the_amdahl_bounds_of_the_parallel_share():
    from modalfem.bench.threads_bench import profile_lines

    text = "\n".join(profile_lines({"pile": {"total_s": 10.0, "parallel_s": 6.0, "kernels": {"a.py:k": 6.0}},
                                    "bar": None}))
    # p = 0.6: 1 / (0.4 + 0.3) = 1.43 on 2 cores, 1 / (0.4 + 0.0375) = 2.29 on 16
    assert "| pile | 10.0 | 60 % | 1.43x | 2.29x | a.py:k 6.00 |" in text
    assert "| bar | failed |" in text


def test_replay_lines_use_the_fastest_replays():
    from modalfem.bench.threads_bench import replay_lines

    text = "\n".join(replay_lines({"pile": {"1": [130.0, 100.0, 120.0], "2": [70.0, 60.0, 90.0]}, "bar": None}, 2))
    # fastest 100 / 60: 1.67x, s = 2 * 0.6 - 1 = 0.2, 16 cores: 1 / (0.2 + 0.05) = 4x
    assert "| pile | 3 | 100.0 / 120.0 | 60.0 / 70.0 | 1.67x | 0.20 | 4.0x |" in text
    assert "| bar | failed |" in text


def test_replay_repeats_the_same_steps_on_both_counts():
    from modalfem.bench import threads_bench

    out = threads_bench.replay("tet", 2, 1, warm=1, window=1)
    assert len(out["1"]) == len(out["2"]) == 2 and min(out["1"] + out["2"]) > 0


def test_probe_counts_the_cores_a_parallel_loop_gets():
    import os

    from modalfem.bench.threads_bench import probe

    # CPU time over wall time of the process: a parallel loop gets at most the cores it may run on, and (even
    # on one thread) a threading layer's idle workers may spin for a while after a parallel region, so the
    # one-thread figure can exceed 1 (1.26 was seen in the pip-only venv): bounded by the cores, not by 1
    cores = len(os.sched_getaffinity(0))
    assert 0.2 < probe(1, seconds=0.3) <= 1.1 * cores
    assert 0.2 < probe(2, seconds=0.3) <= 1.1 * cores


def test_throughput_is_work_per_second_relative_to_one_thread():
    import os

    from modalfem.bench.threads_bench import throughput

    # n threads do at most n (and at least a fraction of one) times the work of one thread, and no more
    # than the cores the process may run on allow
    cores = len(os.sched_getaffinity(0))
    assert 0.2 < throughput(2, seconds=0.4) <= 1.15 * min(2, cores)


def test_cores_line_names_both_measures():
    from modalfem.bench.threads_bench import cores_line

    text = cores_line(2, [2.0, 1.98], [1.41, 1.95])
    assert "2.00 before the runs, 1.98 after" in text
    assert "1.41 before, 1.95 after" in text


def test_kernel_lines():
    from modalfem.bench.threads_bench import kernel_lines

    text = "\n".join(kernel_lines({"cloth: CG": {"1": 20.0, "2": 12.5}}, 2))
    assert "| cloth: CG | 20.00 | 12.50 | 1.60x |" in text
    assert kernel_lines(None, 2) == []


def test_wake_lines_price_the_wake_up_per_step():
    from modalfem.bench.threads_bench import wake_lines

    wake = {"work_us": 100.0, "gaps": {0.0: {"1": 100.0, "2": 55.0}, 2000.0: {"1": 104.0, "2": 79.0}}}
    text = "\n".join(wake_lines(wake, 2, 250.0))
    assert "| 0 | 100.0 | 55.0 | 1.82x |" in text and "| 2000 | 104.0 | 79.0 | 1.32x |" in text
    # (79 - 55) - (104 - 100) = 20 us more per region, 250 launches: 5.0 ms per step
    assert "at 20.0 us more per region" in text and "up to 5.0 ms per step on 2 threads" in text
    assert "launches at least 250 parallel kernels" in text
    assert "ms per step" not in "\n".join(wake_lines(wake, 2, None))
    assert wake_lines(None, 2) == []


def test_wake_probe_times_the_region_after_each_gap_on_both_counts():
    from modalfem.bench.threads_bench import wake_probe

    out = wake_probe(2, gaps_us=(0.0, 300.0), work_us=50.0, calls=5)
    assert out["work_us"] == 50.0 and sorted(out["gaps"]) == [0.0, 300.0]
    for r in out["gaps"].values():
        # the region's work was calibrated to 50 us on one thread (fastest of 5): its median cannot be much less
        # on one thread, nor much less than half of it on two
        assert set(r) == {"1", "2"} and r["1"] > 0.3 * 50.0 and r["2"] > 0.3 * 25.0


def test_profile_summary_counts_the_parallel_kernel_calls():
    import cProfile
    import pstats
    import time

    import numpy as np

    from modalfem.bench import threads_bench

    a = np.zeros(8)
    threads_bench._probe_kernel(a, 10)  # compiled outside the profile
    prof = cProfile.Profile(time.process_time)
    prof.enable()
    for _ in range(3):
        threads_bench._probe_kernel(a, 10)
    np.concatenate([a, a])  # not a parallel kernel
    prof.disable()
    pr = threads_bench._profile_summary(pstats.Stats(prof).stats, 3)
    assert pr["steps"] == 3 and pr["calls"] == {"threads_bench.py:_probe_kernel": 3}
    assert set(pr["kernels"]) == set(pr["calls"]) and 0 <= pr["parallel_s"] <= pr["total_s"]


def test_wake_command_prints_the_layer_and_the_table(capsys):
    from modalfem.bench.threads_bench import _main
    from modalfem._threads import threading_layer

    assert _main(["--wake", "--threads", "2"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"threading layer {threading_layer()};")
    assert "| 0 |" in out and "| 200 |" in out and "| 2000 |" in out


def test_wake_lines_price_the_counted_regions_when_given():
    from modalfem.bench.threads_bench import wake_lines

    wake = {"work_us": 100.0, "gaps": {0.0: {"1": 100.0, "2": 55.0}, 2000.0: {"1": 104.0, "2": 79.0}}}
    counted = {"per_step": 400.0, "after_python": 120.0, "by_kernel": {"_kernels.py:pcg": 300.0, "_x.py:k": 100.0},
               "calls": {"_kernels.py:pcg": 1.0, "_x.py:k": 50.0}}
    text = "\n".join(wake_lines(wake, 2, 250.0, counted))
    # 20 us more per region (as above) times the 400 counted regions, not the 250 profiled calls
    assert "starts 400 parallel regions per step" in text and "up to 8.0 ms per step on 2 threads" in text
    assert "_kernels.py:pcg 300.0 (1.0 calls)" in text and "_x.py:k 100.0 (50.0 calls)" in text
    assert "120 of them after serial Python" in text


def test_count_launches_counts_every_region_of_a_kernel():
    """In a fresh child (the counter must be in place before a kernel is linked): a prange loop is one region, a
    kernel whose np.zeros numba makes a loop of its own two, a serial njit function none."""
    import subprocess
    import sys

    import pytest

    from modalfem._threads import threading_layer

    if threading_layer() != "tbb":
        pytest.skip("the counter wraps the TBB layer's launch")
    code = """
import numba, numpy as np
from modalfem.bench import threads_bench
count = threads_bench.count_launches()

@numba.njit(parallel=True)
def two(n):
    a = np.zeros(2 * n)  # another size than the loop's (numba fuses a same-sized one into it)
    for i in numba.prange(n):
        a[i] += i
    return a

@numba.njit
def none(n):
    return np.zeros(n).sum()

a = np.zeros(64)
got = []
for f in (lambda: threads_bench._probe_kernel(a, 10), lambda: two(1000), lambda: none(1000)):
    f()
    c = count[0]
    f(); f(); f()
    got.append(count[0] - c)
print(got)
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    assert p.stdout.strip().splitlines()[-1] == "[3, 6, 0]"
