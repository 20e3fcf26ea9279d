"""Atomic file writes and their temporaries (standard library only, so the numpy-only runtime can use it).

``write_atomic(path, write, error=..., kind=...)`` calls ``write(binary file object)`` on a temporary
file in the target directory, flushes and fsyncs it, gives it ordinary permissions (mkstemp creates
0600) and renames it over ``path``. On any failure the temporary file is removed and ``path`` is left
as it was; OS errors become one ``error`` (a ``ModalfemError`` subclass) naming the file.

Every temporary modalfem creates next to a target is named ``temp_prefix(name, kind)`` + a random
token: ``.NAME.modalfem-tmp-HOST-PID-TOKEN`` (work in progress) or ``.NAME.modalfem-old-HOST-PID-TOKEN``
(the previous output, moved aside while the new one is moved in). A run that is killed (SIGKILL,
power loss) leaves them behind; ``remove_stale(directory)`` removes those of processes that no longer
run on this host (or older than ``STALE_AGE`` seconds, for other hosts and recycled PIDs) and moves a
``-old-`` entry back to its name if the run died before the new output took its place.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["STALE_AGE", "remove_stale", "temp_prefix", "write_atomic"]

#: seconds after which a temporary of another host (or of a recycled PID) counts as stale
STALE_AGE = 24 * 3600.0

_STALE = re.compile(r"^\.(?P<name>.+)\.modalfem-(?P<kind>tmp|old)-(?P<host>[A-Za-z0-9]*)-(?P<pid>\d+)-[A-Za-z0-9_]+$")


def _host() -> str:
    return re.sub(r"[^A-Za-z0-9]", "", socket.gethostname())[:16]


def temp_prefix(name: str, kind: str = "tmp") -> str:
    """Name prefix of a temporary for target file or folder ``name`` (``kind`` ``"tmp"`` or ``"old"``).

    The caller appends a random token (``tempfile.mkstemp(prefix=...)`` does).
    """
    if kind not in ("tmp", "old"):
        raise ValueError(f"kind must be 'tmp' or 'old', got {kind!r}")
    return f".{name}.modalfem-{kind}-{_host()}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: a process of another user holds the PID
        return True
    return True


def remove_stale(directory, *, max_age: float = STALE_AGE) -> list[str]:
    """Remove the temporaries that killed modalfem runs left in ``directory``.

    An entry is stale when it matches the temporary name pattern and its process is gone (same
    host) or it is older than ``max_age`` seconds. A stale ``-old-`` entry whose target name is free
    (the run died between moving the old output aside and moving the new one in) is renamed back, so
    the previous output reappears; every other stale entry is deleted. Entries of live runs are left
    alone. Errors (permissions, races with another cleaner) are ignored: cleaning is best effort.

    Args:
        directory: folder to scan (missing: nothing to do).
        max_age: age [s] beyond which any matching entry is stale.

    Returns:
        The names acted on, as ``"removed NAME"`` or ``"restored NAME -> TARGET"``.
    """
    done: list[str] = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return done
    host, now = _host(), time.time()
    for e in entries:
        m = _STALE.match(e.name)
        if m is None:
            continue
        try:
            age = now - e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if not (age > max_age or (m["host"] == host and not _alive(int(m["pid"])))):
            continue
        target = os.path.join(directory, m["name"])
        try:
            if m["kind"] == "old" and not os.path.lexists(target):
                os.rename(e.path, target)
                done.append(f"restored {e.name} -> {m['name']}")
                continue
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path)
            else:
                os.unlink(e.path)
            done.append(f"removed {e.name}")
        except OSError:
            pass
    return done


def write_atomic(path, write: Callable, *, error: type[Exception], kind: str) -> None:
    """Write ``path`` through ``write(f)`` on a temporary file + ``os.replace``.

    Stale temporaries of killed runs in the target directory are removed first (``remove_stale``).

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
    remove_stale(directory)
    try:
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path.name), dir=directory)
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
