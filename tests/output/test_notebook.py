"""modalfem.output.notebook: files shown inline in a Jupyter kernel, only checked elsewhere.

The real kernel path (nbclient executing the tutorials, image bytes compared with the files) is
tested in tests/test_tutorials.py; here the kernel is a stand-in, so these run in milliseconds.
"""

from __future__ import annotations

import base64
import re
import subprocess
import sys
import types

import numpy as np
import pytest
from PIL import Image as PILImage

from modalfem.errors import InputError
from modalfem.output import notebook
from modalfem.runtime.wav import write_wav


@pytest.fixture
def files(tmp_path):
    """A PNG, a two-frame GIF and a WAV written by the libraries the tutorials use."""
    png, gif, wav = tmp_path / "a.png", tmp_path / "b.gif", tmp_path / "c.wav"
    PILImage.new("RGB", (8, 6), (200, 30, 30)).save(png)
    frames = [PILImage.new("P", (8, 6), i) for i in (1, 2)]
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=100)
    write_wav(wav, np.sin(2 * np.pi * 440.0 * np.arange(4410) / 44100.0))
    return png, gif, wav


@pytest.fixture
def kernel(monkeypatch):
    """Pretend to be in a Jupyter kernel; collect what ``display`` receives."""
    ipython = pytest.importorskip("IPython")
    import IPython.display

    shown = []
    monkeypatch.setattr(ipython, "get_ipython", lambda: types.SimpleNamespace(kernel=object()))
    monkeypatch.setattr(IPython.display, "display", lambda *objs: shown.extend(objs))
    return shown


def test_outside_a_kernel_nothing_is_shown_and_ipython_is_not_imported(tmp_path):
    png = tmp_path / "a.png"
    PILImage.new("RGB", (4, 4)).save(png)
    code = ("import sys; from modalfem.output.notebook import in_notebook, show; "
            f"print(in_notebook(), show({str(png)!r}), 'IPython' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert proc.stdout.split() == ["False", "0", "False"]


def test_terminal_ipython_is_not_a_notebook(monkeypatch, files):
    ipython = pytest.importorskip("IPython")
    monkeypatch.setattr(ipython, "get_ipython", lambda: types.SimpleNamespace())  # a shell without a kernel
    assert not notebook.in_notebook()
    assert notebook.show(*files) == 0


def test_in_a_kernel_each_file_is_displayed_with_its_bytes(kernel, files):
    png, gif, wav = files
    assert notebook.in_notebook()
    assert notebook.show(png, str(gif), wav) == 3
    image_png, image_gif, audio = kernel
    for obj, path, mime in ((image_png, png, "image/png"), (image_gif, gif, "image/gif")):
        bundle = obj._repr_mimebundle_()
        data = bundle[0] if isinstance(bundle, tuple) else bundle
        assert set(data) == {mime}
        raw = data[mime]
        assert (raw if isinstance(raw, bytes) else base64.b64decode(raw)) == path.read_bytes()
    assert type(audio).__name__ == "Audio" and audio.data == wav.read_bytes()


@pytest.mark.parametrize("name, content, what", [
    ("missing.png", None, "no such file"),
    ("empty.gif", b"", "the file is empty"),
    ("table.csv", b"1,2\n", "unsupported file type '.csv'"),
    ("noext", b"x", "unsupported file type '(none)'"),
])
def test_bad_files_are_refused_in_and_out_of_a_kernel(tmp_path, monkeypatch, name, content, what):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    for in_kernel in (False, True):
        monkeypatch.setattr(notebook, "in_notebook", lambda k=in_kernel: k)
        with pytest.raises(InputError, match=f"cannot show .*{re.escape(name)}: {re.escape(what)}") as info:
            notebook.show(path)
        assert "\n" not in str(info.value)
