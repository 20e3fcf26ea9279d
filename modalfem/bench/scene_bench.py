"""``modalfem bench scene``: what each effect of a scene costs per step (an ablation), side by side in one run.

For every example scene (or the scene files given), the scene runs with all its effects, then once without each
effect kind in turn (every ``[[effects]]`` entry of that kind removed; a gust event goes with the wind it adds
to), and finally with all effects again: the two all-effects runs bracket the others, and their difference is
the noise of the measurement. Each case runs in a fresh child process (its own imports, JIT caches loaded the
same way): the world is built as ``modalfem run`` builds it (modal modes from the model cache), then ``steps``
steps run from t = 0 with the scene's strikes applied as ``modalfem run`` applies them, outputs off (no
recorder, no per-frame checks: only ``World.step``), ``repeats`` times from copies of the start state; the
fastest repetition counts (the first one compiles or loads the kernels of every code path the scene reaches,
e.g. contact kernels first called at the first impact, which warm-up steps before it would miss).

Reported per case: steps/s, ms per step, the step plan's stages (with the effects each evaluates) and which
stages disappeared without the effect (a stage whose only user was that effect is not compiled into the plan
at all), and the effect's cost = ms/step with all effects - ms/step without it, also as % of the full step.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["SECTION", "command", "measure", "render", "run_case"]

SECTION = "## Scenes: what each effect costs"
ALL = "all effects"


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------- child side
def _ablated(scene, drop: str | None):
    """``scene`` without the effects of kind ``drop`` (and, for wind, without its gust events)."""
    if drop is None:
        return scene
    from modalfem.scene.schema import Scene

    d = scene.model_dump(by_alias=True)
    d["effects"] = [e for e in d["effects"] if e["kind"] != drop]
    if drop == "wind":
        d["events"] = [e for e in d["events"] if e["kind"] != "gust"]
    return Scene.model_validate(d)


def run_case(path, *, drop: str | None, steps: int, repeats: int) -> dict:
    """Build scene file ``path`` without effect kind ``drop`` and time ``steps`` world steps (this process),
    ``repeats`` times from copies of the start state.

    Returns:
        dict: ``steps``, ``wall`` [s] (fastest repetition), ``walls`` [s] (all), ``stages`` (stage name -> total
        [s], of the fastest), ``plan`` (stage strings), ``stage_names``, ``effects`` (kinds left), ``build`` [s],
        ``simulated`` [s].
    """
    from modalfem.scene.build import build_scene
    from modalfem.scene.load import load_scene

    path = Path(path)
    scene, base = load_scene(path)
    scene = _ablated(scene, drop)
    t0 = time.perf_counter()
    built = build_scene(scene, base, label=path.name)
    t_build = time.perf_counter() - t0
    world, dt = built.world, built.dt
    control = world.control()
    steps = min(steps, built.steps)
    runs = []
    for _ in range(max(1, repeats)):
        state, strikes = built.state.copy(), list(built.strikes)
        stages: dict = {}
        t0 = time.perf_counter()
        for _ in range(steps):
            control.clear()
            while strikes and strikes[0][0] < state.time + dt * (1 - 1e-9):
                _, body, vertex, J = strikes.pop(0)
                control.add_impulse(body, vertex, J)
            report = world.step(state, state, control, dt)
            for k, v in report.seconds.items():
                stages[k] = stages.get(k, 0.0) + v
        runs.append((time.perf_counter() - t0, stages, state.time))
    wall, stages, simulated = min(runs, key=lambda r: r[0])
    return {"steps": steps, "wall": wall, "walls": [r[0] for r in runs], "stages": stages,
            "plan": [_stage_text(s) for s in world.plan], "stage_names": [s.name for s in world.plan],
            "effects": sorted({e.kind for e in scene.effects}), "build": t_build, "simulated": simulated}


def _stage_text(stage) -> str:
    return stage.name + (f" [{', '.join(stage.effects)}]" if stage.effects else "")


def _child(argv: list[str]) -> int:
    spec = json.loads(argv[0])
    out = run_case(spec["path"], drop=spec["drop"], steps=spec["steps"], repeats=spec["repeats"])
    print(json.dumps(out))
    return 0


# ---------------------------------------------------------------------------------------------- parent side
def _in_child(path: Path, drop: str | None, steps: int, repeats: int, timeout: float) -> dict:
    spec = json.dumps({"path": str(path), "drop": drop, "steps": steps, "repeats": repeats})
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "modalfem.bench.scene_bench", "--child", spec],
                           capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    if r.returncode != 0:
        lines = (r.stderr or r.stdout).strip().splitlines()
        return {"error": lines[-1] if lines else f"exit code {r.returncode}"}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["process"] = time.perf_counter() - t0
    return out


def scene_effects(path) -> list[str]:
    """The effect kinds of scene file ``path``, in the order they first appear."""
    from modalfem.scene.load import load_scene

    scene, _ = load_scene(path)
    kinds: list[str] = []
    for e in scene.effects:
        if e.kind not in kinds:
            kinds.append(e.kind)
    return kinds


def measure(paths, *, steps: int, repeats: int, timeout: float = 1800.0) -> list[dict]:
    """Run the ablation of every scene file in ``paths``; one dict per scene (see ``render``)."""
    out = []
    for path in map(Path, paths):
        kinds = scene_effects(path)
        cases = [(ALL, None)] + [(f"without {k}", k) for k in kinds] + [(ALL, None)]
        results = []
        for i, (label, drop) in enumerate(cases):
            _log(f"[bench scene] {path.stem}: {label} ({i + 1}/{len(cases)}) ...")
            r = _in_child(path, drop, steps, repeats, timeout)
            r.update(case=label, drop=drop)
            if "error" in r:
                _log(f"[bench scene] {path.stem}: {label}: ERROR {r['error']}")
            else:
                reps = ", ".join(f"{1e3 * w / r['steps']:.3f}" for w in r["walls"])
                _log(f"[bench scene] {path.stem}: {label}: {r['steps'] / r['wall']:,.1f} steps/s, "
                     f"{1e3 * r['wall'] / r['steps']:.3f} ms/step (repetitions: {reps} ms/step)")
            results.append(r)
        out.append({"scene": path.stem, "file": str(path), "effects": kinds, "cases": results})
    return out


# ---------------------------------------------------------------------------------------------- table
def _ms(r: dict) -> float | None:
    return None if "error" in r or not r.get("steps") else 1e3 * r["wall"] / r["steps"]


def summarise(scene: dict) -> dict:
    """Baseline (mean of the two all-effects runs), noise (their difference) and per-effect cost [ms/step]."""
    alls = [_ms(r) for r in scene["cases"] if r["drop"] is None]
    alls = [a for a in alls if a is not None]
    base = sum(alls) / len(alls) if alls else None
    noise = abs(alls[0] - alls[-1]) if len(alls) > 1 else None
    full = next((r for r in scene["cases"] if r["drop"] is None and "error" not in r), None)
    rows = []
    for r in scene["cases"]:
        if r["drop"] is None:
            continue
        ms = _ms(r)
        cost = None if ms is None or base is None else base - ms
        gone = [s for s in full["stage_names"] if s not in r.get("stage_names", [])] if full and ms is not None else []
        own = sum(1e3 * full["stages"].get(s, 0.0) / full["steps"] for s in gone) if gone else None
        rows.append({"effect": r["drop"], "ms": ms, "cost": cost, "pct": None if cost is None else 100 * cost / base,
                     "gone": gone, "own": own})
    return {"base": base, "noise": noise, "rows": rows, "full": full}


def _code_version() -> str:
    """``code <commit>`` of the source tree measured (and whether it had uncommitted changes), or ``""``."""
    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "modalfem"], cwd=root, capture_output=True,
                               text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return ""
    if head.returncode != 0:
        return ""
    return f"code {head.stdout.strip()}" + (" with uncommitted changes" if dirty.stdout.strip() else "")


def render(scenes: list[dict], *, command: str, date: str, machine: str, load: tuple, threads: str,
           code: str = "") -> str:
    """The markdown section."""
    lines = [SECTION, "",
             f"`{command}` ({date}; {machine}; load average (1 min) {load[0]:.2f} before, {load[1]:.2f} after; "
             f"{threads}{'; ' + code if code else ''}).", "",
             "Each scene with all its effects, then without each effect kind in turn (a gust goes with its wind), "
             "then with all effects again; every case in a fresh process, the world built as `modalfem run` builds "
             "it, then the same steps from t = 0 with the scene's strikes, outputs off (only `World.step` is timed), "
             "repeated from copies of the start state: the fastest repetition counts (the first compiles or loads "
             "the kernels of every code path the scene reaches). Removing an effect changes the motion too (without "
             "gravity nothing lands, so no contacts are solved): a cost is what the scene spends because of the "
             "effect, its own stage and its consequences in the others. Cost of an effect = ms/step with all effects "
             "(mean of the first and last run) - ms/step without it; the two all-effects runs differ by the "
             "noise shown, so a cost within it is not resolved. 'stages gone' lists the plan's stages that were "
             "not compiled without the effect (it was their only user): an absent effect costs no stage call; "
             "'in them' is what those stages took per step with all effects (first run), so the rest of the cost "
             "is spent inside the stages the effect shares.", ""]
    for sc in scenes:
        s = summarise(sc)
        cases = sc["cases"]
        ok = [r for r in cases if "error" not in r]
        steps = ok[0]["steps"] if ok else 0
        sim = ok[0]["simulated"] if ok else 0.0
        lines.append(f"### {sc['scene']}")
        lines.append("")
        lines.append(f"{steps} steps ({sim:.3g} s simulated); effects: {', '.join(sc['effects']) or 'none'}."
                     + (f" All effects: {s['base']:.3f} ms/step ({1e3 / s['base']:,.1f} steps/s), noise "
                        f"{s['noise']:.3f} ms/step ({100 * s['noise'] / s['base']:.1f} %)." if s["base"] else ""))
        if s["full"]:
            per = ", ".join(f"{k} {1e3 * v / s['full']['steps']:.3f} ms"
                            for k, v in sorted(s["full"]["stages"].items(), key=lambda kv: -kv[1]))
            lines.append(f"Plan with all effects: {'; '.join(s['full']['plan'])}. Stage times (first run, per "
                         f"step): {per}.")
        plans = {tuple(r["plan"]) for r in cases if r["drop"] is None and "error" not in r}
        if len(plans) > 1:
            lines.append("**The two all-effects runs compiled different plans: the code changed during the run; "
                         "do not trust this scene's costs.**")
        lines.append("")
        hdr = ["case", "steps/s", "ms/step", "stages (effects each evaluates)", "stages gone", "in them ms/step",
               "cost ms/step", "cost % of step"]
        lines.append("| " + " | ".join(hdr) + " |")
        lines.append("|" + "|".join("---" for _ in hdr) + "|")
        costs = {row["effect"]: row for row in s["rows"]}
        for r in cases:
            if "error" in r:
                lines.append(f"| {r['case']} | error: {r['error']} | | | | | | |")
                continue
            ms = _ms(r)
            row = costs.get(r["drop"]) if r["drop"] else None
            cost = "" if row is None or row["cost"] is None else f"{row['cost']:+.3f}"
            pct = "" if row is None or row["pct"] is None else f"{row['pct']:+.1f} %"
            gone = "" if row is None else (", ".join(row["gone"]) or "none")
            own = "" if row is None or row["own"] is None else f"{row['own']:.3f}"
            lines.append(f"| {r['case']} | {r['steps'] / r['wall']:,.1f} | {ms:.3f} | {'; '.join(r['plan'])} | "
                         f"{gone} | {own} | {cost} | {pct} |")
        lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


def _threads() -> str:
    env = os.environ.get("MODALFEM_THREADS")
    return f"MODALFEM_THREADS={env}" if env else f"threads: numba default ({os.cpu_count()} cores visible)"


def command(argv: list[str]) -> int:
    """``modalfem bench scene [SCENE ...] [--out BENCHMARKS.md] [--steps N] [--repeats N] [--quick]``."""
    if argv[:1] == ["--child"]:
        return _child(argv[1:])
    ap = argparse.ArgumentParser(prog="modalfem bench scene",
                                 description="Per-effect cost of example scenes (an ablation, each case in a "
                                             "fresh process).")
    ap.add_argument("scenes", nargs="*", metavar="SCENE", help="scene files or example names (default: every "
                                                               "example scene)")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose scene section is replaced")
    ap.add_argument("--steps", type=int, default=1000, help="steps per case (at most the scene's own; 1000)")
    ap.add_argument("--repeats", type=int, default=2, help="timed repetitions per case, the fastest counts (2)")
    ap.add_argument("--quick", action="store_true", help="5 steps, 2 repetitions (smoke test)")
    ap.add_argument("--no-write", action="store_true", help="print the section only, do not touch --out")
    a = ap.parse_args(argv)
    from modalfem.bench.cli import _machine, update_section
    from modalfem.scene.run import examples, find_scene

    steps, repeats = (5, 2) if a.quick else (a.steps, a.repeats)
    if steps < 1 or repeats < 1:
        print("modalfem: error: --steps and --repeats must be >= 1", file=sys.stderr)
        return 2
    try:
        paths = [find_scene(s) for s in a.scenes] if a.scenes else [p for p, _ in examples().values()]
    except Exception as exc:  # noqa: BLE001 - a SceneError naming the scene
        print(f"modalfem: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    load0 = os.getloadavg()[0]
    scenes = measure(paths, steps=steps, repeats=repeats)
    cmd = "python -m modalfem bench scene" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = render(scenes, command=cmd, date=date, machine=_machine(), load=(load0, os.getloadavg()[0]),
                     threads=_threads(), code=_code_version())
    print(section)
    if not a.no_write:
        update_section(a.out, section)
    return 0


if __name__ == "__main__":
    sys.exit(command(sys.argv[1:]))
