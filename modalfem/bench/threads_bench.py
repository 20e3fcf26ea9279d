"""``modalfem bench threads``: how the compiled kernels scale from 1 thread to 2 (or more).

Two goal cases, each in fresh child processes with ``MODALFEM_THREADS`` = 1 and = N (BLAS on one thread):
the 64x64 cloth pile with every collision stage (``modalfem bench cloth``'s case, its whole length) and
the 10k-tet bar's full Newton step (``modalfem bench tet``'s ``newton+cg`` case). The thread counts run
interleaved, ``1 N N 1`` per repeat, so a change of the machine's load hits both alike; each count's best
(least loaded) run is reported, with the load average before and after every run.

From the 1- and N-thread times the serial fraction s of Amdahl's law (``T_N = T_1 (s + (1 - s) / N)``,
so ``s = (N T_N / T_1 - 1) / (N - 1)``) and the speed it implies on 16 cores, ``T_1 / (s + (1 - s) / 16)``.
For the cloth the per-stage times at both counts show which stages scale.

Usage: ``python -m modalfem bench threads [--out BENCHMARKS.md] [--repeats 2] [--threads N] [--quick]``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import shlex
import subprocess
import sys
import time

import numba
import numpy as np

__all__ = ["SECTION", "amdahl", "command", "profile_share", "render", "replay"]

SECTION = "## Threads: scaling of the cloth pile and the tet step"
CLOTH_GOAL_1 = 10.0  # steps/s on one thread
CLOTH_GOAL_RATIO = 1.7  # two threads against one
TET_GOAL_2 = 30.0  # steps/s on two threads
TET_CELLS = (28, 10, 6)  # 10,080 tets


def amdahl(t1: float, tn: float, n: int) -> tuple[float, float]:
    """Serial fraction ``s`` (clipped to [0, 1]) from the times on 1 and ``n`` threads, and the speed-up
    it implies on 16 cores."""
    s = (n * tn / t1 - 1.0) / (n - 1) if n > 1 else 1.0
    s = min(max(s, 0.0), 1.0)
    return s, 1.0 / (s + (1.0 - s) / 16.0)


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:  # pragma: no cover - not Unix
        return float("nan")


def _cloth(steps: int | None, n: int, threads: int, timeout: float) -> dict:
    from modalfem.bench import cloth_bench

    args = ["--case", "pile", "--n", str(n)] + ([] if steps is None else ["--steps", str(steps)])
    return cloth_bench._spawn(args, timeout, threads=threads) or {"error": "timeout"}


def _tet(cells, steps: int, threads: int, timeout: float) -> dict:
    from modalfem.bench import tet_bench

    return tet_bench._run_case(cells, "newton+cg", steps, timeout, threads=threads)


#: kernels whose work runs in parallel chunks although they are not ``parallel=True`` themselves (they call
#: the parallel passes; the cloth ``pcg``'s coarse-level solve, O(192^2) per iteration, the SGS CG's few O(n)
#: copies per solve outside its sweeps (``pcg_sgs_ordered``) and ``select_indexed``'s marking through the vertex
#: index are serial)
_PARALLEL_CALLERS = {("modalfem.cloth._kernels", "pcg"), ("modalfem.cloth._sgs_kernels", "pcg_sgs_ordered"),
                     ("modalfem.tet._kernels", "pcg_twolevel"), ("modalfem.collision._pair_kernels", "select_indexed")}


def _is_parallel(filename: str, name: str) -> bool:
    """The profile entry ``filename:name`` is a compiled kernel with ``parallel=True`` (or in
    ``_PARALLEL_CALLERS``)."""
    import importlib

    norm = filename.replace(os.sep, "/")
    if "/modalfem/" not in norm or not norm.endswith(".py"):
        return False
    module = "modalfem." + norm.rsplit("/modalfem/", 1)[1][:-3].replace("/", ".")
    if (module, name) in _PARALLEL_CALLERS:
        return True
    try:
        fn = getattr(importlib.import_module(module), name, None)
    except ImportError:
        return False
    return bool(getattr(fn, "targetoptions", {}).get("parallel"))


def profile_share(case: str, steps: int | None) -> dict:
    """One-thread CPU profile of a case's steps (set-up outside; ``time.process_time`` as the profiler's
    clock, so waiting for a core on a loaded machine does not count): CPU seconds in parallel kernels and
    in everything, and the kernels' own times. In this process; call it in a child with
    ``MODALFEM_THREADS=1``. ``steps`` None: the pile's 80 steps, 20 tet steps."""
    import cProfile
    import pstats

    from modalfem.bench import cloth_bench, tet_bench

    if case == "cloth":
        from modalfem.cloth import scenes

        # compile (or load from the cache) every kernel outside the profile: a pile of 24 x 24 that meets CCD hits,
        # impact zones and smoothing within 40 steps
        cloth_bench.run_case("pile", 24, 40)
        setup = scenes.pile(64)
        count = setup.steps if steps is None else steps

        def run():
            for _ in range(count):
                setup.scene.step(setup.dt)
    else:
        from modalfem.material import Material
        from modalfem.mesh import box
        from modalfem.tet.effects import Gravity, Pins
        from modalfem.tet.model import tet_model
        from modalfem.tet.solver import TetSolver, TetState

        tet_bench.run_case_here((4, 2, 2), "newton+cg", 1)
        mesh = box(size=tuple(0.05 * c for c in TET_CELLS), cells=TET_CELLS)
        model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
        solver = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))])
        state = TetState.at_rest(model)
        count = steps or 20

        def run():
            for _ in range(count):
                solver.step(state, state, tet_bench.DT)
    prof = cProfile.Profile(time.process_time)
    prof.enable()
    run()
    prof.disable()
    return _profile_summary(pstats.Stats(prof).stats, count)


_LAUNCH_HOOKS: list = []  # the ctypes callbacks the kernels' code calls: they must live as long as the process


def count_launches() -> list | None:
    """Count the parallel regions numba starts from now on in this process: returns ``[count]``, incremented at
    every launch, or None when the threading layer is not TBB. numba calls its layer's ``parallel_for`` through
    the symbol ``numba_parallel_for``, bound when a compiled kernel's code is linked (its first call in the
    process); this points the symbol at a counting wrapper, so it must run before the first parallel kernel of
    the process does. Every region counts: a ``prange`` loop, and also each ``np.zeros``/``np.ones``, array
    expression or reduction that ``parallel=True`` turns into a loop of its own (a kernel's profile counts its
    calls only: one call can start several regions, or none on a serial branch). The wrapper is Python (a few
    us per launch): count in a run that times nothing else."""
    import ctypes

    import llvmlite.binding as ll

    from modalfem._threads import threading_layer

    if threading_layer() != "tbb":
        return None
    from numba.np.ufunc import parallel, tbbpool

    parallel._launch_threads()  # numba's own symbols first (it registers them once), then the wrapper over them
    sig = (None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
           ctypes.c_size_t, ctypes.c_size_t, ctypes.c_int)
    real = ctypes.PYFUNCTYPE(*sig)(tbbpool.parallel_for)  # (fn, args, dims, steps, data, inner_ndim, arrays, threads)
    count = [0]

    def counted(*args):
        count[0] += 1
        real(*args)

    hook = ctypes.CFUNCTYPE(*sig)(counted)
    _LAUNCH_HOOKS.append(hook)
    ll.add_symbol("numba_parallel_for", ctypes.cast(hook, ctypes.c_void_p).value)
    return count


def launches_per_step(steps: int | None) -> dict | None:
    """Parallel regions per step of the 64x64 cloth pile (one thread; :func:`count_launches`, so call it in a fresh
    child before any kernel runs), in all and by the kernel called from Python that started them:
    ``{"per_step": float, "after_python": float, "by_kernel": {"file.py:name": per step}, "calls": {"file.py:name":
    calls per step}}``. ``after_python``: the kernel calls that started at least one region, i.e. the regions that
    follow serial Python and may find the pool asleep (a kernel's further regions follow its first within
    microseconds). None when the layer is not TBB. ``steps`` None: the pile's 80."""
    import collections

    count = count_launches()
    if count is None:
        return None
    from modalfem.bench import cloth_bench
    from modalfem.cloth import scenes

    cloth_bench.run_case("pile", 24, 40)  # every kernel linked (through the counter) before the count
    setup = scenes.pile(64)
    steps = setup.steps if steps is None else steps
    stack: list = []
    by: collections.Counter = collections.Counter()
    calls: collections.Counter = collections.Counter()

    def trace(frame, event, arg):  # a compiled kernel shows as a call of its Python function
        if event == "call":
            stack.append(f"{os.path.basename(frame.f_code.co_filename)}:{frame.f_code.co_name}")
            calls[stack[-1]] += 1
        elif event == "return" and stack:
            stack.pop()

    seen = [0]

    starts = [0]

    def attribute():
        if count[0] != seen[0]:  # launches since the last event belong to the innermost call
            by[stack[-1] if stack else "?"] += count[0] - seen[0]
            seen[0] = count[0]
            starts[0] += 1

    def traced(frame, event, arg):
        if frame.f_code.co_name == "counted" and frame.f_code.co_filename == __file__:
            return  # the counter's own Python wrapper, called from inside the kernel
        attribute()
        trace(frame, event, arg)

    start = count[0]
    seen[0] = start
    sys.setprofile(traced)
    try:
        for _ in range(steps):
            setup.scene.step(setup.dt)
    finally:
        sys.setprofile(None)
    attribute()
    return {"per_step": (count[0] - start) / steps, "after_python": starts[0] / steps,
            "by_kernel": {k: v / steps for k, v in by.most_common()}, "calls": {k: calls[k] / steps for k in by}}


def _profile_summary(stats: dict, steps: int) -> dict:
    """From ``pstats.Stats(...).stats`` of ``steps`` steps: CPU seconds in everything (``total_s``) and in the
    parallel kernels (``parallel_s``), and per kernel its own CPU seconds (``kernels``) and calls (``calls``)."""
    total = sum(v[2] for v in stats.values())
    par = {f"{os.path.basename(f)}:{name}": v for (f, _, name), v in stats.items() if _is_parallel(f, name)}
    kernels = {k: v[2] for k, v in par.items()}
    return {"total_s": total, "parallel_s": sum(kernels.values()), "kernels": kernels,
            "calls": {k: v[1] for k, v in par.items()}, "steps": steps}


def replay(case: str, n: int, repeats: int, *, warm: int, window: int) -> dict:
    """Replayed steps: the case advanced ``warm`` steps, then the same ``window`` steps replayed from a copy
    of that state ``repeats`` times on 1 and on ``n`` threads (interleaved ``1 n n 1``), in this process.
    The fastest replay of each count is the least disturbed by other load (the work is identical).
    Returns ``{"1": [ms/step, ...], "n": [...]}``."""
    import copy

    from modalfem._threads import thread_count

    if case == "cloth":
        from modalfem.cloth import scenes

        setup = scenes.pile(64)
        state, dt = setup.scene, setup.dt

        def advance(obj):
            obj.step(dt)
    else:
        from modalfem.bench import tet_bench
        from modalfem.material import Material
        from modalfem.mesh import box
        from modalfem.tet.effects import Gravity, Pins
        from modalfem.tet.model import tet_model
        from modalfem.tet.solver import TetSolver, TetState

        mesh = box(size=tuple(0.05 * c for c in TET_CELLS), cells=TET_CELLS)
        model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
        state = (TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))]), TetState.at_rest(model))

        def advance(obj):
            obj[0].step(obj[1], obj[1], tet_bench.DT)
    for _ in range(warm):
        advance(state)
    out: dict = {"1": [], str(n): []}
    for t in (1, n):  # one untimed replay per count (first launches of the thread pool at that count)
        with thread_count(t):
            obj = copy.deepcopy(state)
            for _ in range(window):
                advance(obj)
    for r in range(repeats):
        for t in (1, n, n, 1) if r % 2 == 0 else (n, 1, 1, n):
            obj = copy.deepcopy(state)
            with thread_count(t):
                t0 = time.perf_counter()
                for _ in range(window):
                    advance(obj)
                out[str(t)].append(1e3 * (time.perf_counter() - t0) / window)
    return out


def probe(n: int, seconds: float = 1.0) -> float:
    """How many cores this process gets right now: CPU time / wall time of ``seconds`` of a trivially
    parallel compiled loop on ``n`` threads (``n`` on an idle machine; about 1 when other processes hold
    the other cores, e.g. other users' sessions, which the scheduler shares the cores with as groups)."""
    from modalfem._threads import thread_count

    a = np.zeros(64)
    _probe_kernel(a, 10)
    with thread_count(n):
        c0, t0 = time.process_time(), time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            _probe_kernel(a, 20000)
        return (time.process_time() - c0) / (time.perf_counter() - t0)


def throughput(n: int, seconds: float = 1.0) -> float:
    """Work per second of the same trivially parallel compiled loop on ``n`` threads over that on one thread,
    the two counts alternating in slices of ``seconds / 8`` (``n`` when ``n`` free cores run at full speed).
    Unlike :func:`probe` (CPU time / wall time), this also sees a core that the process is scheduled on but
    that runs slowly (a busy hyperthread sibling or a time-sliced virtual CPU): then it reads below ``n``
    while the probe still reads ``n``."""
    from modalfem._threads import thread_count

    a = np.zeros(64)
    done = {1: [0, 0.0], n: [0, 0.0]}
    for t in (1, n):
        with thread_count(t):
            _probe_kernel(a, 10)
    for k in range(8):
        for t in ((1, n) if k % 2 == 0 else (n, 1)):
            with thread_count(t):
                t0 = time.perf_counter()
                while time.perf_counter() - t0 < seconds / 16:
                    _probe_kernel(a, 20000)
                    done[t][0] += 1
                done[t][1] += time.perf_counter() - t0
    return (done[n][0] / done[n][1]) / (done[1][0] / done[1][1])


def _busy(seconds: float) -> None:
    """Python busy for ``seconds`` (the serial glue between two parallel regions)."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        pass


def wake_probe(n: int, gaps_us=(0.0, 200.0, 2000.0), work_us: float = 100.0, calls: int = 100) -> dict:
    """Cost of waking the pool: wall time of one small parallel region (64 chunks, ``work_us`` [us] of work
    on one thread) launched right after ``gap`` [us] of busy serial Python, on 1 and ``n`` threads
    (alternating call by call). While Python runs, the idle workers stop spinning and sleep; a region that
    has to wake them (or a virtual CPU the hypervisor has descheduled) starts late. With free cores the
    ``n``-thread region takes about ``work_us / n`` plus the launch; a time that grows with the gap is the
    wake-up. Returns ``{"work_us": calibrated work, "gaps": {gap: {"1": median us, "n": median us}}}``."""
    from modalfem._threads import thread_count

    a = np.zeros(64)
    with thread_count(1):
        _probe_kernel(a, 10)
        work, best = 1000, np.inf
        for _ in range(5):  # calibrate the work per chunk to ~work_us on one thread (fastest of 5)
            t0 = time.perf_counter()
            _probe_kernel(a, work)
            best = min(best, time.perf_counter() - t0)
        work = max(1, int(work * work_us * 1e-6 / best))
    with thread_count(n):
        _probe_kernel(a, 10)
    out: dict = {}
    for gap in gaps_us:
        times: dict = {1: [], n: []}
        for k in range(2 * calls):
            t = (1, n)[(k + k // 2) % 2]  # 1 n n 1 1 n ...
            with thread_count(t):
                _busy(gap * 1e-6)
                t0 = time.perf_counter()
                _probe_kernel(a, work)
                times[t].append(1e6 * (time.perf_counter() - t0))
        out[float(gap)] = {"1": float(np.median(times[1])), str(n): float(np.median(times[n]))}
    return {"work_us": work_us, "gaps": out}


def wake_lines(wake: dict | None, n: int, launches: float | None = None, counted: dict | None = None) -> list[str]:
    """Markdown lines of :func:`wake_probe`; ``launches``: parallel kernel calls per step of the cloth pile
    (from its profile), to price the wake-up per step; ``counted``: :func:`launches_per_step`'s regions (used
    instead when given: calls are not regions)."""
    if not wake:
        return []
    gaps = wake["gaps"]
    L = ["", (f"Waking the pool: one parallel region of ~{wake['work_us']:.0f} us of work (one thread) launched "
              f"after a gap of busy serial Python, median of many calls, 1 and {n} threads alternating. With free "
              f"cores {n} threads take about 1/{n} of it plus the launch; growth with the gap is the time the "
              "sleeping workers take to wake:"), "",
         f"| serial gap before the region us | 1 thread us | {n} threads us | speed-up |", "|---:|---:|---:|---:|"]
    for gap, r in sorted(gaps.items()):
        L.append(f"| {gap:.0f} | {r['1']:.1f} | {r[str(n)]:.1f} | {r['1'] / r[str(n)]:.2f}x |")
    keys = sorted(gaps)
    if counted:
        launches = counted["per_step"]
        top = ", ".join(f"{k} {v:.1f} ({counted['calls'].get(k, 0.0):.1f} calls)"
                        for k, v in list(counted["by_kernel"].items())[:8])
        what = (f"starts {launches:.0f} parallel regions per step (counted at numba's launch, one thread; by the "
                f"kernel called from Python: {top}), {counted.get('after_python', 0.0):.0f} of them after serial "
                "Python (the others follow another region of the same kernel within microseconds)")
    else:
        what = (f"launches at least {launches or 0:.0f} parallel kernels per step (calls counted in its one-thread "
                "profile; the CG solves launch more inside)")
    if launches and len(keys) > 1:
        # the growth on n threads beyond that on one thread (which has no workers to wake)
        lo, hi = gaps[keys[0]], gaps[keys[-1]]
        extra = max(0.0, (hi[str(n)] - lo[str(n)]) - (hi["1"] - lo["1"]))
        L += ["", (f"The cloth pile {what}: at {extra:.1f} us more per region on "
                   f"{n} threads after a {keys[-1]:.0f} us gap than back to back (beyond the change on one thread), "
                   f"the wake-ups would cost up to {launches * extra / 1e3:.1f} ms per step on {n} threads.")]
    return L


def kernel_times(n: int, repeats: int) -> dict:
    """Single kernels on the goal cases' data, each called ``repeats`` times per thread count (1 and ``n``,
    interleaved), in this process: ``{name: {"1": fastest ms, "n": fastest ms}}``. The pile is taken at
    step 60 (its settled, many-layer phase), the bar after 5 steps."""
    import copy

    from modalfem.bench import tet_bench
    from modalfem.cloth import _kernels as ck
    from modalfem.cloth import scenes
    from modalfem.cloth.solver import _constraints
    from modalfem.collision import _ccd_kernels
    from modalfem.collision._system import System
    from modalfem.collision.repulsion import PairOrder, pair_order, repulsion_pairs, sequential_pair_impulses
    from modalfem.material import Material
    from modalfem.mesh import box
    from modalfem.tet import _kernels as tk
    from modalfem.tet import energies
    from modalfem.tet.effects import Gravity, Pins
    from modalfem.tet.kinematics import svd_rv_of_positions
    from modalfem.tet.model import tet_model
    from modalfem.tet.solver import TetSolver, TetState, _matvec
    from modalfem._threads import thread_count

    setup = scenes.pile(64)
    for _ in range(60):
        setup.scene.step(setup.dt)
    sc = copy.deepcopy(setup.scene)
    sol, x = sc.solver, np.asarray(sc.x)
    pat, lv = sol._pattern, sol._levels
    data = sol._stiffness_data(x).copy()
    pat.add_diagonal(data, sol._m3 / setup.dt**2)  # M / dt^2 + K: the implicit step's matrix
    kind, normal, z = _constraints(pat.n, None, None, None)
    b = np.random.default_rng(0).standard_normal((pat.n, 3))
    Dinv, Cinv = lv.inverses(pat.indptr, pat.indices, data, kind, normal)
    x1 = x + setup.dt * np.asarray(sc.v)
    system = System(sc.model.mesh.triangles, ())
    system.build_cloth_bvh(x)
    cand = system.candidates(x, x1, margin=sc.pipeline.config.eta if sc.pipeline else 1e-3, self_collision=True,
                             culling=False)
    movable, roots = np.ones(len(x), dtype=bool), np.zeros(0, dtype=np.int64)
    h = sc.pipeline.config.thickness if sc.pipeline else 4e-3
    near = system.candidates(x, x, margin=0.5 * h, self_collision=True, culling=True)
    near = repulsion_pairs(x, near.vf, near.ee, thickness=h, dt=setup.dt)  # stage (a)'s pairs closer than h
    grouped = pair_order(x, movable, near[0]).arrange(*near)
    invm, v0 = 1.0 / sc.model.masses, copy.deepcopy(sc).implicit_velocity(setup.dt)[0]  # what stage (a) gets
    mu = sc.pipeline.config.friction if sc.pipeline else 0.3
    mesh = box(size=tuple(0.05 * c for c in TET_CELLS), cells=TET_CELLS)
    model = tet_model(mesh, Material(E=1e6, nu=0.3, rho=1000.0))
    solver, state = TetSolver(model, effects=[Gravity(), Pins(mesh.tag_points("x0"))]), TetState.at_rest(model)
    for _ in range(5):
        solver.step(state, state, tet_bench.DT)
    U, sv, V = svd_rv_of_positions(state.x, model.cells, solver._grad_t)
    d = model.density.derivs(sv, 2)
    A = solver.pattern.matrix(solver.pattern.assemble(
        energies.element_forces_and_hessians(U, V, d, solver._grad_t, model.rest_volumes, element_last=True)[1],
        solver.mass_dofs, upper=True))
    u, out = np.ones(A.shape[0]), np.empty(A.shape[0])

    def pcg():
        ck.pcg(pat.indptr, pat.indices, data, pat.diag, kind, normal, b, z.copy(), 1e-4, 2000, lv.agg, lv.up, lv.off,
               Dinv, Cinv)

    def pcg_sgs():
        from modalfem.cloth import _sgs_kernels

        _sgs_kernels.pcg_sgs(pat.indptr, pat.indices, data, pat.diag, kind, normal, b, z.copy(), 1e-4, 2000)

    blocks = sol._setup("sgs-blocks")

    def pcg_sgs_blocks():
        blocks.solve(data, kind, normal, b, z.copy(), 1e-4, 2000)

    cases = {
        "cloth: implicit-step CG solve, SGS in vertex order (serial sweeps) (rtol 1e-4)": pcg_sgs,
        "cloth: implicit-step CG solve, SGS block multicolour (default; parallel sweeps) (rtol 1e-4)": pcg_sgs_blocks,
        "cloth: implicit-step CG solve, multilevel (rtol 1e-4)": pcg,
        "cloth: stiffness assembly (element blocks + per-block gather)": lambda: sol._stiffness_data(x),
        "cloth: multilevel preconditioner setup (level matrices)": lambda: lv.inverses(
            pat.indptr, pat.indices, data, kind, normal),
        "cloth: repulsion sweeps in pair order (serial), 10 sweeps": lambda: sequential_pair_impulses(
            v0, invm, *near, friction=mu, sweeps=10, order=PairOrder.serial(len(near[0]), len(x))),
        "cloth: repulsion sweeps in parallel groups (default), 10 sweeps": lambda: sequential_pair_impulses(
            v0, invm, *grouped[:4], friction=mu, sweeps=10, order=grouped[4]),
        "cloth: candidate pairs (BVH traversal + pair expansion)": lambda: system.candidates(
            x, x1, margin=1e-3, self_collision=True, culling=False),
        "cloth: CCD of the candidates": lambda: (
            _ccd_kernels.ccd_candidates(True, x, x1, cand.vf, movable, roots, 1e-4, 32, 64),
            _ccd_kernels.ccd_candidates(False, x, x1, cand.ee, movable, roots, 1e-4, 32, 64)),
        "tet: SVD of the deformation gradients": lambda: svd_rv_of_positions(state.x, model.cells, solver._grad_t, V),
        "tet: element forces and Hessians": lambda: energies.element_forces_and_hessians(
            U, V, d, solver._grad_t, model.rest_volumes, element_last=True),
        "tet: CG product (CSR)": lambda: _matvec(A, u, out),
    }
    res = {}
    for name, fn in cases.items():
        best = {1: np.inf, n: np.inf}
        for t in (1, n):
            with thread_count(t):
                fn()
        for r in range(repeats):
            for t in (1, n, n, 1):
                with thread_count(t):
                    t0 = time.perf_counter()
                    fn()
                    best[t] = min(best[t], time.perf_counter() - t0)
        res[name] = {"1": 1e3 * best[1], str(n): 1e3 * best[n]}
    return res


def kernel_lines(kernels: dict | None, n: int) -> list[str]:
    """Markdown lines of ``kernel_times``."""
    if not kernels:
        return []
    L = ["", (f"Kernels alone on the same data (fastest of many calls, 1 and {n} threads interleaved): what they "
              "give when both cores happen to be free, on a busy machine too:"), "",
         f"| kernel | 1 thread ms | {n} threads ms | speed-up |", "|---|---:|---:|---:|"]
    for name, r in kernels.items():
        L.append(f"| {name} | {r['1']:.2f} | {r[str(n)]:.2f} | {r['1'] / r[str(n)]:.2f}x |")
    return L


def _kernels_child(n: int, repeats: int, timeout: float) -> dict | None:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env.pop("MODALFEM_THREADS", None)
    cmd = [sys.executable, "-m", "modalfem.bench.threads_bench", "--kernels", "--threads", str(n), "--repeats",
           str(repeats)]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return None
    if p.returncode != 0:
        print(f"  kernels failed: {(p.stderr.strip().splitlines() or ['?'])[-1]}", file=sys.stderr)
        return None
    return json.loads(p.stdout.strip().splitlines()[-1])


def _replay_child(case: str, n: int, repeats: int, timeout: float) -> dict | None:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env.pop("MODALFEM_THREADS", None)
    cmd = [sys.executable, "-m", "modalfem.bench.threads_bench", "--replay", case, "--threads", str(n),
           "--repeats", str(repeats)]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return None
    if p.returncode != 0:
        print(f"  replay {case} failed: {(p.stderr.strip().splitlines() or ['?'])[-1]}", file=sys.stderr)
        return None
    return json.loads(p.stdout.strip().splitlines()[-1])


#: (label, warm-up steps, replayed steps) of the replays: the pile's settled many-layer phase (steps 61-63
#: of its 80) and the sagging bar after 5 steps
REPLAYS = {"cloth": ("cloth pile 64x64, steps 61-63", 60, 3), "tet": ("tet bar 10080 tets, steps 6-8", 5, 3)}


def replay_lines(replays: dict, n: int) -> list[str]:
    """Markdown lines of the replays: fastest and median ms/step on 1 and ``n`` threads, the speed-up of
    the fastest and the serial fraction it implies."""
    if not replays:
        return []
    L = ["", (f"Replays (the same steps re-run from a copy of one state, 1 and {n} threads interleaved, in one "
              "process): the fastest of the repeats is the least disturbed by other processes, so its ratio is "
              "the best estimate here of what free cores give:"), "",
         f"| steps | repeats | 1 thread fastest / median ms | {n} threads fastest / median ms | speed-up (fastest) "
         "| serial fraction | at 16 cores |", "|---|---:|---:|---:|---:|---:|---:|"]
    for label, rep in replays.items():
        if not rep:
            L.append(f"| {label} | failed | | | | | |")
            continue
        a, b = sorted(rep["1"]), sorted(rep[str(n)])
        s, sp16 = amdahl(a[0], b[0], n)
        L.append(f"| {label} | {len(a)} | {a[0]:.1f} / {a[len(a) // 2]:.1f} | {b[0]:.1f} / {b[len(b) // 2]:.1f} | "
                 f"{a[0] / b[0]:.2f}x | {s:.2f} | {sp16:.1f}x |")
    return L


@numba.njit(parallel=True, cache=True)
def _probe_kernel(a, work):
    for ch in numba.prange(len(a)):
        s = 0.0
        for i in range(work):
            s += math.sqrt(i + ch + 1.0)
        a[ch] = s


def _best(runs: list[dict]) -> dict | None:
    ok = [r for r in runs if "ms_per_step" in r]
    return min(ok, key=lambda r: r["ms_per_step"]) if ok else None


def render(cloth: dict, tet: dict, n: int, *, command: str, date: str, machine: str, layer: str,
           cloth_label: str, tet_label: str) -> str:
    """The markdown section from ``{threads: [runs]}`` of each case (each run with ``load`` = (before,
    after))."""
    L = [SECTION, "", f"- Date: {date}", f"- Machine: {machine}", f"- Command: `{command}`",
         (f"- numba threading layer `{layer}`; each run a fresh process with `MODALFEM_THREADS` = 1 or {n} and "
          "BLAS on one thread; the counts interleaved (`1 N N 1` per repeat); each count's fastest run shown "
          "(ms/step: the case's own measure, see its section); load = 1-minute load average before / after "
          "that run (the machine is shared: a load above its core count slows the N-thread runs most)."),
         ("- Serial fraction s from Amdahl's law on the 1- and N-thread times, `s = (N T_N / T_1 - 1) / (N - 1)`; "
          "'at 16 cores' is the speed that s implies there, `T_1 / (s + (1 - s) / 16)` (an upper bound: memory "
          "bandwidth and launch costs grow with the thread count)."), "",
         "| case | threads | ms/step | steps/s | CPU ms/step | speed-up | serial fraction | at 16 cores | load |",
         "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    verdicts = []
    for label, runs in ((cloth_label, cloth), (tet_label, tet)):
        one, many = _best(runs.get(1, [])), _best(runs.get(n, []))
        for t, r in ((1, one), (n, many)):
            if r is None:
                errs = [x.get("error", "?") for x in runs.get(t, [])]
                L.append(f"| {label} | {t} | {'; '.join(errs) or 'not run'} | | | | | | |")
                continue
            load = "{:.1f} / {:.1f}".format(*r["load"])
            extra = "| | | |"
            if t == n and one is not None:
                s, sp16 = amdahl(one["ms_per_step"], r["ms_per_step"], n)
                extra = (f"| {one['ms_per_step'] / r['ms_per_step']:.2f}x | {s:.2f} | "
                         f"{sp16 * 1e3 / one['ms_per_step']:.1f} steps/s ({sp16:.1f}x) |")
            L.append(f"| {label} | {t} | {r['ms_per_step']:.1f} | {1e3 / r['ms_per_step']:.2f} | "
                     f"{r.get('cpu_ms_per_step', float('nan')):.1f} {extra} {load} |")
        if label == cloth_label and one is not None:
            ok1 = 1e3 / one["ms_per_step"] >= CLOTH_GOAL_1
            verdicts.append(f"Cloth goal (>= {CLOTH_GOAL_1:g} steps/s on one thread): {1e3 / one['ms_per_step']:.2f} "
                            f"steps/s, **{'met' if ok1 else 'not met'}**; intersections "
                            f"{one.get('intersections')} (1 thread)"
                            + (f", {many.get('intersections')} ({n} threads)" if many else "") + ".")
            if many is not None:
                ratio = one["ms_per_step"] / many["ms_per_step"]
                verdicts.append(f"Cloth goal (>= {CLOTH_GOAL_RATIO:g}x on two threads): {ratio:.2f}x, "
                                f"**{'met' if ratio >= CLOTH_GOAL_RATIO else 'not met'}**.")
        if label == tet_label and many is not None:
            sps = 1e3 / many["ms_per_step"]
            verdicts.append(f"Tet goal (>= {TET_GOAL_2:g} steps/s on two threads): {sps:.1f} steps/s, "
                            f"**{'met' if sps >= TET_GOAL_2 else 'not met'}**"
                            + ("" if one is None or one["ms_per_step"] <= 2e3 / TET_GOAL_2 else
                               f" (even a perfect 2x would need <= {2e3 / TET_GOAL_2:.0f} ms/step on one thread; "
                               f"measured {one['ms_per_step']:.0f})") + ".")
    one, many = _best(cloth.get(1, [])), _best(cloth.get(n, []))
    if one is not None and many is not None and "shares" in one and "shares" in many:
        L += ["", f"Cloth pile per stage (ms per step, fastest run of each count; stages as in the cloth section):",
              "", f"| stage | 1 thread | {n} threads | speed-up |", "|---|---:|---:|---:|"]
        for stage, share in one["shares"].items():
            a, b = share * one["ms_per_step"], many["shares"][stage] * many["ms_per_step"]
            L.append(f"| {stage} | {a:.1f} | {b:.1f} | {a / b if b > 0 else float('nan'):.2f}x |")
        rest1 = one["ms_per_step"] * (1 - sum(one["shares"].values()))
        restn = many["ms_per_step"] * (1 - sum(many["shares"].values()))
        L.append(f"| other (Python, inputs, bookkeeping) | {rest1:.1f} | {restn:.1f} | "
                 f"{rest1 / restn if restn > 0 else float('nan'):.2f}x |")
    if verdicts:
        L += [""] + verdicts
    return "\n".join(L) + "\n"


def _profile_child(case: str, steps: int | None, timeout: float) -> dict | None:
    env = {**os.environ, "MODALFEM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "modalfem.bench.threads_bench", "--profile", case,
           "--steps", str(steps or 0)]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return None
    if p.returncode != 0:
        print(f"  profile {case} failed: {(p.stderr.strip().splitlines() or ['?'])[-1]}", file=sys.stderr)
        return None
    return json.loads(p.stdout.strip().splitlines()[-1])


def _launches_child(steps: int | None, timeout: float) -> dict | None:
    env = {**os.environ, "MODALFEM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "modalfem.bench.threads_bench", "--launches", "--steps", str(steps or 0)]
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return None
    if p.returncode != 0:
        return None
    return json.loads(p.stdout.strip().splitlines()[-1])


def profile_lines(profiles: dict) -> list[str]:
    """Markdown lines of the one-thread CPU profiles: the parallel share, the Amdahl bounds it implies
    and the largest kernels."""
    if not profiles:
        return []
    L = ["", ("One-thread CPU profiles (a child per case, `cProfile` with `time.process_time` as its clock: "
              "not inflated by waiting for a core). Parallel share p = CPU time in the parallel kernels / all "
              "CPU time of the run; Amdahl's bound from it, `1 / ((1 - p) + p / N)`, is what N free cores "
              "could give at most:"), "",
         "| case | CPU s | in parallel kernels | bound on 2 cores | bound on 16 cores | largest kernels (CPU s) |",
         "|---|---:|---:|---:|---:|---|"]
    for label, pr in profiles.items():
        if not pr:
            L.append(f"| {label} | failed | | | | |")
            continue
        p = pr["parallel_s"] / pr["total_s"]
        top = sorted(pr["kernels"].items(), key=lambda kv: -kv[1])[:6]
        L.append(f"| {label} | {pr['total_s']:.1f} | {100 * p:.0f} % | {1 / ((1 - p) + p / 2):.2f}x | "
                 f"{1 / ((1 - p) + p / 16):.2f}x | " + ", ".join(f"{k} {v:.2f}" for k, v in top) + " |")
    need = (1 - 1 / CLOTH_GOAL_RATIO) / (1 - 1 / 2)
    L += ["", (f"A speed-up of {CLOTH_GOAL_RATIO:g}x on 2 cores needs a parallel share of at least {100 * need:.0f} % "
               "(Amdahl); what is not in a parallel kernel (the Python of the pipeline's stages, numpy "
               "bookkeeping, the pair store's updates, the impact zones' union-find and per-zone solves) sets the "
               "bound.")]
    return L


def command(argv: list[str]) -> int:
    """``modalfem bench threads``: run both cases at 1 and N threads, print and write the section."""
    ap = argparse.ArgumentParser(prog="modalfem bench threads")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose threads section is replaced")
    ap.add_argument("--threads", type=int, default=None, help="the N of the comparison (default: every core)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per thread count (default 2)")
    ap.add_argument("--tet-steps", type=int, default=20, help="measured tet steps per run (default 20)")
    ap.add_argument("--cloth-steps", type=int, default=None, help="cloth steps per run (default: the scene's 80)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="per run [s]")
    ap.add_argument("--quick", action="store_true", help="tiny cases (smoke test)")
    ap.add_argument("--no-profile", action="store_true", help="skip the one-thread CPU profiles")
    a = ap.parse_args(argv)
    from modalfem.bench.cli import _machine, update_section
    from modalfem._threads import _cores, threading_layer

    n = a.threads or _cores()
    if n < 2:
        print("modalfem: error: bench threads needs at least 2 threads to compare (--threads N)", file=sys.stderr)
        return 2
    cloth_n, cells = (8, (4, 2, 2)) if a.quick else (64, TET_CELLS)
    cloth_steps, tet_steps = (10, 3) if a.quick else (a.cloth_steps, a.tet_steps)
    t0 = time.perf_counter()
    probes, rates = [probe(n)], [throughput(n)]
    print(f"[bench threads] cores this process gets now: {probes[0]:.2f}; work per second on {n} threads / on 1: "
          f"{rates[0]:.2f}", file=sys.stderr, flush=True)
    wake = None if a.quick else wake_probe(n)
    print("[bench threads] warm-up (fills numba's disk cache, not timed) ...", file=sys.stderr, flush=True)
    _cloth(5, 8, n, a.timeout)
    _tet((4, 2, 2), 1, n, a.timeout)
    cloth: dict = {1: [], n: []}
    tet: dict = {1: [], n: []}
    for rep in range(max(1, a.repeats)):
        for t in (1, n, n, 1)[: 2 if a.quick else 4][:: 1 if rep % 2 == 0 else -1]:
            for name, store, run in (("cloth pile", cloth, lambda t=t: _cloth(cloth_steps, cloth_n, t, a.timeout)),
                                     ("tet newton+cg", tet, lambda t=t: _tet(cells, tet_steps, t, a.timeout))):
                before = _load()
                print(f"[bench threads] {name}, {t} thread(s), repeat {rep + 1} (load {before:.1f}) ...",
                      file=sys.stderr, flush=True)
                r = run()
                r["load"] = (before, _load())
                if "ms_per_step" in r:
                    print(f"[bench threads]   {r['ms_per_step']:.1f} ms/step", file=sys.stderr, flush=True)
                store[t].append(r)
    kernels = None
    if not (a.quick or a.no_profile):
        print("[bench threads] kernels alone ...", file=sys.stderr, flush=True)
        kernels = _kernels_child(n, max(10, 5 * a.repeats), a.timeout)
    replays = {}
    if not (a.quick or a.no_profile):
        for case, (label, _, _) in REPLAYS.items():
            print(f"[bench threads] replay: {label} ...", file=sys.stderr, flush=True)
            replays[label] = _replay_child(case, n, max(6, 3 * a.repeats), a.timeout)
    profiles = {}
    if not (a.quick or a.no_profile):
        for case, label, steps in (("cloth", "cloth pile 64x64", cloth_steps),
                                   ("tet", "tet bar, newton+cg", tet_steps)):
            print(f"[bench threads] one-thread CPU profile: {label} ...", file=sys.stderr, flush=True)
            profiles[label] = _profile_child(case, steps, a.timeout)
    cmd = "python -m modalfem bench threads" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    tets = 6 * cells[0] * cells[1] * cells[2]
    section = render(cloth, tet, n, command=cmd, date=date, machine=_machine(), layer=threading_layer(),
                     cloth_label=f"cloth pile {cloth_n}x{cloth_n}, all stages",
                     tet_label=f"tet bar {tets} tets, newton+cg")
    probes.append(probe(n))
    rates.append(throughput(n))
    pile = profiles.get("cloth pile 64x64") or {}
    launches = sum(pile.get("calls", {}).values()) / pile["steps"] if pile.get("steps") else None
    counted = None
    if not (a.quick or a.no_profile):
        print("[bench threads] parallel regions per step of the cloth pile ...", file=sys.stderr, flush=True)
        counted = _launches_child(cloth_steps, a.timeout)
    extra = (kernel_lines(kernels, n) + replay_lines(replays, n) + profile_lines(profiles)
             + wake_lines(wake, n, launches, counted))
    extra += ["", cores_line(n, probes, rates)]
    section = section + "\n".join(extra) + ("\n" if extra else "")
    print(section)
    update_section(a.out, section)
    print(f"bench threads: {time.perf_counter() - t0:.0f} s, section written to {a.out}", file=sys.stderr)
    ok = all(_best(c.get(t, [])) is not None for c in (cloth, tet) for t in (1, n))
    return 0 if ok else 1


def cores_line(n: int, probes: list, rates: list) -> str:
    """The section's closing line: what the process got of the cores before and after the runs."""
    return (f"Cores this process got (CPU time / wall time of a trivially parallel loop on {n} threads, 1 s; "
            f"{n} on an idle machine): {probes[0]:.2f} before the runs, {probes[1]:.2f} after. Work per second of "
            f"that loop on {n} threads over that on 1 thread (alternating, 1 s; {n} when the cores run at full "
            f"speed): {rates[0]:.2f} before, {rates[1]:.2f} after. The scheduler shares the cores between users' "
            "sessions as groups, so with other sessions busy a process gets about one core whatever its thread "
            "count, and no speed-up can show; a core that is scheduled but runs slowly shows in the second "
            "figure only.")


def _main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m modalfem.bench.threads_bench")
    ap.add_argument("--profile", choices=("cloth", "tet"))
    ap.add_argument("--replay", choices=("cloth", "tet"))
    ap.add_argument("--kernels", action="store_true")
    ap.add_argument("--launches", action="store_true", help="parallel regions per step of the cloth pile (JSON)")
    ap.add_argument("--wake", action="store_true", help="wake_probe (e.g. under NUMBA_THREADING_LAYER=omp "
                    "and OMP_WAIT_POLICY / GOMP_SPINCOUNT variants) and print its lines")
    ap.add_argument("--steps", type=int, default=0, help="0: the case's default")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=4)
    a = ap.parse_args(argv)
    if a.kernels:
        print(json.dumps(kernel_times(a.threads, a.repeats)))
    elif a.wake:
        from modalfem._threads import threading_layer

        wake = wake_probe(a.threads)
        print("\n".join([f"threading layer {threading_layer()}; OMP_WAIT_POLICY="
                         f"{os.environ.get('OMP_WAIT_POLICY', '')} GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT', '')}; "
                         f"load {_load():.2f}"] + wake_lines(wake, a.threads)))
    elif a.launches:
        print(json.dumps(launches_per_step(a.steps or None)))
    elif a.replay:
        _, warm, window = REPLAYS[a.replay]
        print(json.dumps(replay(a.replay, a.threads, a.repeats, warm=warm, window=window)))
    else:
        print(json.dumps(profile_share(a.profile, a.steps or None)))
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
