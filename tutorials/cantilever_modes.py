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

# # Vibration modes of a steel cantilever, checked against beam theory
#
# A 1 m long steel bar with a 20 mm x 20 mm square section is clamped at `x = 0`. We compute its
# lowest vibration modes with quadratic (P2) tetrahedra, let modalfem name each mode from its shape
# (`bending-y 1`, `torsion 1`, ...), compare the frequencies *by label* with Euler-Bernoulli and
# Timoshenko beam theory, and draw the first mode shapes.
#
# Run it as a plain script (`python tutorials/cantilever_modes.py`) or open it as a notebook with
# jupytext. Pictures go to `$MODALFEM_OUT` (default `out/tutorials`).

# +
import math
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import modalfem
from modalfem import theory
from modalfem.mesh import box
from modalfem.output.notebook import show

OUT = Path(os.environ.get("MODALFEM_OUT", "out/tutorials"))
OUT.mkdir(parents=True, exist_ok=True)
# -

# ## Mesh, material and modes
#
# `box` splits 40 x 2 x 2 hexahedra into 6 tetrahedra each and tags the faces `x0 ... z1`.
# `fixed="x0"` clamps the whole `x = 0` face. With P2 elements that is 6,075 DOFs: about a second.

# +
L, A = 1.0, 0.02  # length and section side [m]
steel = modalfem.STEEL  # E = 200 GPa, nu = 0.3, rho = 7850 kg/m^3
mesh = box(size=(L, A, A), cells=(40, 2, 2))
res = modalfem.modes(mesh, steel, k=8, degree=2, fixed="x0")
print(mesh)
print(f"backend {res.backend}, solver {res.solver}, {res.shapes.shape[0]} DOFs, "
      f"{res.timings['total']:.2f} s, certificate passed: {res.certificate.passed}")
# -

# ## Comparison with beam theory, by label
#
# The square section has two equal bending stiffnesses, so bending modes come in pairs
# (`bending-y n`, `bending-z n`) with equal frequencies. Euler-Bernoulli theory gives
# `f_n = (beta_n L)^2 / (2 pi L^2) sqrt(E I / (rho A))` with `beta_n L` = 1.8751, 4.6941, 7.8548, ...;
# Timoshenko theory adds shear deformation and rotary inertia (it matters more for higher modes).

# +
section = theory.rectangle_section(A, A)
eb = theory.euler_bernoulli_omegas(steel, L, section, count=4) / (2 * math.pi)
ti = theory.timoshenko_omegas(steel, L, section, count=4) / (2 * math.pi)

rows = []
print(f"{'mode':>4}  {'label':<13} {'FE [Hz]':>10} {'EB [Hz]':>10} {'err EB':>8} {'Timo [Hz]':>10} {'err T':>8}")
for i, (label, f) in enumerate(zip(res.labels, res.frequencies_hz)):
    kind, _, order = label.rpartition(" ")
    if kind.startswith("bending"):
        n = int(order)
        e_eb, e_ti = f / eb[n - 1] - 1, f / ti[n - 1] - 1
        rows.append((label, n, f, e_eb, e_ti))
        print(f"{i:>4}  {label:<13} {f:10.3f} {eb[n - 1]:10.3f} {100 * e_eb:+7.3f}% {ti[n - 1]:10.3f} {100 * e_ti:+7.3f}%")
    else:
        print(f"{i:>4}  {label:<13} {f:10.3f}")
# -

# ## Mode shapes
#
# Each panel shows the beam seen from the side that displays the mode's motion (x-y plane for
# `bending-y`, x-z for `bending-z`), deformed by the mode shape, each node coloured by its
# displacement magnitude. The clamped end is on the left.

# +
points = res.dof_points
fig, axes = plt.subplots(2, 2, figsize=(10, 6), constrained_layout=True)
for ax, i in zip(axes.ravel(), range(0, 8, 2)):
    label = res.labels[i]
    u = res.shape(i)
    mag = np.linalg.norm(u, axis=1)
    c = 1 if label.startswith("bending-y") else 2
    scale = 0.15 * L / mag.max()  # largest displacement drawn as 15 % of the length
    ax.fill([0, L, L, 0], [0, 0, A, A], color="0.85", label="undeformed")  # the box spans [0, A] across
    sc = ax.scatter(points[:, 0] + scale * u[:, 0], points[:, c] + scale * u[:, c], c=mag / mag.max(),
                    s=4, cmap="viridis", vmin=0, vmax=1)
    ax.axvline(0, color="k", lw=3)
    ax.set_title(f"mode {i}: {label}, {res.frequencies_hz[i]:.2f} Hz")
    ax.set_xlabel("x [m]")
    ax.set_ylabel(f"{'xyz'[c]} [m] (deformed, scaled)")
    ax.set_ylim(-0.2 * L, 0.2 * L)
fig.colorbar(sc, ax=axes, shrink=0.8, label="|u| / max |u|")
png = OUT / "cantilever_modes.png"
fig.savefig(png, dpi=110)
print(f"wrote {png}")
show(png)  # inline when run as a notebook
# -

# ## Checks
#
# The script ends by asserting what the table shows: the first three bending pairs are within
# 0.5 % of Euler-Bernoulli and of Timoshenko, each pair is degenerate, and the solve is certified.

# +
assert res.certificate.passed
found = {label for label, *_ in rows}
for n in (1, 2, 3):
    assert {f"bending-y {n}", f"bending-z {n}"} <= found, res.labels
for label, n, f, e_eb, e_ti in rows:
    if n <= 3:
        assert abs(e_eb) < 0.005, (label, e_eb)
        assert abs(e_ti) < 0.005, (label, e_ti)
fy = dict(zip(res.labels, res.frequencies_hz))
for n in (1, 2, 3):
    assert abs(fy[f"bending-y {n}"] / fy[f"bending-z {n}"] - 1) < 1e-6
assert png.exists() and png.stat().st_size > 10_000
print("all checks passed")
