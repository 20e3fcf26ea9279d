"""Atomic output: nothing appears at a target path until every output of a run is complete.

``check_targets`` fails fast (before any computing) on targets that can never be written;
``staged_dir`` builds an output directory in a hidden temporary directory next to it and moves it
into place on success (and removes it on failure); ``write_text_atomic`` writes one file through a
temporary file and ``os.replace``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from modalfem.errors import InputError

__all__ = ["check_targets", "staged_dir", "write_text_atomic"]


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not p.exists():
        p = p.parent
    return p


def check_targets(*, out_dir: str | os.PathLike | None = None, files: tuple = ()) -> None:
    """Fail fast on output targets that cannot be written.

    Args:
        out_dir: output directory (created at the end if it does not exist).
        files: output file paths (their parent directories are created at the end if needed).

    Raises:
        InputError: ``out_dir`` is an existing file, a file target is an existing directory, or the
            nearest existing ancestor of a target is not a writable directory.
    """
    targets = []
    if out_dir is not None:
        d = Path(out_dir)
        if d.exists() and not d.is_dir():
            raise InputError(f"--out {str(d)!r} exists and is not a directory")
        targets.append(d)
    for f in files:
        if f is None:
            continue
        f = Path(f)
        if f.is_dir():
            raise InputError(f"output file {str(f)!r} is an existing directory")
        targets.append(f.parent)
    for t in targets:
        anc = _existing_ancestor(t)
        if not anc.is_dir():
            raise InputError(f"cannot create {str(t)!r}: {str(anc)!r} is not a directory")
        if not os.access(anc, os.W_OK | os.X_OK):
            raise InputError(f"cannot write into {str(anc)!r}: permission denied")


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _os_error(action: str, path: Path, exc: OSError) -> InputError:
    return InputError(f"cannot {action} {str(path)!r}: {exc.strerror or exc}")


@contextlib.contextmanager
def staged_dir(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary directory whose files land in ``out_dir`` when the block succeeds.

    If ``out_dir`` does not exist, the temporary directory is created next to it (in its nearest
    existing ancestor, same file system) and renamed to ``out_dir`` at the end, so ``out_dir``
    appears complete or not at all. If it exists, the temporary directory lives inside it and each
    file is moved in with ``os.replace`` (existing files of the same name are replaced). On any
    exception the temporary directory is removed and the exception propagates.

    Raises:
        InputError: the temporary directory cannot be created or the files cannot be moved.
    """
    out = Path(out_dir).absolute()
    host = out if out.is_dir() else _existing_ancestor(out.parent)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.modalfem-tmp-", dir=host))
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; out_dir gets ordinary permissions
    except OSError as exc:
        raise _os_error("create a temporary directory in", host, exc) from None
    try:
        yield tmp
        try:
            if not out.exists():
                out.parent.mkdir(parents=True, exist_ok=True)
                try:
                    os.replace(tmp, out)
                    return
                except OSError:
                    if not out.is_dir():  # not a lost race with another creator of out_dir
                        raise
            for f in sorted(tmp.iterdir()):
                os.replace(f, out / f.name)
        except OSError as exc:
            raise _os_error("write", out, exc) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` via a temporary file in the same directory + ``os.replace``.

    Missing parent directories are created.

    Raises:
        InputError: the file cannot be written.
    """
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise _os_error("write", path, exc) from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
