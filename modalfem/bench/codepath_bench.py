"""``modalfem bench codepath``: the modes ladder's P2 rungs on forced MKL / OpenBLAS code paths.

A PROXY for AMD CPUs measured on whatever CPU runs it: MKL cannot run its AVX-512 kernels on AMD CPUs and
OpenBLAS runs Zen kernels there, so each case also runs with ``MKL_ENABLE_INSTRUCTIONS`` and
``OPENBLAS_CORETYPE`` forced (``modes_bench.CODE_PATHS``). The same instruction sets, not the same cores,
caches or memory: it shows what the code paths cost, not what an AMD machine measures.

``modalfem bench codepath [--paths default avx2] [--max-dofs N] [--repeat N] [--repeat-small N] [--out FILE]``

Every case (ours = ``modalfem.modes(backend='fenicsx')``, peer A = the dolfinx + SLEPc recipe) runs in a fresh
process (``modes_bench.run_case``) with the path's environment; ours and the peer run under the same settings.
Runs are interleaved (repeat, then path, then case) so that load from other jobs falls on every column alike;
the tables give medians. Replaces the section ``SECTION`` of ``--out`` (others are kept).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import shlex
import statistics
import sys
import time

from modalfem.bench import modes_bench as mb

__all__ = ["PHASES", "RUNGS", "SECTION", "command", "render"]

SECTION = "## Modes on AVX2 code paths (proxy for AMD)"
#: the ladder's P2 rungs (the issue's 3k, 20k, 61k and 140k DOFs)
RUNGS = [mb.Rung(2, (20, 2, 2)), mb.Rung(2, (40, 4, 4)), mb.Rung(2, (60, 6, 6)), mb.Rung(2, (80, 8, 8))]
CASES = ("ours-fenicsx", "peer-A")
#: rungs up to this size run ``--repeat-small`` times
SMALL_DOFS = 25_000
#: our phases shown in the profile table: label -> keys of ``ModalResult.timings`` [s]
PHASES = {
    "mesh + assembly": ("setup",),
    "constraints + shift": ("constraints", "shift"),
    "factorisation": ("eigen.factor",),
    "solves": ("eigen.solve",),
    "certificate": ("eigen.certificate", "certificate"),
    "labels": ("labels",),
}


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _median(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else None


def _phase(res: dict, keys) -> float | None:
    if "total" not in res:
        return None
    if keys == ("setup",):
        return res["setup"]
    tm = res.get("timings", {})
    return sum(float(tm.get(k, 0.0)) for k in keys)


def _fmt(x, spec=".2f") -> str:
    return "n/a" if x is None else format(x, spec)


def _total_cell(cell: dict, runs: dict, path: str, case: str, rung) -> str:
    m, rng, _ = cell[case]
    if m is None:
        errs = [x.get("error") or f"timeout {x.get('timeout')}" for x in runs.get((path, case, rung), [])]
        return "error: " + (errs[0][:80] if errs else "not run")
    return f"{m:.2f} ({rng[0]:.2f}-{rng[1]:.2f})"


def render(runs: dict, rungs, paths, *, command: str, date: str, machine: str, versions: dict) -> str:
    """The markdown section. ``runs[(path, case, rung)]`` = every run's result dict (``run_case``)."""
    L = [SECTION, ""]
    L.append("A PROXY for AMD CPUs, measured on the Intel machine below, NOT on an AMD one: MKL picks its kernels "
             "per CPU (its AVX-512 ones on Intel CPUs) and OpenBLAS runs Zen kernels on AMD CPUs, so every case also "
             "ran with "
             "`MKL_ENABLE_INSTRUCTIONS` and `OPENBLAS_CORETYPE` forced. Same instruction sets, not the same "
             "cores, caches or memory. Ours (`ours-fenicsx`: modes(backend='fenicsx'), default solver, certificate "
             "included) and peer A (the dolfinx + SLEPc recipe, MUMPS on OpenBLAS) ran under the same settings, "
             "each case in a fresh process; the cantilever and columns are those of 'Modes: cantilever ladder'.")
    L.append("")
    L.append(f"- Date: {date}")
    L.append(f"- Command: `{command}`")
    L.append(f"- Machine: {machine}")
    L.append("- Versions: " + ", ".join(f"{k} {v}" for k, v in versions.get("default", {}).items()
                                         if k not in ("MKL", "OpenBLAS core", "OPENBLAS_CORETYPE", "error", "process")))
    L.append("- Paths (environment; kernels the child processes reported: MKL `mkl_cbwr_get_auto_branch`, "
             "OpenBLAS `openblas_get_corename`):")
    for p in paths:
        env = mb.CODE_PATHS[p]
        seen = sorted({f"MKL {r['code_path']['mkl']}, OpenBLAS {r['code_path']['openblas']}"
                       for (q, c, _), rs in runs.items() if q == p and c == "ours-fenicsx"
                       for r in rs if "code_path" in r})
        L.append(f"  - `{p}`: " + (" ".join(f"{k}={v}" for k, v in env.items()) or "nothing forced")
                 + f" -> {'; '.join(seen) or 'n/a'}")
    n_rep = sorted({len(rs) for rs in runs.values()})
    L.append("")
    L.append(f"Totals (mesh to certified eigenpairs, imports excluded) [s], median of {' or '.join(map(str, n_rep))} "
             "interleaved runs (repeat, then path, then case) "
             "(fastest-slowest); ratio = peer A / ours (above 1: ours ahead); 'vs default' = this path's ratio "
             "over the default path's ratio in this run; CPU = median CPU time of the child over the same "
             "interval, all its threads (less sensitive than wall time to other jobs on a loaded machine)."
             + (" Peer A runs the same code under `avx2` and `sse4_2` (the MKL setting does not reach it): the "
                "difference between its two rows is this run's noise." if {"avx2", "sse4_2"} <= set(paths) else ""))
    L.append("")
    hdr = ["P", "cells", "DOFs", "path", "ours s", "peer A s", "peer A / ours", "vs default", "ours CPU s",
           "peer A CPU s", "CPU: peer A / ours", "ours certified", "f1 Hz (ours)"]
    L.append("| " + " | ".join(hdr) + " |")
    L.append("|" + "|".join("---" for _ in hdr) + "|")
    ratios = {}
    for r in rungs:
        for p in paths:
            cell = {}
            for c in CASES:
                rs = [x for x in runs.get((p, c, r), []) if "total" in x and "error" not in x]
                tot = [x["total"] for x in rs]
                cell[c] = (_median(tot), (min(tot), max(tot)) if tot else None, rs)
            o, pa = cell["ours-fenicsx"][0], cell["peer-A"][0]
            ratios[(p, r)] = pa / o if o and pa else None
            rs_o = cell["ours-fenicsx"][2]
            cert = "n/a" if not rs_o else ("yes" if all(x.get("certified") for x in rs_o) else "NO")
            f1 = _median([x["frequencies_hz"][0] for x in rs_o])
            cpu_o = _median([x.get("cpu") for x in rs_o])
            cpu_p = _median([x.get("cpu") for x in cell["peer-A"][2]])

            base = ratios.get(("default", r))
            ratio = ratios[(p, r)]
            vs = "-" if p == "default" or base is None or ratio is None else f"{ratio / base:.2f}"
            cpu_ratio = cpu_p / cpu_o if cpu_o and cpu_p else None
            row = [f"P{r.degree}", r.label, str(r.dofs), f"`{p}`", _total_cell(cell, runs, p, "ours-fenicsx", r),
                   _total_cell(cell, runs, p, "peer-A", r), _fmt(ratio) + ("x" if ratio else ""), vs,
                   _fmt(cpu_o), _fmt(cpu_p), _fmt(cpu_ratio) + ("x" if cpu_ratio else ""), cert, _fmt(f1, ".4f")]
            L.append("| " + " | ".join(row) + " |")
    L.append("")
    L.append("Where the time goes (medians [s]; ours by phase from `ModalResult.timings`, the certificate = "
             "residuals + Sylvester inertia factorisation + checks; peer A: assembly and eigensolve):")
    L.append("")
    hdr = ["DOFs", "path", *PHASES, "ours total", "peer A assembly", "peer A eigen", "peer A total"]
    L.append("| " + " | ".join(hdr) + " |")
    L.append("|" + "|".join("---" for _ in hdr) + "|")
    for r in rungs:
        for p in paths:
            ro = [x for x in runs.get((p, "ours-fenicsx", r), []) if "total" in x]
            rp = [x for x in runs.get((p, "peer-A", r), []) if "total" in x]
            L.append("| " + " | ".join([
                str(r.dofs), f"`{p}`", *(_fmt(_median([_phase(x, k) for x in ro])) for k in PHASES.values()),
                _fmt(_median([x["total"] for x in ro])), _fmt(_median([x["setup"] for x in rp])),
                _fmt(_median([x["eigen"] for x in rp])), _fmt(_median([x["total"] for x in rp]))]) + " |")
    L.append("")
    return "\n".join(L)


def command(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="modalfem bench codepath",
                                 description="Modes ladder (P2 rungs), ours vs the dolfinx + SLEPc recipe, on forced "
                                             "MKL/OpenBLAS code paths (a proxy for AMD CPUs).")
    ap.add_argument("--paths", nargs="+", choices=list(mb.CODE_PATHS), default=["default", "avx2"],
                    help="code paths, each against the same peer runs (default: default avx2)")
    ap.add_argument("--max-dofs", type=int, default=150_000, help="skip rungs with more DOFs (150000: all four)")
    ap.add_argument("--repeat", type=int, default=3, help="interleaved runs of every case, path and rung (3)")
    ap.add_argument("--repeat-small", type=int, default=7,
                    help=f"runs on rungs up to {SMALL_DOFS} DOFs, where one run is short and load shows most (7)")
    ap.add_argument("--timeout", type=float, default=300.0, help="kill one case after S seconds (300)")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose section is replaced")
    ap.add_argument("--save-raw", metavar="JSON", help="also save every run's measurements to JSON")
    ap.add_argument("--from-raw", metavar="JSON", help=argparse.SUPPRESS)  # re-render saved measurements
    a = ap.parse_args(argv)
    from modalfem.backends import have_fenicsx
    from modalfem.bench.cli import _machine, update_section, write_atomic

    rungs = [r for r in RUNGS if r.dofs <= a.max_dofs]
    if not rungs:
        print(f"modalfem: error: no rung has <= {a.max_dofs} DOFs (the smallest has {RUNGS[0].dofs})", file=sys.stderr)
        return 2
    if min(a.repeat, a.repeat_small) < 1:
        print("modalfem: error: --repeat and --repeat-small must be at least 1", file=sys.stderr)
        return 2
    if a.from_raw:
        with open(a.from_raw) as f:
            raw = json.load(f)
        runs = {(d["path"], d["case"], mb.Rung(2, tuple(d["cells"]))): d["runs"] for d in raw["runs"]}
        rungs = [r for r in RUNGS if any(k[2] == r for k in runs)]
        paths = list(dict.fromkeys(k[0] for k in runs))
        section = render(runs, rungs, paths, command=raw["command"], date=raw["date"], machine=raw["machine"],
                         versions=raw["versions"])
        update_section(a.out, section)
        print(section)
        return 0
    if not have_fenicsx():
        print("modalfem: error: bench codepath compares with the dolfinx + SLEPc recipe and needs FEniCSx "
              "(Debian's python3-dolfinx in a --system-site-packages venv)", file=sys.stderr)
        return 2
    paths = list(dict.fromkeys(["default", *a.paths]))  # the default path is the reference of every ratio
    command_line = "python -m modalfem bench codepath" + ("" if not argv else " " + shlex.join(argv))
    t_start = time.perf_counter()
    versions = {p: mb.run_case("info", None, timeout=120, env=mb.CODE_PATHS[p]) for p in paths}
    for p in paths:
        _log(f"[bench codepath] {p}: MKL {versions[p].get('MKL')}, OpenBLAS {versions[p].get('OpenBLAS core')}")
    for c in CASES:  # FFCx cache (the peer compiles its forms; ours too through dolfinx)
        mb.run_case(c, mb.Rung(2, (2, 1, 1)), timeout=300)
    runs: dict = {}
    loads = []
    def repeats(r):
        return a.repeat_small if r.dofs <= SMALL_DOFS else a.repeat

    total = sum(repeats(r) for r in rungs) * len(paths) * len(CASES)
    done = 0
    for r in rungs:
        for rep in range(repeats(r)):
            for p in paths:
                for c in CASES:
                    done += 1
                    res = mb.run_case(c, r, timeout=a.timeout, env=mb.CODE_PATHS[p])
                    runs.setdefault((p, c, r), []).append(res)
                    if "load_1min" in res:
                        loads.append(res["load_1min"])
                    msg = (f"total {res['total']:.2f} s, code path {res.get('code_path')}" if "total" in res
                           else f"ERROR {res.get('error') or res}")
                    _log(f"[bench codepath {done}/{total}] P2 {r.label} ({r.dofs} DOFs) {p} {c} run {rep + 1}: {msg}")
    machine = _machine()
    if loads:
        machine += (f"; 1-minute load average {min(loads):.1f}-{max(loads):.1f} when the cases started (2 cores "
                    "shared with other engineers' jobs: compare the ratios, measured side by side, more than the "
                    "seconds)")
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    if a.save_raw:
        raw = [{"path": p, "case": c, "cells": list(r.cells), "runs": rs} for (p, c, r), rs in runs.items()]
        write_atomic(a.save_raw, json.dumps({"command": command_line, "date": date, "machine": machine,
                                             "versions": versions, "runs": raw}, indent=1))
    section = render(runs, rungs, paths, command=command_line, date=date, machine=machine, versions=versions)
    update_section(a.out, section)
    print(section)
    _log(f"[bench codepath] wrote {a.out} ({time.perf_counter() - t_start:.0f} s)")
    return 0
