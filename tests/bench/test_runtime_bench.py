"""Smoke test of ``modalfem bench runtime --quick``: runs, writes a well-formed section, keeps others.
Speed is not asserted (benchmarks are commands, not tests)."""

from __future__ import annotations

import re

import pytest

from modalfem.bench import runtime_bench as rb


def _rows(lines, header_start):
    i = next(i for i, ln in enumerate(lines) if ln.startswith(header_start))
    hdr = [c.strip() for c in lines[i].strip().strip("|").split("|")]
    rows = []
    for ln in lines[i + 2:]:
        if not ln.startswith("|"):
            break
        rows.append(dict(zip(hdr, (c.strip() for c in ln.strip().strip("|").split("|")))))
    return rows


@pytest.mark.slow  # ~15-30 s: 5 child processes on a shared machine
def test_bench_runtime_quick_writes_a_wellformed_section(tmp_path):
    out = tmp_path / "BENCHMARKS.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkeep me\n\n" + rb.SECTION + "\n\nstale\n")
    assert rb.command(["--quick", "--out", str(out)]) == 0
    text = out.read_text()
    assert "keep me" in text and "stale" not in text and text.count(rb.SECTION) == 1
    section = text[text.index(rb.SECTION):]
    for needle in ("Machine:", "Versions:", "Date:", "Command:", "python -m modalfem bench runtime --quick",
                   "OPENBLAS_NUM_THREADS=1", "Goals at"):
        assert needle in section, needle
    lines = section.splitlines()
    rows = _rows(lines, "| surface vertices")
    assert len(rows) == 4
    for row in rows:
        for col in ("step us", "positions ms", "step + positions ms", "steps/s", "copy of Phi ms",
                    "(step + positions) / copy", "step + body-frame positions ms", "steps/s, body frame"):
            assert float(row[col]) > 0, (col, row)
    fem = _rows(lines, "| cells")
    assert len(fem) == 1 and int(fem[0]["DOFs"]) > 0 and re.fullmatch(r"\d+x", fem[0]["FEM / modal"])
    assert "Layouts of the mode matrix" not in section  # only at the goal size


def test_render_states_both_verdicts_at_the_goal_size():
    """The world-frame and the body-frame verdicts are both printed, each from its own number."""
    goal = {"nv": rb.GOAL[0], "r": rb.GOAL[1], "phi_mb": 17.0, "dtype": "float32", "step": 2e-5, "recon": 1e-3,
            "both": 1.2e-3, "both_body": 0.9e-3, "copy": 1.4e-3, "gemv": 0.8e-3, "normals": 1e-2,
            "modal_normals": 1e-3}
    text = rb.render([goal], [], {}, command="c", date="d", machine="m")
    assert "- Steps/s: 833 -> **NOT met**" in text
    assert "body-frame reconstruction" in text and "1111 -> **met**" in text
    goal["both_body"] = 1.1e-3
    assert "909 -> **NOT met**" in rb.render([goal], [], {}, command="c", date="d", machine="m")


def test_render_contact_gives_each_verdict_from_its_own_number():
    """Steps/s, the ratio to the free step and the verdict of every contact case come from its own timings."""
    bar = {"nv": 1802, "r": 12, "contacts": 451, "free": 4e-5, "contact": 1e-4, "profile": [("solve (k.py)", 5e-5)]}
    tall = {"nv": 50402, "r": 30, "contacts": 3721, "free": 5e-5, "contact": 5e-3, "profile": []}
    pile = {"count": 20, "steps": 600, "step": 4e-3, "free": 1e-3, "contacts": 900, "pair_contacts": 300,
            "separated": 2, "vertices": 12944}
    text = rb.render_contact([("bar", bar), ("tall", tall)], pile, command="c", date="d", machine="m", load="1.0")
    assert text.startswith(rb.CONTACT_SECTION) and "load average when measured: 1.0" in text
    rows = _rows(text.splitlines(), "| case")
    assert [r["verdict"] for r in rows] == ["**met**", "**NOT met**", "**met**"]  # 10000 >= 5000, 200 < 300, 250
    assert [r["steps/s"] for r in rows] == ["10000", "200", "250"]
    assert [r["contact / free"] for r in rows] == ["2.5", "100.0", "4"]  # resting cases to 0.1 (1e-4 / 4e-5)
    assert "- bar: solve (k.py) 50 us" in text
    failed = rb.render_contact([("bar", {"error": "boom"})], {"error": "boom"}, command="c", date="d", machine="m",
                               load="1.0")
    assert failed.count("error: boom") == 2
