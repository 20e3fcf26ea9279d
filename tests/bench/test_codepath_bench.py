"""``modalfem bench codepath``: the section it renders, its bad input, and one real run (FEniCSx, slow)."""

from __future__ import annotations

import pytest

from modalfem.bench import codepath_bench as cb
from modalfem.bench import modes_bench as mb


def _run(total, *, mkl="AVX-512 E1", certified=True, f1=81.48, setup=0.1):
    tm = {"constraints": 0.01, "shift": 0.02, "eigen.factor": 0.3, "eigen.solve": 0.2, "eigen.certificate": 0.1,
          "certificate": 0.001, "labels": 0.03}
    return {"total": total, "cpu": 1.5 * total, "setup": setup, "eigen": total - setup, "timings": tm,
            "certified": certified,
            "frequencies_hz": [f1], "code_path": {"mkl": mkl, "openblas": "SkylakeX"}}


def test_render_gives_medians_ratios_and_the_path_each_child_reported():
    r = cb.RUNGS[0]
    runs = {
        ("default", "ours-fenicsx", r): [_run(1.0), _run(3.0), _run(2.0)],
        ("default", "peer-A", r): [_run(4.0), _run(5.0), _run(6.0)],
        ("avx2", "ours-fenicsx", r): [_run(2.5, mkl="AVX2"), _run(2.5, mkl="AVX2"), _run(2.5, mkl="AVX2")],
        ("avx2", "peer-A", r): [_run(5.0), _run(5.0), {"error": "child exited 1: boom"}],
    }
    text = cb.render(runs, [r], ["default", "avx2"], command="c", date="d", machine="m",
                     versions={"default": {"numpy": "1.24", "process": 1.0}})
    assert text.startswith(cb.SECTION) and "PROXY" in text and "NOT on an AMD" in text
    rows = [ln for ln in text.splitlines() if ln.startswith("| P2")]
    # default: ours median 2.0 (1.0-3.0), peer 5.0 -> 2.50x; avx2: 2.5 vs 5.0 (the error run left out) -> 2.00x,
    # 0.80 of the default path's ratio
    assert "2.00 (1.00-3.00)" in rows[0] and "5.00 (4.00-6.00)" in rows[0] and rows[0].count("2.50x") == 2  # wall, CPU
    assert "| 3.00 | 7.50 |" in rows[0]  # CPU medians
    assert "2.50 (2.50-2.50)" in rows[1] and "2.00x" in rows[1] and "| 0.80 |" in rows[1]
    assert "`avx2`: MKL_ENABLE_INSTRUCTIONS=AVX2 OPENBLAS_CORETYPE=Zen -> MKL AVX2, OpenBLAS SkylakeX" in text
    assert "process" not in text.split("- Versions:")[1].splitlines()[0]


def test_render_says_when_a_certificate_failed_or_a_case_did_not_run():
    r = cb.RUNGS[0]
    runs = {("default", "ours-fenicsx", r): [_run(1.0, certified=False)],
            ("default", "peer-A", r): [{"timeout": 300.0}]}
    text = cb.render(runs, [r], ["default"], command="c", date="d", machine="m", versions={})
    row = next(ln for ln in text.splitlines() if ln.startswith("| P2"))
    assert "| NO |" in row and "error: timeout 300.0" in row and "n/a" in row


def test_bad_input_is_one_line(capsys):
    assert cb.command(["--max-dofs", "10"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("modalfem: error: no rung has <= 10 DOFs") and err.count("\n") == 1
    assert cb.command(["--repeat", "0"]) == 2
    assert "--repeat and --repeat-small must be at least 1" in capsys.readouterr().err


def test_rungs_are_the_issue_sizes():
    assert [r.dofs for r in cb.RUNGS] == [3075, 19683, 61347, 139587]
    assert set(mb.CODE_PATHS) >= {"default", "avx2", "sse4_2"}


@pytest.mark.fenicsx
@pytest.mark.slow
def test_one_rung_on_two_paths_writes_the_section(tmp_path):
    pytest.importorskip("dolfinx")
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    assert cb.command(["--max-dofs", "4000", "--repeat-small", "1", "--out", str(out)]) == 0
    text = out.read_text()
    assert "## Other\n\nkept" in text and cb.SECTION in text
    rows = [ln for ln in text.splitlines() if ln.startswith("| P2 | 20x2x2")]
    assert len(rows) == 2 and all("| yes |" in ln for ln in rows)
    assert "-> MKL AVX2, OpenBLAS Zen" in text  # the forced path took effect in the children
