"""``modalfem bench record``: cost per frame of each output writer of ``modalfem run`` (``modalfem.scene.record``).

The world of ``tutorials/world.py`` (a 16-mode brass bell, a foam tet block, a 16 x 16 cloth over both, the
ground; ``--quick``: a coarse steel bar, a small block and a 6 x 6 cloth) is simulated once with a state kept
every 1/30 s; then each writer alone replays those states into a fresh folder: ParaView (.vtu per body per
frame + scene.pvd), the GIF and the MP4 preview at 640 x 360, the glTF animation (frames kept + scene.glb at the
end) and the sound (WAV files at the end). The peer, in the same run: matplotlib's painter
(``modalfem.world.render.frame_sheet``, one 360 x 360 panel per frame), the renderer the preview would otherwise
use. Wall time per frame [ms], fastest of ``--repeat`` replays; ``finish`` is counted in.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["SECTION", "command", "measure", "render"]

SECTION = "## Scene outputs: cost per frame of each writer"


def _tutorial_world(quick: bool):
    import modalfem
    from modalfem import tet
    from modalfem import world as mw
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel
    from modalfem.effects import Contact, Damping, Gravity, SelfCollision, Sound
    from modalfem.material import Material
    from modalfem.mesh import bell, box
    from modalfem.model import ModalModel

    if quick:
        mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
        res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
        solid = ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))
        z, cells, n = 0.1, (2, 2, 1), 5
    else:
        brass = Material(E=110e9, nu=0.34, rho=8500.0)
        mesh = bell(diameter=0.07, height=0.056, thickness=0.0021, h=0.01)
        res = modalfem.modes(mesh, brass, k=16, degree=2, backend="skfem", solver="scipy")
        solid = ModalModel.from_modes(res, mesh, brass, damping=(2.0, 1e-9))
        z, cells, n = 0.07, (4, 4, 2), 16
    foam = tet.tet_model(box(size=(0.16, 0.16, 0.05), cells=cells), Material(E=3e4, nu=0.3, rho=60.0))
    knit = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)
    cloth = ClothModel(grid((0.3, 0.3), (n, n), origin=(-0.07, -0.07, 0.0)), knit, mass_damping=0.2)
    name = "bar" if quick else "bell"
    return mw.World(
        bodies=[mw.Modal(solid, name=name, position=(0.08, 0.08, z + float(solid.center_of_mass[2]))),
                mw.Tet(foam, name="block"), mw.Cloth(cloth, name="cloth", x0=cloth.mesh.points + (0.0, 0.0, 0.16))],
        obstacles=[mw.Ground(0.0)],
        effects=[Gravity(), Contact(restitution=0.2, friction=0.5, thickness=2e-3), Damping(alpha=1.0, bodies=["block"]),
                 SelfCollision(bodies=["cloth"]), Sound(bodies=[name], listener=(1.0, -1.0, 0.5))]), name


def _states(world, name: str, seconds: float, frame_rate: float, dt: float = 1e-3) -> list:
    """States every 1 / frame_rate s over ``seconds``, with a strike on the modal body half way."""
    s = world.state()
    every = round(1.0 / (frame_rate * dt))
    out = []
    body = world._modal[name]["body"]
    top = int(np.argmax(body.rest[:, 2]))
    steps = round(seconds / dt)
    for i in range(steps + 1):
        if i % every == 0:
            out.append(s.copy())
        if i == steps:
            break
        c = None
        if i == steps // 2:
            c = world.control().add_impulse(name, top, -5e-3 * body.normals(body.positions(s[name]))[top])
        world.step(s, s, c, dt)
    return out


def _replay(world, states, repeat: int, **options) -> tuple[float, float, int]:
    """Fastest wall time per frame [ms] of a Recorder with ``options`` over ``states`` (finish included), the
    frame cost without finish [ms] and the bytes written."""
    from modalfem.scene.record import Recorder

    best, best_frames, size = np.inf, np.inf, 0
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as d:
            rec = Recorder(world, Path(d), **options)
            t0 = time.perf_counter()
            for s in states:
                rec.frame(s)
            t1 = time.perf_counter()
            rec.finish()
            t2 = time.perf_counter()
            best = min(best, (t2 - t0) / len(states))
            best_frames = min(best_frames, (t1 - t0) / len(states))
            size = sum(p.stat().st_size for p in Path(d).rglob("*") if p.is_file())
    return 1e3 * best, 1e3 * best_frames, size


def measure(*, quick: bool = False, repeat: int = 3) -> dict:
    """Per-writer costs (see the module docstring)."""
    world, name = _tutorial_world(quick)
    seconds = 0.2 if quick else 0.7
    states = _states(world, name, seconds, 30.0)
    off = {"paraview": False, "video": None, "gltf": False, "sound": False}
    cases = {}
    rows = [("ParaView (.vtu per body + scene.pvd)", {"paraview": True}),
            ("GIF preview 640 x 360", {"video": "gif"}),
            ("glTF animation (scene.glb)", {"gltf": True}),
            ("sound (WAV per body + mix)", {"sound": True})]
    from modalfem.errors import InputError
    from modalfem.scene.record_video import ffmpeg_exe

    try:
        ffmpeg_exe()
        rows.insert(2, ("MP4 preview 640 x 360 (drawn at 1280 x 720, averaged)", {"video": "mp4"}))
    except InputError:
        pass  # no imageio-ffmpeg: the MP4 row is left out and the section says why
    _replay(world, states[:2], 1, **{**off, **rows[1][1]})  # warm the compiled rasteriser (disk cache)
    for label, opt in rows:
        cases[label] = _replay(world, states, repeat, **{**off, **opt})
    from modalfem.world.render import frame_sheet

    best = np.inf
    with tempfile.TemporaryDirectory() as d:
        for _ in range(repeat):
            t0 = time.perf_counter()
            for k, s in enumerate(states):
                frame_sheet(world, [s], Path(d) / f"f{k}.png", size=3.6, dpi=100)
            best = min(best, (time.perf_counter() - t0) / len(states))
    surfaces = {b.name: world.surface(states[0], b.name) for b in world.bodies}
    return {"cases": cases, "peer": 1e3 * best, "frames": len(states), "seconds": seconds,
            "triangles": {n: len(t) for n, (_, t) in surfaces.items()},
            "vertices": {n: len(x) for n, (x, _) in surfaces.items()}}


def render(result: dict, *, command: str, date: str, machine: str, load: tuple) -> str:
    """The markdown section."""
    tri = ", ".join(f"{n} {result['vertices'][n]} vertices / {t} triangles" for n, t in result["triangles"].items())
    lines = [SECTION, "",
             (f"`{command}` ({date}; {machine}; load average (1 min) {load[0]:.2f} before, {load[1]:.2f} after). "
              f"{result['frames']} frames (30 frames/s over {result['seconds']:g} s of the world of tutorials/world.py: "
              f"{tri}, the ground), each writer alone, fastest of the replays; side by side in one run."), "",
             "| writer | ms/frame (finish included) | ms/frame (frames only) | bytes/frame |", "|---|---|---|---|"]
    gif = None
    for label, (total, frames, size) in result["cases"].items():
        lines.append(f"| {label} | {total:.2f} | {frames:.2f} | {size / result['frames']:,.0f} |")
        if label.startswith("GIF"):
            gif = total
    lines.append(f"| peer: matplotlib painter (world.render.frame_sheet, one 360 x 360 PNG) | {result['peer']:.2f} "
                 "| | |")
    lines.append("")
    if gif:
        lines.append(f"- The GIF preview costs {gif / result['peer']:.2f}x the matplotlib painter's time per frame "
                     f"({result['peer'] / gif:.1f}x faster), with per-pixel depth instead of a per-triangle sort.")
    if not any(k.startswith("MP4") for k in result["cases"]):
        lines.append("- MP4 not measured: imageio-ffmpeg is not installed (pip install imageio-ffmpeg).")
    return "\n".join(lines) + "\n"


def command(argv: list[str]) -> int:
    """``modalfem bench record [--out BENCHMARKS.md] [--repeat N] [--quick]``."""
    ap = argparse.ArgumentParser(prog="modalfem bench record", description="Cost per frame of the run's writers.")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose section is replaced")
    ap.add_argument("--repeat", type=int, default=3, help="replays per writer (the fastest counts)")
    ap.add_argument("--quick", action="store_true", help="small world (smoke test)")
    a = ap.parse_args(argv)
    from modalfem.bench.cli import _machine, update_section

    load0 = os.getloadavg()[0]
    result = measure(quick=a.quick, repeat=max(1, a.repeat))
    cmd = "python -m modalfem bench record" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = render(result, command=cmd, date=date, machine=_machine(), load=(load0, os.getloadavg()[0]))
    print(section)
    update_section(a.out, section)
    return 0


if __name__ == "__main__":
    sys.exit(command(sys.argv[1:]))
