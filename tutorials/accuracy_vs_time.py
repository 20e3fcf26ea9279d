# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: light
#       format_version: '1.5'
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# # Accuracy versus time: how much accuracy to pay for
#
# Low-frequency modes barely depend on fine geometry, so there are cheap ways to get them. This
# tutorial puts four of them side by side on a clamped steel cantilever (1 m x 0.1 m x 0.05 m):
#
# * **full FEM** (`modalfem.modes`) with linear (P1) or quadratic (P2) tetrahedra at several sizes;
# * **coarse-to-fine**: P2 modes on a very coarse mesh, carried to the fine surface the user sees by
#   barycentric embedding (`modalfem.reduction.embed`);
# * **Rayleigh-Ritz** with 12 affine or 30 affine + quadratic smooth fields (times the clamp weight
#   x / L), from the same elasticity forms (`modalfem.reduction.ritz`): a 30 x 30 eigenproblem;
# * **fewer retained modes** r for a dynamic response (tip displacement after an impulse).
#
# Errors are measured against a finer P2 reference. Times here are in-process and on a shared
# machine; `python -m modalfem bench accuracy` measures every method in a fresh process (with peak
# memory) on this cantilever and a tuning fork and writes the table to `BENCHMARKS.md`. The asserts
# at the end use DOF counts, not seconds, as the cost (timings vary from run to run).
#
# Run it as a plain script (`python tutorials/accuracy_vs_time.py`) or open it as a notebook with
# jupytext. Pictures go to `$MODALFEM_OUT` (default `out/tutorials`).

# +
import os
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import modalfem
from modalfem.backends import get_backend
from modalfem.mesh import box
from modalfem.output.notebook import show
from modalfem.reduction.compare import compare_modes
from modalfem.reduction.embed import embed_points
from modalfem.reduction.response import (
    RayleighDamping,
    impulse_response,
    relative_rms_error,
)
from modalfem.reduction.ritz import ritz_modes

OUT = Path(os.environ.get("MODALFEM_OUT", "out/tutorials"))
OUT.mkdir(parents=True, exist_ok=True)
steel = modalfem.STEEL


def beam(n):
    """The cantilever with n hexahedra along its length (6 tetrahedra each)."""
    return box(size=(1.0, 0.1, 0.05), cells=(n, max(1, n // 10), max(1, n // 20)))


# -

# ## The reference
#
# P2 on 40 x 4 x 2 hexahedra (about 11,000 DOFs), 12 modes. Every method's mode shapes are
# evaluated at the reference's P2 nodes (by embedding the nodes in the method's mesh) so that the
# mass-weighted MAC can compare shapes across meshes; modes are matched by MAC.

# +
ref_mesh = beam(40)
ref = modalfem.modes(ref_mesh, steel, k=12, degree=2, fixed="x0")
M_ref = get_backend(ref.backend).assemble(ref_mesh, steel, degree=2)[1]
ref_points = ref_mesh.dof_points(2)
print(f"reference: {ref.shapes.shape[0]} DOFs, first frequencies {np.round(ref.frequencies_hz[:5], 2)} Hz")

tip = np.array([[1.0, 0.05, 0.025]])  # impulse and output point [m]
down = np.array([0.0, 0.0, 1.0])  # the thin direction
damping = RayleighDamping.from_ratios(0.01, ref.omega[0], ref.omega[4])  # 1 % at modes 1 and 5
times = np.linspace(0.0, 1.0, 4001)  # [s]


def tip_response(omega, shapes_at_tip):
    """Tip displacement [m] along z after a 0.01 N s impulse at the tip along z."""
    phi = shapes_at_tip.reshape(3, -1)
    return impulse_response(omega, phi, phi, 0.01 * down, down, times, damping=damping)


u_ref = tip_response(ref.omega, embed_points(ref_mesh, tip).transfer(ref.shapes, degree=2))
N = 3  # compare the first three modes


def measure(name, family, dofs, seconds, omega, shapes_ref, shapes_tip):
    c = compare_modes(omega, shapes_ref, ref.omega, ref.shapes, M=M_ref, count=N)
    err = relative_rms_error(tip_response(omega, shapes_tip), u_ref)
    row = {"name": name, "family": family, "dofs": dofs, "time": seconds, "f_err": c.max_frequency_error,
           "mac": c.min_mac, "resp_err": err}
    print(f"{name:<26} {dofs:>6} DOFs {seconds:7.3f} s  freq err {100 * row['f_err']:8.3f} %  "
          f"MAC {row['mac']:.4f}  response err {100 * err:7.2f} %")
    return row


# -

# ## Full FEM: P1 and P2 ladders
#
# P1 tetrahedra lock in bending: they need far more DOFs than P2 for the same frequency error.

# +
rows = []
fem = {}
for degree, sizes in ((1, (10, 20, 40)), (2, (5, 10, 20))):
    for n in sizes:
        t0 = time.perf_counter()
        mesh = beam(n)
        res = modalfem.modes(mesh, steel, k=8, degree=degree, fixed="x0")
        dt = time.perf_counter() - t0
        fem[(degree, n)] = (mesh, res)
        e_ref, e_tip = embed_points(mesh, ref_points), embed_points(mesh, tip)
        rows.append(measure(f"P{degree} {n}x{max(1, n // 10)}x{max(1, n // 20)}", f"P{degree}", res.shapes.shape[0],
                            dt, res.omega, e_ref.transfer(res.shapes, degree=degree), e_tip.transfer(res.shapes, degree=degree)))
# -

# ## Coarse-to-fine
#
# The modes of a 5 x 1 x 1 P2 mesh (297 DOFs) are carried to the boundary vertices of the fine
# mesh, the surface a renderer would draw. Barycentric embedding uses a bucket grid (no loop over
# points); a point outside the coarse mesh would use its nearest tetrahedron.

# +
t0 = time.perf_counter()
coarse = beam(5)
res_c = modalfem.modes(coarse, steel, k=8, degree=2, fixed="x0")
surface = ref_mesh.points[np.unique(ref_mesh.boundary_facets)]
on_surface = embed_points(coarse, surface).transfer(res_c.shapes, degree=2)
dt = time.perf_counter() - t0
print(f"carried {res_c.shapes.shape[1]} modes to {len(surface)} fine surface vertices: array {on_surface.shape}")
rows.append(measure("coarse P2 5x1x1 -> fine", "coarse->fine", res_c.shapes.shape[0], dt, res_c.omega,
                    embed_points(coarse, ref_points).transfer(res_c.shapes, degree=2),
                    embed_points(coarse, tip).transfer(res_c.shapes, degree=2)))
# the transferred first mode, against the fine mode on the same surface vertices
fine_on_surface = embed_points(ref_mesh, surface).transfer(ref.shapes[:, :1], degree=2)
mac_surface = compare_modes(res_c.omega, on_surface, ref.omega[:1], fine_on_surface).mac[0]
print(f"first mode on the fine surface: plain MAC {mac_surface:.5f}")
# -

# ## Rayleigh-Ritz
#
# The fields are monomials of the scaled coordinate times the clamp weight x / L, so they vanish at
# the clamp. The reduced matrices are integrated on the coarse mesh (exact for a box). By min-max
# the Ritz frequencies are upper bounds of the exact ones.

# +
ritz = {}
for kind in ("affine", "quadratic"):
    t0 = time.perf_counter()
    rm = ritz_modes(coarse, steel, kind=kind, clamp=(0, 0.0))
    dt = time.perf_counter() - t0
    ritz[kind] = rm
    rows.append(measure(f"Ritz {kind}", "Ritz", rm.K_r.shape[0], dt, rm.omega, rm.shapes_at(ref_points),
                        rm.shapes_at(tip)))
# -

# ## Retained modes for the dynamic response
#
# The P2 20 x 2 x 1 modes again, keeping only the first r of them: the tip response error then
# mixes truncation (few modes) and discretisation (the mesh). Over 1 s the first mode dominates,
# but the impulse at the tip also excites the higher bending modes.

# +
mesh20, res20 = fem[(2, 20)]
phi_tip = embed_points(mesh20, tip).transfer(res20.shapes, degree=2)
trunc = {}
for r in (1, 2, 4, 8):
    trunc[r] = relative_rms_error(tip_response(res20.omega[:r], phi_tip.reshape(3, -1)[:, :r]), u_ref)
    print(f"r = {r}: response error {100 * trunc[r]:.2f} %")
# -

# ## The trade-off
#
# Each marker is one method; lower left is better. The left panel shows the largest frequency error
# over the first three modes, the right one the tip response error over 1 s. The response error
# is far more sensitive: a frequency error of 0.1 % shifts the phase of a 40 Hz mode by 0.25 rad
# after one second.

# +
style = {"P1": ("tab:blue", "o"), "P2": ("tab:orange", "s"), "coarse->fine": ("tab:green", "^"), "Ritz": ("tab:red", "D")}
fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
for ax, key, title in ((axes[0], "f_err", f"largest frequency error, first {N} modes"),
                       (axes[1], "resp_err", "tip response RMS error over 1 s")):
    for fam, (color, marker) in style.items():
        sel = [r for r in rows if r["family"] == fam]
        ax.scatter([r["time"] for r in sel], [max(abs(r[key]), 1e-6) for r in sel], c=color, marker=marker,
                   s=60, label=fam, zorder=3)
    for i, r in enumerate(rows):
        ax.annotate(r["name"], (r["time"], max(abs(r[key]), 1e-6)), fontsize=7, xytext=(5, 4 - 9 * (i % 2)),
                    textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time in this process [s] (log)")
    ax.set_ylabel("relative error (log)")
    ax.set_title(f"clamped steel cantilever: {title}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
png = OUT / "accuracy_vs_time.png"
fig.savefig(png, dpi=100)
print(f"wrote {png}")
show(png)  # inline when run as a notebook
# -

# ## Checks
#
# What the plot claims, asserted with DOFs as the (deterministic) cost:
#
# * P2 beats P1 at equal cost: P2 on 10 x 1 x 1 (fewer DOFs than P1 on 40 x 4 x 2) has a smaller
#   frequency error;
# * quadratic Ritz beats affine Ritz, and both bound the reference from above (min-max);
# * the coarse-to-fine modes on the fine surface have the right shape (MAC > 0.99);
# * with the P2 20 x 2 x 1 modes, keeping 8 modes gives a better response than keeping 1.

# +
by = {r["name"]: r for r in rows}
p2, p1 = by["P2 10x1x1"], by["P1 40x4x2"]
assert p2["dofs"] < p1["dofs"] and p2["f_err"] < p1["f_err"], (p2, p1)
for n in (10, 20):  # and P2 beats P1 on the same mesh
    assert by[f"P2 {n}x{max(1, n // 10)}x{max(1, n // 20)}"]["f_err"] < by[f"P1 {n}x{max(1, n // 10)}x{max(1, n // 20)}"]["f_err"]
assert by["Ritz quadratic"]["f_err"] < by["Ritz affine"]["f_err"]
for rm in ritz.values():
    k = min(3, len(rm.omega))
    assert np.all(rm.omega[:k] >= ref.omega[:k] * (1 - 1e-9)), rm.kind  # upper bounds
assert by["coarse P2 5x1x1 -> fine"]["mac"] > 0.99 and mac_surface > 0.99
assert trunc[8] < trunc[1]
assert png.exists() and png.stat().st_size > 10_000
print("all checks passed")
