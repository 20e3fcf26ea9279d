"""All-or-nothing outputs: every file and folder one command writes appears together, or none does.

``check_targets`` fails fast (before any computing) on targets that can never be written.
``OutputSet`` gives each target a temporary next to it (a hidden sibling folder for a folder
target); the writers fill the temporaries, and ``commit`` moves them all into place only when every
one is complete: an existing folder is renamed out of the way, the new one renamed in, then the old
one removed; an existing file is replaced by ``os.replace`` (a hard link keeps the old one until the
whole set is in place). On any failure (an error, Ctrl-C, ``SystemExit``) every temporary is removed
and the previous outputs are left as they were. Temporaries that a killed run (SIGKILL) left behind
carry its host and PID in their names (``modalfem.atomic.temp_prefix``); ``OutputSet`` removes
stale ones of its targets' folders when it starts (``modalfem.atomic.remove_stale``).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from modalfem.atomic import remove_stale, temp_prefix
from modalfem.errors import InputError

__all__ = ["OUT_FILES", "OutputSet", "check_targets", "staged_dir", "write_text_atomic"]

#: the files ``modalfem modes --out DIR`` writes: an existing DIR holding anything else is not replaced
OUT_FILES = frozenset({"modes.json", "modes.png", "modes.vtu", "modes.xdmf", "modes.h5"})


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not os.path.lexists(p):
        p = p.parent
    return p


def check_targets(*, out_dir: str | os.PathLike | None = None, files: tuple = (),
                  out_files: frozenset | None = OUT_FILES) -> None:
    """Fail fast on output targets that cannot be written.

    Args:
        out_dir: output folder (replaced as a whole at the end if it exists).
        files: output file paths (their parent folders are created at the end if needed).
        out_files: names an existing ``out_dir`` may hold (it is replaced, so anything else in it
            would be lost); None accepts any content.

    Raises:
        InputError: ``out_dir`` is an existing file or holds files that are neither modalfem's
            (``out_files``) nor file targets inside it, a file target is an existing folder, is
            ``out_dir`` or is given twice, or the nearest existing ancestor of a target is not a
            writable folder.
    """
    targets = []
    out = None
    if out_dir is not None:
        d = Path(out_dir)
        out = d.absolute()
        if d.exists() and not d.is_dir():
            raise InputError(f"--out {str(d)!r} exists and is not a directory")
        if d.is_dir() and out_files is not None:
            inside = {Path(f).absolute().relative_to(out).parts[0] for f in files
                      if f is not None and Path(f).absolute().is_relative_to(out) and Path(f).absolute() != out}
            known = set(out_files) | inside
            foreign = sorted(e.name for e in os.scandir(d) if e.name not in known and not e.name.startswith("."))
            if foreign:
                more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
                raise InputError(
                    f"--out {str(d)!r} holds files modalfem does not write ({', '.join(foreign[:3])}{more}); "
                    "it is replaced as a whole, so give a new or empty folder"
                )
        if Path.cwd().resolve().is_relative_to(d.resolve()):
            raise InputError(f"--out {str(d)!r} is the current folder or holds it; give a folder inside it")
        targets.append(d)
    seen: set[Path] = set()
    for f in files:
        if f is None:
            continue
        f = Path(f)
        if f.is_dir():
            raise InputError(f"output file {str(f)!r} is an existing directory")
        a = f.absolute()
        if a in seen:
            raise InputError(f"output file {str(f)!r} is given twice")
        seen.add(a)
        if out is not None and a == out:
            raise InputError(f"output file {str(f)!r} is the --out folder")
        if out is not None and a.is_relative_to(out):
            continue  # written into the --out folder's temporary, moved in with it
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


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            os.unlink(path)


class OutputSet:
    """The outputs of one command, moved into place together (see the module docstring).

    Use as a context manager: ``folder(target)`` / ``file(target)`` return temporaries to write,
    ``commit()`` moves them in; leaving the block without ``commit`` (or by an exception) removes
    every temporary.
    """

    def __init__(self) -> None:
        self._entries: list[tuple[Path, Path, bool]] = []  # (target, temporary, is a folder)
        self._cleaned: set[Path] = set()

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, *exc) -> None:
        self.discard()

    def _host_dir(self, target: Path) -> Path:
        """Folder of the temporary: the target's parent, or its nearest existing ancestor (same file system)."""
        host = _existing_ancestor(target.parent)
        if host not in self._cleaned:
            self._cleaned.add(host)
            remove_stale(host)
        return host

    def folder(self, target: str | os.PathLike) -> Path:
        """An empty temporary folder that becomes ``target`` on ``commit``."""
        target = Path(target).absolute()
        host = self._host_dir(target)
        try:
            tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(target.name), dir=host))
        except OSError as exc:
            raise _os_error("create a temporary folder in", host, exc) from None
        self._entries.append((target, tmp, True))
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; the output gets ordinary permissions
        return tmp

    def file(self, target: str | os.PathLike) -> Path:
        """A temporary file path (an empty file) that becomes ``target`` on ``commit``.

        A target inside a folder of this set is written into that folder's temporary (it moves in
        with the folder); register the folder first.
        """
        target = Path(target).absolute()
        for folder, tmp, is_dir in self._entries:
            if is_dir and target != folder and target.is_relative_to(folder):
                path = tmp / target.relative_to(folder)
                try:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.touch()
                except OSError as exc:
                    raise _os_error("write", target, exc) from None
                return path
        host = self._host_dir(target)
        try:
            fd, tmp = tempfile.mkstemp(prefix=temp_prefix(target.name), dir=host)
        except OSError as exc:
            raise _os_error("write", target, exc) from None
        os.close(fd)
        self._entries.append((target, Path(tmp), False))
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600
        return Path(tmp)

    def discard(self) -> None:
        """Remove every temporary not yet moved into place."""
        for _, tmp, _ in self._entries:
            _remove(tmp)
        self._entries = []

    def commit(self) -> None:
        """Move every temporary into place; on failure undo the moves done and restore the old outputs.

        Raises:
            InputError: a target cannot be written (the previous outputs are then unchanged).
        """
        created: list[Path] = []
        undo: list[tuple[str, Path, Path]] = []
        olds: list[Path] = []
        current = None
        try:
            for target, tmp, is_dir in self._entries:
                current = target
                missing = []
                p = target.parent
                while not os.path.lexists(p):
                    missing.append(p)
                    p = p.parent
                for d in reversed(missing):
                    os.mkdir(d)
                    created.append(d)
                if is_dir:
                    for f in Path(tmp).iterdir():  # the folder's files reach the disk before it is swapped in
                        _fsync(f)
                if os.path.lexists(target):
                    old = target.parent / (temp_prefix(target.name, "old") + secrets.token_hex(6))
                    if is_dir:
                        os.rename(target, old)
                        undo.append(("rename", old, target))
                        olds.append(old)
                    else:
                        try:
                            os.link(target, old)  # keeps the old file until the set is complete
                            undo.append(("replace", old, target))
                            olds.append(old)
                        except OSError:
                            pass  # no hard links here: the old file is replaced without a way back
                os.replace(tmp, target)
                undo.append(("rename", target, tmp))
            for old in olds:
                _remove(old)
            self._entries = []
        except BaseException as exc:
            for action, src, dst in reversed(undo):
                with contextlib.suppress(OSError):
                    if action == "rename":
                        os.rename(src, dst)
                    elif os.path.samefile(src, dst):  # not replaced yet: drop the link (rename would be a no-op)
                        os.unlink(src)
                    else:
                        os.replace(src, dst)
            for d in reversed(created):
                with contextlib.suppress(OSError):
                    os.rmdir(d)
            self.discard()
            if isinstance(exc, OSError):
                raise _os_error("write", current, exc) from None
            raise


def _fsync(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def staged_dir(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder that replaces ``out_dir`` as a whole when the block succeeds.

    A one-target ``OutputSet``: on any exception the temporary folder is removed, ``out_dir`` is left
    as it was, and the exception propagates.

    Raises:
        InputError: the temporary folder cannot be created or moved into place.
    """
    with OutputSet() as outs:
        tmp = outs.folder(out_dir)
        yield tmp
        outs.commit()


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` via a temporary file in the same directory + ``os.replace``.

    Missing parent directories are created.

    Raises:
        InputError: the file cannot be written.
    """
    with OutputSet() as outs:
        outs.file(path).write_text(text, encoding="utf-8")
        outs.commit()
