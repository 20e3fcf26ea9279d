"""The broken-scene corpus: every file in tests/scene/broken/ is refused with one line and nothing written.

Each corpus file starts with comment lines that say what it must produce:

    # expect: <a substring of the error line>
    # key: <the key path the line must name>          (for errors about a key)
    # json-schema: rejects                           (the shipped JSON Schema refuses it too; see test_schema_file)

``modalfem run FILE --out DIR`` must exit with code 2 and print exactly one stderr line
``modalfem: error: FILE: ...`` holding the expected substring and key path, no traceback, nothing on stdout;
DIR must not exist afterwards and no temporaries may be left next to it. Files in broken/data/ are the
corrupt inputs some scenes name.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from modalfem.cli import main

BROKEN = Path(__file__).parent / "broken"
FILES = sorted(BROKEN.glob("*.toml"))
REPO = Path(__file__).resolve().parents[2]


def header(path: Path) -> dict:
    """The ``# name: value`` lines at the top of a corpus file."""
    out = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.startswith("# ") or ":" not in line:
            break
        name, value = line[2:].split(":", 1)
        out[name.strip()] = value.strip()
    return out


def check_one_line(path: Path, code: int, out: str, err: str, *, stdout_empty: bool = True) -> str:
    """Assert the refusal contract for ``path``; returns the error line."""
    h = header(path)
    lines = err.splitlines()
    assert code == 2, f"{path.name}: exit code {code}, stderr {err!r}"
    assert len(lines) == 1, f"{path.name}: {len(lines)} stderr lines: {err!r}"
    line = lines[0]
    assert line.startswith("modalfem: error: "), line
    assert "Traceback" not in err and "unexpected" not in line, line
    assert path.name in line, f"the line does not name the file: {line}"
    assert h["expect"] in line, f"{path.name}: {h['expect']!r} not in {line!r}"
    if "key" in h:
        assert f": {h['key']}:" in line, f"{path.name}: key path {h['key']!r} not in {line!r}"
    if stdout_empty:
        assert out == "", f"{path.name}: stdout {out!r}"
    return line


def test_the_corpus_is_large_and_every_file_says_what_it_expects():
    assert len(FILES) >= 30
    for f in FILES:
        assert header(f).get("expect"), f"{f.name} has no '# expect:' first line"
    assert len({header(f)["expect"] for f in FILES}) >= 30  # not one problem thirty times


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_run_refuses_with_one_line_and_writes_nothing(path, tmp_path, capsys):
    before = sorted(os.listdir(BROKEN))
    out = tmp_path / "out"
    code = main(["run", str(path), "--out", str(out)])
    cap = capsys.readouterr()
    check_one_line(path, code, cap.out, cap.err)
    assert not out.exists()
    assert os.listdir(tmp_path) == [], f"left behind: {os.listdir(tmp_path)}"
    assert sorted(os.listdir(BROKEN)) == before  # nothing written next to the scene either


def test_run_keeps_an_existing_output_folder_as_it_was(tmp_path, capsys):
    """A bad scene run into the folder of an earlier run leaves that folder untouched."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"earlier": true}\n')
    path = BROKEN / "range-nu-half.toml"
    code = main(["run", str(path), "--out", str(out)])
    cap = capsys.readouterr()
    check_one_line(path, code, cap.out, cap.err)
    assert sorted(os.listdir(out)) == ["summary.json"]
    assert (out / "summary.json").read_text() == '{"earlier": true}\n'
    assert os.listdir(tmp_path) == ["out"]


# a load error, a validation error, a check after validation, a file error at build and a start-state error
SUBPROCESS = ["invalid-toml", "unknown-key-body", "sound-on-cloth", "corrupt-model-file", "overlapping-blocks"]


@pytest.mark.parametrize("stem", SUBPROCESS)
def test_real_process_refuses_with_one_line(stem, tmp_path):
    path = BROKEN / f"{stem}.toml"
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-m", "modalfem", "run", str(path), "--out", str(out)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300, env=env)
    check_one_line(path, r.returncode, r.stdout, r.stderr)
    assert not out.exists() and os.listdir(tmp_path) == []


# the plan builds the world without the start check (it lists stages; overlaps are run's concern)
START_STATE = {"overlapping-blocks", "body-inside-ground", "body-inside-sphere"}
PLAN_FILES = [f for f in FILES if f.stem not in START_STATE]


@pytest.mark.parametrize("path", PLAN_FILES, ids=[f.stem for f in PLAN_FILES])
def test_plan_refuses_with_one_line(path, capsys):
    code = main(["plan", str(path)])
    cap = capsys.readouterr()
    check_one_line(path, code, cap.out, cap.err)


@pytest.mark.parametrize("stem", sorted(START_STATE))
def test_plan_of_a_scene_refused_for_its_start_state_still_lists_the_stages(stem, capsys):
    code = main(["plan", str(BROKEN / f"{stem}.toml")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert cap.out.startswith("1. ") and "step:" in cap.out
