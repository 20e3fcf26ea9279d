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


@pytest.mark.parametrize("how", ["--data", "env", "empty folder"])
def test_missing_data_is_one_line_naming_the_dataset_the_path_and_the_source(tmp_path, capsys, monkeypatch, how):
    where = tmp_path / "nope"
    argv = ["--quick", "--out", str(tmp_path / "x.md")]
    if how == "--data":
        argv += ["--data", str(where)]
    else:
        if how == "empty folder":  # a folder without the <scene>/<kind>/*.csv layout
            (where / "scene" / "vertex-face").mkdir(parents=True)
        monkeypatch.setenv(ccd_bench.DATA_ENV, str(where))
        assert ccd_bench.default_data_dir() == where
    assert ccd_bench.command(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("modalfem: error:")
    for needle in ("CCD sample queries", "Wang et al. 2021", repr(str(where)), ccd_bench.DATA_SOURCE, "--data DIR",
                   ccd_bench.DATA_ENV):
        assert needle in err, (needle, err)
    assert not (tmp_path / "x.md").exists()


def test_default_data_dir_outside_a_checkout_is_relative_to_the_current_folder(tmp_path, monkeypatch):
    """An installed package (no pyproject.toml two levels up) looks beside the current folder, not
    beside site-packages or a temporary build folder."""
    import modalfem.bench.ccd_bench as mod

    monkeypatch.delenv(ccd_bench.DATA_ENV, raising=False)
    fake = tmp_path / "site-packages" / "modalfem" / "bench" / "ccd_bench.py"
    monkeypatch.setattr(mod, "__file__", str(fake))
    monkeypatch.chdir(tmp_path)
    assert ccd_bench.default_data_dir() == tmp_path.parent / "shared" / "data" / "ccd-sample-queries"
    (tmp_path / "site-packages" / "pyproject.toml").parent.mkdir(parents=True)
    (tmp_path / "site-packages" / "pyproject.toml").write_text("")
    assert ccd_bench.default_data_dir() == tmp_path / "shared" / "data" / "ccd-sample-queries"
