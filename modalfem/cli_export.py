"""``modalfem export MODEL.npz OUT.glb [--html PAGE.html]``: modes as glTF morph targets, and a page.

The model file (``modalfem modes ... --save MODEL.npz``) becomes a binary glTF whose morph targets
are the deformation modes (``modalfem.output.gltf``); ``--html`` also writes a self-contained page
(three.js, the JavaScript modal runtime and the .glb inlined) where a click strikes the body and
plays its sound. Both files are one output set: written to temporaries and moved into place
together, or (on any error, Ctrl-C, SIGTERM) neither is. Bad input (not a model file, a newer schema,
-k out of range, a target that cannot be written) is one line ``modalfem: error: ...`` (exit 2).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(sub) -> argparse.ArgumentParser:
    """Register the ``export`` subcommand on the ``modalfem`` subparsers ``sub``."""
    e = sub.add_parser("export", help="write a model's modes as glTF morph targets (.glb), and an HTML page",
                       description="Write the surface of a modal model (MODEL.npz from `modalfem modes --save`) "
                                   "with its modes as glTF morph targets, and optionally a self-contained HTML "
                                   "page that animates and sounds it when clicked.")
    e.add_argument("model", type=Path, metavar="MODEL.npz", help="model file written by `modalfem modes --save`")
    e.add_argument("glb", type=Path, metavar="OUT.glb", help="binary glTF file to write")
    e.add_argument("--html", type=Path, metavar="PAGE.html",
                   help="also write a self-contained page (three.js bundled; no network, no Python to view)")
    e.add_argument("-k", type=int, default=None, help="export the first K modes (default all)")
    e.add_argument("--crease-angle", type=float, default=60.0,
                   help="faces meeting at more than this angle [deg] keep separate normals (default 60; 180: smooth)")
    e.add_argument("--damping", type=float, nargs=2, metavar=("ALPHA", "BETA"), default=None,
                   help="Rayleigh damping alpha [1/s] and beta [s] replacing the model's (mu_i = alpha + beta "
                        "omega_i^2; e.g. 2 1e-9 for a long-ringing bell)")
    e.add_argument("--no-normal-targets", action="store_true",
                   help="write only POSITION morph targets (normals then stay at rest)")
    e.add_argument("--title", default=None, help="page title (default: the model file name)")
    e.add_argument("--quiet", action="store_true", help="no progress lines")
    e.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    return e


def _check_names(args) -> None:
    from modalfem.errors import InputError

    if args.glb.suffix.lower() != ".glb":
        raise InputError(f"OUT.glb must name a .glb file (binary glTF), got {str(args.glb)!r}")
    if args.html is not None and args.html.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"--html must name a .html file, got {str(args.html)!r}")
    model = args.model.absolute()
    for target in (args.glb, args.html):
        if target is not None and target.absolute() == model:
            raise InputError(f"{str(target)!r} is the model file itself: choose another output name")
    if args.k is not None and args.k < 1:
        raise InputError(f"-k must be an integer >= 1, got {args.k}")


def run(args, argv) -> int:
    """Run ``modalfem export`` with parsed ``args``; returns the exit code (0)."""
    from modalfem.cli import _Progress

    say = _Progress(quiet=args.quiet)
    try:
        return _export(args, say)
    finally:
        say.close()


def _export(args, say) -> int:
    from modalfem.errors import InputError
    from modalfem.model import ModalModel
    from modalfem.output import OutputSet, check_targets
    from modalfem.output.gltf import glb_bytes, modal_surface, page_html

    _check_names(args)
    check_targets(files=tuple(p for p in (args.glb, args.html) if p is not None))
    t0 = time.perf_counter()
    say(f"model: {args.model}")
    model = ModalModel.load(args.model)
    say(f"model: {model!r}")
    say("surface and morph targets")
    surface = modal_surface(model, mode_count=args.k, crease_angle=args.crease_angle,
                            normals=not args.no_normal_targets, damping=args.damping,
                            progress=lambda i, n: i % max(1, n // 10) or say.bar(i, n, "normal targets"))
    data = glb_bytes(model, crease_angle=args.crease_angle, surface=surface,
                     source={"model_file": args.model.name})
    page = None
    if args.html is not None:
        say("page")
        page = page_html(data, title=args.title or f"{args.model.stem}: {surface.mode_count} modes")
    targets = [str(p) for p in (args.glb, args.html) if p is not None]
    say(f"writing {', '.join(targets)}")
    with OutputSet() as outs:
        for target, content in ((args.glb, data), (args.html, page)):
            if target is None:
                continue
            tmp = outs.file(target)
            try:
                tmp.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
            except OSError as exc:
                raise InputError(f"cannot write {str(target)!r}: {exc.strerror or exc}") from None
        outs.commit()
    f = surface.omega / (2 * 3.141592653589793)
    say.done(f"wrote {', '.join(targets)} in {time.perf_counter() - t0:.2f} s")
    say.close()
    print(f"{surface.mode_count} modes ({f[0]:.6g}..{f[-1]:.6g} Hz) as morph targets on {surface.vertex_count} "
          f"vertices ({model.vertex_count} model vertices split at {args.crease_angle:g} deg creases), "
          f"{len(surface.indices)} triangles")
    print(f"glb: {args.glb} ({len(data) / 1e6:.2f} MB)")
    if page is not None:
        print(f"html: {args.html} ({len(page.encode('utf-8')) / 1e6:.2f} MB; open it in a browser, click the body)")
    return 0
