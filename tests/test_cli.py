"""The ``modalfem`` command line: outputs, one-line errors with exit code 2, no partial files."""

from __future__ import annotations

import json
import subprocess
import sys

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
