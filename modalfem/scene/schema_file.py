"""The shipped JSON Schema of scene files: ``modalfem/scene/scene.schema.json``, written from ``json_schema()``.

``python -m modalfem.scene.schema_file`` rewrites the file (atomically) from ``modalfem.scene.schema``;
``--check`` only says whether the committed file is current (exit code 1 if not). A test compares the two,
so the file cannot drift from the pydantic models that ``modalfem run`` validates with.

Editors: Taplo (the TOML language server behind VS Code's "Even Better TOML" extension, also used by
Neovim, Helix and Zed) picks a schema for a document, highest priority first, from an editor setting or
``taplo check --schema URL``, then a ``#:schema`` header directive, then a ``$schema`` key at the root of the
document, then its configuration file and schema catalogues. Scene files are strict (a ``$schema`` key is an
unknown key to ``modalfem run``), so use the directive: put ``#:schema ./scene.schema.json`` (a path relative
to the scene file, or a ``file://`` / ``https://`` URL) as the first line of the scene, before
``schema = "modalfem.scene/1"``; or associate ``*.scene.toml`` files with the schema once in the editor
(``evenBetterToml.schema.associations``) or in a ``.taplo.toml`` ``[[rule]]``. The editor then completes
keys, shows each key's description with its SI unit on hover and underlines wrong types, out-of-range values
and unknown keys as you type (``taplo check scene.toml`` does the same on the command line; checked with
Taplo 0.9 from npm ``@taplo/cli``). What only ``modalfem run`` checks: did-you-mean hints, referenced files,
unique names, effects a body kind cannot take, strikes after the end, bodies overlapping at t = 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

__all__ = ["SCHEMA_FILE", "schema_text", "write_schema"]

#: the shipped schema file (package data of ``modalfem.scene``)
SCHEMA_FILE = Path(__file__).with_name("scene.schema.json")


def schema_text() -> str:
    """The text of ``scene.schema.json``: ``json_schema()`` as indented JSON (key order as pydantic gives it)."""
    from modalfem.scene.schema import json_schema

    return json.dumps(json_schema(), indent=2, ensure_ascii=True, allow_nan=False) + "\n"


def write_schema(path=None) -> Path:
    """Write the schema to ``path`` (default ``SCHEMA_FILE``) atomically; returns the path written.

    Raises:
        InputError: the file cannot be written (one line naming it).
    """
    from modalfem.atomic import write_atomic
    from modalfem.errors import InputError

    p = Path(path) if path is not None else SCHEMA_FILE
    text = schema_text().encode("utf-8")
    write_atomic(p, lambda f: f.write(text), error=InputError, kind="JSON Schema")
    return p


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m modalfem.scene.schema_file",
                                 description="Write (or check) the JSON Schema of scene files.")
    ap.add_argument("--out", metavar="FILE", help=f"where to write it (default {SCHEMA_FILE})")
    ap.add_argument("--check", action="store_true", help="only say whether the file is current (exit 1 if not)")
    a = ap.parse_args(argv)
    target = Path(a.out) if a.out else SCHEMA_FILE
    if a.check:
        current = target.is_file() and target.read_text(encoding="utf-8") == schema_text()
        print(f"{target}: {'current' if current else 'OUT OF DATE (python -m modalfem.scene.schema_file)'}")
        return 0 if current else 1
    print(write_schema(target))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
