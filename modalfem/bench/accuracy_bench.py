"""Accuracy versus time: every way of getting modes, measured side by side (``modalfem bench accuracy``).

Two bodies: a clamped steel cantilever (1 m x 0.1 m x 0.05 m, clamped at x = 0; a rectangular
section so no two bending modes are degenerate) and a free steel tuning fork
(``modalfem.mesh.tuning_fork``). Methods, each timed in a fresh subprocess (so its peak RSS is its own):

* ``P1 <size>`` / ``P2 <size>``: full FEM (``modalfem.modes``) on a mesh ladder, k = 10 modes;
* ``coarse P2 <size> -> fine``: P2 modes on a coarse mesh carried to the fine (reference) mesh's
  boundary vertices by barycentric embedding (``modalfem.reduction.embed``);
* ``Ritz affine`` / ``Ritz quadratic``: Rayleigh-Ritz (``modalfem.reduction.ritz``) integrated on the
  coarsest mesh (clamp weight for the cantilever);
* ``P2 <size>, r = ...``: r in {5, 10, 20, 40} retained modes for the dynamic response.

Reference: P2 on a finer mesh than any method, with ``K_REF`` modes. Errors, per method: the largest
relative frequency error and the smallest mass-weighted MAC over the first ``N_COMPARE`` reference
modes (modes matched by MAC, shapes compared on the reference P2 nodes), and the relative RMS error of
the tip displacement over 1 s after a tip impulse (modal superposition of the method's modes, Rayleigh
damping of 1 % at reference modes 1 and 5; deformation modes only, i.e. the free fork's rigid drift is
left out). Costs: wall time of the method (mesh generation to modes on the user's mesh; imports and
the error evaluation excluded) and the child's peak RSS.

The child is ``python -m modalfem.bench.accuracy_bench --body B --case C ... --context ctx.npz
--out result.npz``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["BODIES", "SECTION", "Body", "command", "pareto_front"]

SECTION = "## Accuracy versus time"
E, NU, RHO = 200e9, 0.3, 7850.0
K_MODES = 10
K_REF = 60
N_COMPARE = 5
R_SWEEP = (5, 10, 20, 40)
ZETA = 0.01
T_END, N_T = 1.0, 20001
IMPULSE = 0.01  # [N s]


@dataclass(frozen=True)
class Body:
    """One benchmark body: mesh sizes (cells along the cantilever, or tuning-fork h [m]) per role."""

    name: str
    title: str
    ref: float
    p1: tuple
    p2: tuple
    coarse: tuple
    r_mesh: float
    tip: tuple
    direction: tuple
    clamped: bool

    def mesh(self, size: float):
        from modalfem.mesh import box, tuning_fork

        if self.name == "cantilever":
            return box(size=(1.0, 0.1, 0.05), cells=_beam_cells(size))
        return tuning_fork(h=float(size))

    def label(self, size: float) -> str:
        if self.name == "cantilever":
            return "x".join(map(str, _beam_cells(size)))
        return f"h={1e3 * size:g}mm"


def _beam_cells(n: float) -> tuple[int, int, int]:
    """Hexahedra of the 1 m x 0.1 m x 0.05 m beam with n along its length (about cubic cells)."""
    n = int(n)
    return n, max(1, round(n / 10)), max(1, round(n / 20))


BODIES = {
    "cantilever": Body("cantilever", "clamped steel cantilever 1 m x 0.1 m x 0.05 m", 60, (10, 20, 40, 80),
                       (10, 20, 30, 40), (5, 10), 60, (1.0, 0.05, 0.025), (0.0, 0.0, 1.0), True),
    "fork": Body("fork", "free steel tuning fork (80 mm prongs)", 0.0015, (0.004, 0.003, 0.002), (0.006, 0.004, 0.003, 0.002),
                 (0.008, 0.006), 0.0015, (0.006, 0.08, 0.003), (1.0, 0.0, 0.0), False),
}
QUICK = {"cantilever": Body("cantilever", BODIES["cantilever"].title, 20, (10, 20), (5, 10), (5,), 20,
                            (1.0, 0.05, 0.025), (0.0, 0.0, 1.0), True)}


# ---------------------------------------------------------------------------------- child side
def _material():
    from modalfem.material import Material

    return Material(E=E, nu=NU, rho=RHO, name="steel")


def _at(mesh, degree: int, shapes: np.ndarray, points: np.ndarray) -> np.ndarray:
    from modalfem.reduction.embed import embed_points

    return embed_points(mesh, points).transfer(shapes, degree=degree)


def run_case_here(body: Body, case: str, size: float, k: int, ctx: dict) -> dict:
    """Run one method (timed) and evaluate its modes at the reference points (untimed)."""
    # imports stay outside the clock (as in ``modes_bench``)
    import scipy.sparse.linalg  # noqa: F401
    import skfem  # noqa: F401

    import modalfem
    import modalfem.backends.skfem
    import modalfem.eigen.scipy_solver
    import modalfem.forms.skfem_ritz
    from modalfem.backends import have_fenicsx, have_slepc
    from modalfem.reduction import embed, ritz
    if have_fenicsx():
        import dolfinx.fem.petsc  # noqa: F401
        import ufl  # noqa: F401

        import modalfem.backends.fenicsx
    if have_slepc():
        import modalfem.eigen.slepc
    if body.name == "fork":
        import gmsh  # noqa: F401  (the fork's mesh generation is timed, the import is not)

    mat = _material()
    fixed = "x0" if body.clamped else None
    clamp = (0, 0.0) if body.clamped else None
    tip = np.asarray([body.tip])
    t0 = time.perf_counter()
    if case in ("fem-p1", "fem-p2", "coarse"):
        degree = 1 if case == "fem-p1" else 2
        mesh = body.mesh(size)
        res = modalfem.modes(mesh, mat, k=k, degree=degree, fixed=fixed)
        if case == "coarse":  # carry to the fine surface the user sees
            on_surface = embed.carry_modes(res, mesh, ctx["surface"])
            assert on_surface.shape[0] == 3 * len(ctx["surface"])
        wall = time.perf_counter() - t0
        freqs, dofs = res.frequencies_hz, res.shapes.shape[0]
        shapes_ref = _at(mesh, degree, res.shapes, ctx["points"])
        shapes_tip = _at(mesh, degree, res.shapes, tip)
    else:
        kind, _, backend = case.split("-", 1)[1].partition("-")
        mesh = body.mesh(size)
        rm = ritz.ritz_modes(mesh, mat, kind=kind, clamp=clamp, backend=backend or "auto")
        wall = time.perf_counter() - t0
        freqs, dofs = rm.frequencies_hz, rm.K_r.shape[0]
        shapes_ref, shapes_tip = rm.shapes_at(ctx["points"]), rm.shapes_at(tip)
    return {"wall": wall, "dofs": int(dofs), "freqs": np.asarray(freqs), "shapes": shapes_ref,
            "tip": shapes_tip.reshape(3, -1)}


def run_reference_here(body: Body, k: int, solver: str = "auto") -> dict:
    """Reference P2 modes on the finest mesh, with the points and mass matrix the errors need."""
    import modalfem
    from modalfem.backends import get_backend

    mesh = body.mesh(body.ref)
    t0 = time.perf_counter()
    res = modalfem.modes(mesh, _material(), k=k, degree=2, fixed="x0" if body.clamped else None, solver=solver)
    wall = time.perf_counter() - t0
    M = get_backend("auto").assemble(mesh, _material(), degree=2)[1]
    return {"wall": wall, "dofs": int(res.shapes.shape[0]), "freqs": res.frequencies_hz, "shapes": res.shapes,
            "tip": _at(mesh, 2, res.shapes, np.asarray([body.tip])), "points": mesh.dof_points(2),
            "surface": mesh.points[np.unique(mesh.boundary_facets)], "M": M}


def _child(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m modalfem.bench.accuracy_bench")
    ap.add_argument("--body", required=True)
    ap.add_argument("--case", required=True)
    ap.add_argument("--size", type=float, default=0.0)
    ap.add_argument("--k", type=int, default=K_MODES)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--solver", default="auto")
    ap.add_argument("--context")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    import resource

    import scipy.sparse as sp

    body = (QUICK if a.quick else BODIES)[a.body]
    if a.case == "reference":
        out = run_reference_here(body, a.k, a.solver)
        sp.save_npz(a.out + ".M.npz", out.pop("M"))
    else:
        with np.load(a.context) as z:
            ctx = {key: z[key] for key in z.files}
        out = run_case_here(body, a.case, a.size, a.k, ctx)
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    tmp = a.out + ".tmp.npz"
    np.savez(tmp, **out)
    os.replace(tmp, a.out)
    return 0


def _run_child(args: list[str], out: str, timeout: float) -> dict:
    """Run a child in a fresh interpreter; its npz result as a dict, or {"error": ...}."""
    cmd = [sys.executable, "-m", "modalfem.bench.accuracy_bench", *args, "--out", out]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=timeout,
                           check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout:.0f} s"}
    if p.returncode != 0 or not os.path.exists(out):
        tail = [ln for ln in p.stderr.splitlines() if ln.strip()][-1:] or ["no output"]
        return {"error": f"exit {p.returncode}: {tail[0][:200]}"}
    with np.load(out) as z:
        r = {key: z[key] for key in z.files}
    r["process"] = time.perf_counter() - t0
    return r


# ---------------------------------------------------------------------------------- parent side
def _response(freqs_hz, tip, damping, body: Body, times) -> np.ndarray:
    from modalfem.reduction.response import impulse_response

    d = np.asarray(body.direction, dtype=float)
    return impulse_response(2 * np.pi * np.asarray(freqs_hz), tip, tip, IMPULSE * d, d, times, damping=damping)


def _errors(r: dict, ref: dict, M, damping, body: Body, times, u_ref) -> dict:
    from modalfem.reduction.compare import compare_modes
    from modalfem.reduction.response import relative_rms_error

    n = min(N_COMPARE, len(r["freqs"]))
    c = compare_modes(r["freqs"], r["shapes"], ref["freqs"], ref["shapes"], M=M, count=n)
    u = _response(r["freqs"], r["tip"], damping, body, times)
    return {"freq_err": c.max_frequency_error, "mac": c.min_mac, "compared": n,
            "resp_err": relative_rms_error(u, u_ref), "u": u}


def _methods(body: Body) -> list[tuple[str, str, str, float, int]]:
    """(family, label, case, size, k) for every method of a body."""
    from modalfem.backends import have_fenicsx

    m = [("P1", f"P1 {body.label(s)}", "fem-p1", s, K_MODES) for s in body.p1]
    m += [("P2", f"P2 {body.label(s)}", "fem-p2", s, K_MODES) for s in body.p2]
    m += [("coarse->fine", f"coarse P2 {body.label(s)} -> fine", "coarse", s, K_MODES) for s in body.coarse]
    m += [("Ritz", f"Ritz {kind}", f"ritz-{kind}", body.coarse[0], 0) for kind in ("affine", "quadratic")]
    if have_fenicsx():  # the same Ritz fields by scikit-fem quadrature: no JIT/UFL processing cost
        m += [("Ritz", f"Ritz {kind} (skfem)", f"ritz-{kind}-skfem", body.coarse[0], 0)
              for kind in ("affine", "quadratic")]
    m += [("modes r", f"P2 {body.label(body.r_mesh)}, r = {r}", "fem-p2", body.r_mesh, r) for r in R_SWEEP]
    return m


def pareto_front(times, errors) -> np.ndarray:
    """Indices of the non-dominated (time, error) points, sorted by time (lower is better in both)."""
    t, e = np.asarray(times, dtype=float), np.asarray(errors, dtype=float)
    order = np.lexsort((e, t))
    front, best = [], np.inf
    for i in order:
        if np.isfinite(e[i]) and e[i] < best:
            front.append(i)
            best = e[i]
    return np.asarray(front, dtype=np.int64)


def _run_body(body: Body, quick: bool, tmp: str, log) -> dict:
    from modalfem.reduction.response import RayleighDamping, relative_rms_error

    q = ["--quick"] if quick else []
    k_ref = max(R_SWEEP) + 20 if not quick else 20
    ref_out = os.path.join(tmp, f"{body.name}-ref.npz")
    log(f"[bench accuracy] {body.name}: reference P2 {body.label(body.ref)} (k = {k_ref}) ...")
    ref = _run_child(["--body", body.name, "--case", "reference", "--k", str(k_ref), *q], ref_out, 1200)
    ref_solver = "auto"
    if "error" in ref:  # e.g. a crash inside the PETSc stack: the reference may come from SciPy instead
        log(f"[bench accuracy] {body.name}: reference failed ({ref['error']}); retrying with solver='scipy'")
        ref_solver = "scipy"
        ref = _run_child(["--body", body.name, "--case", "reference", "--k", str(k_ref), "--solver", "scipy", *q],
                         ref_out, 1200)
    if "error" in ref:
        raise RuntimeError(f"reference of {body.name} failed: {ref['error']}")
    import scipy.sparse as sp

    M = sp.load_npz(ref_out + ".M.npz")
    ctx = os.path.join(tmp, f"{body.name}-ctx.npz")
    np.savez(ctx, points=ref["points"], surface=ref["surface"])
    w = 2 * np.pi * ref["freqs"]
    damping = RayleighDamping.from_ratios(ZETA, w[0], w[min(4, len(w) - 1)])
    times = np.linspace(0.0, T_END, N_T)
    u_ref = _response(ref["freqs"], ref["tip"], damping, body, times)
    r_conv = min(max(R_SWEEP), len(w) - 1)
    conv = relative_rms_error(_response(ref["freqs"][:r_conv], ref["tip"][:, :r_conv], damping, body, times), u_ref)
    rows = []
    for family, label, case, size, k in _methods(body):
        if quick and family == "modes r" and k > 10:
            continue
        out = os.path.join(tmp, f"{body.name}-{len(rows)}.npz")
        args = ["--body", body.name, "--case", case, "--size", repr(float(size)), "--k", str(k or K_MODES),
                "--context", ctx, *q]
        r = _run_child(args, out, 600)
        row = {"family": family, "label": label}
        if "error" in r:
            row["error"] = r["error"]
            log(f"[bench accuracy] {body.name} {label}: ERROR {r['error']}")
        else:
            row.update(wall=float(r["wall"]), rss=float(r["peak_rss_mb"]), dofs=int(r["dofs"]), r=len(r["freqs"]),
                       **_errors(r, ref, M, damping, body, times, u_ref))
            log(f"[bench accuracy] {body.name} {label}: {row['wall']:.2f} s, {row['rss']:.0f} MB, "
                f"freq err {row['freq_err']:.2e}, MAC {row['mac']:.4f}, response err {row['resp_err']:.2e}")
        rows.append(row)
    return {"body": body, "rows": rows, "ref_wall": float(ref["wall"]), "ref_dofs": int(ref["dofs"]),
            "ref_rss": float(ref["peak_rss_mb"]), "k_ref": k_ref, "ref_solver": ref_solver, "r_conv": r_conv, "conv": conv,
            "f_ref": ref["freqs"][:N_COMPARE], "damping": damping, "times": times, "u_ref": u_ref}


# ---------------------------------------------------------------------------------- output
_STYLE = {"P1": ("tab:blue", "o"), "P2": ("tab:orange", "s"), "coarse->fine": ("tab:green", "^"),
          "Ritz": ("tab:red", "D"), "modes r": ("tab:purple", "v")}


def _fmt(x: float, pct: bool = True) -> str:
    if not np.isfinite(x):
        return "-"
    return f"{100 * x:.3g} %" if pct else f"{x:.4f}"


def render(results: list[dict], *, command: str, date: str, machine: str, versions: str, plot: str) -> str:
    """The markdown section (starts with ``SECTION``)."""
    L = [SECTION, "",
         ("Every way modalfem offers to get modes, measured on the same machine in one run, each case in a fresh "
         "subprocess. Errors are against a reference (P2 on a finer mesh than any method): 'freq err' = largest "
         f"relative frequency error over the first {N_COMPARE} reference modes (modes matched by MAC); 'MAC' = "
         "smallest mass-weighted MAC of those pairs (shapes compared on the reference P2 nodes); 'response err' = "
         f"relative RMS error of the tip displacement over {T_END:g} s after a {IMPULSE:g} N s tip impulse "
         f"(modal superposition of the method's r modes, Rayleigh damping with {100 * ZETA:g} % at reference "
         "modes 1 and 5, deformation modes only). 'time' = wall time of the method from mesh generation to "
         "modes on the user's mesh (for coarse->fine: coarse P2 modes plus their transfer to the fine mesh's "
         "boundary vertices by barycentric embedding), imports and error evaluation excluded; 'peak RSS' = "
         "`ru_maxrss` of the child process. Ritz fields are integrated on the coarsest mesh; for the "
         "cantilever they carry the clamp weight x / L. FEM cases compute k = 10 modes; 'modes r' "
         "computes only r modes on the reference mesh itself, so its response error is the truncation "
         "error alone (its frequencies are the reference's: not plotted in the frequency panels)."), "",
         f"- Date: {date}", f"- Command: `{command}`",
         f"- Machine: {machine} (shared with other jobs while measured: compare the ratios more than the seconds)",
         f"- Versions: {versions}", f"- Pareto plot: `{plot}`", "",
         f"![Accuracy versus time: error against wall time, log axes, one labelled marker per method]({plot})", ""]
    for res in results:
        b, d = res["body"], res["damping"]
        L.append(f"### {b.title}")
        L.append("")
        L.append(f"Reference: P2 {b.label(b.ref)}, {res['ref_dofs']} DOFs, {res['k_ref']} modes, solver "
                 f"{res['ref_solver']} "
                 f"({res['ref_wall']:.1f} s, {res['ref_rss']:.0f} MB); first frequencies "
                 + ", ".join(f"{f:.2f}" for f in res["f_ref"]) + " Hz. Damping alpha = "
                 f"{d.alpha:.4g} 1/s, beta = {d.beta:.4g} s. Reference response converged to "
                 f"{_fmt(res['conv'])} (r = {res['r_conv']} vs {res['k_ref']} modes).")
        L.append("")
        L.extend(_summary(res["rows"]))
        L.append("")
        L.append("| method | DOFs | r | time s | peak RSS MB | freq err | MAC | response err | time / P2 coarsest |")
        L.append("|---|---|---|---|---|---|---|---|---|")
        base = next((r["wall"] for r in res["rows"] if r["family"] == "P2" and "wall" in r), float("nan"))
        for r in res["rows"]:
            if "error" in r:
                L.append(f"| {r['label']} | - | - | - | - | - | - | - | {r['error']} |")
                continue
            L.append(f"| {r['label']} | {r['dofs']} | {r['r']} | {r['wall']:.3f} | {r['rss']:.0f} | "
                     f"{_fmt(r['freq_err'])} | {_fmt(r['mac'], pct=False)} | {_fmt(r['resp_err'])} | "
                     f"{r['wall'] / base:.2f}x |")
        L.append("")
    return "\n".join(L).rstrip() + "\n"


def _labels(ax, t, e, texts) -> None:
    """Annotate points without overlaps: each label takes the first free spot (measured text boxes)
    among growing rings of offsets around its marker, inside the axes; moved labels get a leader line."""
    fig = ax.figure
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    xy = ax.transData.transform(np.column_stack([t, e]))
    frame = ax.get_window_extent(renderer)
    pad = 3.0
    taken = [(x - 5, y - 5, x + 5, y + 5) for x, y in xy]  # the markers themselves
    rings = [(dx, dy) for r in (1, 2, 3, 4, 5, 6) for dx, dy in
             ((6, 2), (6, -10), (-6, 2), (-6, -10), (0, 8), (0, -16))
             for dx, dy in [(dx * r, dy + (r - 1) * (8 if dy > 0 else -8))]]
    def place(n, dx, dy, strict):
        text = ax.annotate(texts[n], (t[n], e[n]), fontsize=7, xytext=(dx, dy), textcoords="offset points",
                           ha="left" if dx >= 0 else "right", va="bottom")
        bb = text.get_window_extent(renderer)
        box = (bb.x0 - pad, bb.y0 - pad, bb.x1 + pad, bb.y1 + pad)
        ok = (bb.x0 >= frame.x0 and bb.x1 <= frame.x1 and bb.y0 >= frame.y0 and bb.y1 <= frame.y1
              and all(box[2] <= o[0] or box[0] >= o[2] or box[3] <= o[1] or box[1] >= o[3] for o in taken))
        if ok and strict:  # its own marker must be the nearest one to the label (no misreading)
            gap = np.hypot(np.maximum(np.maximum(box[0] - xy[:, 0], xy[:, 0] - box[2]), 0),
                           np.maximum(np.maximum(box[1] - xy[:, 1], xy[:, 1] - box[3]), 0))
            ok = gap[n] <= gap.min() + 1e-9
        if not ok:
            text.remove()
        return ok, box

    for n in np.argsort(xy[:, 0]):
        spot = next(((dx, dy, box) for strict in (True, False) for dx, dy in rings
                     for ok, box in [place(n, dx, dy, strict)] if ok), None)
        if spot is None:  # nowhere free: the default spot, overlapping
            spot = (*rings[0], place(n, *rings[0], strict=False)[1])
            ax.annotate(texts[n], (t[n], e[n]), fontsize=7, xytext=rings[0], textcoords="offset points")
        dx, dy, box = spot
        if (dx, dy) != rings[0]:  # moved away: a leader line says whose label it is
            ax.annotate("", (t[n], e[n]), xytext=(dx, dy + 3), textcoords="offset points",
                        arrowprops={"arrowstyle": "-", "lw": 0.4, "color": "0.5"})
        taken.append(box)


def _summary(rows: list[dict]) -> list[str]:
    """Bullet lines: the fastest method reaching each error level (frequency and response)."""
    ok = [r for r in rows if "wall" in r]
    out = []
    for key, what, levels in (("freq_err", "largest frequency error (first 5 modes)", (0.1, 0.01, 0.001)),
                              ("resp_err", "tip response error", (0.5, 0.1, 0.01))):
        parts = []
        for lev in levels:
            hit = [r for r in ok if abs(r[key]) <= lev and not (key == "freq_err" and r["family"] == "modes r")]
            if hit:
                best = min(hit, key=lambda r: r["wall"])
                parts.append(f"<= {100 * lev:g} %: {best['label']} ({best['wall']:.2f} s)")
            else:
                parts.append(f"<= {100 * lev:g} %: none")
        out.append(f"- Fastest to a {what} " + "; ".join(parts) + ".")
    return out


def plot_pareto(results: list[dict], path: str) -> None:
    """Pareto PNG: error vs time (log-log), one labelled marker per method, fronts dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(results), figsize=(7.5 * len(results), 10), squeeze=False)
    for j, res in enumerate(results):
        for i, (key, name) in enumerate([("freq_err", f"largest frequency error, first {N_COMPARE} modes"),
                                          ("resp_err", f"tip response RMS error over {T_END:g} s")]):
            ax = axes[i, j]
            # r only changes the response: its frequencies are the reference's own (error 0)
            rows = [r for r in res["rows"] if "wall" in r and (key == "resp_err" or r["family"] != "modes r")]
            t = np.array([r["wall"] for r in rows])
            e = np.maximum(np.array([abs(r[key]) for r in rows]), 1e-6)
            for fam, (color, marker) in _STYLE.items():
                sel = [n for n, r in enumerate(rows) if r["family"] == fam]
                if sel:
                    ax.scatter(t[sel], e[sel], c=color, marker=marker, s=55, label=fam, zorder=3)
            front = pareto_front(t, e)
            ax.plot(t[front], e[front], "k--", lw=0.8, zorder=2, label="Pareto front")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_ylim(e.min() / 2, e.max() * 4)  # headroom for the labels of the least accurate methods
            ax.set_xlim(t.min() / 1.6, t.max() * 2.2)
            _labels(ax, t, e, [r["label"].replace(" -> fine", "->fine") for r in rows])
            ax.set_xlabel("wall time of the method [s] (log)")
            ax.set_ylabel(f"{name} (log, relative)")
            ax.set_title(f"{res['body'].title}:\n{name}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8, loc="best")
    fig.suptitle("modalfem: accuracy versus time (lower left is better; errors vs a finer P2 reference)")
    fig.tight_layout()
    from modalfem.bench.cli import save_figure

    save_figure(fig, path, dpi=110)


def _versions_line() -> str:
    from modalfem.bench import modes_bench as mb

    v = mb.run_case("info", None, timeout=120)
    return ", ".join(f"{k} {x}" for k, x in v.items() if k != "process" and k != "error")


def command(argv: list[str]) -> int:
    """``modalfem bench accuracy [--out BENCHMARKS.md] [--plot PNG] [--quick] [--bodies ...]``."""
    from modalfem.bench.cli import _machine, update_section

    ap = argparse.ArgumentParser(prog="modalfem bench accuracy",
                                 description="Accuracy versus time of full FEM, coarse-to-fine, Ritz and mode count.")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose accuracy section is replaced")
    ap.add_argument("--plot", default=None, help="Pareto PNG (default: bench/accuracy_pareto.png next to --out)")
    ap.add_argument("--quick", action="store_true", help="cantilever only, tiny meshes (smoke test)")
    ap.add_argument("--bodies", nargs="+", choices=list(BODIES), default=list(BODIES))
    a = ap.parse_args(argv)
    plot = a.plot or os.path.join(os.path.dirname(os.path.abspath(a.out)), "bench", "accuracy_pareto.png")
    cmd = "python -m modalfem bench accuracy" + ("" if not argv else " " + shlex.join(argv))
    log = lambda msg: print(msg, file=sys.stderr, flush=True)
    t_start = time.perf_counter()
    bodies = [QUICK["cantilever"]] if a.quick else [BODIES[n] for n in a.bodies]
    results = []
    with tempfile.TemporaryDirectory(prefix="modalfem-accuracy-") as tmp:
        if not a.quick:  # warm the FFCx cache (forms and Ritz expressions) outside the measurements
            log("[bench accuracy] warming the JIT cache ...")
            warm = [("cantilever", "fem-p1", 5), ("cantilever", "fem-p2", 5)]
            warm += [(b.name, f"ritz-{kind}", b.coarse[0]) for b in bodies for kind in ("affine", "quadratic")]
            for name, case, size in warm:
                _run_child(["--body", name, "--case", case, "--size", repr(float(size)), "--k", "2",
                            "--context", _tiny_context(tmp)], os.path.join(tmp, "warm.npz"), 600)
        for body in bodies:
            results.append(_run_body(body, a.quick, tmp, log))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = render(results, command=cmd, date=date, machine=_machine(), versions=_versions_line(),
                     plot=os.path.relpath(plot, os.path.dirname(os.path.abspath(a.out))))
    plot_pareto(results, plot)
    update_section(a.out, section)
    print(section)
    log(f"[bench accuracy] wrote {a.out} and {plot} ({time.perf_counter() - t_start:.0f} s)")
    return 0


def _tiny_context(tmp: str) -> str:
    path = os.path.join(tmp, "tiny-ctx.npz")
    if not os.path.exists(path):
        pts = np.array([[0.5, 0.05, 0.025], [1.0, 0.05, 0.025]])
        np.savez(path, points=pts, surface=pts)
    return path


def main(argv: list[str] | None = None) -> int:
    """Child entry point (one case); see the module docstring."""
    return _child(list(sys.argv[1:] if argv is None else argv))


if __name__ == "__main__":
    sys.exit(main())
