"""The ``modalfem`` command line: outputs, one-line errors with exit code 2, no partial files."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from modalfem.cli import main

PIP_PATH = ["--backend", "skfem", "--solver", "scipy"]  # runs without FEniCSx


def _run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_clamped_box_writes_summary_paraview_and_sheet(tmp_path, capsys):
    out = tmp_path / "run"
    code, stdout, _ = _run(
        ["modes", "box", "--size", "1", "0.1", "0.1", "--cells", "10", "2", "2", "--fixed", "x0", "-k", "5",
         "--out", str(out), "--json", str(tmp_path / "s.json"), "--quiet", *PIP_PATH],
        capsys,
    )
    assert code == 0
    assert "certificate passed" in stdout
    data = json.loads((tmp_path / "s.json").read_text())
    assert data == json.loads((out / "modes.json").read_text()) | {"timings": data["timings"]}
    f = np.array(data["frequencies_hz"])
    assert len(f) == 5 and np.all(np.diff(f) >= 0) and f[0] > 0
    assert data["rigid_mode_count"] == 0 and data["certificate"]["passed"]
    assert data["mesh"]["dofs"] == 3 * data["mesh"]["nodes"] and data["mesh"]["free_dofs"] < data["mesh"]["dofs"]
    assert data["material"]["E"] == 200e9 and data["constraints"]["fixed"] == ["x0"]
    assert {"numpy", "scipy", "modalfem"} <= set(data["versions"])
    import meshio

    m = meshio.read(out / "modes.vtu")
    assert {"mode_01", "mode_05"} <= set(m.point_data)
    assert m.point_data["mode_01"].shape[1] == 3
    png = (out / "modes.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert (out / "modes.xdmf").stat().st_size > 1000


def test_free_body_reports_six_rigid_modes(tmp_path, capsys):
    code, _, _ = _run(["modes", "box", "--size", "0.1", "0.1", "0.1", "--cells", "2", "2", "2", "-k", "3",
                       "--json", str(tmp_path / "s.json"), "--quiet", *PIP_PATH], capsys)
    assert code == 0
    data = json.loads((tmp_path / "s.json").read_text())
    assert data["rigid_mode_count"] == 6 and data["certificate"]["inertia_count"] >= 9


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["box", "--E", "-1", "--nu", "0.3", "--rho", "7800"], "Young's modulus"),
        (["box", "--E", "1e9", "--nu", "0.5", "--rho", "7800"], "Poisson"),
        (["box", "--E", "1e9", "--nu", "0.3", "--rho", "0"], "density"),
        (["box", "--fixed", "nope"], "unknown tag 'nope'"),
        (["box", "--cells", "2", "1", "1", "-k", "100000"], "exceeds"),
        (["box", "--material", "unobtainium"], "unknown material"),
        (["rod", "--size", "1", "1", "1"], "--size does not apply"),
        (["nosuchgenerator"], "mesh file not found"),
        (["box", "--roller", "z0"], "TAG:COMPONENTS"),
        (["box", "-k", "0"], "-k must be"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_no_outputs(argv, needle, tmp_path, capsys):
    out, js = tmp_path / "out", tmp_path / "s.json"
    code, _, err = _run(["modes", *argv, "--out", str(out), "--json", str(js), "--quiet", *PIP_PATH], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("modalfem: error:") and needle in lines[0], err
    assert not out.exists() and not js.exists()
    assert list(tmp_path.iterdir()) == []  # no staging leftovers either


def test_malformed_mesh_file(tmp_path, capsys):
    bad = tmp_path / "bad.msh"
    bad.write_bytes(b"$MeshFormat\ngarbage\n\x00\x01")
    code, _, err = _run(["modes", str(bad), "--out", str(tmp_path / "o"), "--quiet", *PIP_PATH], capsys)
    assert code == 2 and err.count("\n") == 1 and "bad.msh" in err
    assert not (tmp_path / "o").exists()


def test_failure_after_the_solve_leaves_no_partial_directory(tmp_path, capsys, monkeypatch):
    from modalfem.output import sheet

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("modalfem.output.plot_mode_sheet", boom)
    monkeypatch.setattr(sheet, "plot_mode_sheet", boom)
    out = tmp_path / "o"
    code, _, err = _run(["modes", "box", "--cells", "4", "1", "1", "-k", "2", "--fixed", "x0", "--out", str(out),
                         "--quiet", *PIP_PATH], capsys)
    assert code == 2 and err.startswith("modalfem: error:")
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_python_dash_m_and_progress(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "modalfem", "modes", "box", "--cells", "6", "1", "1", "-k", "2", "--fixed", "x0",
         "--json", str(tmp_path / "s.json"), *PIP_PATH],
        capture_output=True, text=True, timeout=300, check=False,
    )
    assert r.returncode == 0, r.stderr
    assert "assembly" in r.stderr and "eigen" in r.stderr  # progress lines with elapsed seconds
    assert json.loads((tmp_path / "s.json").read_text())["certificate"]["passed"]
    r = subprocess.run([sys.executable, "-m", "modalfem", "modes"], capture_output=True, text=True, timeout=120,
                       check=False)
    assert r.returncode == 2 and r.stderr.startswith("modalfem: error:")


# ---------------------------------------------------------------- --save MODEL (ModalModel file)


def test_save_writes_a_loadable_model(tmp_path, capsys):
    from modalfem.model import ModalModel

    path = tmp_path / "models" / "box.npz"  # missing parent directories are created
    code, stdout, _ = _run(["modes", "box", "--size", "0.2", "0.05", "0.05", "--cells", "4", "1", "1", "-k", "3",
                            "--save", str(path), "--json", str(tmp_path / "s.json"), "--quiet", *PIP_PATH], capsys)
    assert code == 0 and f"model: {path}" in stdout
    m = ModalModel.load(path)
    data = json.loads((tmp_path / "s.json").read_text())
    assert np.allclose(m.frequencies_hz, data["frequencies_hz"], rtol=1e-12)
    assert m.mode_count == 3 and m.provenance["fixed"] is None and m.provenance["rigid_mode_count"] == 6
    assert m.provenance["source"]["generator"] == "box" and m.material["name"] == "steel"
    assert data["outputs"]["model"] == str(path)
    assert sorted(p.name for p in path.parent.iterdir()) == ["box.npz"]  # no temporary files left
    code, _, _ = _run(["modes", "box", "--cells", "4", "1", "1", "-k", "2", "--fixed", "x0", "--save", str(path),
                       "--quiet", *PIP_PATH], capsys)
    assert code == 0 and ModalModel.load(path).provenance["fixed"] == "fixed x0"  # replaced in place


@pytest.mark.parametrize("argv, needle", [
    (["box", "-k", "0"], "-k must be"),
    (["box", "--material", "unobtainium"], "unknown material"),
])
def test_save_with_bad_input_writes_nothing(argv, needle, tmp_path, capsys):
    code, _, err = _run(["modes", *argv, "--save", str(tmp_path / "m.npz"), "--quiet", *PIP_PATH], capsys)
    assert code == 2 and err.count("\n") == 1 and needle in err
    assert list(tmp_path.iterdir()) == []


def test_save_onto_a_directory_is_bad_input(tmp_path, capsys):
    code, _, err = _run(["modes", "box", "--cells", "2", "1", "1", "-k", "1", "--save", str(tmp_path), "--quiet",
                         *PIP_PATH], capsys)
    assert code == 2 and err.count("\n") == 1 and "existing directory" in err
    assert list(tmp_path.iterdir()) == []


def test_failure_after_the_solve_leaves_an_existing_model_unchanged(tmp_path, capsys, monkeypatch):
    from modalfem.output import sheet

    model = tmp_path / "m.npz"
    model.write_bytes(b"old model")

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("modalfem.output.plot_mode_sheet", boom)
    monkeypatch.setattr(sheet, "plot_mode_sheet", boom)
    code, _, err = _run(["modes", "box", "--cells", "4", "1", "1", "-k", "2", "--fixed", "x0", "--out",
                         str(tmp_path / "o"), "--save", str(model), "--quiet", *PIP_PATH], capsys)
    assert code == 2 and err.count("\n") == 1
    assert model.read_bytes() == b"old model" and [p.name for p in tmp_path.iterdir()] == ["m.npz"]


def test_failure_while_saving_the_model_writes_nothing(tmp_path, capsys, monkeypatch):
    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", boom)
    code, _, err = _run(["modes", "box", "--cells", "4", "1", "1", "-k", "2", "--fixed", "x0", "--out",
                         str(tmp_path / "o"), "--json", str(tmp_path / "s.json"), "--save", str(tmp_path / "m.npz"),
                         "--quiet", *PIP_PATH], capsys)
    assert code == 2 and err.count("\n") == 1 and "No space left" in err
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- outputs of one run are one set

SMALL = ["modes", "box", "--size", "0.4", "0.05", "0.05", "--cells", "4", "1", "1", "-k", "2", "--fixed", "x0",
         "--quiet", *PIP_PATH]


def _tree(path):
    """Every entry under ``path`` (hidden ones too) with its bytes: equal trees mean nothing changed."""
    return {str(p.relative_to(path)): (p.read_bytes() if p.is_file() else None) for p in sorted(path.rglob("*"))}


def _old_outputs(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    for name in ("modes.json", "modes.png", "modes.vtu", "modes.xdmf"):
        (out / name).write_text(f"old {name}")
    (tmp_path / "s.json").write_text("old summary")
    (tmp_path / "m.npz").write_bytes(b"old model")
    return out


def _json_targets(tmp_path):
    (tmp_path / "afile").write_text("a file, not a folder")
    (tmp_path / "adir").mkdir()
    yield "parent is a file", tmp_path / "afile" / "s.json", "not a directory"
    yield "is a directory", tmp_path / "adir", "existing directory"
    if os.path.isdir("/proc/self"):  # unwritable even for root: fails only when the JSON is written
        yield "unwritable folder", Path(f"/proc/modalfem-test-{os.getpid()}.json"), "cannot write"


@pytest.mark.parametrize("old", [False, True], ids=["no previous out", "previous out"])
def test_failing_json_target_writes_nothing_and_keeps_the_old_out(tmp_path, capsys, old):
    for what, js, needle in list(_json_targets(tmp_path)):
        out = _old_outputs(tmp_path) if old and not (tmp_path / "out").exists() else tmp_path / "out"
        before = _tree(tmp_path)
        code, _, err = _run([*SMALL, "--out", str(out), "--json", str(js)], capsys)
        assert code == 2, what
        assert err.count("\n") == 1 and err.startswith("modalfem: error:") and needle in err, (what, err)
        assert _tree(tmp_path) == before, what  # no --out created, old one unchanged, no temporaries
        assert out.exists() == old


@pytest.mark.parametrize("signal_", [KeyboardInterrupt, SystemExit, "SIGTERM"])
@pytest.mark.parametrize("victim", ["modes.xdmf", "modes.png", "model"])
def test_kill_between_files_leaves_the_old_outputs_and_no_temporaries(tmp_path, capsys, monkeypatch, signal_,
                                                                       victim):
    import signal

    import modalfem.output
    from modalfem.model import ModalModel

    out = _old_outputs(tmp_path)
    before = _tree(tmp_path)

    def kill(*a, **k):
        if signal_ == "SIGTERM":
            os.kill(os.getpid(), signal.SIGTERM)  # the CLI turns it into SystemExit(143)
            time.sleep(5)
        raise signal_()

    real_write_modes = modalfem.output.write_modes
    if victim == "modes.xdmf":  # the .vtu is written, the .xdmf is not
        monkeypatch.setattr(modalfem.output, "write_modes",
                            lambda p, *a, **k: kill() if str(p).endswith(".xdmf") else real_write_modes(p, *a, **k))
    elif victim == "modes.png":
        monkeypatch.setattr(modalfem.output, "plot_mode_sheet", kill)
    else:  # the --out folder is complete, the model is not
        monkeypatch.setattr(ModalModel, "save", kill)
    argv = [*SMALL, "--out", str(out), "--json", str(tmp_path / "s.json"), "--save", str(tmp_path / "m.npz")]
    if signal_ is KeyboardInterrupt:
        assert _run(argv, capsys)[0] == 130
    else:
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code in (None, 143)
    assert _tree(tmp_path) == before


def test_existing_out_is_replaced_as_a_whole(tmp_path, capsys):
    out = _old_outputs(tmp_path)
    (out / "modes.h5").write_text("old heavy data")
    code, _, _ = _run([*SMALL, "--out", str(out)], capsys)
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == ["modes.h5", "modes.json", "modes.png", "modes.vtu", "modes.xdmf"]
    assert all(not (out / n).read_bytes().startswith(b"old") for n in os.listdir(out))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz", "out", "s.json"]


def test_json_and_model_inside_out_move_in_with_the_folder(tmp_path, capsys, monkeypatch):
    """The README's `--json out/modes.json --out out/`, with the model in the folder too."""
    import modalfem.output

    out = tmp_path / "out"
    argv = [*SMALL, "--out", str(out), "--json", str(out / "modes.json"), "--save", str(out / "models" / "m.npz")]
    for _ in range(2):  # the second run replaces the first run's folder, model included
        code, _, _ = _run(argv, capsys)
        assert code == 0
        assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
            "models", "models/m.npz", "modes.h5", "modes.json", "modes.png", "modes.vtu", "modes.xdmf"]
        assert [p.name for p in tmp_path.iterdir()] == ["out"]
    before = _tree(tmp_path)
    monkeypatch.setattr(modalfem.output, "plot_mode_sheet", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    assert _run(argv, capsys)[0] == 130
    assert _tree(tmp_path) == before


def test_out_holding_other_files_is_refused_before_solving(tmp_path, capsys):
    out = _old_outputs(tmp_path)
    (out / "notes.txt").write_text("mine")
    before = _tree(tmp_path)
    code, _, err = _run([*SMALL, "--out", str(out)], capsys)
    assert code == 2 and err.count("\n") == 1 and "notes.txt" in err
    assert _tree(tmp_path) == before


def test_stale_temporaries_of_a_killed_run_are_removed_by_the_next_run(tmp_path, capsys):
    from modalfem.atomic import _host

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # a PID that no longer runs: the "killed" run
    tag = f"modalfem-tmp-{_host()}-{p.pid}-x1y2z3"
    (tmp_path / f".out.{tag}").mkdir()
    (tmp_path / f".out.{tag}" / "modes.vtu").write_text("half written")
    (tmp_path / f".s.json.{tag}").write_text("{")
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / f".m.npz.{tag}").write_bytes(b"half a model")
    live = tmp_path / f".s.json.modalfem-tmp-{_host()}-{os.getpid()}-running"  # a run still going: kept
    live.write_text("{")
    code, _, _ = _run([*SMALL, "--out", str(tmp_path / "out"), "--json", str(tmp_path / "s.json"),
                       "--save", str(tmp_path / "models" / "m.npz")], capsys)
    assert code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["models", "out", "s.json", live.name])
    assert [p.name for p in (tmp_path / "models").iterdir()] == ["m.npz"]


# ---------------------------------------------------------------- ParaView files read back


def test_xdmf_from_out_reads_back_with_meshio(tmp_path, capsys, monkeypatch):
    pytest.importorskip("h5py", reason="meshio's XDMF reader needs h5py (a modalfem dependency)")
    import meshio

    import modalfem

    results = []
    real = modalfem.modes
    monkeypatch.setattr(modalfem, "modes", lambda *a, **k: results.append(real(*a, **k)) or results[-1])
    out = tmp_path / "o"
    code, _, _ = _run([*SMALL, "--degree", "2", "--out", str(out)], capsys)
    assert code == 0
    res, = results
    m = meshio.read(out / "modes.xdmf")
    np.testing.assert_array_equal(m.points, res.dof_points)
    assert m.cells[0].type == "tetra10"
    for i in range(2):
        np.testing.assert_array_equal(m.point_data[f"mode_{i + 1:02d}"], res.shape(i))
    v = meshio.read(out / "modes.vtu")
    np.testing.assert_array_equal(v.point_data["mode_02"], res.shape(1))


# ---------------------------------------------------------------- progress and the cost of writing


STAGES = ("mesh:", "constraints", "assembly", "shift", "eigen", "certificate", "labels", "writing", "wrote")


def test_progress_line_for_every_stage_and_silence_with_quiet(tmp_path):
    argv = [sys.executable, "-m", "modalfem", "modes", "box", "--cells", "6", "1", "1", "-k", "2", "--fixed", "x0",
            "--out", str(tmp_path / "o"), *PIP_PATH]
    r = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    for stage in STAGES:
        assert any(stage in ln and ln.startswith("[") and " s] " in ln for ln in lines), (stage, r.stderr)
    wrote, = [ln for ln in lines if "] wrote" in ln]
    assert "modes.png" in wrote and "the solve took" in wrote
    assert "\r" not in r.stderr  # not a terminal: plain lines
    r = subprocess.run([*argv, "--quiet"], capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0 and r.stderr == ""


class _FakeTerminal:
    def __init__(self):
        self.text = ""

    def isatty(self):
        return True

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_live_progress_line_on_a_terminal(monkeypatch):
    from modalfem.cli import _Progress

    monkeypatch.setenv("COLUMNS", "60")
    term = _FakeTerminal()
    p = _Progress(stream=term)
    p.interval = 0.05
    p("eigen (block)")
    time.sleep(1.3)  # the background thread redraws the line with the running seconds
    p("writing")
    p.bar(1, 4, "modes.xdmf")
    p.done("wrote")
    p.close()
    first = term.text.split("\n")[0]
    assert first.count("\r") >= 5 and "eigen (block)  1 s" in first and first.endswith(" s\x1b[K")
    assert "[#####...............] 1/4 modes.xdmf" in term.text
    assert term.text.endswith("] wrote\n")
    long = _FakeTerminal()
    p = _Progress(stream=long)
    p("mesh: " + "x" * 200)  # wider than the terminal: cut, or \r could not redraw a wrapped line
    p.close()
    assert all(len(seg.replace("\x1b[K", "").rstrip("\n")) <= 59 for seg in long.text.split("\r")), long.text
    assert "..." in long.text
    quiet = _FakeTerminal()
    q = _Progress(stream=quiet, quiet=True)
    q("eigen")
    q.bar(1, 2)
    q.done("wrote")
    q.close()
    assert quiet.text == ""


def test_plain_progress_repeats_a_long_stage():
    from modalfem.cli import _Progress

    log = _FakeTerminal()
    log.isatty = lambda: False
    p = _Progress(stream=log)
    p.heartbeat = 0.5
    p("eigen (block)")
    time.sleep(2.3)
    p.close()
    assert "\r" not in log.text and "eigen (block) (still running, " in log.text


def test_writing_the_outputs_costs_less_than_the_solve(tmp_path, capsys):
    """A 17.7k-DOF P2 result: the JSON records the output stage, and it is cheaper than the solve."""
    js = tmp_path / "s.json"
    code, _, _ = _run(["modes", "box", "--size", "1", "0.2", "0.1", "--cells", "32", "6", "3", "-k", "6",
                       "--out", str(tmp_path / "o"), "--json", str(js), "--quiet", *PIP_PATH], capsys)
    assert code == 0
    t = json.loads(js.read_text())["timings"]
    parts = {k: v for k, v in t.items() if k.startswith("output.")}
    assert set(parts) == {"output.modes.vtu", "output.modes.xdmf", "output.modes.png"}
    assert sum(parts.values()) <= t["output"]
    assert t["output"] < t["total"], t


def test_warnings_are_one_line_each(tmp_path, capsys):
    """A part exported in millimetres (a 0.3 x 0.05 x 0.05 m bar as 300 x 50 x 50): one line
    'modalfem: warning: ...' naming --unit-scale, not Python's file:line + source format."""
    from modalfem.mesh import box, write

    path = write(box(size=(300.0, 50.0, 50.0), cells=(6, 1, 1)), tmp_path / "bar_mm.msh")
    assert main(["modes", str(path), "-k", "2", "--degree", "1", "--backend", "skfem", "--quiet"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    warn = [ln for ln in err if "warning" in ln.lower()]
    assert len(warn) == 1 and warn[0].startswith("modalfem: warning: ") and "unit" in warn[0], err
    assert not any(".py:" in ln for ln in err)
