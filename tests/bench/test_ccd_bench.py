"""Smoke test of ``modalfem bench ccd --quick``: it runs and writes a well-formed section."""

from __future__ import annotations

import pytest

from modalfem.bench import ccd_bench

DATA = ccd_bench.default_data_dir()


@pytest.mark.skipif(not DATA.is_dir(), reason=f"CCD sample queries not found at {DATA}")
def test_quick_bench_writes_section(tmp_path):
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    assert ccd_bench.command(["--quick", "--out", str(out)]) == 0
    text = out.read_text()
    assert "## Other\n\nkept" in text
    sec = text[text.index(ccd_bench.SECTION):]
    rows = [ln.split("|") for ln in sec.splitlines() if ln.startswith("| ") and not ln.startswith("| scene")]
    total = [r for r in rows if r[1].strip() == "**all**"]
    assert len(total) == 1 and int(total[0][5]) == 0  # zero false negatives
    pipeline = [r for r in rows if r[1].strip().startswith(("accordion", "same"))]
    assert len(pipeline) == 2 and all(int(r[-2]) == 0 for r in pipeline)  # nothing left unresolved
    assert all(int(r[5]) <= int(r[4]) for r in pipeline)  # culling never adds tests
    assert "Machine:" in sec and "Command:" in sec


def test_missing_data_dir_is_a_clear_error(tmp_path, capsys):
    assert ccd_bench.command(["--quick", "--out", str(tmp_path / "x.md"), "--data", str(tmp_path / "nope")]) == 2
    assert "not found" in capsys.readouterr().out
