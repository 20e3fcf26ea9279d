"""``modalfem bench ...``: benchmark commands that write sections of ``BENCHMARKS.md``.

``modalfem bench modes [--out BENCHMARKS.md] [--max-dofs N] [--peer-timeout S] [--repeat N] [--quick]``
runs the clamped-cantilever ladder (``modalfem.bench.modes_bench``) for ours and the two peers, each case
in a fresh subprocess (small rungs ``--repeat`` times, interleaved, the median run shown), prints progress
on stderr and the markdown section on stdout, and replaces the section ``## Modes: cantilever ladder``
of ``--out`` atomically (other sections are kept).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import os
import platform
import shlex
import sys
import time

from modalfem.atomic import write_atomic as _write
from modalfem.bench import modes_bench as mb
from modalfem.errors import ModalfemError

__all__ = ["SECTION", "available", "main", "refine_reference", "replace_section", "save_figure", "update_section", "write_atomic"]

SECTION = "## Modes: cantilever ladder"
GOAL_DOFS = 130_000  # "140k-DOF P2" goal rung: the largest P2 rung with at least this many DOFs
GOAL_SECONDS = 10.0
GOAL_RATIO = 2.0


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------- machine
def _machine() -> str:
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        import psutil

        ram = f"{psutil.virtual_memory().total / 2**30:.1f} GiB RAM"
    except Exception:  # noqa: BLE001 - best effort (optional library, probe, sampling)
        ram = f"{os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.1f} GiB RAM"
    return f"{cpu}, {os.cpu_count()} cores, {ram}, {platform.system()} {platform.release()}"


# ---------------------------------------------------------------------------------- reference
def refine_reference(points: list[tuple[float, float]], source: str = "P2") -> tuple[float, str]:
    """Converged first frequency [Hz] from (h, f) pairs of one discretisation, finest last.

    With three or more rungs: Richardson extrapolation f = f_ref + C h^p through the three finest,
    p solved for (bisection on the ratio of differences, kept in [0.5, 6]). With fewer: the finest
    value itself. Returns the value and a sentence saying which was used.
    """
    pts = sorted(points, key=lambda t: -t[0])  # coarse to fine
    if len(pts) < 3:
        h, f = pts[-1]
        return f, f"{source} at the finest P2 rung of this run (h = 1/{round(1 / h)} m), so its own error is 0 by construction"
    (h1, f1), (h2, f2), (h3, f3) = pts[-3:]
    target = (f1 - f2) / (f2 - f3) if f2 != f3 else float("nan")

    def g(p):
        return (h1**p - h2**p) / (h2**p - h3**p) - target

    lo, hi = 0.5, 6.0
    if not (math.isfinite(target) and g(lo) * g(hi) < 0):
        return f3, f"{source} at the finest P2 rung of this run (Richardson fit failed: non-monotone convergence)"
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if g(lo) * g(mid) <= 0:
            hi = mid
        else:
            lo = mid
    p = 0.5 * (lo + hi)
    C = (f2 - f3) / (h2**p - h3**p)
    ref = f3 - C * h3**p
    return ref, (f"Richardson extrapolation of {source} through the three finest P2 rungs "
                 f"(observed order p = {p:.2f}): {ref:.4f} Hz")


# ---------------------------------------------------------------------------------- formatting
def _s(x) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.2f}"


def _time_cell(r: dict, key: str = "total") -> str:
    if "timeout" in r:
        return f"> {r['timeout']:.0f} s (timeout)"
    if "skipped" in r:
        return f"skipped ({r['skipped']})"
    if "error" in r:
        return "error"
    return _s(r.get(key))


def _ratio(peer: dict | None, ours: dict | None) -> str:
    if not peer or not ours or "total" not in ours or "error" in ours:
        return "n/a"
    if "timeout" in peer:
        return f"> {peer['timeout'] / ours['total']:.2f}x"
    if "total" not in peer:
        return "n/a"
    return f"{peer['total'] / ours['total']:.2f}x"


def _pct(f, ref) -> str:
    return "n/a" if f is None or ref is None else f"{100 * (f / ref - 1):+.3f} %"


def render(results: dict, rungs, versions: dict, *, command: str, date: str, machine: str,
           peer_timeout: float, f_timo: float, f_eb: float, repeat_note: str = "") -> str:
    """The markdown section (starts with ``SECTION``)."""
    p2 = [r for r in rungs if r.degree == 2]
    ref_pts, source = [], None
    for c in ("ours-fenicsx", "peer-A", "ours-skfem", "peer-B"):
        ref_pts = [(SIZE_L / r.cells[0], results[(c, r)]["frequencies_hz"][0]) for r in p2
                   if "frequencies_hz" in results.get((c, r), {})]
        if ref_pts:
            source = f"`{c}` P2 f1"
            break
    f_ref, ref_note = refine_reference(ref_pts, source) if ref_pts else (None, "not available (no P2 result)")

    L = []
    L.append(SECTION)
    L.append("")
    L.append("Clamped steel cantilever 1 m x 0.1 m x 0.1 m (E = 200 GPa, nu = 0.3, rho = 7850 kg/m^3), "
             "clamped at x = 0, box of nx x ny x nz hexahedra split into 6 tetrahedra each, "
             f"lowest {mb.K_MODES} modes. Each case ran in a fresh subprocess, one after another.")
    L.append("")
    L.append(f"- Date: {date}")
    L.append(f"- Command: `{command}`")
    L.append(f"- Machine: {machine} (shared with other jobs while measured: compare the ratios, "
             "measured side by side in this run, more than the absolute seconds)")
    L.append("- Versions: " + ", ".join(f"{k} {v}" for k, v in versions.items() if k != "process"))
    L.append("- Cases:")
    for name, (desc, _) in mb.CASES.items():
        L.append(f"  - `{name}`: {desc}")
    L.append("")
    L.append("Columns: DOFs = all displacement DOFs (clamped ones included); setup = mesh + assembly "
             "(peer A includes FFCx form compilation, cache warmed first unless `--quick`); eigen = everything "
             "after assembly (constraints, factorisation, solve, and for ours the certificate, also shown "
             "alone in 'cert'); total = setup + eigen, imports excluded; CPU = CPU time of the child over the same "
             "interval, all its threads (on a loaded machine it shows each case's work where the wall time also "
             "shows the scheduler); process = child process wall "
             "time incl. interpreter start and imports; peak RSS = `ru_maxrss` of the child. "
             f"f1 = first bending frequency. Timoshenko f1 = {f_timo:.4f} Hz (`modalfem.theory.timoshenko_omegas`, "
             "Cowper shear coefficient, cross-checked by a 1D Timoshenko FE model in the smoke test; "
             f"Euler-Bernoulli would be {f_eb:.4f} Hz): the beam is thick, and Timoshenko itself differs "
             "from 3D elasticity by a few tenths of a percent, so that column floors at that model error. "
             f"'err vs 3D ref' uses {ref_note}. Ours meshes with `modalfem.mesh.box`, the peers with their own "
             "generators (dolfinx `create_box`, scikit-fem `MeshTet.init_tensor`): same hexahedra and DOF "
             "counts, but a different 6-tetrahedra split, so f1 differs a little on coarse meshes."
             + (f" {repeat_note}" if repeat_note else ""))
    L.append("")
    hdr = ["P", "cells", "DOFs", "case", "setup s", "eigen s", "cert s", "total s", "total range s", "CPU s",
           "process s", "peak RSS MB", "f1 Hz", "err vs Timoshenko", "err vs 3D ref", "certified", "total / ours-fenicsx"]
    L.append("| " + " | ".join(hdr) + " |")
    L.append("|" + "|".join("---" for _ in hdr) + "|")
    for r in rungs:
        ours = results.get(("ours-fenicsx", r))
        for c in mb.CASES:
            res = results.get((c, r))
            if res is None:
                continue
            fr = res.get("frequencies_hz")
            f1 = fr[0] if fr else None
            ok = "" if "error" in res or "frequencies_hz" not in res else (
                ("yes" if res.get("certified") else "NO") if mb.CASES[c][1] else "-")
            rss = res.get("peak_rss_mb")
            if rss is None and res.get("rss_seen_mb"):
                rss_txt = f">= {res['rss_seen_mb']:.0f} (sampled)"
            else:
                rss_txt = "n/a" if rss is None else f"{rss:.0f}"
            row = [f"P{r.degree}", r.label, str(res.get("dofs", r.dofs)), f"`{c}`",
                   _time_cell(res, "setup"), _time_cell(res, "eigen"),
                   _s(res.get("certificate")) if "total" in res and mb.CASES[c][1] else "-",
                   _time_cell(res, "total"),
                   "{:.2f}-{:.2f}".format(*res["total_range"]) if "total_range" in res else "-",
                   _s(res.get("cpu")) if "cpu" in res else "-",
                   _s(res.get("process")) if "skipped" not in res else "-",
                   rss_txt, "n/a" if f1 is None else f"{f1:.4f}",
                   _pct(f1, f_timo), _pct(f1, f_ref), ok,
                   "1.00x" if c == "ours-fenicsx" and "total" in res else _ratio(res, ours)]
            L.append("| " + " | ".join(row) + " |")
    errors = [(c, r, res["error"]) for (c, r), res in results.items() if "error" in res]
    if errors:
        L.append("")
        L.append("Errors:")
        for c, r, e in errors:
            L.append(f"- `{c}` P{r.degree} {r.label}: {e}")

    # accuracy at equal DOFs
    acc = []
    for n in sorted({r.dofs for r in rungs}):
        same = {r.degree: r for r in rungs if r.dofs == n}
        if 1 in same and 2 in same and f_ref is not None:
            f = {d: next((results[(c, r)]["frequencies_hz"][0] for c in mb.CASES
                          if "frequencies_hz" in results.get((c, r), {})), None) for d, r in same.items()}
            if None not in f.values():
                acc.append(f"- {n} DOFs: P1 {same[1].label} {_pct(f[1], f_ref)}, "
                           f"P2 {same[2].label} {_pct(f[2], f_ref)}")
    if acc:
        L += ["", "Accuracy at equal size (f1 error vs the 3D reference above):", "", *acc]

    # ratio summary
    L.append("")
    L.append("Ratios (peer total time / our total time at the same rung, this run):")
    L.append("")
    hdr2 = ["P", "cells", "DOFs", *(f"{c} s" for c in mb.CASES),
            "peer-A / ours-fenicsx", "peer-B / ours-skfem", "peer-B / ours-fenicsx"]
    L.append("| " + " | ".join(hdr2) + " |")
    L.append("|" + "|".join("---" for _ in hdr2) + "|")
    for r in rungs:
        g = {c: results.get((c, r), {}) for c in mb.CASES}
        L.append("| " + " | ".join([
            f"P{r.degree}", r.label, str(r.dofs),
            *(_time_cell(g[c]) if g[c] else "n/a" for c in mb.CASES),
            _ratio(g["peer-A"], g["ours-fenicsx"]), _ratio(g["peer-B"], g["ours-skfem"]),
            _ratio(g["peer-B"], g["ours-fenicsx"])]) + " |")

    # goals
    L.append("")
    L.append(f"Goals: P2 at ~140k DOFs, {mb.K_MODES} modes, total <= {GOAL_SECONDS:.0f} s wall "
             f"(ours-fenicsx); and >= {GOAL_RATIO:.0f}x faster than peer A at that rung.")
    L.append("")
    big = [r for r in rungs if r.degree == 2 and r.dofs >= GOAL_DOFS]
    if not big:
        L.append("- Not measured: this ladder stops below the goal rung (run without `--max-dofs`/`--quick`).")
    else:
        r = big[-1]
        ours, pa = results.get(("ours-fenicsx", r), {}), results.get(("peer-A", r), {})
        if "total" in ours:
            met = ours["total"] <= GOAL_SECONDS
            L.append(f"- {GOAL_SECONDS:.0f} s goal at P2 {r.label} ({r.dofs} DOFs): total {ours['total']:.2f} s "
                     f"(process incl. imports {ours['process']:.2f} s) -> **{'met' if met else 'NOT met'}**"
                     + ("" if ours.get("certified") else " (certificate did NOT pass)"))
        else:
            L.append(f"- {GOAL_SECONDS:.0f} s goal at P2 {r.label}: ours-fenicsx has no result ({_time_cell(ours)})"
                     " -> **NOT met**")
        if "total" in ours and ("total" in pa or "timeout" in pa):
            ratio = (pa.get("total") or pa["timeout"]) / ours["total"]
            met = ratio >= GOAL_RATIO
            L.append(f"- {GOAL_RATIO:.0f}x goal vs peer A at P2 {r.label}: peer A / ours = "
                     f"{'> ' if 'timeout' in pa else ''}{ratio:.1f}x -> **{'met' if met else 'NOT met'}**")
        else:
            L.append(f"- {GOAL_RATIO:.0f}x goal vs peer A at P2 {r.label}: not measured -> **NOT met**")
    L.append("")
    return "\n".join(L)


SIZE_L = mb.SIZE[0]


def replace_section(text: str, section: str) -> str:
    """``text`` with the section whose heading is the first line of ``section`` (a ``## `` heading)
    replaced by ``section`` (appended if absent); a section ends at the next level-1/level-2 heading
    (``# `` or ``## ``). Every benchmark command owns one section of ``BENCHMARKS.md`` this way."""
    heading = section.strip().splitlines()[0].strip()
    if not heading.startswith("## "):
        raise ValueError(f"a benchmark section must start with a '## ' heading, got {heading!r}")
    lines = text.splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.strip() == heading), None)
    new = section.rstrip("\n").splitlines()
    if start is None:
        body = text.rstrip("\n")
        if not body:
            body = "# Benchmarks"
        return body + "\n\n" + "\n".join(new) + "\n"
    end = next((j for j in range(start + 1, len(lines))
                if lines[j].startswith("## ") or lines[j].startswith("# ")), len(lines))
    out = lines[:start] + new + ([""] if end < len(lines) else []) + lines[end:]
    return "\n".join(out).rstrip("\n") + "\n"


def update_section(path: str, section: str) -> None:
    """Replace (or append) ``section`` in the markdown file ``path`` atomically, keeping the others."""
    old = ""
    if os.path.exists(path):
        with open(path) as f:
            old = f.read()
    write_atomic(path, replace_section(old, section))


def save_figure(fig, path: str, *, dpi: int) -> None:
    """Write the matplotlib figure ``fig`` to ``path`` as PNG, atomically (:mod:`modalfem.atomic`), creating
    its directory; the figure is closed either way."""
    import matplotlib.pyplot as plt

    try:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        _write(path, lambda f: fig.savefig(f, format="png", dpi=dpi), error=ModalfemError, kind="PNG")
    finally:
        plt.close(fig)


def write_atomic(path: str, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically through :func:`modalfem.atomic.write_atomic`."""
    _write(path, lambda f: f.write(text.encode("utf-8")), error=ModalfemError, kind="text")


# ---------------------------------------------------------------------------------- command
def _modes(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="modalfem bench modes",
                                 description="Cantilever modes ladder: ours vs dolfinx+SLEPc and scikit-fem+SciPy.")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose modes section is replaced")
    ap.add_argument("--max-dofs", type=int, default=150_000, help="skip rungs with more DOFs (default 150000)")
    ap.add_argument("--peer-timeout", type=float, default=300.0, help="kill a peer case after S seconds (300)")
    ap.add_argument("--ours-timeout", type=float, default=None,
                    help="kill one of our cases after S seconds (default max(600, peer timeout))")
    ap.add_argument("--quick", action="store_true", help="tiny ladder (P1 and P2 20x2x2), no JIT warm-up")
    ap.add_argument("--cases", nargs="+", choices=list(mb.CASES), default=list(mb.CASES))
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of every case on rungs up to --repeat-max-dofs, interleaved; the median total is "
                         "shown (default 3)")
    ap.add_argument("--repeat-max-dofs", type=int, default=25_000, help="largest rung repeated (default 25000)")
    ap.add_argument("--save-raw", metavar="JSON", help="also save the raw measurements to JSON")
    ap.add_argument("--from-raw", metavar="JSON", help=argparse.SUPPRESS)  # re-render saved measurements
    a = ap.parse_args(argv)
    ours_timeout = a.ours_timeout or max(600.0, a.peer_timeout)
    command = "python -m modalfem bench modes" + ("" if not argv else " " + shlex.join(argv))
    rungs = mb.ladder(quick=a.quick, max_dofs=a.max_dofs)
    if not rungs:
        print(f"modalfem: error: no rung has <= {a.max_dofs} DOFs", file=sys.stderr)
        return 2

    from modalfem.backends import have_fenicsx

    fenicsx = have_fenicsx()
    t_start = time.perf_counter()
    if a.from_raw:
        with open(a.from_raw) as f:
            raw = json.load(f)
        rungs = [mb.Rung(d["degree"], tuple(d["cells"])) for d in raw["rungs"]]
        results = {(d["case"], mb.Rung(d["degree"], tuple(d["cells"]))): d["result"] for d in raw["results"]}
        return _finish(a, raw["command"], raw["date"], raw["machine"], raw["versions"], rungs, results, t_start)
    _log(f"[bench modes] {len(rungs)} rungs x {len(a.cases)} cases; peer timeout {a.peer_timeout:.0f} s")
    versions = mb.run_case("info", None, timeout=120)
    if not a.quick and fenicsx:
        for c in [c for c in a.cases if c in mb.NEEDS_FENICSX]:
            for deg in sorted({r.degree for r in rungs}):
                _log(f"[bench modes] warming the FFCx cache: {c} P{deg} 2x1x1")
                mb.run_case(c, mb.Rung(deg, (2, 1, 1)), timeout=300)

    results: dict = {}
    timed_out_at: dict = {}
    runs: dict = {}  # (case, rung) -> every run's result, when the rung is repeated
    for r in rungs:
        repeats = max(1, a.repeat) if r.dofs <= a.repeat_max_dofs else 1
        for rep, c in [(rep, c) for rep in range(repeats) for c in a.cases]:  # repeats interleaved
            is_ours = mb.CASES[c][1]
            tag = f"[bench modes] P{r.degree} {r.label} ({r.dofs} DOFs) {c}" + (f" run {rep + 1}" if rep else "")
            if c in mb.NEEDS_FENICSX and not fenicsx:
                results[(c, r)] = {"skipped": "FEniCSx not installed"}
                continue
            if (c, r.degree) in timed_out_at:
                if (c, r) not in runs:  # (a repeat keeps the runs it has)
                    results[(c, r)] = {"skipped": f"timed out at {timed_out_at[(c, r.degree)]}"}
                _log(f"{tag}: skipped (timed out at a smaller rung)")
                continue
            _log(f"{tag} ...")
            res = mb.run_case(c, r, timeout=ours_timeout if is_ours else a.peer_timeout)
            runs.setdefault((c, r), []).append(res)
            results[(c, r)] = _median_run(runs[(c, r)])
            if "timeout" in res:
                timed_out_at[(c, r.degree)] = r.label
                _log(f"{tag}: > {res['timeout']:.0f} s (timeout, killed)")
            elif "error" in res:
                _log(f"{tag}: ERROR {res['error']}")
            else:
                f1 = res["frequencies_hz"][0]
                _log(f"{tag}: total {res['total']:.2f} s (setup {res['setup']:.2f}, eigen {res['eigen']:.2f}), "
                     f"process {res['process']:.1f} s, RSS {res['peak_rss_mb']:.0f} MB, f1 {f1:.4f} Hz")

    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    machine = _machine()
    loads = [res["load_1min"] for rs in runs.values() for res in rs if "load_1min" in res]
    if loads:  # 2 cores: a load above ~1 means other work shared them
        machine += f"; 1-minute load average {min(loads):.1f}-{max(loads):.1f} when the cases started"
    if a.save_raw:
        raw = {"command": command, "date": date, "machine": machine, "versions": versions,
               "rungs": [{"degree": r.degree, "cells": list(r.cells)} for r in rungs],
               "results": [{"case": c, "degree": r.degree, "cells": list(r.cells), "result": res}
                           for (c, r), res in results.items()]}
        write_atomic(a.save_raw, json.dumps(raw, indent=1))
    return _finish(a, command, date, machine, versions, rungs, results, t_start)


def _median_run(results: list[dict]) -> dict:
    """The run with the median total among those that finished (the last run when none did), with
    ``runs`` (how many) and ``total_range`` (fastest and slowest total) added when there were several."""
    done = sorted((r for r in results if "total" in r and "error" not in r), key=lambda r: r["total"])
    if not done:
        return results[-1]
    out = dict(done[(len(done) - 1) // 2])
    if len(results) > 1:
        out["runs"] = len(results)
        out["total_range"] = [done[0]["total"], done[-1]["total"]]
    return out


def _finish(a, command, date, machine, versions, rungs, results, t_start) -> int:
    repeated = [r for r in rungs if any(res.get("runs", 1) > 1 for (c, q), res in results.items() if q == r)]
    note = ""
    if repeated:
        n = max(res.get("runs", 1) for res in results.values())
        note = (f"Rungs up to {max(q.dofs for q in repeated)} DOFs ran every case {n} times, "
                "interleaved (ours, peers, ours, ...): the row is the run with the median total; 'total range' "
                "gives the fastest and slowest total.")
    section = render(results, rungs, versions, command=command, date=date, machine=machine,
                     peer_timeout=a.peer_timeout, repeat_note=note,
                     f_timo=mb.timoshenko_cantilever_hz(), f_eb=mb.euler_bernoulli_cantilever_hz())
    update_section(a.out, section)
    print(section)
    _log(f"[bench modes] wrote {a.out} ({time.perf_counter() - t_start:.0f} s)")
    return 0


def available() -> list[str]:
    """Benchmark names: ``modes`` plus every module ``modalfem/bench/<name>_bench.py`` that defines
    ``command(argv: list[str]) -> int`` (a benchmark is added by adding its module, nothing else)."""
    import pkgutil

    import modalfem.bench as pkg

    names = {"modes"}
    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name.endswith("_bench") and info.name != "modes_bench":
            names.add(info.name[: -len("_bench")])
    return sorted(names)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``modalfem bench``: ``argv`` starts with the benchmark name (see ``available``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "bench":  # tolerate callers that pass the subcommand name too
        argv = argv[1:]
    names = available()
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: modalfem bench {{{','.join(names)}}} [options]   (modalfem bench NAME -h for options)")
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name == "modes":
        return _modes(rest)
    if name not in names:
        print(f"modalfem: error: unknown benchmark {name!r}; available: {', '.join(names)}", file=sys.stderr)
        return 2
    import importlib

    return int(importlib.import_module(f"modalfem.bench.{name}_bench").command(rest))


if __name__ == "__main__":
    sys.exit(main())
