"""``modalfem`` command line (also ``python -m modalfem``).

Subcommands:
  * ``modalfem modes MESH_OR_GENERATOR ...``: lowest modes of a mesh file (.msh, .vtu, .xdmf, ...)
    or a generated body (box, plate, rod, tuning_fork, bell); writes a JSON summary and, with
    ``--out DIR``, mode shapes for ParaView (modes.vtu, modes.xdmf) and a PNG sheet (modes.png);
    with ``--save MODEL.npz``, a ``ModalModel`` file for the numpy-only runtime (``modalfem.model``).
  * ``modalfem bench modes ...``: the cantilever-ladder benchmark (``modalfem.bench.cli``).

Every ``ModalfemError`` (bad material, unknown tag, malformed mesh, k too large, ...) becomes one
line ``modalfem: error: ...`` on stderr and exit code 2; no output file is written unless the whole
run succeeded (outputs are staged in a temporary directory and moved into place at the end).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
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
    g.add_argument("--h", type=float, help="target element size [m] (rod, tuning_fork, bell)")
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
    o.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")

    b = sub.add_parser("bench", help="benchmarks that write BENCHMARKS.md (see `modalfem bench modes -h`)",
                       add_help=False)
    b.add_argument("args", nargs=argparse.REMAINDER)
    return p


def _load_mesh(args):
    from modalfem.errors import InputError

    name = args.mesh
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


def _stage_model(model, target: Path) -> Path:
    """Save ``model`` under a hidden temporary name next to ``target`` (moved into place at the end)."""
    import tempfile

    from modalfem.errors import InputError

    target = Path(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise InputError(f"cannot write {str(target)!r}: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        model.save(tmp)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return Path(tmp)


def _run_modes(args, argv) -> int:
    import modalfem
    from modalfem.errors import InputError
    from modalfem.output import (
        check_targets,
        plot_mode_sheet,
        staged_dir,
        summary,
        summary_json,
        write_modes,
        write_text_atomic,
    )

    t0 = time.perf_counter()

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:7.2f} s] {msg}", file=sys.stderr, flush=True)

    if not isinstance(args.k, int) or args.k < 1:
        raise InputError(f"-k must be an integer >= 1, got {args.k}")
    if args.sheet_modes < 1:
        raise InputError(f"--sheet-modes must be >= 1, got {args.sheet_modes}")
    check_targets(out_dir=args.out, files=tuple(p for p in (args.json, args.save) if p is not None))
    material = _material(args)
    fixed, constraints = _constraints(args)
    say(f"mesh: {args.mesh}")
    t = time.perf_counter()
    mesh, source = _load_mesh(args)
    t_mesh = time.perf_counter() - t
    say(f"mesh: {mesh!r}")
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

        model = ModalModel.from_modes(res, mesh, material, provenance={
            "fixed": None if held == "free" else held, "source": source, "command": ["modalfem", *argv]})
        outputs["model"] = str(args.save)
    t = time.perf_counter()
    data = summary(res, mesh=mesh, material=material, source=source, constraints=constraints,
                   timings={"mesh": t_mesh}, outputs=outputs, command=["modalfem", *argv])
    staged_model = _stage_model(model, args.save) if model is not None else None
    try:
        if args.out is not None:
            say(f"writing {args.out}/")
            with staged_dir(args.out) as tmp:
                write_modes(tmp / "modes.vtu", mesh, res)
                write_modes(tmp / "modes.xdmf", mesh, res)
                body = source.get("generator") or Path(str(source.get("file"))).name
                title = f"{body}, {material.name or 'custom'}, {held}, P{args.degree}"
                plot_mode_sheet(tmp / "modes.png", mesh, res, count=min(args.sheet_modes, len(res.omega)),
                                title=title)
                data["timings"]["output"] = time.perf_counter() - t
                (tmp / "modes.json").write_text(summary_json(data), encoding="utf-8")
        if args.json is not None:
            data["timings"]["output"] = time.perf_counter() - t
            write_text_atomic(args.json, summary_json(data))
        if staged_model is not None:
            say(f"writing {args.save}")
            try:
                os.replace(staged_model, args.save)
            except OSError as exc:
                raise InputError(f"cannot write {str(args.save)!r}: {exc.strerror or exc}") from None
            staged_model = None
    finally:
        if staged_model is not None:
            with contextlib.suppress(OSError):
                os.unlink(staged_model)
    cert = res.certificate
    print(f"{'mode':>4}  {'frequency [Hz]':>15}  {'residual':>9}  label")
    for i, (f, lab) in enumerate(zip(res.frequencies_hz, res.labels)):
        r = cert.residuals[i] if i < len(cert.residuals) else float("nan")
        print(f"{i + 1:>4}  {f:15.6g}  {r:9.2e}  {lab}")
    print(f"rigid modes: {res.rigid_mode_count}; certificate {'passed' if cert.passed else 'FAILED'} "
          f"(inertia {cert.inertia_count} below {cert.inertia_shift:.4g} rad^2/s^2, "
          f"orthonormality {cert.orthonormality_error:.1e}); {res.backend} + {res.solver}, "
          f"{res.timings['total']:.2f} s")
    for what, path in (("json", args.json), ("outputs", args.out), ("model", args.save)):
        if path is not None:
            print(f"{what}: {path}")
    return 0 if cert.passed else 1


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 1 certificate failed, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    from modalfem.errors import ModalfemError

    debug = "--debug" in argv
    try:
        if argv[:1] == ["bench"]:
            from modalfem.bench.cli import main as bench_main

            return int(bench_main(argv[1:]))
        args = build_parser().parse_args(argv)
        if args.version:
            import modalfem

            print(f"modalfem {modalfem.__version__}")
            return 0
        if args.command != "modes":
            build_parser().print_help(sys.stderr)
            return 2
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
