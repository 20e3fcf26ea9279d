"""CCD benchmark: the 7,279 exact-answer queries of ``../shared/data/ccd-sample-queries``.

For every scene and kind (vertex-face, edge-edge) the conservative CCD of
:mod:`modalfem.collision.ccd` (numba-compiled, one loop over the queries) runs on all queries of the
kind in one call; the table gives the false negatives (must be 0), the false positives and the time per
query. A second column times the same code called one query at a time on a subset, so the cost of the
Python call per query is a ratio measured in the same run. ``load_queries`` is shared with the tests.

A second table runs the whole collision pipeline (all stages on) on synthetic cloth scenes: the
pair tests of the BVH traversals with and without normal-cone culling, and the time per step.

Command: ``python -m modalfem bench ccd [--out BENCHMARKS.md] [--quick] [--data DIR]``. The dataset is
not part of modalfem: without it the command says in one line what it needs, where it looked
(``default_data_dir``) and where to get it (``DATA_SOURCE``), and exits 2.
"""

from __future__ import annotations

import argparse
import glob
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "DATA_ENV",
    "DATA_SOURCE",
    "SECTION",
    "QuerySet",
    "command",
    "default_data_dir",
    "load_queries",
    "missing_data_message",
    "render",
    "run",
]

SECTION = "## CCD: exact-answer sample queries"
KINDS = ("vertex-face", "edge-edge")


@dataclass(frozen=True)
class QuerySet:
    """Queries of one scene and kind.

    Attributes:
        scene: folder name (e.g. ``erleben-spikes``).
        kind: ``vertex-face`` or ``edge-edge``.
        x0: (k, 4, 3) positions [m] at t0.
        x1: (k, 4, 3) positions [m] at t1.
        truth: (k,) bool, exact answer.
    """

    scene: str
    kind: str
    x0: np.ndarray
    x1: np.ndarray
    truth: np.ndarray


#: where the dataset comes from (a ``git clone`` of it is a valid ``--data`` folder)
DATA_SOURCE = "https://github.com/Continuous-Collision-Detection/Sample-Queries"
#: environment variable naming the dataset folder (between ``--data`` and the default)
DATA_ENV = "MODALFEM_CCD_DATA"


def default_data_dir() -> Path:
    """Where the bench looks for the dataset when ``--data`` is not given.

    ``$MODALFEM_CCD_DATA`` if set; else ``../shared/data/ccd-sample-queries`` beside the source
    checkout this module runs from (a folder with ``pyproject.toml``: the CI layout); else, for an
    installed package, ``../shared/data/ccd-sample-queries`` relative to the current directory.
    """
    env = os.environ.get(DATA_ENV)
    if env:
        return Path(env).expanduser()
    checkout = Path(__file__).resolve().parents[2]
    if (checkout / "pyproject.toml").is_file():
        return checkout.parent / "shared" / "data" / "ccd-sample-queries"
    return Path.cwd().parent / "shared" / "data" / "ccd-sample-queries"


def missing_data_message(root: str | os.PathLike) -> str:
    """One line: the dataset the bench needs, where it looked, and how to get it."""
    return (
        f"the CCD bench needs the CCD sample queries (Wang et al. 2021, 'A Large-Scale Benchmark and an "
        f"Efficient and Robust Algorithm for Continuous Collision Detection', exact-answer queries in "
        f"<scene>/{{vertex-face,edge-edge}}/*.csv) and found none in {str(Path(root).absolute())!r}; "
        f"get them with `git clone {DATA_SOURCE}` and pass --data DIR (or set {DATA_ENV}=DIR)"
    )


def load_queries(data_dir: str | os.PathLike | None = None, *, limit: int | None = None) -> list[QuerySet]:
    """Read the query CSV files (rationals converted exactly to float64).

    Args:
        data_dir: the dataset folder (default :func:`default_data_dir`).
        limit: keep at most this many queries per file (None: all).

    Returns:
        One :class:`QuerySet` per scene and kind, sorted by scene.

    Raises:
        FileNotFoundError: the folder does not exist or holds no query files
            (message: ``missing_data_message``).
    """
    root = Path(data_dir) if data_dir is not None else default_data_dir()
    if not root.is_dir():
        raise FileNotFoundError(missing_data_message(root))
    out = []
    for scene in sorted(p.name for p in root.iterdir() if p.is_dir()):
        for kind in KINDS:
            files = sorted(glob.glob(str(root / scene / kind / "*.csv")))
            blocks = []
            for f in files:
                with open(f) as fh:
                    lines = fh.read().split()
                if limit is not None:
                    lines = lines[: 8 * limit]
                # exact rationals: Python int true division rounds correctly (exact here)
                vals = [[int(c) for c in ln.split(",")] for ln in lines]
                blocks.append(np.array([[r[0] / r[1], r[2] / r[3], r[4] / r[5], r[6]] for r in vals]))
            if not blocks:
                continue
            rows = np.concatenate(blocks)
            pts = rows[:, :3].reshape(-1, 8, 3)
            truth = rows[::8, 3] == 1
            out.append(QuerySet(scene, kind, pts[:, :4].copy(), pts[:, 4:].copy(), truth))
    if not out:
        raise FileNotFoundError(missing_data_message(root))
    return out


def run(sets: list[QuerySet], *, single: int = 200) -> list[dict]:
    """Run the CCD on each set: counts and seconds per query (batched, and one at a time on ``single``)."""
    from modalfem.collision.ccd import edge_edge_ccd, vertex_face_ccd

    rows = []
    warm = set()
    for qs in sets:
        fun = vertex_face_ccd if qs.kind == "vertex-face" else edge_edge_ccd
        if qs.kind not in warm:  # compile (or load) the numba kernel outside the clock
            fun(qs.x0[:1], qs.x1[:1])
            warm.add(qs.kind)
        t0 = time.perf_counter()
        hit, _ = fun(qs.x0, qs.x1)
        batched = (time.perf_counter() - t0) / len(qs.truth)
        k = min(single, len(qs.truth))
        t0 = time.perf_counter()
        for i in range(k):
            fun(qs.x0[i : i + 1], qs.x1[i : i + 1])
        one = (time.perf_counter() - t0) / max(k, 1)
        rows.append({
            "scene": qs.scene, "kind": qs.kind, "queries": len(qs.truth), "colliding": int(qs.truth.sum()),
            "fn": int((~hit & qs.truth).sum()), "fp": int((hit & ~qs.truth).sum()),
            "us_batched": batched * 1e6, "us_single": one * 1e6,
        })
    return rows


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    xs, ys = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return pts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def accordion_pile(n: int, *, layers: int = 4, gap: float = 0.006) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 1 m square cloth of n x n quads folded like an accordion into ``layers`` layers ``gap`` [m]
    apart above z = 0.01 m: (positions [m], triangles, rest positions [m])."""
    rest, tri = _grid(n)
    width = n // layers
    u = np.minimum(rest[:, 0] * n, n - 1e-9)
    seg = np.floor(u / width).astype(int)
    loc = u - width * seg
    x = np.stack([np.where(seg % 2 == 0, loc, width - loc) / n, rest[:, 1], seg * gap + 0.01], axis=1)
    return x, tri, rest


def pipeline_rows(quick: bool) -> list[dict]:
    """Run the collision pipeline on the synthetic scenes (see the module docstring)."""
    from modalfem.collision.obstacles import Plane
    from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline

    n = 16 if quick else 64
    x, tri, rest = accordion_pile(n)
    # falling at 0.5 m/s with a smooth velocity variation, dt = 10 ms
    v = np.zeros_like(x)
    v[:, 2] = -0.5 + 0.1 * np.sin(7 * rest[:, 0]) * np.cos(5 * rest[:, 1])
    v[:, 0] = 0.05 * np.sin(3 * rest[:, 1])
    rng = np.random.default_rng(0)
    scenes = [
        (f"accordion pile {n}x{n}, 4 layers 6 mm apart, falling 0.5 m/s", x, tri, rest, v),
        ("same, with 0.5 m/s random velocity noise", x, tri, rest, v + rng.normal(scale=0.5, size=v.shape)),
    ]
    rows = []
    for name, x0, tr, ref, vel in scenes:
        masses = np.full(len(x0), 1e-4)
        floor = [Plane([0, 0, 0], [0, 0, 1])]
        cfg = CollisionConfig(thickness=0.004, measure_culling=True)
        pipe = CollisionPipeline(tr, config=cfg, obstacles=floor, reference_positions=ref)
        _, st = pipe.resolve(x0, vel, masses, 0.01)
        cfg = CollisionConfig(thickness=0.004)
        CollisionPipeline(tr, config=cfg, obstacles=floor, reference_positions=ref).resolve(x0, vel, masses, 0.01)
        reps = 2 if quick or "noise" in name else 5
        secs = {}
        for _ in range(reps):
            # a new pipeline per call: one that saw the same start positions re-uses its broad phase
            pipe = CollisionPipeline(tr, config=cfg, obstacles=floor, reference_positions=ref)
            _, s2 = pipe.resolve(x0, vel, masses, 0.01)
            for k, val in s2.seconds.items():
                secs[k] = secs.get(k, 0.0) + val / reps
        rows.append({
            "scene": name, "vertices": len(x0), "triangles": len(tr), "unculled": st.pair_tests_unculled,
            "culled": st.pair_tests, "ms": {k: 1e3 * val for k, val in secs.items()},
            "zones": st.zone_iterations, "unresolved": s2.unresolved, "hits": s2.ccd_hits,
        })
    return rows


def render(rows: list[dict], *, command: str, machine: str, pipe_rows: list[dict] = ()) -> str:
    """The markdown section (starts with ``SECTION``)."""
    lines = [
        SECTION, "",
        f"Machine: {machine}. Python {platform.python_version()}, NumPy {np.__version__}.",
        f"Command: `{command}`.", "",
        (
            "Conservative CCD (Bernstein subdivision of the coplanarity cubic + distance lower bounds, "
            "tolerance 0 plus rounding bounds) on the exact-answer queries of Wang et al. (2021). "
            "FN must be 0. Time per query: all queries of a row in one compiled call, and one call per "
            "query (first 200) in the same run."
        ),
        "",
        "| scene | kind | queries | colliding | FN | FP | us/query batched | us/query one-by-one | gain |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    tot = {"queries": 0, "colliding": 0, "fn": 0, "fp": 0, "tb": 0.0, "ts": 0.0}
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['kind']} | {r['queries']} | {r['colliding']} | {r['fn']} | {r['fp']} | "
            f"{r['us_batched']:.1f} | {r['us_single']:.1f} | {r['us_single'] / r['us_batched']:.1f}x |"
        )
        for key in ("queries", "colliding", "fn", "fp"):
            tot[key] += r[key]
        tot["tb"] += r["us_batched"] * r["queries"]
        tot["ts"] += r["us_single"] * r["queries"]
    q = max(tot["queries"], 1)
    lines.append(
        f"| **all** | | {tot['queries']} | {tot['colliding']} | {tot['fn']} | {tot['fp']} | {tot['tb'] / q:.1f} | "
        f"{tot['ts'] / q:.1f} | {tot['ts'] / max(tot['tb'], 1e-12):.1f}x |"
    )
    if pipe_rows:
        lines += [
            "",
            (
                "Collision pipeline, all stages on (thickness 4 mm, dt 10 ms, floor plane), BVH leaf pair "
                "tests with and without normal-cone culling, and the mean time per `resolve` (same run):"
            ),
            "",
            (
                "| scene | vertices | triangles | pair tests unculled | culled | removed | ms/step "
                "| broad phase | repulsion | CCD | zones | CCD hits per pass | unresolved |"
            ),
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in pipe_rows:
            ms = r["ms"]
            removed = 100.0 * (1 - r["culled"] / max(r["unculled"], 1))
            lines.append(
                f"| {r['scene']} | {r['vertices']} | {r['triangles']} | {r['unculled']} | {r['culled']} | "
                f"{removed:.0f}% | {ms['total']:.0f} | {ms['broad_phase']:.0f} | {ms['repulsion']:.0f} | "
                f"{ms['ccd']:.0f} | {ms['impact_zones']:.0f} | {r['hits']} | {r['unresolved']} |"
            )
    return "\n".join(lines) + "\n"


def command(argv: list[str]) -> int:
    """``modalfem bench ccd``: run the dataset and write the section to ``--out``."""
    from modalfem.bench.cli import _machine, update_section

    ap = argparse.ArgumentParser(prog="modalfem bench ccd")
    ap.add_argument("--out", default="BENCHMARKS.md")
    ap.add_argument("--quick", action="store_true", help="first 20 queries of each file")
    ap.add_argument("--data", default=None,
                    help=f"dataset folder (default ${DATA_ENV}, else ../shared/data/ccd-sample-queries; "
                         f"get it from {DATA_SOURCE})")
    a = ap.parse_args(argv)
    try:
        sets = load_queries(a.data, limit=20 if a.quick else None)
    except FileNotFoundError as e:
        print(f"modalfem: error: {e}", file=sys.stderr)
        return 2
    rows = run(sets, single=20 if a.quick else 200)
    cmd = "python -m modalfem bench ccd" + (" --quick" if a.quick else "")
    section = render(rows, command=cmd, machine=_machine(), pipe_rows=pipeline_rows(a.quick))
    update_section(a.out, section)
    print(section)
    return 0 if all(r["fn"] == 0 for r in rows) else 1


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(command(__import__("sys").argv[1:]))
