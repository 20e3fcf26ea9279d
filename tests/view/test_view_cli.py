"""``modalfem view``: bad input is one line and exit 2; a served view prints its URL and stops cleanly."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import urllib.request

import pytest

from modalfem.cli import main


@pytest.mark.parametrize("make, words", [
    (lambda d: d / "missing.npz", "does not exist"),
    (lambda d: (d / "text.npz").write_text("hello") and d / "text.npz", "not a .npz archive"),
    (lambda d: d, "is a directory"),
])
def test_bad_model_file_is_one_line_exit_2(tmp_path, capsys, make, words):
    assert main(["view", str(make(tmp_path)), "--no-browser"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("modalfem: error: ") and words in err and err.count("\n") == 1


def test_bad_options_are_one_line_exit_2(view_model_file, capsys):
    for argv, words in ((["--mode", "9"], "mode must be in 1..8"), (["--mode", "x"], "invalid int value"),
                        (["--amplitude", "2"], "amplitude"), (["--port", "-3"], "port"), ([], None)):
        code = main(["view", *([str(view_model_file)] if words else []), *argv, "--no-browser"])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("modalfem: error: ") and err.count("\n") == 1
        assert (words or "MODEL.npz") in err


def test_help_lists_view(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "view" in capsys.readouterr().out


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_serves_prints_the_url_and_stops_cleanly(view_model_file, sig):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "modalfem", "view", str(view_model_file), "--no-browser",
                             "--mode", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline()
        assert line.startswith("modalfem view: http://127.0.0.1:"), line + proc.stderr.read()
        url = line.split()[2]
        with urllib.request.urlopen(url, timeout=10) as r:
            assert b"<canvas" in r.read()
        with urllib.request.urlopen(url + "scene", timeout=10) as r:
            scene = json.loads(r.read())
        assert scene["bodies"][0]["mode_count"] == 8
        assert next(c for c in scene["controls"] if c["name"] == "mode")["value"] == 1  # --mode 2, 0-based
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)  # a loaded CI machine; a hang never ends
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    assert out.strip() == "modalfem view: stopped" and err == ""
