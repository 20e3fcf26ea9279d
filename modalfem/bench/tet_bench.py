"""``modalfem bench tet``: milliseconds per implicit step of the tetrahedral soft body at ~1k, 10k, 50k tets.

Scene: a bar of soft rubber-like material (E = 1 MPa, nu = 0.3, rho = 1000 kg/m^3) clamped at one end
(``Pins``) and sagging under ``Gravity``, dt = 1/30 s, ``energy="stable"``. Each size runs in a fresh
single-threaded subprocess (``OPENBLAS_NUM_THREADS=OMP_NUM_THREADS=MKL_NUM_THREADS=1``) for three
variants measured side by side: Newton (<= 8 iterations, tol 1e-6 of the body size) with two-level
PCG, one linearised step (``newton_max=1``) with two-level PCG, and one linearised step with SuperLU (``splu``;
only up to 10k tets). Reported: median ms per step (after 2 warm-up steps), steps/s, Newton
iterations and CG iterations per step, and the share of the step spent in linear solves.

Usage: ``python -m modalfem bench tet [--out BENCHMARKS.md] [--quick] [--steps N]``.
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

import numpy as np

__all__ = ["QUICK_SIZES", "SECTION", "SIZES", "VARIANTS", "command", "openblas_core", "run_case_here"]

SECTION = "## Tet soft body: implicit step"
#: hexahedra per axis (6 tets each): ~1k, ~10k, ~50k tetrahedra; cell size 0.05 m
SIZES = [(14, 4, 3), (28, 10, 6), (42, 20, 10)]
QUICK_SIZES = [(4, 2, 2)]
#: name -> (newton_max, linear solver, largest tet count it runs at)
VARIANTS = {
    "newton+cg": (8, "cg", 10**9),
    "linearised+cg": (1, "cg", 10**9),
    "linearised+splu": (1, "splu", 20_000),
}
GOAL_STEPS_PER_S = 30.0
DT = 1.0 / 30.0
_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "MODALFEM_THREADS")


def openblas_core() -> str | None:
    """The core type the loaded OpenBLAS runs its kernels for (e.g. ``"SkylakeX"``, or ``"Prescott"`` when
    a generic build misdetects the CPU; ``OPENBLAS_CORETYPE`` overrides it), or None if not found.

    Asks the library itself (``openblas_get_corename``) among the shared objects this process has mapped.
    """
    import ctypes

    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({ln.split()[-1] for ln in fh if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    except OSError:
        return None
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("openblas_get_corename", "openblas_get_corename64_", "scipy_openblas_get_corename64_"):
            fn = getattr(lib, name, None)
            if fn is not None:
                fn.restype = ctypes.c_char_p
                core = fn()
                return core.decode() if core else None
    return None


def run_case_here(cells, variant: str, steps: int) -> dict:
    """Run one size and variant in this process; returns the measurements (times in ms)."""
    from modalfem.material import Material
    from modalfem.mesh import box
    from modalfem.tet.effects import Gravity, Pins
    from modalfem.tet.model import tet_model
    from modalfem.tet.solver import TetSolver, TetState

    newton_max, linear, _ = VARIANTS[variant]
    mesh = box(size=tuple(0.05 * c for c in cells), cells=tuple(cells))
    model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    t0 = time.perf_counter()
    solver = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))], newton_max=newton_max,
                       linear_solver=linear)
    setup = time.perf_counter() - t0
    state = TetState.at_rest(model)
    infos, cpu = [], []
    for _ in range(steps + 2):
        c0 = time.process_time()
        infos.append(solver.step(state, state, DT))
        cpu.append(time.process_time() - c0)
    infos, cpu = infos[2:], cpu[2:]
    total = np.array([i.total_s for i in infos])
    return {
        "tets": model.cell_count, "vertices": model.point_count, "setup_ms": 1e3 * setup,
        "ms_per_step": 1e3 * float(np.median(total)),
        "cpu_ms_per_step": 1e3 * float(np.median(cpu)),
        "newton_per_step": float(np.mean([i.newton_iterations for i in infos])),
        "cg_per_step": float(np.mean([i.linear_iterations for i in infos])),
        "solve_share": float(sum(i.solve_s for i in infos) / total.sum()),
        "finite": bool(np.all(np.isfinite(state.x))),
        "openblas_core": openblas_core(), "openblas_coretype_env": os.environ.get("OPENBLAS_CORETYPE"),
    }


def _run_case(cells, variant: str, steps: int, timeout: float, *, threads: int = 1) -> dict:
    """One size and variant in a child process whose compiled kernels use ``threads`` threads (BLAS: one)."""
    env = {**os.environ, **{k: "1" for k in _THREADS}, "MODALFEM_THREADS": str(threads)}
    cmd = [sys.executable, "-m", "modalfem.bench.tet_bench", "--case", json.dumps([list(cells), variant, steps])]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout:.0f} s"}
    if p.returncode != 0:
        return {"error": (p.stderr.strip().splitlines() or ["failed"])[-1][:200]}
    return json.loads(p.stdout.strip().splitlines()[-1])


def _section(rows: list[tuple], command: str, seconds: float) -> str:
    import scipy

    from modalfem.bench.cli import _machine

    today = _dt.datetime.now(_dt.timezone.utc).date().isoformat()
    cores = sorted({(r.get("openblas_core"), r.get("openblas_coretype_env")) for _, _, r, _ in rows if "error" not in r},
                   key=str)
    blas = "; ".join(f"OpenBLAS core {c or 'unknown'} (`OPENBLAS_CORETYPE` {'unset' if e is None else repr(e)})"
                     for c, e in cores)
    head = (f"Command: `{command}` ({today}, {seconds:.0f} s). Machine: {_machine()}. "
            f"Python {sys.version.split()[0]}, numpy {np.__version__}, scipy {scipy.__version__}"
            f"{'; ' + blas if blas else ''}; one thread per case (`MODALFEM_THREADS=OPENBLAS_NUM_THREADS=1`; 2 threads: "
            "`modalfem bench threads`), each case a fresh "
            "process.")
    scene = ("Scene: clamped soft bar (E = 1 MPa, nu = 0.3, rho = 1000 kg/m^3) sagging under gravity, "
             "dt = 1/30 s, `energy=\"stable\"`, backward Euler on the incremental potential with exact element "
             "Hessians (projected to PSD only when a solve meets negative curvature). `newton+cg`: up to 8 "
             "Newton iterations (tol 1e-6 x body size) from the predicted positions, with a backtracking "
             "line search, an iteration after a full step under 300 x tol reusing the previous matrix, PCG "
             "(rtol 1e-3 for the solve that can end a step, 0.03 for earlier ones; compiled; the first solve of a "
             "`linearised` step warm-started from the previous step's velocity change) with the two-level preconditioner (Jacobi + rigid motions of ~48 vertex aggregates, "
             "coarse space reused for up to 6 solves); `linearised`: one Newton step per time "
             "step (Baraff-Witkin); `splu`: SuperLU factorisation per solve. Median of the measured steps "
             "after 2 warm-up steps; `CPU ms/step` is the process CPU time of a step (less sensitive to other "
             f"load on the machine). Goal: >= {GOAL_STEPS_PER_S:.0f} steps/s at 10k tets on one core.")
    header = ("| tets | vertices | variant | ms/step | CPU ms/step | steps/s | Newton it/step | CG it/step "
              "| linear-solve share | vs linearised+cg |")
    lines = [SECTION, "", head, "", scene, "", header, "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for cells, variant, r, ref in rows:
        if "error" in r:
            lines.append(f"| {6 * int(np.prod(cells))} | - | {variant} | {r['error']} | | | | | | |")
            continue
        ratio = f"{r['ms_per_step'] / ref['ms_per_step']:.2f}x" if ref and "error" not in ref else "-"
        lines.append(f"| {r['tets']} | {r['vertices']} | {variant} | {r['ms_per_step']:.1f} | {r['cpu_ms_per_step']:.1f} | "
                     f"{1e3 / r['ms_per_step']:.1f} | {r['newton_per_step']:.2f} | {r['cg_per_step']:.0f} | "
                     f"{100 * r['solve_share']:.0f} % | {ratio} |")
    goal = [r for cells, variant, r, _ in rows
            if "error" not in r and variant == "linearised+cg" and 9_000 <= r["tets"] <= 11_000]
    if goal:
        r = goal[0]
        sps = 1e3 / r["ms_per_step"]
        verdict = (f"Goal ({GOAL_STEPS_PER_S:.0f} steps/s at 10k tets, one core): {r['tets']} tets, linearised+cg, "
                   f"{r['ms_per_step']:.1f} ms/step = {sps:.1f} steps/s (CPU {r['cpu_ms_per_step']:.1f} ms) -> "
                   f"**{'met' if sps >= GOAL_STEPS_PER_S else 'NOT met'}**.")
        lines += ["", verdict]
    return "\n".join(lines) + "\n"


def command(argv: list[str]) -> int:
    """``modalfem bench tet``: run the ladder, print the section and write it into ``--out``."""
    from modalfem.bench.cli import update_section

    ap = argparse.ArgumentParser(prog="modalfem bench tet")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose tet section is replaced")
    ap.add_argument("--quick", action="store_true", help="one tiny mesh, 3 steps (smoke test)")
    ap.add_argument("--steps", type=int, default=None, help="measured steps per case (default 10, quick 3)")
    ap.add_argument("--timeout", type=float, default=900.0, help="kill a case after S seconds")
    a = ap.parse_args(argv)
    steps = a.steps or (3 if a.quick else 10)
    command_line = "python -m modalfem bench tet" + ("" if not argv else " " + shlex.join(argv))
    t0 = time.perf_counter()
    rows = []
    for cells in QUICK_SIZES if a.quick else SIZES:
        ref = None
        for variant in VARIANTS:
            if 6 * int(np.prod(cells)) > VARIANTS[variant][2]:
                continue
            print(f"[bench tet] {cells} {variant} ...", file=sys.stderr, flush=True)
            r = _run_case(cells, variant, steps, a.timeout)
            print(f"[bench tet] {cells} {variant}: {r}", file=sys.stderr, flush=True)
            if variant == "linearised+cg":
                ref = r
            rows.append((cells, variant, r, None))
        rows = [(c, v, r, ref if c == cells else rr) for c, v, r, rr in rows]
    text = _section(rows, command_line, time.perf_counter() - t0)
    print(text)
    update_section(a.out, text)
    return 0 if all("error" not in r for _, _, r, _ in rows) else 1


def _main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", required=True)
    cells, variant, steps = json.loads(ap.parse_args().case)
    print(json.dumps(run_case_here(tuple(cells), variant, int(steps))))
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
