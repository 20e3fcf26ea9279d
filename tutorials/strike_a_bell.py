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

# # Strike a bell: modes to 20 kHz, a model file, a drop, a strike, an animation and its sound
#
# A 70 mm brass hand bell. Offline we compute its free vibration modes up to the limit of hearing
# and save them as a model file. At runtime (numpy only) we load the file, drop the bell onto the
# ground, let it bounce and roll, strike it with a hammer, and record every impact for the sound:
# each impact rings the modes as damped sinusoids, summed into a 44.1 kHz WAV file. We render an
# animation offscreen, plot the spectrum, and check momentum, energy and frequency facts.
#
# Run it as a plain script (`python tutorials/strike_a_bell.py`) or open it as a notebook with
# jupytext. Outputs go to `$MODALFEM_OUT` (default `out/tutorials`): `bell.npz`, `bell_drop.gif`,
# `bell_frames.png`, `bell.wav`, `bell_spectrum.png`.

# +
import os
import time
from pathlib import Path

import numpy as np

import modalfem
from modalfem import runtime as rt
from modalfem.effects import Gravity
from modalfem.mesh import bell
from modalfem.model import ModalModel
from modalfem.output.animation import (
    fit_camera,
    plot_spectrum,
    render_frames,
    write_frame_sheet,
    write_gif,
)
from modalfem.output.notebook import show
from modalfem.runtime.rotation import quat_from_axis_angle, quat_multiply
from modalfem.runtime.sound import ModalSound
from modalfem.runtime.synthesis import F_MAX_HZ
from modalfem.runtime.wav import write_wav

OUT = Path(os.environ.get("MODALFEM_OUT", "out/tutorials"))
OUT.mkdir(parents=True, exist_ok=True)
t_start = time.perf_counter()
# -

# ## 1. Modes up to 20 kHz
#
# Sound is where the high modes matter: every mode below 20 kHz can be heard, so the model must
# hold all of them. `k = 36` deformation modes reach past 20 kHz for this bell, and the
# certificate's inertia count (Sylvester's law) proves that no eigenvalue below the highest one
# returned was missed, so the model is complete up to 20 kHz. P2 tetrahedra, free-free (six rigid
# modes found and set aside).

# +
brass = modalfem.BRASS  # E = 100 GPa, nu = 0.34, rho = 8500 kg/m^3
mesh = bell(diameter=0.07, height=0.056, thickness=0.0021, h=0.007)  # [m]
res = modalfem.modes(mesh, brass, k=36, degree=2)
f_hz = res.frequencies_hz
audible = int(np.sum(f_hz < F_MAX_HZ))
print(mesh)
print(f"{res.shapes.shape[0]} DOFs, {res.rigid_mode_count} rigid modes, certificate passed: {res.certificate.passed}, "
      f"{res.timings['total']:.1f} s")
print(f"{len(f_hz)} modes from {f_hz[0]:.0f} to {f_hz[-1]:.0f} Hz: {audible} below {F_MAX_HZ:.0f} Hz")
for label, f in list(zip(res.labels, f_hz))[:8]:
    print(f"  {label:<14} {f:9.1f} Hz")
# -

# ## 2. The model file
#
# `ModalModel.from_modes` keeps the boundary surface, the mode shapes restricted to its vertices,
# the frequencies, the rigid-body mass properties and Rayleigh damping `mu_i = alpha + beta
# omega_i^2`: here `alpha = 3 1/s`, `beta = 1e-9 s`, so the fundamental rings for about a second
# and the 20 kHz modes for a tenth of that. The runtime loads the file with numpy only.

# +
model = ModalModel.from_modes(res, mesh, brass, damping=(3.0, 1e-9))
model_path = OUT / "bell.npz"
model.save(model_path)
body = rt.load(model_path)
print(model)
print(f"model file {model_path.stat().st_size / 1e3:.0f} kB, mass {body.mass * 1e3:.1f} g")
# -

# ## 3. Drop, bounce, roll, strike
#
# The bell starts 8 cm above the ground lying on its side, tilted and spinning, under gravity
# with ground contact (restitution 0.5, friction 0.4). Steps of 1 ms: the modes are advanced
# exactly. The contacts see the flexible bell (`modal=True`, the default): the velocity of a
# touching vertex includes its vibration and the contact compliance includes the modes, so every
# impact makes the bell ring with energy taken from the impact (no contact solve ever adds energy).
# An instantaneous hit on the thin lip moves the modes easily (their compliance at a lip vertex is
# 6 to 20 times the rigid one, along the axis and across it), so the bell bounces less than a
# rigid one with the same restitution and keeps ringing. What the impacts do to the vibration is
# also what we hear: their impulses are fed through the mode shapes into the sound. At t = 0.45 s a hammer
# strikes the top of the sound bow with 0.03 N s (a 30 g hammer at 1 m/s), which the simulation
# applies to the modes too.
#
# Sound is opt-in: a `ModalSound` receives every impact, i.e. the contact impulses of the steps
# where the bell hits the ground (resting contact, about `m g dt` per step, is not an impact and
# would only add a buzz at the step rate) and the strike. The listener sits 1 m away.

# +
g = 9.81
solver = rt.ModalSolver(body, effects=[Gravity((0.0, 0.0, -g)),
                                       rt.Obstacles([rt.Ground(0.0)], restitution=0.5, friction=0.4, modal=True)])
lying = quat_multiply(quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.4),
                      quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(100.0)))
state = solver.state(position=(0.0, 0.0, 0.08), orientation=lying, angular_velocity=(1.0, 3.0, 0.0))
sound = ModalSound(model, listener=(1.0, -1.0, 0.5), distance=1.0)
print(sound.band.describe())

dt, t_strike, t_end, frame_every = 1e-3, 0.45, 0.75, 15
bow = np.flatnonzero(body.rest[:, 2] < body.rest[:, 2].min() + 0.006)  # sound-bow vertices (near the lip)
tip, J_strike = None, None

e0 = solver.energy(state) + body.mass * g * state.position[2]
p0 = solver.momentum(state)[0]
frames, frame_t, energies, impacts, first_contact = [], [], [], [], None
for step in range(round(t_end / dt)):
    t = state.time
    if step % frame_every == 0:
        frames.append((state.position.copy(), state.rotation(), state.q.copy()))
        frame_t.append(t)
    control = None
    if abs(t - t_strike) < 0.5 * dt:
        R = state.rotation()
        x = body.positions(state)
        tip = int(bow[np.argmax(x[bow, 2])])  # the highest point of the sound bow, hit from outside
        J_strike = -0.03 * body.normals(x)[tip]  # 0.03 N s into the surface
        before = state.copy()
        probe = state.copy()
        solver.apply_impulse(probe, tip, J_strike)  # the impulse law, checked below
        strike_check = (before, probe)
        control = rt.Control().add_impulse(tip, J_strike)
        sound.add_impulses(t, tip, J_strike, rotation=R, contact_time=4e-4)
    contacts = solver.collide(state, dt)
    R = state.rotation()
    if contacts.count and first_contact is None:
        first_contact = (t, state.copy())
    solver.step(state, state, control, contacts, dt)
    # an impact, not resting contact (which pushes with about m g dt every step)
    if sound.add_contacts(t, contacts, rotation=R, min_impulse=5 * body.mass * g * dt, contact_time=1.5e-4):
        impacts.append((t, float(contacts.impulses.sum())))
    energies.append((state.time, solver.energy(state) + body.mass * g * state.position[2]))
frames.append((state.position.copy(), state.rotation(), state.q.copy()))
frame_t.append(state.time)
energies = np.array(energies)
print(f"{len(impacts)} impact steps, first contact at t = {first_contact[0]:.3f} s, "
      f"largest impact {max(j for _, j in impacts):.3f} N s")
print(f"energy: start {e0 * 1e3:.2f} mJ, before the strike {energies[energies[:, 0] <= t_strike][-1, 1] * 1e3:.2f} mJ, "
      f"end {energies[-1, 1] * 1e3:.2f} mJ")
print(f"simulation done after {time.perf_counter() - t_start:.1f} s")
# -

# ## 4. Animation
#
# Offscreen rendering (matplotlib Agg, fixed camera, checkered ground with the bell's shadow).
# The deformation (the ringing after the strike) is magnified so that the largest one in the clip
# is 5 % of the diameter: the real vibration is micrometres. One frame every 15 ms, played at 25
# frames per second: 0.6x real time. The ringing at kHz is sampled every 15 ms, so the frames show
# its decaying amplitude, not its period.

# +
u_max = max(np.abs(body.shapes @ q).max() for _, _, q in frames)
magnify = 0.05 * 0.07 / max(u_max, 1e-30)
X = np.array([c + (body.rest + magnify * (body.shapes @ q).reshape(-1, 3)) @ R.T for c, R, q in frames])
camera = fit_camera(X, elev=25.0, azim=-60.0)
labels = [f"t = {t:.3f} s" + ("   strike!" if abs(t - t_strike) < 0.5 * frame_every * dt else "") for t in frame_t]
images = render_frames(X, body.triangles, camera=camera, labels=labels)
write_gif(OUT / "bell_drop.gif", images, fps=25)
pick = sorted({*np.linspace(0, len(images) - 1, 7).round().astype(int), round(t_strike / (frame_every * dt))})
write_frame_sheet(OUT / "bell_frames.png", images[pick], columns=4)
print(f"{len(images)} frames, deformation magnified {magnify:.0f}x; wrote bell_drop.gif and bell_frames.png")
show(OUT / "bell_drop.gif", OUT / "bell_frames.png")  # inline when run as a notebook
# -

# ## 5. Sound
#
# The sound is rendered for 3 s from the recorded impacts: each is an exact sum of damped
# sinusoids at the model's frequencies, weighted by how much the mode moves the surface that faces
# the listener. A real contact is not instantaneous: the bell's lip on stone lasts about 0.15 ms,
# the (leather) hammer 0.4 ms, and the sound hears each velocity change spread over a half-sine
# pulse that long, which tempers the modes above about `1 / duration` Hz. Modes above 20 kHz are
# dropped (listed above).
#
# After the clip ends (t = 0.75 s) no more impacts are recorded and the bell rings freely: the
# peaks of that tail's spectrum (Hann window) should sit at the model frequencies.

# +
duration = 3.0
pressure = sound.render(duration)  # [Pa] at the listener
gain = write_wav(OUT / "bell.wav", pressure)
fs = sound.sample_rate
tail = pressure[int(np.ceil((t_end + 1e-3) * fs)):]
n_pad = 1 << 20
spec = np.abs(np.fft.rfft(tail * np.hanning(len(tail)), n=n_pad))
freqs = np.fft.rfftfreq(n_pad, 1 / fs)
is_peak = (spec[1:-1] > spec[:-2]) & (spec[1:-1] >= spec[2:]) & (spec[1:-1] > 1e-2 * spec.max())
peaks = freqs[1:-1][is_peak]
miss = np.array([np.abs(sound.kept_hz - p).min() for p in peaks])
plot_spectrum(OUT / "bell_spectrum.png", pressure, fs, model_hz=sound.kept_hz, dropped_hz=sound.band.dropped_hz,
              f_max_hz=F_MAX_HZ, peaks_hz=peaks, ylabel="pressure at 1 m [Pa]",
              title="70 mm brass bell: dropped, bounced, struck at t = 0.45 s")
print(f"peak pressure {np.abs(pressure).max():.3g} Pa at 1 m; ringing tail: {len(peaks)} spectral peaks above "
      f"-40 dB, farthest from a model frequency {miss.max():.3f} Hz")
for p, m in zip(peaks, miss):
    print(f"  peak {p:9.2f} Hz   nearest model mode {m:.3f} Hz away")
print(f"wrote bell.wav ({duration:.0f} s, 44.1 kHz, 16 bit) and bell_spectrum.png; "
      f"total {time.perf_counter() - t_start:.1f} s")
show(OUT / "bell_spectrum.png", OUT / "bell.wav")  # the spectrum, and a player for the sound
# -

# ## Checks
#
# * all modes below 20 kHz are in the model (certified, highest mode above 20 kHz), and the
#   higher ones were dropped from the sound;
# * free fall: until the first contact the momentum grows by exactly `m g t` and the energy
#   (kinetic + potential + modal) is conserved; contacts then only dissipate it until the strike;
# * the strike: linear momentum changes by exactly the impulse J, angular momentum by `r x J`, and
#   the modal velocities by `Phi(p)^T R^T J`, which adds `0.5 |dqdot|^2 + qdot . dqdot` of modal energy;
# * no surface vertex is below the ground at the end;
# * every spectral peak lies within 1 Hz of a model frequency, there are many of them, and
#   nothing above 20 kHz is heard.

# +
assert res.certificate.passed and res.rigid_mode_count == 6
assert f_hz[-1] > F_MAX_HZ and audible >= 20
np.testing.assert_array_equal(sound.band.dropped_indices, np.flatnonzero(f_hz >= F_MAX_HZ))

t1, s1 = first_contact
p1 = solver.momentum(s1)[0]
assert t1 > 0.05
np.testing.assert_allclose(p1 - p0, body.mass * np.array([0.0, 0.0, -g]) * t1, rtol=0, atol=1e-9)
e1 = solver.energy(s1) + body.mass * g * s1.position[2]
assert abs(e1 - e0) < 1e-9 * e0, (e1, e0)
before_strike = energies[energies[:, 0] <= t_strike, 1]
assert before_strike.max() <= e0 * (1 + 1e-6) and before_strike[-1] < 0.99 * e0

before, after = strike_check
r_tip = body.positions(before, precise=True)[tip] - before.position
np.testing.assert_allclose(solver.momentum(after)[0] - solver.momentum(before)[0], J_strike, atol=1e-12)
np.testing.assert_allclose(after.angular_momentum - before.angular_momentum, np.cross(r_tip, J_strike), atol=1e-12)
dq = body.point_shapes(tip).T @ (before.rotation().T @ J_strike)
np.testing.assert_allclose(after.qdot - before.qdot, dq, atol=1e-12)
gain_modal = body.modal_energy(after) - body.modal_energy(before)
assert abs(gain_modal - (0.5 * dq @ dq + before.qdot @ dq)) < 1e-9 * abs(gain_modal)

assert body.positions(state, precise=True)[:, 2].min() >= -1e-9
assert len(impacts) >= 2 and abs(state.time - t_end) < 1e-9

assert len(peaks) >= 8 and miss.max() < 1.0, miss
full = np.abs(np.fft.rfft(pressure))
assert full[np.fft.rfftfreq(len(pressure), 1 / fs) > F_MAX_HZ + 500].max() < 1e-3 * full.max()
for name in ("bell.npz", "bell_drop.gif", "bell_frames.png", "bell.wav", "bell_spectrum.png"):
    assert (OUT / name).stat().st_size > 1000, name
print("all checks passed")
