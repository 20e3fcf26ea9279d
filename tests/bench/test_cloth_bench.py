"""Smoke test of ``modalfem bench cloth --quick``: runs tiny cases and writes a well-formed section."""

from __future__ import annotations

from modalfem.bench import cloth_bench


def test_quick_bench_writes_its_section(tmp_path):
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkeep\n")
    assert cloth_bench.command(["--quick", "--out", str(out)]) == 0
    text = out.read_text()
    assert "keep" in text and text.count(cloth_bench.SECTION) == 1
    rows = [ln for ln in text.splitlines() if ln.startswith(("| drape", "| pile"))]
    assert len(rows) == 2
    header = next(ln for ln in text.splitlines() if ln.startswith("| scene |"))
    names = [c.strip() for c in header.strip("|").split("|")]
    for ln in rows:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        assert len(cells) == len(names)
        assert float(cells[3]) > 0  # ms/step
        assert cells[-1] == "0"  # intersections
        assert float(cells[names.index("smoothing CG its")]) >= 0
        assert float(cells[names.index("ms/step 2nd half")]) > 0
    assert "| vertices | CG (sgs-blocks) ms | CG its |" in text  # the solver table names the CG's preconditioner
    png = tmp_path / "bench" / "cloth_steps.png"  # the per-step picture, linked from the section
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and "](bench/cloth_steps.png)" in text
    assert not list((tmp_path / "bench").glob(".*tmp*"))  # written atomically


def test_render_marks_failed_cases():
    text = cloth_bench.render([{"case": "pile", "n": 64, "error": "boom"}], [], command="c", date="d", machine="m",
                              versions="v")
    assert "boom" in text and cloth_bench.SECTION in text
    lines = text.splitlines()
    head = next(ln for ln in lines if ln.startswith("| scene"))
    row = next(ln for ln in lines if ln.startswith("| pile"))
    assert row.count("|") == head.count("|")


def test_scene_selection_and_no_solver_table(tmp_path):
    out = tmp_path / "B.md"
    assert cloth_bench.command(["--quick", "--scenes", "pile", "--no-solvers", "--no-ablation", "--out", str(out)]) == 0
    text = out.read_text()
    lines = text.splitlines()
    assert not any(ln.startswith("| setting |") for ln in lines)  # --no-ablation: no ablation table
    head = next(ln for ln in lines if ln.startswith("| scene"))
    rows = [ln for ln in lines if ln.startswith(("| drape", "| pile"))]
    assert len(rows) == 1 and rows[0].startswith("| pile") and rows[0].count("|") == head.count("|")
    cells = dict(zip((c.strip() for c in head.strip("|").split("|")), (c.strip() for c in rows[0].strip("|").split("|"))))
    assert float(cells["CPU ms/step"]) > 0
    assert "Jacobi-CG" not in text


def test_a_case_runs_the_scenes_own_length_by_default():
    from modalfem.cloth import scenes

    r = cloth_bench.run_case("pile", 6, check_every=10)
    assert r["steps"] == scenes.pile(6).steps > 40  # the whole fall and settling, not a prefix
    assert r["late_ms_per_step"] > 0 and r["intersections"] == 0
    ms = r["step_ms"]  # every step's wall time, None on the probe steps (every 10th, not timed)
    assert len(ms) == r["steps"] and all((v is None) == ((k + 1) % 10 == 0) for k, v in enumerate(ms))
    timed = [v for v in ms if v is not None]
    assert abs(sum(timed) / len(timed) - r["ms_per_step"]) < 1e-9 * r["ms_per_step"]


def test_quick_bench_writes_the_stage_ablation(tmp_path):
    out = tmp_path / "B.md"
    assert cloth_bench.command(["--quick", "--scenes", "pile", "--no-solvers", "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    head = next(ln for ln in lines if ln.startswith("| setting |"))
    names = [c.strip() for c in head.strip("|").split("|")]
    start = lines.index(head) + 2
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines[start:start + len(cloth_bench.ABLATIONS)]]
    assert [r[0] for r in rows] == [label for label, _ in cloth_bench.ABLATIONS]
    cells = {r[0]: dict(zip(names, r)) for r in rows}
    base = cells[cloth_bench.ABLATIONS[0][0]]
    assert float(base["x time of all stages"]) == 1.0 and float(base["ms/step"]) > 0
    b = float(base["ms/step"])
    for r in cells.values():  # every setting ran and is compared with the first row's time (cells rounded)
        m = float(r["ms/step"])
        assert m > 0
        assert (m - 0.5) / (b + 0.5) - 0.005 <= float(r["x time of all stages"]) <= (m + 0.5) / (b - 0.5) + 0.005
    assert float(cells["stage (d) off: no smoothing, so no re-check"]["smoothing %"]) == 0


def test_scene_options_reach_the_scene():
    r = cloth_bench.run_case("pile", 6, 12, options={"smoothing": 0.0, "ccd_passes": 1})
    assert r["smooth_cg_iterations"] == 0 and r["shares"]["smoothing"] < 1e-3
    assert cloth_bench._options(["smoothing=0.5", "culling=false", "ccd_passes=2"]) == {
        "smoothing": 0.5, "culling": False, "ccd_passes": 2}
    import pytest

    for bad in ("smoothing", "=1", "culling=nope"):
        with pytest.raises(SystemExit):
            cloth_bench._options([bad])


def test_a_failed_ablation_run_is_shown_and_fails_the_bench(tmp_path, monkeypatch):
    real = cloth_bench._spawn

    def spawn(args, timeout):
        return {"error": "boom"} if "repulsion=false" in args else real(args, timeout)

    monkeypatch.setattr(cloth_bench, "_spawn", spawn)
    out = tmp_path / "B.md"
    assert cloth_bench.command(["--quick", "--scenes", "pile", "--no-solvers", "--out", str(out)]) == 1
    lines = out.read_text().splitlines()
    head = next(ln for ln in lines if ln.startswith("| setting |"))
    row = next(ln for ln in lines if ln.startswith("| stage (a) off"))
    assert "boom" in row and row.count("|") == head.count("|")
