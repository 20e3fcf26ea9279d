"""``modalfem run SCENE --out DIR``, ``modalfem run --list`` and ``modalfem plan SCENE``.

A bad scene is one line ``modalfem: error: FILE: KEY.PATH: problem`` and exit code 2 with nothing written
(raised as ``SceneError`` to ``modalfem.cli.main``). Ctrl-C during the steps keeps the frames so far
(exit code 130, said on stderr).
"""

from __future__ import annotations

import argparse
import sys

from modalfem.cli import _Parser  # usage errors: one line, exit code 2
from modalfem.errors import InputError

__all__ = ["plan_main", "run_main"]


def _run_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="modalfem run", description="Simulate a scene file (or an example scene by name) and write "
                "the outputs it names: ParaView time series, preview video, sound, glTF, summary.json.")
    p.add_argument("scene", nargs="?", metavar="SCENE", help="a scene file (.toml) or the name of an example scene")
    p.add_argument("--out", metavar="DIR", help="output folder (replaced as a whole at the end)")
    p.add_argument("--list", action="store_true", help="list the example scenes (name first) and exit")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return p


def run_main(argv: list[str]) -> int:
    args = _run_parser().parse_args(argv)
    from modalfem.scene.run import examples, run_scene

    if args.list:
        for name, (_, desc) in examples().items():
            print(f"{name}  {desc}".rstrip())
        return 0
    if not args.scene:
        raise InputError("modalfem run needs a SCENE (a .toml file or an example name; modalfem run --list)")
    if not args.out:
        raise InputError("modalfem run needs --out DIR (the folder the outputs go to)")
    result = run_scene(args.scene, args.out, quiet=args.quiet)
    return 130 if result.interrupted else 0


def _plan_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="modalfem plan", description="Print the step plan of a scene: which stages run, in order, for "
                "which bodies (and the effects each evaluates).")
    p.add_argument("scene", metavar="SCENE", help="a scene file (.toml) or the name of an example scene")
    return p


def plan_main(argv: list[str]) -> int:
    args = _plan_parser().parse_args(argv)
    from modalfem.scene.run import plan_scene

    print(plan_scene(args.scene, progress=lambda m: print(m, file=sys.stderr, flush=True)))
    return 0
