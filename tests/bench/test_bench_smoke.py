"""Smoke test of ``modalfem bench modes``: the command runs on a tiny ladder and writes a well-formed
section. Speed is not asserted (benchmarks are commands, not tests)."""

from __future__ import annotations

import importlib.util
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from modalfem.bench import cli as bench_cli
from modalfem.bench import modes_bench as mb

SECTION = "## Modes: cantilever ladder"
REPO = Path(__file__).resolve().parents[2]


def _num(cell: str) -> float:
    m = re.fullmatch(r"\s*([+-]?\d+(?:\.\d+)?(?:e[+-]?\d+)?)\s*(?:%|x)?\s*", cell)
    assert m, f"not a number: {cell!r}"
    return float(m.group(1))


def _tables(lines: list[str]) -> list[list[dict]]:
    """Markdown tables in ``lines`` as lists of {header: cell} rows."""
    tables, i = [], 0
    while i < len(lines):
        if lines[i].startswith("| ") and i + 1 < len(lines) and lines[i + 1].startswith("|---"):
            hdr = [c.strip() for c in lines[i].strip().strip("|").split("|")]
            rows, j = [], i + 2
            while j < len(lines) and lines[j].startswith("|"):
                cells = [c.strip() for c in lines[j].strip().strip("|").split("|")]
                assert len(cells) == len(hdr), f"row has {len(cells)} cells, header {len(hdr)}: {lines[j]}"
                rows.append(dict(zip(hdr, cells)))
                j += 1
            tables.append(rows)
            i = j
        else:
            i += 1
    return tables


# ------------------------------------------------------------------------------- pure helpers
def test_replace_section_keeps_other_sections():
    old = "# Benchmarks\n\n## Other\n\nkeep me\n\n" + SECTION + "\n\nstale\n\n## Later\n\nalso keep\n"
    new = bench_cli.replace_section(old, SECTION + "\n\nfresh\n")
    assert "stale" not in new and "fresh" in new
    assert "keep me" in new and "also keep" in new
    assert new.count(SECTION) == 1
    assert new.index("## Other") < new.index(SECTION) < new.index("## Later")
    appended = bench_cli.replace_section("# Benchmarks\n\n## Other\n\nx\n", SECTION + "\n\nfresh\n")
    assert appended.endswith(SECTION + "\n\nfresh\n") and "## Other" in appended


def test_refine_reference_recovers_a_known_limit():
    f = lambda h: 80.0 * (1 + 0.3 * h**1.6)
    ref, note = bench_cli.refine_reference([(1 / n, f(1 / n)) for n in (20, 40, 60, 80)])
    assert abs(ref - 80.0) < 1e-9 and "p = 1.60" in note


def test_beam_theory_of_the_thick_cantilever():
    eb, timo = mb.euler_bernoulli_cantilever_hz(), mb.timoshenko_cantilever_hz()
    assert 81.5 < eb < 81.6  # (1.875104^2 / 2 pi) sqrt(EI / rho A) / L^2
    assert 0.99 * eb < timo < eb  # shear and rotary inertia lower it by under 1 % (L/h = 10)
    # two independent Timoshenko solutions: transfer matrix (modalfem.theory) and 1D FE
    assert abs(mb.timoshenko_cantilever_fe_hz() / timo - 1) < 1e-6
    slender = mb.timoshenko_cantilever_fe_hz(h=0.01, b=0.01)
    assert abs(slender / mb.euler_bernoulli_cantilever_hz(h=0.01, b=0.01) - 1) < 1e-4


def test_ladder_sizes():
    full = mb.ladder()
    assert max(r.dofs for r in full if r.degree == 2) == 139_587  # P2 80x8x8
    assert all(r.dofs <= 20_000 for r in mb.ladder(max_dofs=20_000))
    assert len(mb.ladder(quick=True)) <= 2


# ------------------------------------------------------------------------------- the command
@pytest.mark.skipif(importlib.util.find_spec("modalfem.modes") is None, reason="modalfem.modes not written yet")
def test_bench_modes_quick_writes_a_wellformed_section(tmp_path):
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other benchmark\n\nkeep me\n\n" + SECTION + "\n\nstale table\n")
    main = "modalfem" if importlib.util.find_spec("modalfem.__main__") else "modalfem.bench.cli"
    args = ([] if main == "modalfem.bench.cli" else ["bench"]) + [
        "modes", "--quick", "--out", str(out), "--peer-timeout", "240"]
    proc = subprocess.run([sys.executable, "-m", main, *args], capture_output=True, text=True, timeout=900, check=False,
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "[bench modes]" in proc.stderr  # progress on stderr

    text = out.read_text()
    assert "keep me" in text and "stale table" not in text and text.count(SECTION) == 1
    section = text[text.index(SECTION):]
    for needle in ("Machine:", "Versions:", "numpy", "scipy", "BLAS", "Date:", "Command:", "Goals:",
                   "python -m modalfem bench modes --quick"):
        assert needle in section, needle

    from modalfem.backends import have_fenicsx

    cases = {"ours-skfem", "peer-B"} | ({"ours-fenicsx", "ours-slepc", "peer-A"} if have_fenicsx() else set())
    main_table, ratio_table = _tables(section.splitlines())[:2]
    seen = set()
    for row in main_table:
        case = row["case"].strip("`")
        rung = (row["P"], row["cells"])
        assert row["P"] in ("P1", "P2") and re.fullmatch(r"\d+x\d+x\d+", row["cells"])
        if case not in cases:
            assert row["total s"].startswith("skipped"), row
            continue
        seen.add((case, rung))
        assert int(row["DOFs"]) > 0
        for col in ("setup s", "eigen s", "total s", "CPU s", "process s", "peak RSS MB", "f1 Hz"):
            assert _num(row[col]) > 0, (case, col, row[col])
        err_t = _num(row["err vs Timoshenko"])
        assert math.isfinite(err_t) and math.isfinite(_num(row["err vs 3D ref"]))
        if row["P"] == "P2":
            # P2 on 20x2x2 is within ~0.3 % of 3D; Timoshenko differs from 3D by ~0.4 %
            assert abs(err_t) < 2.0, row
        if case.startswith("ours"):
            assert _num(row["cert s"]) >= 0 and row["certified"] == "yes", row
        lo, hi = (_num(x) for x in row["total range s"].split("-"))  # the quick rungs run 3 times
        assert lo <= _num(row["total s"]) <= hi, row
    assert {c for c, _ in seen} == cases
    assert len({r for _, r in seen}) == len(mb.ladder(quick=True))

    assert ratio_table and all(int(r["DOFs"]) > 0 for r in ratio_table)
    for r in ratio_table:
        if have_fenicsx():
            assert _num(r["peer-A / ours-fenicsx"]) > 0
        assert _num(r["peer-B / ours-skfem"]) > 0


def test_bench_discovers_benchmark_modules_and_rejects_unknown(capsys):
    names = bench_cli.available()
    assert "modes" in names and "modes_bench" not in names
    assert bench_cli.main(["no-such-benchmark"]) == 2
    assert "available: " in capsys.readouterr().err


def test_replace_section_requires_a_heading():
    import pytest

    with pytest.raises(ValueError, match="## "):
        bench_cli.replace_section("# Benchmarks\n", "no heading here\n")
