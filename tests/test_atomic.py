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
