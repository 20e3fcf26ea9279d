"""``modalfem bench runtime``: cost of one modal step + surface reconstruction, against its floors.

For r modes x nv surface vertices the runtime step (``ModalSolver.step`` with no effects: exact modal
update + free rigid update) and the reconstruction ``ModalBody.positions`` (one (3 nv x r)
matrix-vector product plus O(nv)) are timed, side by side in the same child process with:

* the memory-bandwidth floor: a plain copy of the same mode matrix (``np.copyto``);
* the vector-matrix product alone, and the matrix in other layouts (vertex-major (3 nv, r) in C and
  Fortran order, float32);
* one implicit full-FEM step of a real body (P1 linear elasticity, scikit-fem assembly, backward
  Euler ``(M + dt^2 K) v1 = M v0 - dt K u0`` with a SuperLU factorisation made beforehand), against
  the modal step + reconstruction of the same body's surface.

Every case runs in a fresh child process with ``OPENBLAS_NUM_THREADS=OMP_NUM_THREADS=MKL_NUM_THREADS=1``
(one core). Mode shapes are random (the cost does not depend on their values) on a grid-ordered
closed torus surface of nv vertices and 2 nv triangles. Times are medians of
9 repeats, each long enough (>= 0.05 s) to be above the timer resolution.
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

__all__ = ["SECTION", "command", "measure_case", "measure_fem", "render"]

SECTION = "## Runtime: modal step + reconstruction"
VERTICES = (10_000, 50_000, 200_000)
MODES = (10, 30, 60)
GOAL = (50_000, 30)  # (vertices, modes) of the goals
GOAL_STEPS_PER_S = 1000.0
GOAL_FLOOR_RATIO = 2.0
FEM_SIZE = (0.4, 0.1, 0.1)  # [m] steel box of the full-FEM comparison
FEM_CELLS = (40, 10, 10)
DT = 1e-3  # [s]
_ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "MODALFEM_THREADS")}
CONTACT_SECTION = "## Runtime: modal contact"


def _timeit(fn, *, repeats: int = 9, min_time: float = 0.05) -> float:
    """Median seconds per call of ``fn()`` over ``repeats`` timed loops of >= ``min_time`` each."""
    fn()
    t0 = time.perf_counter()
    fn()
    one = max(time.perf_counter() - t0, 1e-7)
    n = max(1, int(min_time / one))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        times.append((time.perf_counter() - t0) / n)
    return float(np.median(times))


def _synthetic_body(vertices: np.ndarray, triangles: np.ndarray, r: int, *, dtype=None):
    from types import SimpleNamespace

    from modalfem.runtime import ModalBody

    rng = np.random.default_rng(0)
    nv = len(vertices)
    model = SimpleNamespace(vertices=vertices, triangles=triangles,
                            shapes=rng.standard_normal((3 * nv, r)) * 1e-3, omega=np.linspace(1e3, 1e5, r),
                            mass=1.0, center_of_mass=vertices.mean(axis=0), inertia=np.diag([1.0, 1.2, 1.4]),
                            damping=(0.0, 1e-7))
    return ModalBody(model) if dtype is None else ModalBody(model, dtype=dtype)


def _torus_surface(nv: int):
    """Closed triangulated torus (major radius 0.1 m, minor 0.03 m) of nv vertices (n1 x n2 grid), grid-ordered
    like a real surface mesh (neighbouring vertices close in memory), 2 triangles per vertex."""
    divisors = [d for d in range(3, nv // 3 + 1) if nv % d == 0] or [max(3, round(np.sqrt(nv * 3.0)))]
    n1 = min(divisors, key=lambda d: abs(d - np.sqrt(nv * 3.0)))  # n1 x n2 = nv exactly when possible
    n2 = max(3, nv // n1)
    a, b = np.meshgrid(np.linspace(0, 2 * np.pi, n1, endpoint=False), np.linspace(0, 2 * np.pi, n2, endpoint=False),
                       indexing="ij")
    x = np.stack([(0.1 + 0.03 * np.cos(b)) * np.cos(a), (0.1 + 0.03 * np.cos(b)) * np.sin(a), 0.03 * np.sin(b)],
                 axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n1), np.arange(n2), indexing="ij")
    v00, v10 = i * n2 + j, ((i + 1) % n1) * n2 + j
    v01, v11 = i * n2 + (j + 1) % n2, ((i + 1) % n1) * n2 + (j + 1) % n2
    tris = np.concatenate([np.stack([v00, v10, v11], -1).reshape(-1, 3), np.stack([v00, v11, v01], -1).reshape(-1, 3)])
    return x, tris


def _step_and_recon(body):
    from modalfem.runtime import ModalSolver

    solver = ModalSolver(body)
    st = solver.state(angular_velocity=(1.0, 2.0, 3.0))
    st.qdot[:] = 1e-3
    buf = np.empty((body.vertex_count, 3), dtype=body.shapes_t.dtype)

    def step():
        solver.step(st, st, None, None, DT)

    def recon():
        body.positions(st, out=buf)

    def both():
        solver.step(st, st, None, None, DT)
        body.positions(st, out=buf)

    return st, step, recon, both, buf


def measure_case(nv: int, r: int, *, layouts: bool = False) -> dict:
    """Seconds per call of the runtime pieces and their floors for one (vertices, modes) case."""
    verts, tris = _torus_surface(nv)
    nv = len(verts)
    body = _synthetic_body(verts, tris, r)
    st, step, recon, both, buf = _step_and_recon(body)
    Phi = body.shapes_t  # the layout the runtime uses: modes-major (r, 3 nv)
    dst = np.empty_like(Phi)
    u = np.empty(3 * nv, dtype=Phi.dtype)
    q = st.q.astype(Phi.dtype)
    out = {"nv": nv, "r": r, "phi_mb": Phi.nbytes / 2**20, "dtype": str(Phi.dtype),
           "step": _timeit(step), "recon": _timeit(recon), "both": _timeit(both),
           "copy": _timeit(lambda: np.copyto(dst, Phi)),
           "both_body": _timeit(lambda: (step(), body.positions(st, out=buf, frame="body"))),
           "gemv": _timeit(lambda: np.dot(q, Phi, out=u)),
           "normals": _timeit(lambda: body.normals(buf), repeats=3)}
    nbuf = np.empty_like(buf)
    body.modal_normals(st, out=nbuf)  # builds the normal basis once, outside the timing
    out["modal_normals"] = _timeit(lambda: body.modal_normals(st, out=nbuf))
    if layouts:
        PhiC = np.ascontiguousarray(Phi.T)  # vertex-major (3 nv, r), C order
        out["gemv_vertex_major"] = _timeit(lambda: np.matmul(PhiC, q, out=u))
        PhiF = np.asfortranarray(PhiC)
        out["gemv_fortran"] = _timeit(lambda: np.matmul(PhiF, q, out=u))
        del PhiF, PhiC, dst
        b64 = _synthetic_body(verts, tris, r, dtype=np.float64)
        _, _, recon64, both64, _ = _step_and_recon(b64)
        dst64 = np.empty_like(b64.shapes_t)
        out["recon_f64"] = _timeit(recon64)
        out["both_f64"] = _timeit(both64)
        out["copy_f64"] = _timeit(lambda: np.copyto(dst64, b64.shapes_t))
    return out


def measure_fem(cells, *, r: int = 30) -> dict:
    """One implicit full-FEM step of a steel box vs the modal step + reconstruction of its surface."""
    import scipy.sparse.linalg as spla

    from modalfem.backends.skfem import assemble
    from modalfem.material import STEEL
    from modalfem.mesh import box

    mesh = box(size=FEM_SIZE, cells=tuple(cells))
    K, M = assemble(mesh, STEEL, degree=1)
    n = K.shape[0]
    A = (M + DT * DT * K).tocsc()
    t0 = time.perf_counter()
    lu = spla.splu(A)
    factor = time.perf_counter() - t0
    rng = np.random.default_rng(2)
    u0, v0 = rng.standard_normal(n) * 1e-6, rng.standard_normal(n) * 1e-3

    def implicit_step():
        v1 = lu.solve(M @ v0 - DT * (K @ u0))
        return u0 + DT * v1

    t_fem = _timeit(implicit_step, repeats=3)
    surf = np.unique(mesh.boundary_facets)
    remap = np.full(mesh.point_count, -1)
    remap[surf] = np.arange(len(surf))
    body = _synthetic_body(mesh.points[surf], remap[mesh.boundary_facets], r)
    _, _, _, both, _ = _step_and_recon(body)
    return {"cells": list(cells), "dofs": int(n), "nv": len(surf), "r": r, "factor": factor,
            "fem_step": t_fem, "modal": _timeit(both), "nnz_lu": int(lu.L.nnz + lu.U.nnz)}


# ------------------------------------------------------------------------------ child process
def _child(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", choices=["runtime", "fem", "info", "resting", "pile"], required=True)
    ap.add_argument("--model", help="model file of a resting case")
    ap.add_argument("--models", help="folder of the pile's model files")
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--nv", type=int)
    ap.add_argument("--r", type=int)
    ap.add_argument("--cells", type=int, nargs=3)
    ap.add_argument("--layouts", action="store_true")
    ap.add_argument("--json-out", required=True)
    a = ap.parse_args(argv)
    if a.case == "runtime":
        res = measure_case(a.nv, a.r, layouts=a.layouts)
    elif a.case == "fem":
        res = measure_fem(a.cells)
    elif a.case == "resting":
        from modalfem.bench.contact_bench import measure_resting

        res = measure_resting(a.model)
    elif a.case == "pile":
        from modalfem.bench.contact_bench import measure_pile

        res = measure_pile({k: os.path.join(a.models, k + ".npz") for k in ("small_bar", "fork", "bell")},
                           count=a.count, steps=a.steps)
    else:
        import platform

        import scipy

        res = {"python": platform.python_version(), "numpy": np.__version__, "scipy": scipy.__version__,
               "threads": ", ".join(f"{k}={os.environ.get(k, '-')}" for k in sorted(_ONE_THREAD)),
               "coretype": os.environ.get("OPENBLAS_CORETYPE", "-")}
    with open(a.json_out, "w") as f:
        json.dump(res, f)
    return 0


def _spawn(args: list[str], timeout: float = 900.0) -> dict:
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "out.json")
        env = {**os.environ, **_ONE_THREAD}
        try:
            p = subprocess.run([sys.executable, "-m", "modalfem.bench.runtime_bench", "--child", *args,
                                "--json-out", path], env=env, capture_output=True, text=True, timeout=timeout,
                               check=False)
        except subprocess.TimeoutExpired:
            return {"error": f"timeout after {timeout:.0f} s"}
        if p.returncode != 0 or not os.path.exists(path):
            return {"error": (p.stderr.strip().splitlines() or ["failed"])[-1]}
        with open(path) as f:
            return json.load(f)


# ------------------------------------------------------------------------------ report
def _ms(s: float) -> str:
    return f"{1e3 * s:.3f}"


def render(cases: list[dict], fem: list[dict], info: dict, *, command: str, date: str, machine: str) -> str:
    """The markdown section (starts with ``SECTION``)."""
    intro = ("One step of `ModalSolver.step` with no effects (exact modal update of r modes + free rigid "
             "update) and the reconstruction `ModalBody.positions` (world surface vertices, one (3 nv x r) "
             "matrix-vector product + O(nv)) with the runtime's default storage: float32 mode matrix, modes-major "
             "(r, 3 nv), C-ordered, the rest shape as one more row (the dynamics stay float64). The memory-bandwidth "
             "floor is a plain copy of the same mode matrix (`np.copyto`), timed in the same process. "
             "Each case in a fresh child process on one thread (OMP/OpenBLAS/MKL_NUM_THREADS=1); medians of 9 "
             "timed loops. Shapes are random (the cost does not depend on their values) on a grid-ordered "
             "closed torus surface (about nv vertices, 2 nv triangles). Normals: area-weighted vertex normals from "
             "the deformed triangles (`normals`), and the same linearised in the modes (`modal_normals`: one more "
             "streaming pass over an (r, 3 nv) matrix, second order in the deformation).")
    machine_line = (f"- Machine: {machine} (shared with other jobs while measured: compare the ratios, "
                    "measured side by side in one process, more than the absolute times)")
    versions = (f"- Versions: Python {info.get('python', '?')}, numpy {info.get('numpy', '?')}, "
                f"scipy {info.get('scipy', '?')} (offline side only); threads {info.get('threads', '?')}; "
                f"OPENBLAS_CORETYPE={info.get('coretype', '-')}")
    header = ("| surface vertices | modes | Phi MB | step us | positions ms | step + positions ms | steps/s | "
              "q @ Phi_t ms | copy of Phi ms | (step + positions) / copy | normals ms | modal normals ms | "
              "step + body-frame positions ms | steps/s, body frame |")
    L = [SECTION, "", intro, "", f"- Date: {date}", f"- Command: `{command}`", machine_line, versions, "",
         header, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        if "error" in c:
            L.append(f"| {c['nv']} | {c['r']} | error: {c['error']} ||||||||||")
            continue
        L.append(f"| {c['nv']} | {c['r']} | {c['phi_mb']:.1f} | {1e6 * c['step']:.1f} | {_ms(c['recon'])} | "
                 f"{_ms(c['both'])} | {1 / c['both']:.0f} | {_ms(c['gemv'])} | {_ms(c['copy'])} | "
                 f"{c['both'] / c['copy']:.2f} | {_ms(c['normals'])} | {_ms(c['modal_normals'])} | "
                 f"{_ms(c['both_body'])} | {1 / c['both_body']:.0f} |")
    goal = next((c for c in cases if (c.get("nv"), c.get("r")) == GOAL and "error" not in c), None)
    L += ["", (f"Goals at {GOAL[0]} vertices x {GOAL[1]} modes: >= {GOAL_STEPS_PER_S:.0f} steps/s (step + "
               f"positions) on one core, and within {GOAL_FLOOR_RATIO:.0f}x of the copy floor."), ""]
    if goal is None:
        L.append("- Not measured in this run (run without `--quick`).")
    else:
        sps = 1 / goal["both"]
        ratio = goal["both"] / goal["copy"]
        L.append(f"- Steps/s: {sps:.0f} -> **{'met' if sps >= GOAL_STEPS_PER_S else 'NOT met'}** "
                 f"(the mode matrix alone is {goal['phi_mb']:.0f} MB per step: 1000 steps/s needs "
                 f"{goal['phi_mb'] * 1000 / 1024:.1f} GB/s of memory bandwidth from one core; this core copies "
                 f"it at {2 * goal['phi_mb'] / goal['copy'] / 1024:.1f} GB/s read + write)")
        L.append(f"- Floor: (step + positions) / copy = {ratio:.2f} -> "
                 f"**{'met' if ratio <= GOAL_FLOOR_RATIO else 'NOT met'}**")
        sps_b = 1 / goal["both_body"]
        L.append(f"- Steps/s with the body-frame reconstruction (`positions(state, frame=\"body\")` = X + Phi q, "
                 "plus the 4 x 4 `model_matrix(state)` that a renderer's vertex shader applies): "
                 f"{sps_b:.0f} -> **{'met' if sps_b >= GOAL_STEPS_PER_S else 'NOT met'}** "
                 f"({goal['both_body'] / goal['copy']:.2f}x the copy floor; the world frame adds the rigid-motion "
                 f"pass, {_ms(goal['both'] - goal['both_body'])} ms)")
        if "gemv_fortran" in goal:
            L += ["", (f"Layouts of the mode matrix at {GOAL[0]} x {GOAL[1]} (same process, {goal['dtype']}): "
                       f"modes-major (r, 3 nv) `q @ Phi_t` (the runtime's) {_ms(goal['gemv'])} ms; vertex-major "
                       f"(3 nv, r) C-ordered `Phi @ q` {_ms(goal['gemv_vertex_major'])} ms; the same "
                       f"Fortran-ordered {_ms(goal['gemv_fortran'])} ms. With float64 storage "
                       f"(`ModalBody(model, dtype=np.float64)`, the model's exact values): positions "
                       f"{_ms(goal['recon_f64'])} ms, step + positions {_ms(goal['both_f64'])} ms = "
                       f"{1 / goal['both_f64']:.0f} steps/s, {goal['both_f64'] / goal['copy_f64']:.2f}x the copy "
                       f"of the float64 matrix ({_ms(goal['copy_f64'])} ms).")]
    fem_intro = ("Versus one implicit full-FEM step of the same body (steel box "
                 f"{FEM_SIZE[0]} x {FEM_SIZE[1]} x {FEM_SIZE[2]} m, P1 linear elasticity assembled by scikit-fem, "
                 "backward Euler `(M + dt^2 K) v1 = M v0 - dt K u0`, SuperLU factorisation done once beforehand "
                 "and not counted in the step): modal = step + positions of that body's surface with 30 modes.")
    fem_header = ("| cells | DOFs | surface vertices | factorisation s | LU nnz | implicit FEM step ms | "
                  "modal step + positions ms | FEM / modal |")
    L += ["", fem_intro, "", fem_header, "|---|---|---|---|---|---|---|---|"]
    for f in fem:
        if "error" in f:
            L.append(f"| {'x'.join(map(str, f.get('cells', [])))} | error: {f['error']} |||||||")
            continue
        L.append(f"| {'x'.join(map(str, f['cells']))} | {f['dofs']} | {f['nv']} | {f['factor']:.2f} | "
                 f"{f['nnz_lu']} | {_ms(f['fem_step'])} | {_ms(f['modal'])} | {f['fem_step'] / f['modal']:.0f}x |")
    return "\n".join(L) + "\n"


def render_contact(resting: list[dict], pile: dict, *, command: str, date: str, machine: str, load: str) -> str:
    """The contact section (starts with ``CONTACT_SECTION``): resting bodies and the pile, each against the
    free step of the same bodies measured in the same process."""
    from modalfem.bench.contact_bench import GOALS

    L = [CONTACT_SECTION, "",
         ("Contact of modal bodies (`runtime.contact`: compiled matrix-free sequential impulses in generalised "
          "velocity space, O(6 + r) per contact and sweep; bodies touching each other in a `world.World`'s "
          "solid contact solve). Real models (modes from scikit-fem + SciPy, built once per run; see "
          "`modalfem/bench/contact_bench.py`). Each case in a fresh child process on one thread; the free step "
          "(`ModalSolver.step` without effects) of the same bodies is timed in the same process, and the contact "
          "cost is given as a ratio to it. dt = 1 ms."), "",
         f"- Date: {date}", f"- Command: `{command}`",
         f"- Machine: {machine}; load average when measured: {load} (other jobs shared the 2 cores: absolute "
         "times are inflated, the ratios less so)", "",
         ("Times are wall-clock medians; the CPU columns are the process's CPU time over the same calls (time spent "
          "waiting for a core is not in them: what one free core would give). The verdict is on the wall-clock "
          "steps/s."), "",
         "| case | surface vertices | modes | contacts | free step us | contact step us | contact / free | "
         "steps/s | CPU: free / contact us | CPU contact / free | CPU steps/s | goal steps/s | verdict | "
         "load before / after |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def cpu_of(r, free, step) -> str:
        if free not in r:
            return "? | ? | ?"
        return (f"{1e6 * r[free]:.1f} / {1e6 * r[step]:.0f} | {r[step] / r[free]:.1f} | {1.0 / r[step]:.0f}")

    def load_of(r) -> str:
        return " / ".join(f"{x:.2f}" for x in r["load"]) if "load" in r else "?"

    for name, r in resting:
        if "error" in r:
            L.append(f"| {name} | error: {r['error']} ||||||||||||")
            continue
        sps = 1.0 / r["contact"]
        goal = GOALS[name]
        L.append(f"| {name} resting on the ground | {r['nv']} | {r['r']} | {r['contacts']} | {1e6 * r['free']:.1f} | "
                 f"{1e6 * r['contact']:.0f} | {r['contact'] / r['free']:.1f} | {sps:.0f} | "
                 f"{cpu_of(r, 'free_cpu', 'contact_cpu')} | {goal:.0f} | "
                 f"**{'met' if sps >= goal else 'NOT met'}** | {load_of(r)} |")
    if "error" in pile:
        L.append(f"| pile | error: {pile['error']} ||||||||||||")
    elif pile:
        sps = 1.0 / pile["step"]
        L.append(f"| pile of {pile['count']} bodies in a box, one `World` ({pile['steps']} steps from the drop) | "
                 f"{pile['vertices']} (all bodies) | 8 each | {pile['contacts']} (max; up to {pile['pair_contacts']} "
                 f"body pairs exchanging impulses) | {1e6 * pile['free']:.0f} (all bodies) | {1e6 * pile['step']:.0f} | "
                 f"{pile['step'] / pile['free']:.0f} | {sps:.0f} | {cpu_of(pile, 'free_cpu', 'step_cpu')} | "
                 f"{GOALS['pile']:.0f} | "
                 f"**{'met' if sps >= GOALS['pile'] else 'NOT met'}** | {load_of(pile)} |")
    L += ["", ("Where the time of a step goes (cProfile on the process's CPU clock, own time per step, largest first; "
               "resting cases over 50 steps, the pile over 20 steps at its end):"), ""]
    for name, r in resting + [("pile", pile)]:
        if "profile" in r:
            L.append(f"- {name}: " + "; ".join(f"{fn} {1e6 * t:.0f} us" for fn, t in r["profile"]))
    if pile and "error" not in pile:
        sw = pile.get("sweeps", [0, 0, 0])
        L += ["", (f"Pile: stepped by a `world.World` (20 modal bodies, the box's ground and walls as static "
                   f"obstacles); its solid contact solve took {sw[0]:.1f} sweeps per step on average (at most "
                   f"{sw[1]}; capped at {sw[2]}, as the former `runtime.pairs.ContactGroup` did); "
                   f"{pile.get('intersections', '?')} intersecting triangle pairs at the end (exact test); momentum "
                   "of every body-body impulse and the no-energy-gain rule are tested in "
                   "tests/world/test_modal_contacts.py.")]
    return "\n".join(L) + "\n"


def _contact_cases(quick: bool) -> tuple[list, dict]:
    from modalfem.bench.contact_bench import build_models

    with tempfile.TemporaryDirectory() as d:
        print("[bench runtime] contact models (scikit-fem modes)", file=sys.stderr, flush=True)
        try:
            paths = build_models(d)
        except Exception as exc:  # noqa: BLE001 - reported in the table
            err = {"error": f"models: {exc}"}
            return [("bar", err), ("tall", err)], err
        resting = []
        for name in ("bar", "tall"):
            print(f"[bench runtime] {name} resting on the ground", file=sys.stderr, flush=True)
            resting.append((name, _spawn(["--case", "resting", "--model", paths[name]])))
        print("[bench runtime] pile of bodies in a box", file=sys.stderr, flush=True)
        pile = _spawn(["--case", "pile", "--models", d, "--count", "6" if quick else "20",
                       "--steps", "20" if quick else "600"], 1800.0)
    return resting, pile


def command(argv: list[str]) -> int:
    """``modalfem bench runtime [--out BENCHMARKS.md] [--quick]``: measure and write the section."""
    ap = argparse.ArgumentParser(prog="modalfem bench runtime",
                                 description="Modal step + reconstruction vs the copy floor and a full-FEM step.")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose runtime section is replaced")
    ap.add_argument("--quick", action="store_true", help="tiny sizes (smoke test)")
    ap.add_argument("--only", choices=["all", "step", "contact"], default="all",
                    help="measure only the step section or only the contact section (default: both)")
    a = ap.parse_args(argv)
    from modalfem.bench.cli import _machine, update_section

    cmd = "python -m modalfem bench runtime" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    if a.only in ("all", "step"):
        _step_section(a, cmd, date)
    if a.only in ("all", "contact"):
        resting, pile = _contact_cases(a.quick)
        load = "?"
        if os.path.exists("/proc/loadavg"):
            with open("/proc/loadavg") as f:
                load = f.read().split()[0]
        contact = render_contact(resting, pile, command=cmd, date=date, machine=_machine(), load=load)
        print(contact)
        update_section(a.out, contact)
    return 0


def _step_section(a, cmd: str, date: str) -> None:
    """Measure and write the step + reconstruction section."""
    vertices, modes = ((2000, 5000), (5, 10)) if a.quick else (VERTICES, MODES)
    fem_cells = [(8, 2, 2)] if a.quick else [FEM_CELLS]
    info = _spawn(["--case", "info"], 120)
    cases = []
    for nv in vertices:
        for r in modes:
            print(f"[bench runtime] {nv} vertices x {r} modes", file=sys.stderr, flush=True)
            res = _spawn(["--case", "runtime", "--nv", str(nv), "--r", str(r)]
                         + (["--layouts"] if (nv, r) == GOAL else []))
            cases.append({"nv": nv, "r": r, **res})
    fem = []
    for cells in fem_cells:
        print(f"[bench runtime] implicit FEM step, box {cells}", file=sys.stderr, flush=True)
        fem.append({"cells": list(cells), **_spawn(["--case", "fem", "--cells", *map(str, cells)])})
    from modalfem.bench.cli import _machine, update_section

    section = render(cases, fem, info, command=cmd, date=date, machine=_machine())
    print(section)
    update_section(a.out, section)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        sys.exit(_child(sys.argv[2:]))
    sys.exit(command(sys.argv[1:]))
