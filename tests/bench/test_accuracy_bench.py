"""``modalfem bench accuracy``: the Pareto helper, and a smoke run of ``--quick`` (slow: ~12 fresh
processes) that writes a well-formed section and a PNG. Speed is not asserted."""

from __future__ import annotations

import re

import numpy as np
import pytest

from modalfem.bench import accuracy_bench as ab
from modalfem.bench import cli as bench_cli


def test_pareto_front_keeps_exactly_the_non_dominated_points():
    t = np.array([1.0, 2.0, 3.0, 0.5, 2.5, 4.0])
    e = np.array([0.5, 0.1, 0.2, 0.9, 0.05, 0.05])
    front = ab.pareto_front(t, e)
    assert list(front) == [3, 0, 1, 4]
    for i in range(len(t)):  # every other point is dominated by a front point
        if i not in front:
            assert any(t[j] <= t[i] and e[j] <= e[i] for j in front)


def test_accuracy_is_a_discovered_benchmark():
    assert "accuracy" in bench_cli.available()


def test_every_method_family_is_listed():
    for body in ab.BODIES.values():
        fams = [m[0] for m in ab._methods(body)]
        assert fams.count("P1") >= 3 and fams.count("P2") >= 3 and fams.count("coarse->fine") == 2
        assert {"Ritz", "modes r"} <= set(fams)
        assert sorted(m[4] for m in ab._methods(body) if m[0] == "modes r") == list(ab.R_SWEEP)


@pytest.mark.slow
def test_quick_run_writes_a_section_and_a_plot(tmp_path):
    out, png = tmp_path / "B.md", tmp_path / "pareto.png"
    out.write_text("# Benchmarks\n\n## Other\n\nkeep me\n")
    assert ab.command(["--quick", "--out", str(out), "--plot", str(png)]) == 0
    text = out.read_text()
    assert "keep me" in text and text.count(ab.SECTION) == 1
    rows = [ln for ln in text.splitlines() if ln.startswith("| ") and not ln.startswith("| method")]
    labels = [r.split("|")[1].strip() for r in rows]
    for want in ("P1 10x1x1", "P2 5x1x1", "coarse P2 5x1x1 -> fine", "Ritz affine", "Ritz quadratic"):
        assert want in labels, labels
    for r in rows:
        cells = [c.strip() for c in r.strip().strip("|").split("|")]
        assert re.fullmatch(r"\d+(\.\d+)?", cells[3]), r  # a time in seconds, not an error
        assert 0.0 <= float(cells[6]) <= 1.0  # MAC
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
