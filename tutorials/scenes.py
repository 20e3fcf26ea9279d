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

# # Scenes: write a scene file, plan it, run it, read its summary
#
# A scene file names everything a simulation needs once: the bodies (modal, tet, cloth), the obstacles,
# the effects (gravity, wind, damping, contact, self-collision, pseudo-forces, sound), the events (a strike,
# a gust), the time step and what to write. `modalfem run SCENE --out DIR` simulates exactly what it names
# and writes ParaView files, a preview video, the sound and a glTF animation; `modalfem plan SCENE` prints
# the stages each step runs. This tutorial does both from Python, on a steel bar dropped onto a soft foam
# block lying on the ground, then struck.
#
# Run it as a plain script (`python tutorials/scenes.py`) or open it as a notebook with jupytext.
# Outputs go to `$MODALFEM_OUT` (default `out/tutorials`): `scenes/bar-on-foam.toml` and the run folder
# `scenes/bar-on-foam/`.

# +
import json
import os
from pathlib import Path

import numpy as np

from modalfem import scene
from modalfem.output.notebook import show

OUT = Path(os.environ.get("MODALFEM_OUT", "out/tutorials")) / "scenes"
OUT.mkdir(parents=True, exist_ok=True)
# -

# ## 1. The scene file
#
# TOML, checked against the schema `modalfem.scene/1` (every key, its unit and range:
# `modalfem/scene/scene.schema.json`). Positions are translations of the meshes as given: the box
# generator puts a box's corner at the origin, so the 16 x 16 x 5 cm foam block spans z = 0 .. 0.05 m and
# the bar starts 3 cm above it. The bar's 8 modes are computed on the first run and cached.

# +
text = """
schema = "modalfem.scene/1"
name = "bar-on-foam"
description = "A steel bar dropped on a foam block on the ground, struck at t = 0.3 s"

[time]
dt = 1e-3          # s
duration = 0.4     # s
frame_rate = 50    # frames per second

[[bodies]]
kind = "modal"
name = "bar"
mesh = { generator = "box", size = [0.12, 0.016, 0.016], cells = [12, 2, 2] }
material = "steel"
modes = 8
position = [0.02, 0.072, 0.08]

[[bodies]]
kind = "tet"
name = "foam"
mesh = { generator = "box", size = [0.16, 0.16, 0.05], cells = [4, 4, 2] }
material = { E = 3e4, nu = 0.3, rho = 60.0 }

[[obstacles]]
kind = "ground"

[[effects]]
kind = "gravity"

[[effects]]
kind = "contact"
restitution = 0.2
friction = 0.5

[[effects]]
kind = "damping"
alpha = 1.0
bodies = ["foam"]

[[effects]]
kind = "sound"
bodies = ["bar"]

[[events]]
kind = "strike"
body = "bar"
time = 0.3
point = [0.06, 0.008, 0.016]     # the middle of the bar's top face, in its own frame [m]
impulse = [0.0, 0.0, -0.004]     # down [N s]
"""
path = OUT / "bar-on-foam.toml"
path.write_text(text)
# -

# A mistake in a scene file is one line naming the file, the key and the problem, before anything runs:

# +
try:
    scene.scene_from_text(text.replace("restitution", "restitusion"), label="bar-on-foam.toml")
except Exception as exc:  # modalfem.errors.SceneError
    message = str(exc)
print(message)
assert "effects[1].restitusion: unknown key (did you mean 'restitution'?)" in message
# -

# ## 2. The plan
#
# The world compiles the stages its bodies and effects need, once: here the tet step, the contacts between
# solids, the modal step and the sound. There is no cloth, so no cloth stage; nothing asks for
# self-collision, so no self-collision stage.

# +
plan = scene.plan_scene(path)
print(plan)
stages = [line.split(". ", 1)[1].split(":")[0] for line in plan.splitlines()]
assert stages == ["tet step", "solid contacts", "modal step", "sound"]
# -

# ## 3. Run it
#
# `run_scene` is `modalfem run`: a progress line on stderr, then every output written at once into the
# folder (a failure leaves no folder; Ctrl-C keeps the frames so far and says so).

# +
result = scene.run_scene(path, OUT / "bar-on-foam")
summary = result.summary
print(sorted(p.name for p in result.out.iterdir()))
show(result.out / "preview.gif")
# -

# ## 4. Read the summary
#
# `summary.json` holds what a user checks or plots: wall time per stage, contacts, energies and momenta per
# body, the exact intersection check at every frame, the sound's strongest frequencies and the modes
# nearest to them.

# +
s = json.loads((result.out / "summary.json").read_text())
print(f"{s['time']['steps_run']} steps in {s['wall_seconds']['run']:.1f} s "
      f"({s['wall_seconds']['steps_per_second']:.0f} steps/s); per stage [s]: "
      + ", ".join(f"{k} {v:.2f}" for k, v in s["wall_seconds"]["stages"].items()))
print(f"intersections: {s['intersections']['total']} in {s['intersections']['checked_frames']} checked frames")
bar = s["bodies"]["bar"]
print(f"bar: energy {bar['energy_start_J'] * 1e3:.2f} mJ at the start, {bar['energy_end_J'] * 1e3:.2f} mJ at the end")
snd = s["sound"]["bar"]
print("sound peaks [Hz]:", [round(f) for f in snd["peaks_hz"]], "nearest modes [Hz]:",
      [round(f) for f in snd["nearest_mode_hz"]])
# -

# The checks: no two surfaces ever crossed; the whole world's energy (kinetic + elastic + gravity potential)
# ended below where it started although the strike added some (the bound is the strike's energy on a free
# bar, J^2 / (2 m) for the centre-of-mass part and at most the same again for rotation and modes); the bar
# came to rest on the foam (its momentum at the end is small against what gravity gave it over the drop);
# and the loudest line of the sound is one of the bar's own modes, within 2 FFT bins. (The quieter peaks
# near a mode are sidebands: the bar rocks on the foam while it rings, which modulates what the listener
# hears.)

# +
assert s["intersections"]["checked_frames"] == s["frames"] and s["intersections"]["total"] == 0
mass = 7850.0 * 0.12 * 0.016 * 0.016
J = 0.004
e_start = sum(b["energy_start_J"] for b in s["bodies"].values())
e_end = sum(b["energy_end_J"] for b in s["bodies"].values())
assert e_end < e_start + 2 * J**2 / (2 * mass)
assert np.linalg.norm(bar["momentum_end"]) < 0.2 * mass * 9.81 * 0.4
assert abs(snd["peaks_hz"][0] - snd["nearest_mode_hz"][0]) <= 2 * snd["bin_hz"]
for name in ("scene.pvd", "preview.gif", "scene.glb", "summary.json", "sound"):
    assert (result.out / name).exists(), name
# -
