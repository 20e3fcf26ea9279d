"""``modalfem`` command line (also ``python -m modalfem``).

Subcommands:
  * ``modalfem modes MESH_OR_GENERATOR ...``: lowest modes of a mesh file (.msh, .vtu, .xdmf, ...)
    or a generated body (box, plate, rod, tuning_fork, bell); writes a JSON summary and, with
    ``--out DIR``, mode shapes for ParaView (modes.vtu, modes.xdmf) and a PNG sheet (modes.png);
    with ``--save MODEL.npz``, a ``ModalModel`` file for the numpy-only runtime (``modalfem.model``).
  * ``modalfem bench modes ...``: the cantilever-ladder benchmark (``modalfem.bench.cli``).
  * ``modalfem export MODEL.npz OUT.glb [--html PAGE.html]``: modes as glTF morph targets and a
    self-contained page (``modalfem.cli_export``).
  * ``modalfem view MODEL.npz``: live mode explorer in the browser (``modalfem.view.cli``).

Every ``ModalfemError`` (bad material, unknown tag, malformed mesh, k too large, ...) becomes one
line ``modalfem: error: ...`` on stderr and exit code 2. The outputs of one run (the ``--out`` folder,
``--json``, ``--save``) are one set (``modalfem.output.OutputSet``): all are written to temporaries
and moved into place together at the end, or, on any failure, Ctrl-C or SIGTERM, none is and the
previous ones stay as they were.

Progress goes to stderr (nothing with ``--quiet``): one line per stage with the elapsed time; on a
terminal the current stage's line counts its seconds live, elsewhere a long stage repeats its line
every ``_Progress.heartbeat`` seconds. ``--verbose`` also lets through the FEniCSx JIT compiler's
log (``modalfem.backends.fenicsx``).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import warnings
import threading
import time
from pathlib import Path

__all__ = ["build_parser", "main"]

GENERATOR_NAMES = ("box", "plate", "rod", "tuning_fork", "bell")


class _ArgumentError(Exception):
    """argparse usage error, reported as one line with exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit code 2, via main()
        raise _ArgumentError(message)


def build_parser() -> argparse.ArgumentParser:
    """The argparse parser of the ``modalfem`` command."""
    p = _Parser(prog="modalfem", description="Certified vibration modes of 3D elastic bodies.")
    p.add_argument("--version", action="store_true", help="print the version and exit")
    sub = p.add_subparsers(dest="command", parser_class=_Parser)

    m = sub.add_parser("modes", help="lowest vibration modes of a mesh file or a generated body")
    m.add_argument("mesh", metavar="MESH_OR_GENERATOR",
                   help=f"mesh file (.msh, .vtu, .xdmf, ...) or a generator: {', '.join(GENERATOR_NAMES)}")
    g = m.add_argument_group("generated bodies [m]")
    g.add_argument("--size", type=float, nargs=3, metavar=("LX", "LY", "LZ"), help="box/plate size [m]")
    g.add_argument("--cells", type=int, nargs=3, metavar=("NX", "NY", "NZ"), help="box/plate cells per axis")
    g.add_argument("--length", type=float, help="rod length [m]")
    g.add_argument("--radius", type=float, help="rod radius [m]")
    g.add_argument("--h", type=float, help="target element size [m] (rod, tuning_fork, bell; surface files)")
    f = m.add_argument_group("mesh files")
    f.add_argument("--unit-scale", type=float, default=1.0,
                   help="factor turning file coordinates into metres (1e-3 for a file in mm)")
    mat = m.add_argument_group("material")
    mat.add_argument("--material", default=None, help="preset: steel, aluminium, brass (default steel)")
    mat.add_argument("--E", type=float, help="Young's modulus [Pa]")
    mat.add_argument("--nu", type=float, help="Poisson's ratio [-]")
    mat.add_argument("--rho", type=float, help="density [kg/m^3]")
    c = m.add_argument_group("constraints")
    c.add_argument("--fixed", action="append", default=[], metavar="TAG",
                   help="clamp all components on a tagged face (repeatable)")
    c.add_argument("--roller", action="append", default=[], metavar="TAG:COMPONENTS",
                   help="hold only some components on a tag, e.g. z0:z (repeatable)")
    s = m.add_argument_group("solve")
    s.add_argument("-k", type=int, default=10, help="number of deformation modes (default 10)")
    s.add_argument("--degree", type=int, default=2, choices=(1, 2), help="Lagrange degree (default 2)")
    s.add_argument("--backend", default="auto", choices=("auto", "fenicsx", "skfem"))
    s.add_argument("--solver", default="auto", choices=("auto", "block", "slepc", "scipy"))
    s.add_argument("--lumped", action="store_true", help="lumped (diagonal) mass matrix")
    o = m.add_argument_group("outputs")
    o.add_argument("--json", type=Path, help="JSON summary file")
    o.add_argument("--out", type=Path, help="directory for modes.png, modes.vtu, modes.xdmf, modes.json")
    o.add_argument("--save", type=Path, metavar="MODEL",
                   help="write a ModalModel file (.npz) for the runtime: boundary surface, boundary-only "
                        "deformation modes, mass properties, material, damping defaults, provenance")
    o.add_argument("--sheet-modes", type=int, default=8, help="modes drawn in modes.png (default 8)")
    o.add_argument("--quiet", action="store_true", help="no progress lines")
    o.add_argument("--verbose", action="store_true",
                   help="also show the FEniCSx JIT compiler's log (FFCx, cffi/gcc lines)")
    o.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    from modalfem.reduction import transfer_cli

    transfer_cli.add_arguments(m)

    b = sub.add_parser("bench", help="benchmarks that write BENCHMARKS.md (see `modalfem bench modes -h`)",
                       add_help=False)
    b.add_argument("args", nargs=argparse.REMAINDER)
    from modalfem.cli_export import add_parser as add_export_parser

    add_export_parser(sub)
    sub.add_parser("view", help="live mode explorer of a model file in the browser (see `modalfem view -h`)",
                   add_help=False).add_argument("args", nargs=argparse.REMAINDER)
    sub.add_parser("run", help="simulate a scene file or example scene (see `modalfem run -h`, `--list`)",
                   add_help=False).add_argument("args", nargs=argparse.REMAINDER)
    sub.add_parser("plan", help="print the step plan of a scene (see `modalfem plan -h`)",
                   add_help=False).add_argument("args", nargs=argparse.REMAINDER)
    return p


def _load_mesh(args, say=None):
    from modalfem.errors import InputError

    name = args.mesh
    from modalfem.mesh.solid import is_surface_file, load_surface

    if is_surface_file(name):  # STL/OBJ/PLY/OFF: made solid; report printed and stored in source["surface"]
        return load_surface(name, h=args.h, unit_scale=args.unit_scale, progress=say,
                            others={o: getattr(args, o) for o in ("size", "cells", "length", "radius")})
    if name in GENERATOR_NAMES:
        from modalfem.mesh import GENERATORS

        kw: dict = {}
        allowed = {
            "box": ("size", "cells"),
            "plate": ("size", "cells"),
            "rod": ("length", "radius", "h"),
            "tuning_fork": ("h",),
            "bell": ("h",),
        }[name]
        for opt in ("size", "cells", "length", "radius", "h"):
            val = getattr(args, opt)
            if val is None:
                continue
            if opt not in allowed:
                raise InputError(f"--{opt} does not apply to the {name} generator (it takes: "
                                 f"{', '.join('--' + a for a in allowed)})")
            kw[opt] = tuple(val) if isinstance(val, list) else val
        if args.unit_scale != 1.0:
            raise InputError("--unit-scale applies to mesh files, not to generated bodies (given in metres)")
        return GENERATORS[name](**kw), {"generator": name, "parameters": kw}
    for opt in ("size", "cells", "length", "radius", "h"):
        if getattr(args, opt) is not None:
            raise InputError(f"--{opt} is a generator option; {name!r} is read as a mesh file")
    from modalfem.mesh import read

    return read(name, unit_scale=args.unit_scale), {"file": str(name), "unit_scale": args.unit_scale}


def _material(args):
    from modalfem.errors import MaterialError
    from modalfem.material import MATERIALS, STEEL, Material

    custom = [v is not None for v in (args.E, args.nu, args.rho)]
    if args.material is not None:
        if any(custom):
            raise MaterialError("give either --material or --E/--nu/--rho, not both")
        if args.material not in MATERIALS:
            raise MaterialError(f"unknown material {args.material!r}; presets: {', '.join(sorted(MATERIALS))}")
        return MATERIALS[args.material]
    if any(custom):
        if not all(custom):
            raise MaterialError("a custom material needs all of --E [Pa], --nu and --rho [kg/m^3]")
        return Material(E=args.E, nu=args.nu, rho=args.rho, name="custom")
    return STEEL


def _constraints(args):
    from modalfem.constraints import Fix
    from modalfem.errors import ConstraintError

    fixed: list = [Fix(t) for t in args.fixed]
    for spec in args.roller:
        tag, sep, comps = spec.partition(":")
        if not sep or not tag or not comps:
            raise ConstraintError(f"--roller takes TAG:COMPONENTS such as z0:z, got {spec!r}")
        fixed.append(Fix(tag, components=comps))
    return (fixed or None), {"fixed": list(args.fixed), "roller": list(args.roller)}


class _Progress:
    """Stage lines on stderr for ``modes()``'s ``progress(msg)`` callback and the writing stage.

    Each stage prints ``[elapsed s] msg``. When the stream is a terminal, a background thread redraws
    the current stage's line every ``interval`` seconds with its running time (``\\r``, one line);
    elsewhere (logs, pipes) a stage that runs longer than ``heartbeat`` seconds repeats its line
    with ``still running`` so a log shows the run is alive. ``bar`` shows countable work as a bar.
    With ``quiet`` nothing is printed.
    """

    interval = 0.25
    heartbeat = 15.0

    def __init__(self, *, quiet: bool = False, stream=None, live: bool | None = None):
        self.stream = sys.stderr if stream is None else stream
        self.quiet = quiet
        if live is None:
            try:
                live = bool(self.stream.isatty())
            except (AttributeError, ValueError):
                live = False
        self.live = live and not quiet
        self.t0 = time.perf_counter()
        self._msg: str | None = None
        self._t_stage = self.t0
        self._detail = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._beats = 0

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # a closed stderr must not fail the run
            pass

    def _head(self, t: float) -> str:
        return f"[{t - self.t0:7.2f} s] {self._msg}"

    def _line(self, tail: str) -> str:
        """The live line, cut to the terminal width (a wrapped line could not be redrawn with \\r)."""
        import shutil

        head = self._head(self._t_stage)
        room = shutil.get_terminal_size((100, 24)).columns - 1 - len(tail)
        if len(head) > room:
            head = head[: max(room - 3, 12)] + "..."
        return "\r" + head + tail + "\x1b[K"

    def _draw(self, now: float) -> None:
        tail = f"  {self._detail}" if self._detail else ""
        self._write(self._line(f"{tail}  {now - self._t_stage:.0f} s"))

    def _end_stage(self, now: float) -> None:
        if self._msg is not None and self.live:
            self._write(self._line(f"  {now - self._t_stage:.2f} s") + "\n")
        self._msg, self._detail, self._beats = None, "", 0

    def __call__(self, msg: str) -> None:
        """Start stage ``msg`` (ends the previous one)."""
        if self.quiet:
            return
        now = time.perf_counter()
        with self._lock:
            self._end_stage(now)
            self._msg, self._t_stage = str(msg), now
            if self.live:
                self._draw(now)
            else:
                self._write(self._head(now) + "\n")
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="modalfem-progress", daemon=True)
            self._thread.start()

    def bar(self, done: int, total: int, what: str = "") -> None:
        """Countable progress of the current stage: ``done`` of ``total`` (``what``: the item at hand)."""
        if self.quiet or self._msg is None:
            return
        width = 20
        fill = int(round(width * done / max(total, 1)))
        with self._lock:
            self._detail = f"[{'#' * fill}{'.' * (width - fill)}] {done}/{total} {what}".rstrip()
            if self.live:
                self._draw(time.perf_counter())
            else:
                self._write(f"[{time.perf_counter() - self.t0:7.2f} s]   {done}/{total} {what}".rstrip() + "\n")

    def done(self, msg: str) -> None:
        """End the current stage and print ``msg`` as a plain line."""
        if self.quiet:
            return
        now = time.perf_counter()
        with self._lock:
            self._end_stage(now)
            self._write(f"[{now - self.t0:7.2f} s] {msg}\n")

    def close(self) -> None:
        """Stop the background thread and end the current line."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if not self.quiet:
            with self._lock:
                self._end_stage(time.perf_counter())

    def _run(self) -> None:
        wait = self.interval if self.live else 1.0
        while not self._stop.wait(wait):
            now = time.perf_counter()
            with self._lock:
                if self._msg is None:
                    continue
                if self.live:
                    self._draw(now)
                elif now - self._t_stage >= self.heartbeat * (self._beats + 1):
                    self._beats += 1
                    self._write(f"{self._head(self._t_stage)} (still running, {now - self._t_stage:.0f} s)\n")


def _run_modes(args, argv) -> int:
    progress = _Progress(quiet=args.quiet)
    try:
        return _modes_command(args, argv, progress)
    finally:
        progress.close()


def _modes_command(args, argv, say: _Progress) -> int:
    import modalfem
    from modalfem.errors import InputError
    from modalfem.output import OutputSet, check_targets, plot_mode_sheet, summary, summary_json, write_modes

    if not isinstance(args.k, int) or args.k < 1:
        raise InputError(f"-k must be an integer >= 1, got {args.k}")
    if args.sheet_modes < 1:
        raise InputError(f"--sheet-modes must be >= 1, got {args.sheet_modes}")
    check_targets(out_dir=args.out, files=tuple(p for p in (args.json, args.save) if p is not None))
    from modalfem.reduction import transfer_cli

    render_surface = transfer_cli.read(args)  # None without --render-surface; read before the solve
    material = _material(args)
    fixed, constraints = _constraints(args)
    say(f"mesh: {args.mesh}")
    t = time.perf_counter()
    mesh, source = _load_mesh(args, say)
    t_mesh = time.perf_counter() - t
    say(f"mesh: {mesh!r}")
    transfer_cli.check(args, render_surface, mesh, say)
    res = modalfem.modes(mesh, material, k=args.k, degree=args.degree, fixed=fixed, backend=args.backend,
                         solver=args.solver, lumped=args.lumped, progress=say)
    outputs = {}
    if args.out is not None:
        outputs = {"sheet": "modes.png", "paraview_vtu": "modes.vtu", "paraview_xdmf": "modes.xdmf",
                   "summary": "modes.json"}
    held = ", ".join([f"fixed {t}" for t in args.fixed] + [f"roller {r}" for r in args.roller]) or "free"
    model = None
    if args.save is not None:  # built (and validated) before anything is written
        from modalfem.model import ModalModel

        prov = {"fixed": None if held == "free" else held, "source": source, "command": ["modalfem", *argv]}
        if render_surface is not None:
            model, render_info = transfer_cli.build(args, render_surface, res, mesh, material, fixed, prov, say)
        else:
            model = ModalModel.from_modes(res, mesh, material, provenance=prov)
        outputs["model"] = str(args.save)
    data = summary(res, mesh=mesh, material=material, source=source, constraints=constraints,
                   timings={"mesh": t_mesh}, outputs=outputs, command=["modalfem", *argv])
    if render_surface is not None:
        data["render_surface"] = render_info
    targets = [str(p) + ("/" if p == args.out else "") for p in (args.out, args.json, args.save) if p is not None]
    t_out = time.perf_counter()
    write_times: dict[str, float] = {}
    with OutputSet() as outs:
        steps = []
        if args.out is not None:
            tmp = outs.folder(args.out)
            body = source.get("generator") or Path(str(source.get("file"))).name
            title = f"{body}, {material.name or 'custom'}, {held}, P{args.degree}"
            count = min(args.sheet_modes, len(res.omega))
            steps += [
                ("modes.vtu", lambda: write_modes(tmp / "modes.vtu", mesh, res)),
                ("modes.xdmf", lambda: write_modes(tmp / "modes.xdmf", mesh, res)),
                ("modes.png", lambda: plot_mode_sheet(tmp / "modes.png", mesh, res, count=count, title=title)),
            ]
        if model is not None:
            model_tmp = outs.file(args.save)
            steps.append((Path(args.save).name, lambda: model.save(model_tmp)))
        json_tmp = outs.file(args.json) if args.json is not None else None
        if steps or json_tmp is not None:
            say(f"writing {', '.join(targets)}")
        for i, (name, step) in enumerate(steps):
            say.bar(i, len(steps) + 1, name)
            t = time.perf_counter()
            step()
            write_times[name] = time.perf_counter() - t
        if steps or json_tmp is not None:
            say.bar(len(steps), len(steps) + 1, "JSON")
        if args.out is not None and (tmp / "modes.h5").exists():
            outputs["paraview_xdmf_data"] = "modes.h5"
        data["timings"]["output"] = time.perf_counter() - t_out
        data["timings"].update({f"output.{k}": v for k, v in write_times.items()})
        data["outputs"] = outputs
        text = summary_json(data)
        for path, target in ((args.out and tmp / "modes.json", Path(str(args.out)) / "modes.json"),
                             (json_tmp, args.json)):
            if path:
                try:
                    path.write_text(text, encoding="utf-8")
                except OSError as exc:
                    raise InputError(f"cannot write {str(target)!r}: {exc.strerror or exc}") from None
        outs.commit()
    if targets:
        parts = ", ".join(f"{k} {v:.2f} s" for k, v in write_times.items())
        say.done(f"wrote {', '.join(targets)} in {time.perf_counter() - t_out:.2f} s" + (f" ({parts})" if parts else "")
                 + f"; the solve took {res.timings['total']:.2f} s")
    say.close()
    cert = res.certificate
    print(f"{'mode':>4}  {'frequency [Hz]':>15}  {'residual':>9}  label")
    for i, (f, lab) in enumerate(zip(res.frequencies_hz, res.labels)):
        r = cert.residuals[i] if i < len(cert.residuals) else float("nan")
        print(f"{i + 1:>4}  {f:15.6g}  {r:9.2e}  {lab}")
    print(f"rigid modes: {res.rigid_mode_count}; certificate {'passed' if cert.passed else 'FAILED'} "
          f"(inertia {cert.inertia_count} below {cert.inertia_shift:.4g} rad^2/s^2, "
          f"orthonormality {cert.orthonormality_error:.1e}); {res.backend} + {res.solver}, "
          f"{res.timings['total']:.2f} s")
    if render_surface is not None:
        transfer_cli.print_report(render_info)
    for what, path in (("json", args.json), ("outputs", args.out), ("model", args.save)):
        if path is not None:
            print(f"{what}: {path}")
    return 0 if cert.passed else 1


@contextlib.contextmanager
def _terminate_as_exit():
    """SIGTERM raises ``SystemExit(143)`` in the main thread, so staged outputs are cleaned up."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise SystemExit(128 + signum)

    try:
        old = signal.signal(signal.SIGTERM, handler)
    except (ValueError, OSError):  # not allowed here (embedded interpreter)
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


@contextlib.contextmanager
def _jit_verbosity(verbose: bool):
    """``--verbose``: let the FEniCSx JIT compiler's log through (``modalfem.backends.fenicsx.VERBOSE``)."""
    from modalfem.backends import fenicsx

    old = fenicsx.VERBOSE
    fenicsx.VERBOSE = bool(verbose) or old
    try:
        yield
    finally:
        fenicsx.VERBOSE = old


@contextlib.contextmanager
def _one_line_warnings(debug: bool):
    """Python warnings (a mechanism, a body size that suggests the wrong unit, ...) as one stderr line
    ``modalfem: warning: ...`` instead of Python's file:line plus source-line format (kept with --debug)."""
    if debug:
        yield
        return
    previous = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"modalfem: warning: {str(message).splitlines()[0]}", file=sys.stderr)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = previous


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 1 certificate failed, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    from modalfem.errors import ModalfemError

    debug = "--debug" in argv
    try:
        if argv[:1] == ["bench"]:
            from modalfem.bench.cli import main as bench_main

            return int(bench_main(argv[1:]))
        if argv[:1] == ["view"]:
            from modalfem.view.cli import main as view_main

            return int(view_main(argv[1:]))
        if argv[:1] in (["run"], ["plan"]):
            from modalfem.scene.cli import plan_main, run_main

            with _terminate_as_exit(), _one_line_warnings(debug):
                return int((run_main if argv[0] == "run" else plan_main)([a for a in argv[1:] if a != "--debug"]))
        args = build_parser().parse_args(argv)
        if args.version:
            import modalfem

            print(f"modalfem {modalfem.__version__}")
            return 0
        if args.command == "export":
            from modalfem.cli_export import run as export_run

            with _terminate_as_exit(), _one_line_warnings(debug):
                return export_run(args, argv)
        if args.command != "modes":
            build_parser().print_help(sys.stderr)
            return 2
        with _terminate_as_exit(), _jit_verbosity(args.verbose), _one_line_warnings(debug):
            return _run_modes(args, argv)
    except _ArgumentError as exc:
        print(f"modalfem: error: {exc}", file=sys.stderr)
        return 2
    except ModalfemError as exc:
        print(f"modalfem: error: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("modalfem: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if debug:
            raise
        print(f"modalfem: error: unexpected {type(exc).__name__}: {exc} (rerun with --debug for the traceback)",
              file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
