"""modalfem.atomic: one atomic writer for model files, WAV and pictures."""

import os

import pytest

from modalfem.atomic import write_atomic
from modalfem.errors import InputError, ModelFileError


def test_writes_replaces_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "a.bin"
    write_atomic(target, lambda f: f.write(b"one"), error=InputError, kind="test")
    write_atomic(target, lambda f: f.write(b"two"), error=InputError, kind="test")
    assert target.read_bytes() == b"two"
    assert os.listdir(tmp_path) == ["a.bin"]
    assert (target.stat().st_mode & 0o777) != 0o600  # not mkstemp's private mode


def test_failure_keeps_the_old_file_and_names_it(tmp_path):
    target = tmp_path / "m.npz"
    target.write_bytes(b"old")

    def boom(f):
        f.write(b"partial")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        write_atomic(target, boom, error=ModelFileError, kind="model")

    def oserror(f):
        raise OSError(28, "No space left on device")

    with pytest.raises(ModelFileError, match="cannot write model file .*No space left"):
        write_atomic(target, oserror, error=ModelFileError, kind="model")
    assert target.read_bytes() == b"old" and os.listdir(tmp_path) == ["m.npz"]
    with pytest.raises(InputError, match="cannot write PNG file"):
        write_atomic(tmp_path / "missing" / "x.png", lambda f: None, error=InputError, kind="PNG")


def _dead_pid() -> int:
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # reaped: the PID names no process (until the system recycles it)
    return p.pid


def _stale_name(target: str, kind: str, pid: int, host: str | None = None) -> str:
    """A temporary's name as ``temp_prefix`` makes it, for another PID (and host)."""
    from modalfem.atomic import _host

    return f".{target}.modalfem-{kind}-{_host() if host is None else host}-{pid}-k1ll3d"


def test_remove_stale_cleans_up_after_killed_runs_only(tmp_path):
    import time

    from modalfem.atomic import temp_prefix

    assert temp_prefix("a.bin") == _stale_name("a.bin", "tmp", os.getpid())[: -len("k1ll3d")]

    from modalfem.atomic import STALE_AGE, remove_stale

    dead = _dead_pid()
    (tmp_path / _stale_name("m.npz", "tmp", dead)).write_bytes(b"half a model")
    (tmp_path / _stale_name("out", "tmp", dead)).mkdir()
    (tmp_path / _stale_name("out", "tmp", dead) / "modes.png").write_bytes(b"half a picture")
    # killed after moving the old output aside, before moving the new one in: the old one comes back
    (tmp_path / _stale_name("prev", "old", dead)).mkdir()
    (tmp_path / _stale_name("prev", "old", dead) / "modes.json").write_text("previous")
    # killed after the new output was in place: the old one is just deleted
    (tmp_path / "s.json").write_text("new")
    (tmp_path / _stale_name("s.json", "old", dead)).write_text("old")
    live = tmp_path / (temp_prefix("x.json") + "running")  # this process: alive
    live.write_text("in progress")
    other_host = tmp_path / _stale_name("y.json", "tmp", dead, host="elsewhere")  # unknown liveness, recent
    other_host.write_text("?")
    ancient = tmp_path / _stale_name("z.json", "tmp", os.getpid(), host="elsewhere")
    ancient.write_text("?")
    old = time.time() - STALE_AGE - 60
    os.utime(ancient, (old, old))
    (tmp_path / ".unrelated.tmp").write_text("not ours")

    done = remove_stale(tmp_path)
    assert len(done) == 5, done
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [".unrelated.tmp", "prev", "s.json", live.name, other_host.name])
    assert (tmp_path / "prev" / "modes.json").read_text() == "previous" and (tmp_path / "s.json").read_text() == "new"
    assert remove_stale(tmp_path / "missing") == []


def test_write_atomic_removes_stale_temporaries_of_its_directory(tmp_path):
    stale = tmp_path / _stale_name("a.bin", "tmp", _dead_pid())
    stale.write_bytes(b"left by a killed run")
    write_atomic(tmp_path / "a.bin", lambda f: f.write(b"ok"), error=InputError, kind="test")
    assert os.listdir(tmp_path) == ["a.bin"]
