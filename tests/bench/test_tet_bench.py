"""Smoke test of ``modalfem bench tet``: the quick ladder runs and writes a well-formed section into a
temporary file, keeping other sections. Speed is not asserted (benchmarks are commands, not tests)."""

from __future__ import annotations

import re

from modalfem.bench import tet_bench as tb


def test_run_case_here_measures_a_step():
    r = tb.run_case_here((2, 1, 1), "newton+cg", 2)
    assert r["tets"] == 12 and r["finite"]
    assert r["ms_per_step"] > 0 and 1 <= r["newton_per_step"] <= 8 and 0 <= r["solve_share"] <= 1
    assert r["openblas_core"] is None or r["openblas_core"] == tb.openblas_core()


def test_quick_bench_writes_its_section(tmp_path):
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkeep me\n")
    assert tb.command(["--quick", "--out", str(out)]) == 0
    text = out.read_text()
    assert "keep me" in text and text.count(tb.SECTION) == 1
    section = text[text.index(tb.SECTION):]
    assert "OpenBLAS core " in section  # the BLAS kernels in use are stated (or "unknown")
    rows = [line for line in section.splitlines() if re.match(r"\| \d+ \|", line)]
    assert [r.split("|")[3].strip() for r in rows] == list(tb.VARIANTS)
    for r in rows:
        cells = [c.strip() for c in r.strip("|").split("|")]
        assert float(cells[3]) > 0 and float(cells[4]) > 0  # ms/step, steps/s
        assert float(cells[4]) > 0 and cells[8].endswith("%")  # CPU ms/step, solve share


def test_goal_verdict_follows_the_10k_linearised_row():
    row = {"tets": 10080, "vertices": 2233, "ms_per_step": 28.9, "cpu_ms_per_step": 28.9, "newton_per_step": 1.0,
           "cg_per_step": 16, "solve_share": 0.3}
    fast = tb._section([((28, 10, 6), "linearised+cg", row, None)], "cmd", 1.0)
    slow = tb._section([((28, 10, 6), "linearised+cg", {**row, "ms_per_step": 40.0}, None)], "cmd", 1.0)
    assert "34.6 steps/s" in fast and "**met**" in fast
    assert "25.0 steps/s" in slow and "**NOT met**" in slow
