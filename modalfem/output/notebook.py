"""Show saved pictures and sounds inline when a script runs as a Jupyter notebook.

The tutorials write every figure to a file (so that a plain-script run leaves it on disk) and then
call ``show(path)``: inside a Jupyter kernel (JupyterLab, Notebook, nbclient, VS Code) the file is
put into the cell's output (PNG, JPEG and GIF as images, WAV as an audio player); in a plain
interpreter nothing is displayed and IPython is not imported. The same checks apply either way, so
a script run catches a missing file or an unsupported format too.
"""

from __future__ import annotations

import sys
from pathlib import Path

from modalfem.errors import InputError

__all__ = ["SHOWABLE_SUFFIXES", "in_notebook", "show"]

_IMAGE_FORMATS = {".png": "png", ".gif": "gif", ".jpg": "jpeg", ".jpeg": "jpeg"}
_AUDIO_SUFFIXES = (".wav",)
SHOWABLE_SUFFIXES = tuple(_IMAGE_FORMATS) + _AUDIO_SUFFIXES
"""File suffixes ``show`` accepts (lower case)."""


def in_notebook() -> bool:
    """Whether this code runs in a Jupyter kernel (an IPython shell that has a kernel).

    A plain interpreter, or IPython in a terminal, is not a notebook: rich output would only print
    an object's repr there. IPython is not imported by this check (a kernel has always imported it).
    """
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = ipython.get_ipython()
    return shell is not None and getattr(shell, "kernel", None) is not None


def show(*paths) -> int:
    """Display saved files in the current notebook cell's output.

    Args:
        *paths: files written earlier (``str`` or ``Path``): ``.png``, ``.gif``, ``.jpg``/``.jpeg``
            images (embedded, so the executed notebook keeps them) or ``.wav`` sound (an audio
            player).

    Returns:
        The number of files displayed: ``len(paths)`` in a Jupyter kernel, 0 elsewhere.

    Raises:
        InputError: a file does not exist, is empty, or has a suffix not listed above (checked
            in and out of notebooks alike).
    """
    files = [Path(p) for p in paths]
    for f in files:
        suffix = f.suffix.lower()
        if suffix not in SHOWABLE_SUFFIXES:
            raise InputError(f"cannot show {f}: unsupported file type {suffix or '(none)'!r} "
                             f"(expected one of {', '.join(SHOWABLE_SUFFIXES)})")
        if not f.is_file():
            raise InputError(f"cannot show {f}: no such file")
        if f.stat().st_size == 0:
            raise InputError(f"cannot show {f}: the file is empty")
    if not in_notebook():
        return 0
    from IPython.display import Audio, Image, display

    for f in files:
        suffix = f.suffix.lower()
        if suffix in _AUDIO_SUFFIXES:
            display(Audio(filename=str(f)))
        else:
            display(Image(filename=str(f), format=_IMAGE_FORMATS[suffix]))
    return len(files)
