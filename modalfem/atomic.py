"""Atomic file writes (standard library only, so the numpy-only runtime can use it too).

``write_atomic(path, write, error=..., kind=...)`` calls ``write(binary file object)`` on a temporary
file in the target directory, flushes and fsyncs it, gives it ordinary permissions (mkstemp creates
0600) and renames it over ``path``. On any failure the temporary file is removed and ``path`` is left
as it was; OS errors become one ``error`` (a ``ModalfemError`` subclass) naming the file.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["write_atomic"]


def write_atomic(path, write: Callable, *, error: type[Exception], kind: str) -> None:
    """Write ``path`` through ``write(f)`` on a temporary file + ``os.replace``.

    Args:
        path: target file; its directory must exist.
        write: callable receiving the open binary file object.
        error: exception class raised (one line) when the file cannot be written.
        kind: what the file is, for the message (``"model"``, ``"WAV"``, ``"PNG"``).

    Raises:
        error: the directory is missing or unwritable, the disk is full, ...; other exceptions from
            ``write`` propagate unchanged (the target is untouched either way).
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise error(f"cannot write {kind} file {str(path)!r}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        mask = os.umask(0o022)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise error(f"cannot write {kind} file {str(path)!r}: {exc.strerror or exc}") from None
        raise
