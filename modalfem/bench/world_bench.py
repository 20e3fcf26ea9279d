"""``modalfem bench world``: what a ``World`` step costs, side by side in one run (one process, the thread setting
of the machine unless ``MODALFEM_THREADS`` says otherwise).

Cases:

* ``free``: one free modal body (a steel bar, ~1k surface vertices, 12 modes): ``ModalSolver.step`` alone against
  ``World.step`` of a world holding only that body (the world's overhead: the issue asks for the free step's rate);
* ``stack``: modal bars dropped on each other onto the ground (the compiled solid-contact solve between bodies plus
  each bar's own ground contact), steps/s and contacts per step;
* ``tets``: a stiff tet cube landing on a soft tet foam block on the ground (a tet group's joint step),
  steps/s, the tet step's ms per step, contacts per step;
* ``mixed``: the tutorial scene: a brass bell dropped onto a soft tet block on the ground, a cloth falling over
  both (every stage of the plan), steps/s and each stage's share.

Every scene is checked with the exact triangle-triangle test at its end (0 intersecting pairs, reported).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import shlex
import sys
import time

__all__ = ["SECTION", "command", "measure", "render"]

SECTION = "## World: one step over modal, tet and cloth bodies"


def _bar(cells=(12, 6, 3), k=12):
    import modalfem
    from modalfem.mesh import box
    from modalfem.model import ModalModel

    mesh = box(size=(0.2, 0.1, 0.05), cells=cells)
    res = modalfem.modes(mesh, modalfem.STEEL, k=k, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))


def _rate(fn, seconds: float) -> float:
    fn()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        fn()
        n += 1
    return n / (time.perf_counter() - t0)


def measure(*, seconds: float = 2.0, quick: bool = False) -> list[dict]:
    """Run the cases; returns one dict per case (see ``render``)."""
    from modalfem import runtime as rt
    from modalfem import world as mw
    from modalfem.effects import Contact, Gravity

    out = []
    model = _bar((6, 3, 2) if quick else (12, 6, 3))
    body = rt.ModalBody(model)
    solver = rt.ModalSolver(body)
    s, s2 = solver.state(), solver.state()
    w = mw.World(bodies=[mw.Modal(model, name="bar")])
    ws = w.state()
    # interleaved windows, the best of each: on a shared machine a single window of either can land on a busy core
    free = world = 0.0
    for _ in range(5):
        free = max(free, _rate(lambda: solver.step(s, s, None, None, 1e-3), seconds / 5))
        world = max(world, _rate(lambda: w.step(ws, ws, None, 1e-3), seconds / 5))
    out.append({"case": "free", "what": f"1 modal bar ({body.vertex_count} vertices, {body.mode_count} modes)",
                "solver": free, "world": world})

    n_bars = 3 if quick else 6
    steps = 200 if quick else 600
    for _run in ("warm-up", "timed"):  # the first run only compiles (or loads) every kernel the scene reaches, untimed
        bars = [mw.Modal(model, name=f"bar{i}", position=(0.02 * (i % 2), 0.01 * (i % 3), 0.03 + 0.06 * i))
                for i in range(n_bars)]
        w = mw.World(bodies=bars, obstacles=[mw.Ground(0.0)],
                     effects=[Gravity(), Contact(restitution=0.2, friction=0.5)])
        ws = w.state()
        contacts, t0 = 0, time.perf_counter()
        for _ in range(steps):
            r = w.step(ws, ws, None, 1e-3)
            contacts += r.contacts.get("solid", 0)
        dt_wall = time.perf_counter() - t0
    out.append({"case": "stack", "what": f"{n_bars} modal bars dropped on each other and the ground, dt = 1 ms",
                "rate": steps / dt_wall, "contacts": contacts / steps, "intersections": len(w.intersections(ws))})

    from modalfem import tet
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel
    from modalfem.effects import Damping, SelfCollision
    from modalfem.material import Material
    from modalfem.mesh import box

    foam = tet.tet_model(box(size=(0.16, 0.16, 0.05), cells=(4, 4, 2)), Material(E=3e4, nu=0.3, rho=60.0))
    _tets(foam, 0.1 if quick else 0.3)  # untimed: compiles (or loads) every kernel the scene reaches
    out.append(_tets(foam, 0.1 if quick else 0.3))
    knit = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)
    nc = 10 if quick else 16
    cloth = ClothModel(grid((0.3, 0.3), (nc, nc), origin=(-0.07, -0.07, 0.0)), knit, mass_damping=0.2)
    small = _bar((4, 2, 2), k=8)
    for _run in ("warm-up", "timed"):  # the first run only compiles (or loads) every kernel the scene reaches, untimed
        w = mw.World(bodies=[mw.Modal(small, name="bar", position=(0.08, 0.08, 0.09)), mw.Tet(foam, name="block"),
                             mw.Cloth(cloth, name="cloth", x0=cloth.mesh.points + (0.0, 0.0, 0.16))],
                     obstacles=[mw.Ground(0.0)],
                     effects=[Gravity(), Contact(restitution=0.2, friction=0.5), Damping(alpha=1.0, bodies=["block"]),
                              SelfCollision(bodies=["cloth"])])
        ws = w.state()
        steps = 100 if quick else 400
        stage: dict = {}
        t0 = time.perf_counter()
        for _ in range(steps):
            r = w.step(ws, ws, None, 1e-3)
            for k, v in r.seconds.items():
                stage[k] = stage.get(k, 0.0) + v
        dt_wall = time.perf_counter() - t0
    out.append({"case": "mixed", "what": f"a steel bar on a soft tet block ({foam.point_count} vertices) on the "
                f"ground, a {nc}x{nc} cloth over both, dt = 1 ms",
                "rate": steps / dt_wall, "stages": {k: 1e3 * v / steps for k, v in stage.items()},
                "intersections": len(w.intersections(ws))})
    return out


def _tets(foam, duration: float) -> dict:
    """The ``tets`` case: a 6 cm tet cube (1 MPa) landing on the soft foam block (30 kPa) on the ground, the two
    stepped as one tet group (``world.tetgroup``) while they may touch, dt = 1 ms for ``duration`` [s]."""
    from modalfem import tet
    from modalfem import world as mw
    from modalfem.effects import Contact, Gravity
    from modalfem.material import Material
    from modalfem.mesh import box

    cube = tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))
    w = mw.World(bodies=[mw.Tet(cube, name="cube", position=(0.05, 0.05, 0.07)), mw.Tet(foam, name="block")],
                 obstacles=[mw.Ground(0.0)], effects=[Gravity(), Contact(restitution=0.2, friction=0.5)])
    ws = w.state()
    steps = round(duration / 1e-3)
    tet_s, contacts, t0 = 0.0, 0, time.perf_counter()
    for _ in range(steps):
        r = w.step(ws, ws, None, 1e-3)
        tet_s += r.seconds.get("tet step", 0.0)
        contacts += r.contacts.get("tet", 0)
    dt_wall = time.perf_counter() - t0
    return {"case": "tets", "what": f"a 6 cm tet cube ({cube.point_count} vertices, 1 MPa) landing on a soft tet "
            f"foam block ({foam.point_count} vertices, 30 kPa) on the ground, dt = 1 ms, {duration:g} s",
            "rate": steps / dt_wall, "tet_ms": 1e3 * tet_s / steps, "contacts": contacts / steps,
            "intersections": len(w.intersections(ws))}


def render(cases: list[dict], *, command: str, date: str, machine: str, load: tuple) -> str:
    """The markdown section."""
    head = (f"`{command}` ({date}; {machine}; load average (1 min) {load[0]:.2f} before, {load[1]:.2f} after). "
            "Side by side in one run; each scene below the table is run once untimed first (numba compiles or loads "
            "every kernel it reaches), then timed on a fresh world.")
    lines = [SECTION, "", head, ""]
    for c in cases:
        if c["case"] == "free":
            lines += ["| case | ModalSolver.step [steps/s] | World.step [steps/s] | world / solver |", "|---|---|---|---|",
                      f"| {c['what']} | {c['solver']:,.0f} | {c['world']:,.0f} | {c['world'] / c['solver']:.2f}x |", ""]
        elif c["case"] == "stack":
            lines.append(f"- {c['what']}: {c['rate']:,.0f} steps/s, {c['contacts']:.0f} contacts per step in the "
                         f"solid solve, {c['intersections']} intersecting triangle pairs at the end.")
        elif c["case"] == "tets":
            lines.append(f"- {c['what']}: {c['rate']:,.1f} steps/s, tet step (the joint step of the tet group) "
                         f"{c['tet_ms']:.2f} ms per step, {c['contacts']:.0f} tet contacts per step, "
                         f"{c['intersections']} intersecting triangle pairs at the end.")
        else:
            share = ", ".join(f"{k} {v:.2f} ms" for k, v in sorted(c["stages"].items(), key=lambda kv: -kv[1]))
            lines.append(f"- {c['what']}: {c['rate']:,.1f} steps/s ({share} per step), {c['intersections']} "
                         "intersecting triangle pairs at the end.")
    return "\n".join(lines) + "\n"


def command(argv: list[str]) -> int:
    """``modalfem bench world [--out BENCHMARKS.md] [--seconds S] [--quick]``."""
    ap = argparse.ArgumentParser(prog="modalfem bench world", description="World step costs.")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose world section is replaced")
    ap.add_argument("--seconds", type=float, default=2.0, help="measuring window of the free-step rates [s]")
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    a = ap.parse_args(argv)
    from modalfem.bench.cli import _machine, update_section

    load0 = os.getloadavg()[0]
    cases = measure(seconds=a.seconds, quick=a.quick)
    cmd = "python -m modalfem bench world" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = render(cases, command=cmd, date=date, machine=_machine(), load=(load0, os.getloadavg()[0]))
    print(section)
    update_section(a.out, section)
    return 0


if __name__ == "__main__":
    sys.exit(command(sys.argv[1:]))
