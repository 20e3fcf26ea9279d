"""Cloth benchmark (``modalfem bench cloth``): the drape and the pile with every collision stage on.

For each scene (``modalfem.cloth.scenes.drape`` / ``pile``) and size (vertices per side) one child
process, pinned to one thread (``OMP_NUM_THREADS=1`` etc.), steps the scene and reports per step:
wall time, CPU time, the share of each stage (cloth implicit step, the pipeline's broad phase, repulsion, CCD,
impact zones, and stage (d) smoothing with its re-check), triangle-pair tests before and after
normal-cone culling, impact zones, CG iterations, and the intersecting pairs found by the
independent check (``modalfem.cloth.scenes.intersections``) every ``--check-every`` steps and at the end.
A second table compares the two linear solvers (block-Jacobi-CG and SuperLU) on the implicit step
alone (the twist scene without collisions). ``--scenes`` and ``--no-solvers`` select what runs.

Each case runs the scene's own length (``Setup.steps``: drape 100 steps, pile 80, i.e. 1 s and 0.8 s at
dt = 10 ms; the 128x128 cases half of it), so the pile's settled, many-layer phase is in the average;
the column "ms/step 2nd half" is that phase alone. The child is
``python -m modalfem.bench.cloth_bench --case drape --n 32 --json-out r.json`` (``--steps`` to override).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time

import numpy as np

__all__ = ["SECTION", "command", "run_case"]

SECTION = "## Cloth: drape and pile with collisions"
GOAL_STEPS_PER_S = 10.0
STAGES = ("implicit", "broad_phase", "repulsion", "ccd", "impact_zones", "smoothing")
_ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "MODALFEM_THREADS")}
#: the stage ablation on the goal's scene: (what changes, scene options); the first row is the goal's setting
ABLATIONS = (
    ("every stage on (the goal's setting)", {}),
    ("stage (d) off: no smoothing, so no re-check", {"smoothing": 0.0}),
    ("stage (a) off: no repulsion (CCD and zones only)", {"repulsion": False}),
    ("1 CCD pass instead of 3", {"ccd_passes": 1}),
    ("no culling (proximity search unculled)", {"culling": False}),
    ("swept searches culled too", {"swept_culling": True}),
    ("self-collision off (ground only)", {"self_collision": False}),
)


def run_case(case: str, n: int, steps: int | None = None, *, check_every: int = 10, linear_solver: str = "cg",
             collisions: bool = True, options: dict | None = None) -> dict:
    """Step one scene in this process (``steps`` None: the scene's own length, ``Setup.steps``); returns the
    per-step averages (see module docstring), ``late_ms_per_step`` over the second half of the steps.
    ``options``: keyword arguments of the scene function (``smoothing`` [s], ``CollisionConfig`` fields)."""
    import dataclasses

    from modalfem.cloth import scenes

    setup = scenes.SCENES[case](n, collisions=collisions, **(options or {}))
    steps = setup.steps if steps is None else int(steps)
    step_ms: list = []  # wall ms of each step (None: a probe step, not timed)
    sc = setup.scene
    sc.solver.linear_solver = linear_solver
    sums = dict.fromkeys(STAGES, 0.0)
    total = cpu = 0.0
    unculled = culled = zones = zone_steps = max_zone = cg = smooth_cg = timed = measured = 0
    intersections = 0
    for k in range(steps):
        probe = sc.pipeline is not None and (k + 1) % check_every == 0
        if probe:  # counting unculled pair tests costs time: only on probe steps, which are not timed
            base = sc.pipeline.config
            sc.pipeline.config = dataclasses.replace(base, measure_culling=True)
        c0 = time.process_time()
        st = sc.step(setup.dt)
        c1 = time.process_time()
        if probe:
            sc.pipeline.config = base
            step_ms.append(None)
            unculled += st.collision.pair_tests_unculled or 0
            culled += st.collision.pair_tests
            measured += 1
        else:
            timed += 1
            total += st.seconds["total"]
            cpu += c1 - c0
            step_ms.append(1e3 * st.seconds["total"])
        if not probe:
            sums["implicit"] += st.seconds["forces"] + st.seconds["implicit"]
            sums["smoothing"] += st.seconds["smoothing"]
        cg += st.linear.iterations
        smooth_cg += st.smooth_iterations
        if st.collision is not None:
            if not probe:
                for key in ("broad_phase", "repulsion", "ccd", "impact_zones"):
                    sums[key] += st.collision.seconds.get(key, 0.0)
            last = st.recheck if st.recheck is not None else st.collision
            zones += len(last.zone_sizes)
            zone_steps += bool(last.zone_sizes)
            max_zone = max([max_zone, *last.zone_sizes])
            if (k + 1) % check_every == 0 or k == steps - 1:
                intersections += scenes.intersections(setup)
    late = [v for v in step_ms[(steps + 1) // 2:] if v is not None]  # steps k with 2 k >= steps
    return {
        "case": case, "n": n, "steps": steps, "ms_per_step": 1e3 * total / max(timed, 1),
        "cpu_ms_per_step": 1e3 * cpu / max(timed, 1), "late_ms_per_step": sum(late) / max(len(late), 1),
        "step_ms": step_ms,
        "shares": {k: v / total for k, v in sums.items()},
        "pair_tests_unculled": unculled / max(measured, 1), "pair_tests": culled / max(measured, 1),
        "zones_per_step": zones / steps, "zone_steps": zone_steps, "max_zone": max_zone,
        "cg_iterations": cg / steps, "smooth_cg_iterations": smooth_cg / steps, "intersections": int(intersections), "finite": bool(np.isfinite(sc.x).all()),
    }


def _child(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m modalfem.bench.cloth_bench")
    ap.add_argument("--case", required=True)
    ap.add_argument("--n", type=int, required=True)
    ap.add_argument("--steps", type=int, default=None, help="default: the scene's own length")
    ap.add_argument("--linear-solver", default="cg")
    ap.add_argument("--no-collisions", action="store_true")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=JSON",
                    help="a scene option, e.g. smoothing=0 or culling=false (repeatable)")
    ap.add_argument("--json-out", required=True)
    a = ap.parse_args(argv)
    r = run_case(a.case, a.n, a.steps, linear_solver=a.linear_solver, collisions=not a.no_collisions,
                 options=_options(a.option))
    with open(a.json_out, "w") as f:
        json.dump(r, f)
    return 0


def _options(items: list[str]) -> dict:
    """``["smoothing=0", "culling=false"]`` -> ``{"smoothing": 0, "culling": False}`` (values are JSON)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"--option wants KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            raise SystemExit(f"--option {key}: value {value!r} is not JSON (numbers, true/false)") from None
    return out


def _spawn(args: list[str], timeout: float, *, threads: int = 1) -> dict | None:
    """Run one case in a child process whose compiled kernels use ``threads`` threads (BLAS: one)."""
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "r.json")
        env = {**os.environ, **_ONE_THREAD, "MODALFEM_THREADS": str(threads)}
        cmd = [sys.executable, "-m", "modalfem.bench.cloth_bench", *args, "--json-out", out]
        try:
            p = subprocess.run(cmd, env=env, timeout=timeout, capture_output=True, text=True, check=False)
        except subprocess.TimeoutExpired:
            print(f"  timeout after {timeout:.0f} s: {' '.join(args)}", file=sys.stderr)
            return None
        if p.returncode != 0:
            tail = (p.stderr.strip().splitlines() or ["?"])[-1]
            print(f"  failed: {' '.join(args)}: {tail}", file=sys.stderr)
            return {"error": tail}
        with open(out) as f:
            return json.load(f)


def plot_steps(results: list[dict], path: str) -> bool:
    """PNG of the wall time of every step of each case (log scale; probe steps left out), written
    atomically to ``path``; False (nothing written) when no case has per-step times."""
    rows = [r for r in results if r.get("step_ms")]
    if not rows:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes_ = sorted({r["case"] for r in rows})
    fig, axes = plt.subplots(1, len(scenes_), figsize=(6.5 * len(scenes_), 4.2), squeeze=False)
    for ax, case in zip(axes[0], scenes_):
        for r in (r for r in rows if r["case"] == case):
            ms = np.array([np.nan if v is None else v for v in r["step_ms"]], dtype=float)
            ax.plot(np.arange(1, len(ms) + 1), ms, marker=".", ms=3, lw=1, label=f"{r['n']}x{r['n']}")
        if case == "pile":
            ax.axhline(1e3 / GOAL_STEPS_PER_S, color="k", ls="--", lw=0.8, label="goal (64x64)")
        ax.set_yscale("log")
        ax.set_xlabel("step (dt = 10 ms)")
        ax.set_ylabel("wall time per step [ms] (log)")
        ax.set_title(f"{case}: every stage on, one thread")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    from modalfem.bench.cli import save_figure

    save_figure(fig, path, dpi=100)
    return True


def _default_preconditioner() -> str:
    """The implicit step's CG preconditioner the bench's "cg" runs use (``ImplicitEuler``'s default)."""
    import inspect

    from modalfem.cloth.solver import ImplicitEuler

    return inspect.signature(ImplicitEuler).parameters["cg_preconditioner"].default


def render(results: list[dict], solvers: list[dict], *, command: str, date: str, machine: str, versions: str,
           plot: str | None = None, ablation: list[dict] | None = None, ablation_n: int = 64,
           load: tuple | None = None) -> str:
    """The markdown section (``plot``: path of the per-step PNG relative to the markdown file, if any;
    ``ablation``: the stage ablation's runs, labelled, the first with every stage on; ``load``: the 1-minute
    load average at the start and the end of the run)."""
    L = [SECTION, "", f"- Date: {date}", f"- Machine: {machine}", f"- Versions: {versions}", f"- Command: `{command}`",
         ("- One thread per case (MODALFEM/OMP/OpenBLAS/MKL_NUM_THREADS=1; 2 threads: `modalfem bench threads`), one child process per case; all stages on "
          "(repulsion, CCD, impact zones, culling by normal cones and projected contours in the proximity "
          "search, smoothing with re-check). Scenes: `modalfem.cloth.scenes.drape` (1 m cloth onto a 0.3 m ball) and `pile` (1 m "
          "cloth dropped vertically onto the ground), dt = 10 ms."),
         ("- CPU ms/step is this process's CPU time per step (`time.process_time`): on a shared machine it "
          "counts less of the waiting for a core than the wall time."),
         *([] if load is None else [
             f"- Load average (1 min): {load[0]:.1f} at the start, {load[1]:.1f} at the end"
             + (f" (above the {os.cpu_count()} cores: other work shared the machine, and the wall times are upper "
                "bounds)." if max(load) > (os.cpu_count() or 1) else ": no other work competed for the cores.")]),
         ("- Each case runs its scene's whole length (drape 100 steps, pile 80; the 128x128 cases half of it); "
          "ms/step 2nd half is the wall time per step over the second half of the steps (for the pile its "
          "settled, many-layer phase)."),
         ("- Shares are of the step's wall time; pair tests are triangle-pair BVH leaf tests per step before "
          "and after culling (the proximity and the swept traversal of the first pipeline call), counted on "
          "every 10th step (those steps are left out of the timings); zones = impact zones per step after "
          "the final pipeline call; intersections = intersecting pairs found by the independent check "
          "every 10 steps and at the end; CG its = conjugate-gradient iterations of the implicit solve per "
          "step, smoothing CG its = those of the smoothing solve (multilevel-preconditioned CG, numba)."), "",
         "| scene | vertices | steps | ms/step | steps/s | CPU ms/step | ms/step 2nd half | "
         + " | ".join(f"{s} %" for s in STAGES)
         + " | pair tests unculled | pair tests culled | culled % | zones/step | max zone | CG its | smoothing CG its"
         " | intersections |",
         "|---" * (17 + len(STAGES) - 2) + "|"]
    for r in results:
        if "error" in r or "ms_per_step" not in r:
            msg = r.get("error", "timeout")
            L.append(f"| {r['case']} | {r['n']}x{r['n']} | - | {msg} |" + " |" * (11 + len(STAGES)))
            continue
        sh = " | ".join(f"{100 * r['shares'][s]:.0f}" for s in STAGES)
        cut = 100 * (1 - r["pair_tests"] / r["pair_tests_unculled"]) if r["pair_tests_unculled"] else 0.0
        L.append(f"| {r['case']} | {r['n']}x{r['n']} | {r['steps']} | {r['ms_per_step']:.0f} | "
                 f"{1e3 / r['ms_per_step']:.2f} | {r.get('cpu_ms_per_step', float('nan')):.0f} | "
                 f"{r.get('late_ms_per_step', float('nan')):.0f} | {sh} | {r['pair_tests_unculled']:.0f} | {r['pair_tests']:.0f} | "
                 f"{cut:.0f} | {r['zones_per_step']:.2f} | {r['max_zone']} | {r['cg_iterations']:.0f} | "
                 f"{r.get('smooth_cg_iterations', float('nan')):.0f} | "
                 f"{r['intersections']} |")
    if plot:
        L += ["", f"![Wall time of every step of each case, log scale: the fall, then the settled pile]({plot})"]
    goal = [r for r in results if r.get("case") == "pile" and r.get("n") == 64 and "ms_per_step" in r]
    if goal:
        g = goal[0]
        ok = 1e3 / g["ms_per_step"] >= GOAL_STEPS_PER_S and g["intersections"] == 0
        L += ["", (f"Goal (64x64 pile, all stages, >= {GOAL_STEPS_PER_S:g} steps/s on one core, zero "
                   f"intersections): {1e3 / g['ms_per_step']:.2f} steps/s, {g['intersections']} intersections: "
                   f"**{'met' if ok else 'not met'}**.")]
    if ablation:
        L += _ablation_table(ablation, ablation_n)
    if solvers:
        L += ["", ("Linear solver of the implicit step (the twist scene without collisions, first 10 steps: the "
                   "handles deform the sheet): ms per implicit step (assembly + solve)"),
              "", f"| vertices | CG ({_default_preconditioner()}) ms | CG its | SuperLU ms | CG / SuperLU |",
              "|---|---|---|---|---|"]
        for s in solvers:
            L.append(f"| {s['n']}x{s['n']} | {s['cg']:.1f} | {s['cg_its']:.0f} | {s['splu']:.1f} | "
                     f"{s['cg'] / s['splu']:.2f}x |")
    return "\n".join(L) + "\n"


def _ablation_table(rows: list[dict], n: int) -> list[str]:
    """Markdown lines of the stage ablation: each setting's time against the first row's (every stage on),
    and what it gives up (impact zones, intersections)."""
    base = rows[0].get("ms_per_step") if rows else None
    L = ["", (f"Stage ablation: the {n}x{n} pile (its whole length, one thread, one process per row), one "
              "setting changed per row: what each stage costs and what switching it off gives up (impact "
              "zones are the rigid fail-safe; intersections by the independent check every 10 steps). The "
              "first row re-runs the main table's case next to the others: its difference from that row is "
              "the machine's noise between runs."), "",
         ("| setting | ms/step | steps/s | x time of all stages | ms/step 2nd half | smoothing % | zones/step | "
          "max zone | intersections |"), "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "ms_per_step" not in r:
            L.append(f"| {r['label']} | {r.get('error', 'timeout')} |" + " |" * 7)
            continue
        rel = f"{r['ms_per_step'] / base:.2f}" if base else "-"
        L.append(f"| {r['label']} | {r['ms_per_step']:.0f} | {1e3 / r['ms_per_step']:.2f} | {rel} | "
                 f"{r['late_ms_per_step']:.0f} | {100 * r['shares']['smoothing']:.0f} | {r['zones_per_step']:.2f} | "
                 f"{r['max_zone']} | {r['intersections']} |")
    return L


def _versions_line() -> str:
    import scipy

    return f"Python {sys.version.split()[0]}, numpy {np.__version__}, scipy {scipy.__version__}"


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover - not Unix
        return float("nan")


def command(argv: list[str]) -> int:
    """``modalfem bench cloth [--out BENCHMARKS.md] [--sizes 32 64 128] [--steps S] [--scenes drape pile]
    [--no-solvers] [--quick] [--plot PNG]``."""
    ap = argparse.ArgumentParser(prog="modalfem bench cloth")
    ap.add_argument("--out", default="BENCHMARKS.md")
    ap.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128])
    ap.add_argument("--steps", type=int, default=None,
                    help="steps per case (default: each scene's own length, drape 100, pile 80; the 128 case runs half)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="per case [s]")
    ap.add_argument("--scenes", nargs="+", choices=("drape", "pile"), default=["drape", "pile"],
                    help="scenes to run (default: both)")
    ap.add_argument("--no-solvers", action="store_true", help="skip the linear solver table (twist scene)")
    ap.add_argument("--no-ablation", action="store_true", help="skip the stage ablation table (pile)")
    ap.add_argument("--ablation-n", type=int, default=64, help="vertices per side of the ablation's pile")
    ap.add_argument("--quick", action="store_true", help="tiny sizes and few steps (smoke test)")
    ap.add_argument("--plot", default=None, help="per-step PNG (default: bench/cloth_steps.png next to --out)")
    a = ap.parse_args(argv)
    plot = a.plot or os.path.join(os.path.dirname(os.path.abspath(a.out)), "bench", "cloth_steps.png")
    sizes, steps = ([8], 10) if a.quick else (a.sizes, a.steps)
    ablation_n = 8 if a.quick else a.ablation_n
    t0 = time.perf_counter()
    load0 = _load()
    results, solvers = [], []
    from modalfem.cloth import scenes

    for case in a.scenes:
        full = steps if steps is not None else scenes.SCENES[case](8).steps
        for n in sizes:
            k = full if n <= 64 else max(2, full // 2)
            print(f"cloth bench: {case} {n}x{n}, {k} steps", file=sys.stderr, flush=True)
            r = _spawn(["--case", case, "--n", str(n), "--steps", str(k)], a.timeout)
            results.append({"case": case, "n": n, **(r or {})})
    for n in [] if a.no_solvers else sizes:
        row = {"n": n}
        for ls in ("cg", "splu"):
            r = _spawn(["--case", "twist", "--n", str(n), "--steps", "10", "--no-collisions", "--linear-solver", ls],
                       a.timeout)
            if not r or "error" in r:
                break
            row[ls] = r["ms_per_step"] * r["shares"]["implicit"]
            row[f"{ls}_its"] = r["cg_iterations"]
        if "splu" in row:
            solvers.append(row)
    ablation = []
    for label, opts in [] if a.no_ablation else ABLATIONS:
        print(f"cloth bench: ablation, pile {ablation_n}x{ablation_n}: {label}", file=sys.stderr, flush=True)
        args = ["--case", "pile", "--n", str(ablation_n)] + ([] if steps is None else ["--steps", str(steps)])
        for key, value in opts.items():
            args += ["--option", f"{key}={json.dumps(value)}"]
        r = _spawn(args, a.timeout)
        ablation.append({"label": label, "options": opts, **(r or {"error": "timeout"})})
    from modalfem.bench.cli import _machine, update_section

    cmd = "python -m modalfem bench cloth" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    rel = None
    if plot_steps(results, plot):
        rel = os.path.relpath(os.path.abspath(plot), os.path.dirname(os.path.abspath(a.out)))
    section = render(results, solvers, command=cmd, date=date, machine=_machine(), versions=_versions_line(),
                     plot=rel, ablation=ablation, ablation_n=ablation_n, load=(load0, _load()))
    print(section)
    update_section(a.out, section)
    print(f"cloth bench: {time.perf_counter() - t0:.0f} s, section written to {a.out}", file=sys.stderr)
    return 0 if all("ms_per_step" in r for r in results + ablation) else 1


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
