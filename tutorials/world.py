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

# # One world: a bell on a soft block, a cloth over both, a strike you can hear
#
# `modalfem.world` steps modal, tet and cloth bodies together. Every kind follows one contract (a fixed
# model, a state, a control, a step) and takes its effects from one vocabulary (`modalfem.effects`):
# gravity, wind, damping, contact, self-collision, pseudo-forces, sound. The world compiles a plan of
# the stages its bodies and effects need, once, and runs only those.
#
# Here a small brass bell (a modal body: rigid motion plus its vibration modes) drops onto a soft foam
# block (a tet body: large deformation, implicit steps) lying on the ground, a cloth falls over both,
# and at t = 0.5 s a hammer strikes the bell. Contact acts both ways between every pair: the bell
# dents the foam and the foam pushes back, the cloth drapes and weighs on both. We check that no two
# surfaces ever cross, that the impulses between bodies are equal and opposite, that energy only
# leaves, and that the sound rings at the bell's own frequencies.
#
# Run it as a plain script (`python tutorials/world.py`) or open it as a notebook with jupytext.
# Outputs go to `$MODALFEM_OUT` (default `out/tutorials`): `world.png`, `world.wav`.

# +
import os
import time
from pathlib import Path

import numpy as np

import modalfem
from modalfem import tet
from modalfem import world as mw
from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel
from modalfem.effects import Contact, Damping, Gravity, SelfCollision, Sound
from modalfem.material import Material
from modalfem.mesh import bell, box
from modalfem.model import ModalModel
from modalfem.output.notebook import show
from modalfem.runtime.wav import write_wav
from modalfem.world.render import frame_sheet

OUT = Path(os.environ.get("MODALFEM_OUT", "out/tutorials"))
OUT.mkdir(parents=True, exist_ok=True)
t_start = time.perf_counter()
# -

# ## 1. Three bodies
#
# The bell's modes come from the offline side (`modalfem.modes`, here scikit-fem + SciPy, P2
# tetrahedra, 16 modes: to 15 kHz for this 7 cm bell). The block is 16 x 16 x 5 cm of soft foam
# (E = 30 kPa), the cloth a 30 x 30 cm knit.

# +
brass = Material(E=110e9, nu=0.34, rho=8500.0)
bell_mesh = bell(diameter=0.07, height=0.056, thickness=0.0021, h=0.01)
res = modalfem.modes(bell_mesh, brass, k=16, degree=2, backend="skfem", solver="scipy")
bell_model = ModalModel.from_modes(res, bell_mesh, brass, damping=(2.0, 1e-9))
print(bell_model)

foam = tet.tet_model(box(size=(0.16, 0.16, 0.05), cells=(4, 4, 2)), Material(E=3e4, nu=0.3, rho=60.0))
knit = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5)
cloth = ClothModel(grid((0.3, 0.3), (16, 16), origin=(-0.07, -0.07, 0.0)), knit, mass_damping=0.2)
print(f"foam block: {foam.mesh.point_count} vertices, {foam.mass if hasattr(foam, 'mass') else foam.masses.sum():.3f} kg;"
      f" cloth: {cloth.mesh.point_count} vertices, {cloth.masses.sum() * 1e3:.1f} g")
# -

# ## 2. The world and its plan
#
# The block lies on the ground, the bell hangs 2 cm above its middle, mouth down, the cloth 12 cm up.
# Effects apply to every body that can take them unless they name bodies: the bell alone sounds, the
# cloth alone collides with itself. `describe_plan` lists the stages a step runs, in order.

# +
bell_z = 0.05 + 0.02 - float(bell_model.center_of_mass[2]) + float(bell_model.vertices[:, 2].min())
world = mw.World(
    bodies=[
        mw.Modal(bell_model, name="bell", position=(0.08, 0.08, 0.07 + float(bell_model.center_of_mass[2]))),
        mw.Tet(foam, name="block"),
        mw.Cloth(cloth, name="cloth", x0=cloth.mesh.points + (0.0, 0.0, 0.16)),
    ],
    obstacles=[mw.Ground(0.0)],
    effects=[Gravity(), Contact(restitution=0.2, friction=0.5, thickness=2e-3), Damping(alpha=1.0, bodies=["block"]),
             SelfCollision(bodies=["cloth"]), Sound(bodies=["bell"], listener=(1.0, -1.0, 0.5))],
)
print(world.describe_plan())
# -

# ## 3. Run it
#
# 1 ms steps for 0.7 s. At t = 0.5 s the hammer strikes the bell's shoulder with 5 mN s along the
# inward normal. Every 10 steps we run the exact triangle-triangle intersection test between every pair
# of surfaces. We also keep the impulses the bodies gave each other (`StepReport.exchanged`).

# +
dt, t_strike, t_end = 1e-3, 0.5, 0.7
state = world.state()
bell_body = world._modal["bell"]["body"]
shoulder = int(np.argmax(bell_body.rest[:, 2]))
energy = {n: [] for n in ("bell", "block", "cloth")}
received = {"bell": np.zeros(3), "block": np.zeros(3), "cloth": np.zeros(3)}
pairs = {}
p_bell0 = world.momentum(state, "bell")[0].copy()
crossings, checks, snapshots, ground_hits = 0, 0, [], 0
for step in range(round(t_end / dt)):
    control = None
    if abs(state.time - t_strike) < 0.5 * dt:
        x = bell_body.positions(state["bell"])
        J_strike = -5e-3 * bell_body.normals(x)[shoulder]
        control = world.control().add_impulse("bell", shoulder, J_strike)
        probe = state["bell"].copy()  # the energy the strike gives the bell (rigid and modal)
        world._modal["bell"]["solver"].apply_impulse(probe, shoulder, J_strike)
        e_strike = world._modal["bell"]["solver"].energy(probe) - world._modal["bell"]["solver"].energy(state["bell"])
    report = world.step(state, state, control, dt)
    ground_hits += report.contacts.get("modal_static", 0)
    for a, b, J, _ in report.exchanged:
        received[a] += J
        received[b] -= J
        key = tuple(sorted((a, b)))
        pairs[key] = pairs.get(key, 0) + 1
    if step % 10 == 9:
        checks += 1
        crossings += len(world.intersections(state))
    if step in (0, 120, 300, 699):
        snapshots.append(state.copy())
    for n, series in energy.items():
        series.append(world.energy(state, n)["total"])
print(f"{checks} intersection checks, {crossings} crossings; body pairs that touched: {pairs}")
print(f"simulation done after {time.perf_counter() - t_start:.1f} s")
# -

# The contact stages in the plan ran only for the pairs that touched; this is what the three bodies did:

# +
path = frame_sheet(world, snapshots, OUT / "world.png")
show(path)
# -

# ## 4. Momentum: what one body gave, the other received
#
# Every impulse between two bodies is recorded once, as received by one and given by the other.
# The bell's momentum therefore changed by exactly gravity plus what the block and the cloth gave it
# plus the strike (it never touched the ground):

# +
m_bell = bell_model.mass
dp_bell = world.momentum(state, "bell")[0] - p_bell0
expected = m_bell * np.array([0.0, 0.0, -9.81]) * t_end + received["bell"] + J_strike
print(f"bell: momentum change {dp_bell} kg m/s, gravity + contacts + strike {expected} kg m/s")
# -

# ## 5. Energy and sound
#
# The foam and the cloth are damped and the contacts are inelastic, so the world's energy never rises but
# by what the hammer gave. The foam meets the bell inside its own implicit step: the bell's surface is a
# moving obstacle there, so the foam's elasticity and the contact are solved together, and the bell takes
# the reaction. The bell's sound is every impact it took (its landing on the foam and the strike) rendered
# through its modes.

# +
e = {n: np.array(v) for n, v in energy.items()}
total = e["bell"] + e["block"] + e["cloth"]
e_start = sum(world.energy(snapshots[0], n)["total"] for n in e)
print(f"energy: after the first step {e_start * 1e3:.2f} mJ, highest later {total.max() * 1e3:.2f} mJ, "
      f"before the strike {total[round(t_strike / dt) - 2] * 1e3:.2f} mJ, the strike gave {e_strike * 1e3:.3f} mJ, "
      f"end {total[-1] * 1e3:.2f} mJ")
snd = world.sound("bell")
p = snd.render(1.0)
write_wav(OUT / "world.wav", p, sample_rate=snd.sample_rate)
tail = p[int((t_strike + 0.02) * snd.sample_rate):]
spec = np.abs(np.fft.rfft(tail * np.hanning(len(tail))))
f = np.fft.rfftfreq(len(tail), 1.0 / snd.sample_rate)
local = np.flatnonzero((spec[1:-1] > spec[:-2]) & (spec[1:-1] >= spec[2:])) + 1
peaks = f[local[np.argsort(spec[local])[-3:]]]
hz = bell_model.frequencies_hz
nearest = [float(hz[np.argmin(np.abs(hz - q))]) for q in peaks]
print(f"loudest frequencies after the strike {np.round(peaks, 1)} Hz; nearest bell modes {np.round(nearest, 1)} Hz")
show(OUT / "world.wav")
# -

# +
assert crossings == 0 and checks == 70
assert ("bell", "block") in pairs and ("block", "cloth") in pairs
assert ground_hits == 0
assert np.allclose(dp_bell, expected, rtol=0, atol=1e-9 * m_bell * 9.81 * t_end + 1e-12)
assert total[-1] < 0.9 * e_start  # damped foam and cloth, inelastic contacts: a tenth of it is gone at least
# never above the start but for the strike; allowance: the foam's Newton iteration stops at vertex updates below
# tol * size, so the contact planes the bell is pushed from are uncertain by that much, against the weight of all
# three bodies, at every step
solver = world._tet["block"]["solver"]
weight = (m_bell + foam.masses.sum() + cloth.masses.sum()) * 9.81
allow = len(total) * weight * solver.tol * foam.size
i_strike = round(t_strike / dt)
assert total[:i_strike].max() <= e_start + allow
assert total[i_strike:].max() <= total[i_strike - 1] + e_strike + allow
assert 0 < e_strike < 1e-3
bin_hz = snd.sample_rate / len(tail)
assert all(abs(q - n) <= 2 * bin_hz for q, n in zip(peaks, nearest))
# -
