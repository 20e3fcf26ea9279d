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
