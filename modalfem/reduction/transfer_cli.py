"""Command-line glue of ``modalfem modes ... --render-surface FINE --save MODEL [--check-transfer [REF]]``.

``modalfem.cli`` registers the options with ``add_arguments`` and calls ``read``, ``build`` and
``print_report`` (``modalfem.reduction.transfer`` does the work). The surface file is read before
the solve, so a bad file fails at once; the model is built before anything is written (the outputs
stay all-or-nothing).
"""

from __future__ import annotations

from pathlib import Path

from modalfem.errors import InputError

__all__ = ["add_arguments", "build", "check", "print_report", "read"]


def add_arguments(parser) -> None:
    """The ``render surface`` option group of ``modalfem modes``."""
    r = parser.add_argument_group("render surface (coarse physics, fine surface; needs --save)")
    r.add_argument("--render-surface", type=Path, metavar="SURFACE",
                   help="triangle surface (.obj, .stl, .ply, .off) the model file carries instead of the "
                        "coarse boundary: modes interpolated in the coarse elements, mass properties and "
                        "rotation coupling from the volume mesh")
    r.add_argument("--render-unit-scale", type=float, default=None, metavar="FACTOR",
                   help="factor turning the surface file's coordinates into metres (default: --unit-scale)")
    r.add_argument("--max-transfer-distance", type=float, default=None, metavar="METRES",
                   help="refuse surface vertices farther than this from the coarse mesh's surface [m] "
                        "(default: half the median coarse boundary edge)")
    r.add_argument("--check-transfer", nargs="?", const="refine", default=None, metavar="REF_MESH",
                   help="compare the transferred modes (frequency error, MAC on the surface) with a finer "
                        "solve: on REF_MESH (a tet mesh of the fine surface) or, without it, on the coarse "
                        "mesh refined once (each tetrahedron split into 8)")


def read(args):
    """The ``RenderSurface`` of ``args.render_surface`` (None without it); checks the option combination."""
    if args.render_surface is None:
        for opt, val in (("--check-transfer", args.check_transfer), ("--render-unit-scale", args.render_unit_scale),
                         ("--max-transfer-distance", args.max_transfer_distance)):
            if val is not None:
                raise InputError(f"{opt} needs --render-surface SURFACE")
        return None
    if args.save is None:
        raise InputError("--render-surface needs --save MODEL (the model file that carries the surface)")
    from modalfem.reduction.render_surface import read_surface

    scale = args.unit_scale if args.render_unit_scale is None else args.render_unit_scale
    if not (scale > 0 and scale < float("inf")):
        raise InputError(f"--render-unit-scale must be a finite factor > 0 (file units to metres), got {scale!r}")
    if args.max_transfer_distance is not None and not (0 < args.max_transfer_distance < float("inf")):
        raise InputError(f"--max-transfer-distance must be a finite length > 0 [m], got {args.max_transfer_distance!r}")
    return read_surface(args.render_surface, unit_scale=scale)


def check(args, surface, mesh, say) -> None:
    """Refuse a surface too far from the coarse mesh before the solve (no-op without a surface)."""
    if surface is None:
        return
    from modalfem.reduction.transfer import surface_distances

    say(f"render surface: distances of {surface.vertex_count} vertices to the coarse mesh")
    surface_distances(mesh, surface.vertices, max_distance=args.max_transfer_distance)


def build(args, surface, res, mesh, material, fixed, provenance: dict, say):
    """``(model, info)``: the model on the fine surface and a JSON-ready record of the transfer (and check)."""
    from modalfem.reduction.transfer import render_surface_model
    from modalfem.reduction.transfer_check import check_transfer

    say(f"render surface: {surface.vertex_count} vertices, {len(surface.triangles)} triangles")
    model, report = render_surface_model(res, mesh, material, surface, max_distance=args.max_transfer_distance,
                                         provenance=provenance)
    info = {"file": str(args.render_surface), "sha256": surface.fingerprint, "vertex_count": surface.vertex_count,
            "triangle_count": len(surface.triangles), "transfer": report.as_dict(), "line": report.line()}
    if args.check_transfer is not None:
        ref_mesh = None
        if args.check_transfer != "refine":
            from modalfem.mesh import read as read_mesh

            say(f"check transfer: reading {args.check_transfer}")
            ref_mesh = read_mesh(args.check_transfer, unit_scale=args.unit_scale)
        check = check_transfer(res, mesh, material, surface, reference_mesh=ref_mesh, fixed=fixed,
                               backend=args.backend, solver=args.solver, lumped=args.lumped,
                               max_distance=args.max_transfer_distance, progress=say)
        info["check"] = check.as_dict()
    return model, info


def print_report(info) -> None:
    """The transfer lines under the mode table (stdout)."""
    if not info:
        return
    print(f"render surface: {info['file']}: {info['line']}")
    check = info.get("check")
    if check:
        print(f"transfer check against a finer solve ({check['reference']}, {check['reference_dof_count']} DOFs, "
              f"{check['seconds']:.1f} s); MAC on the fine surface, area-weighted:")
        print(f"{'mode':>4}  {'coarse [Hz]':>12}  {'reference [Hz]':>14}  {'error':>8}  {'MAC':>9}")
        for i, (f, fr, e, m) in enumerate(zip(check["frequencies_hz"], check["reference_frequencies_hz"],
                                              check["frequency_error"], check["mac"])):
            print(f"{i + 1:>4}  {f:12.6g}  {fr:14.6g}  {100 * e:+7.3f}%  {m:9.6f}")
        print(f"max |frequency error| {100 * check['max_frequency_error']:.3f} %, min MAC {check['min_mac']:.6f}")
