"""Modal sound (``runtime.sound``, ``runtime.synthesis``, ``runtime.wav``).

Spectrum peaks at the model's eigenfrequencies, decay at mu_i / 2, band limit, contact pulses,
listener weights, agreement with the runtime solver, WAV round trip, errors.

The model is a free steel plate 200 x 120 x 8 mm (P2, 34 deformation modes from 1 kHz to above
20 kHz) computed by ``modalfem.modes``; frequencies and damping are read from the model, never typed in.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import wave
from types import SimpleNamespace

import numpy as np
import pytest

import modalfem
import modalfem.runtime as rt
from modalfem.errors import InputError, SimulationError
from modalfem.mesh import box
from modalfem.model import ModalModel
from modalfem.runtime import ModalBody, ModalSolver
from modalfem.runtime.sound import ModalSound, listener_weights, vertex_vector_areas
from modalfem.runtime.synthesis import (
    F_MAX_HZ,
    SAMPLE_RATE,
    band_limit,
    pulse_factor,
    synthesize,
)
from modalfem.runtime.wav import read_wav, write_wav

FS = SAMPLE_RATE
DAMPING = (6.0, 2e-9)  # alpha [1/s], beta [s]: light, mu/2 from 3 to ~20 1/s over the band


@pytest.fixture(scope="module")
def plate():
    mesh = box(size=(0.2, 0.12, 0.008), cells=(6, 4, 1))
    res = modalfem.modes(mesh, modalfem.STEEL, k=34, degree=2)
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=DAMPING)


def _struck(model, *, duration=4.0, **kw):
    """Sound of the plate struck at a corner vertex, obliquely, heard from an oblique direction."""
    snd = ModalSound(model, listener=(0.3, 0.5, 1.0), **kw)
    corner = int(np.argmin(np.linalg.norm(model.vertices - model.vertices.min(axis=0), axis=1)))
    snd.add_impulses(0.0105, corner, (0.2, -0.3, 1.0))
    return snd, snd.render(duration)


def _spectrum(x, pad=2**20):
    X = np.abs(np.fft.rfft(x, n=pad))
    return np.fft.rfftfreq(pad, 1 / FS), X


def _peak_hz(f, X, near, half_width):
    """Frequency of the largest |X| within near +- half_width [Hz], refined by a parabola on log |X|."""
    sel = np.flatnonzero(np.abs(f - near) <= half_width)
    j = sel[np.argmax(X[sel])]
    a, b, c = np.log(X[j - 1:j + 2])
    return f[j] + 0.5 * (a - c) / (a - 2 * b + c) * (f[1] - f[0])


def _expected_heights(snd, model):
    """Spectral peak height of each kept mode, |amplitude * lambda^2 / omega_d| / zeta (up to a common factor)."""
    mu = model.modal_damping[snd.band.kept]
    w = model.omega[snd.band.kept]
    amp = np.abs(np.array(snd._amps).sum(axis=0))
    return amp * w / (0.5 * mu)


# ------------------------------------------------------------------------------------- band
def test_band_limit_keeps_modes_below_20_khz_and_reports_the_others(plate):
    f = plate.frequencies_hz
    assert f.min() < 2000 and f.max() > F_MAX_HZ  # the model spans the band limit
    band = band_limit(plate.omega, plate.modal_damping)
    np.testing.assert_array_equal(band.kept, np.flatnonzero(f < F_MAX_HZ))
    np.testing.assert_array_equal(band.dropped_indices, np.flatnonzero(f >= F_MAX_HZ))
    np.testing.assert_allclose(band.dropped_hz, f[f >= F_MAX_HZ])
    assert all("band limit" in why for _, _, why in band.dropped)
    assert f"{len(band.kept)} modes kept" in band.describe() and "dropped" in band.describe()
    # Nyquist and overdamping are reasons of their own
    low = band_limit(plate.omega, plate.modal_damping, sample_rate=8000, f_max_hz=1e6)
    assert np.all(f[low.kept] < 4000) and any("Nyquist" in why for _, _, why in low.dropped)
    heavy = band_limit(plate.omega, 2.5 * plate.omega)
    assert len(heavy.kept) == 0 and all(why == "overdamped" for _, _, why in heavy.dropped)


# ------------------------------------------------------------------------------------- spectrum
def test_spectrum_peaks_sit_at_the_eigenfrequencies(plate):
    snd, x = _struck(plate)
    f, X = _spectrum(x)
    kept_hz = snd.kept_hz
    height = _expected_heights(snd, plate)
    loud = height > 1e-2 * height.max()
    assert loud.sum() >= 10
    for fi in kept_hz[loud]:
        assert abs(_peak_hz(f, X, fi, 8.0) - fi) < 1.0, fi
    # conversely every strong local maximum of the spectrum is a kept model frequency
    strong = np.flatnonzero((X[1:-1] > X[:-2]) & (X[1:-1] >= X[2:]) & (X[1:-1] > 1e-2 * X.max())) + 1
    assert len(strong) >= 10
    for j in strong:
        assert np.abs(kept_hz - f[j]).min() < 1.0, f[j]


def test_modes_above_the_band_limit_are_absent_from_the_spectrum(plate):
    # move the two highest modes to 20.5 and 21.5 kHz (below Nyquist): audible only without the band limit
    omega = plate.omega.copy()
    omega[-2:] = 2 * np.pi * np.array([20500.0, 21500.0])
    model = dataclasses.replace(plate, omega=np.sort(omega))
    _, x_limited = _struck(model)
    _, x_wide = _struck(model, f_max_hz=22000.0)
    f, Xl = _spectrum(x_limited)
    _, Xw = _spectrum(x_wide)
    for fd in (20500.0, 21500.0):
        near = np.abs(f - fd) < 20.0
        assert abs(_peak_hz(f, Xw, fd, 20.0) - fd) < 1.0  # a peak without the band limit ...
        assert _local_maxima(Xw[near]) == 1
        assert _local_maxima(Xl[near]) == 0  # ... and none with it: only the tails of lower modes
        assert Xl[near].max() < 0.2 * Xw[near].max()


def _local_maxima(X):
    return int(np.sum((X[1:-1] > X[:-2]) & (X[1:-1] >= X[2:])))


def test_each_mode_decays_at_half_its_modal_damping(plate):
    snd, x = _struck(plate, duration=1.5)
    kept_hz = snd.kept_hz
    mu = plate.modal_damping[snd.band.kept]
    height = _expected_heights(snd, plate)
    gap = np.diff(np.concatenate([[-1e9], kept_hz, [1e9]]))
    isolated = (np.minimum(gap[:-1], gap[1:]) > 60.0) & (height > 3e-2 * height.max())
    assert isolated.sum() >= 5
    n_win, hop = 8192, 2205  # Hann frames of 0.19 s every 50 ms
    win = np.hanning(n_win)
    starts = np.arange(int(0.02 * FS), len(x) - n_win, hop)
    frames = np.array([np.abs(np.fft.rfft(win * x[s:s + n_win], n=4 * n_win)) for s in starts])
    freqs = np.fft.rfftfreq(4 * n_win, 1 / FS)
    t = (starts + n_win / 2) / FS
    for fi, mui in zip(kept_hz[isolated], mu[isolated]):
        sel = np.abs(freqs - fi) < 4.0
        env = frames[:, sel].max(axis=1)
        use = env > 1e-3 * env[0]
        slope = np.polyfit(t[use], np.log(env[use]), 1)[0]
        assert use.sum() >= 8
        assert abs(-slope / (0.5 * mui) - 1) < 0.03, (fi, -slope, 0.5 * mui)


# ------------------------------------------------------------------------------------- synthesis
def test_recursive_and_direct_synthesis_agree_with_the_closed_form():
    omega = 2 * np.pi * np.array([440.0, 1234.5, 5000.0])
    mu = np.array([3.0, 8.0, 40.0])
    times = np.array([0.1234567, 0.0, 0.1234567, 0.31])  # off-grid, unsorted, repeated
    amps = np.array([[1.0, -0.5, 0.2], [0.3, 0.0, 1.0], [-0.2, 0.1, 0.0], [0.5, 0.5, -0.5]])
    zeta = mu / 2
    wd = np.sqrt(omega**2 - zeta**2)
    tn = np.arange(int(0.5 * FS)) / FS
    for derivative in (0, 1, 2):
        ref = np.zeros_like(tn)
        for tk, a in zip(times, amps):
            tau = (tn - tk)[:, None]
            e, s, c = np.exp(-zeta * tau), np.sin(wd * tau), np.cos(wd * tau)
            y = [e * s / wd, e * (c - zeta * s / wd), e * ((zeta**2 - wd**2) * s / wd - 2 * zeta * c)][derivative]
            ref += np.where(tau >= 0, y, 0.0) @ a
        for method in ("recursive", "direct"):
            got = synthesize(omega, mu, times, amps, 0.5, derivative=derivative, method=method)
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def test_contact_time_equals_a_half_sine_train_of_small_impulses():
    omega = 2 * np.pi * np.array([500.0, 3000.0, 9000.0])
    mu = np.array([2.0, 5.0, 30.0])
    t0, tau, n = 0.01, 5e-4, 400
    amp = np.array([[1.0, 1.0, 1.0]])
    pulse = synthesize(omega, mu, [t0], amp, 0.1, contact_times=[tau])
    s = (np.arange(n) + 0.5) * tau / n  # midpoint rule over the half-sine g(s) = pi/(2 tau) sin(pi s / tau)
    g = np.pi / (2 * tau) * np.sin(np.pi * s / tau) * tau / n
    train = synthesize(omega, mu, t0 + s, g[:, None] * amp, 0.1)
    after = np.arange(len(pulse)) / FS > t0 + tau
    np.testing.assert_allclose(pulse[after], train[after], atol=1e-4 * np.abs(train).max())
    # and it is a low-pass: |G| ~ (pi / (omega tau))^2 above pi / tau
    G = np.abs(pulse_factor(-mu / 2 + 1j * omega, [tau]))[0]
    assert G[0] > 0.9 and G[2] < 2 * (np.pi / (omega[2] * tau)) ** 2
    np.testing.assert_allclose(pulse_factor(-mu / 2 + 1j * omega, [0.0]), 1.0)


def test_sound_is_linear_in_the_impacts(plate):
    a, b = ModalSound(plate), ModalSound(plate)
    both = ModalSound(plate)
    a.add_impulses(0.01, 3, (0.0, 0.0, 1.0))
    b.add_impulses(0.2, [17, 40], [(1.0, 0.5, 0.0), (0.0, -0.5, 0.2)])
    both.add_impulses(0.2, 17, (1.0, 0.5, 0.0))
    both.add_impulses(0.01, 3, (0.0, 0.0, 1.0))
    both.add_impulses(0.2, 40, (0.0, -0.5, 0.2))
    xa = a.render(0.5)
    np.testing.assert_allclose(both.render(0.5), xa + b.render(0.5), atol=1e-12 * np.abs(xa).max())


def test_rotating_body_impulse_and_listener_together_changes_nothing(plate):
    c, s = math.cos(0.7), math.sin(0.7)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])
    d, J = np.array([0.3, 0.5, 1.0]), np.array([0.2, -0.3, 1.0])
    body = ModalSound(plate, listener=d)
    body.add_impulses(0.0, 5, J)
    world = ModalSound(plate, listener=R @ d)
    dq = world.add_impulses(0.0, 5, R @ J, rotation=R)
    np.testing.assert_allclose(dq, plate.shapes[15:18].T @ J, atol=1e-12 * np.abs(dq).max())
    x = body.render(0.2)
    np.testing.assert_allclose(world.render(0.2), x, atol=1e-10 * np.abs(x).max())


def test_modal_velocity_change_matches_the_runtime_solver(plate):
    body = ModalBody(plate, dtype=np.float64)  # same shapes as ModalSound's, to round-off
    solver = ModalSolver(body)
    state = solver.state(orientation=(0.9, 0.1, -0.3, 0.2), angular_velocity=(0.0, 1.0, 2.0))
    point = body.surface_point(7, (0.2, 0.3, 0.5))
    J = np.array([0.1, -0.4, 0.7])
    before = state.qdot.copy()
    solver.apply_impulse(state, point, J)
    dq = ModalSound(plate).add_impulses(0.0, [point, 3], [J, (0.0, 0.0, 0.0)], rotation=state.rotation())
    np.testing.assert_allclose(dq, state.qdot - before, atol=1e-12 * np.abs(dq).max())


def test_contact_impacts_of_a_dropped_plate_are_heard(plate):
    body = ModalBody(plate)
    g, dt = 9.81, 1e-3
    solver = ModalSolver(body, effects=[rt.Gravity((0, 0, -g)), rt.Obstacles([rt.Ground(0.0)], modal=False)])
    tilt = np.array([np.cos(0.1), np.sin(0.1), 0.0, 0.0])  # 11.5 degrees about x
    state = solver.state(position=(0.0, 0.0, 0.03), orientation=tilt)
    snd = ModalSound(plate)
    quiet = ModalSound(plate)
    for _ in range(150):
        t, R = state.time, state.rotation()
        contacts = solver.collide(state, dt)
        solver.step(state, state, None, contacts, dt)
        snd.add_contacts(t, contacts, rotation=R, min_impulse=5 * plate.mass * g * dt)
        quiet.add_contacts(t, contacts, rotation=R, min_impulse=1e3)
    assert snd.impact_count >= 1 and quiet.impact_count == 0
    x = snd.render(0.3)
    assert np.all(np.isfinite(x)) and np.abs(x[: int(0.03 * FS)]).max() == 0  # silent before the first hit
    assert np.abs(x).max() > 0
    # the same impulses given point by point give the same sound
    fake = SimpleNamespace(vertex=np.array([3, 9]), normal=np.array([[0, 0, 1.0], [0, 0.6, 0.8]]),
                           impulses=np.array([0.2, 0.1]))
    a, b = ModalSound(plate), ModalSound(plate)
    assert a.add_contacts(0.01, fake) and not a.add_contacts(0.02, None)
    b.add_impulses(0.01, [3, 9], fake.impulses[:, None] * fake.normal)
    np.testing.assert_array_equal(a.render(0.05), b.render(0.05))


# ------------------------------------------------------------------------------------- weights
def _uv_sphere(radius, n_theta=48, n_phi=96):
    th = np.linspace(0, np.pi, n_theta + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    v = radius * np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    v = np.vstack([[0, 0, radius], v, [0, 0, -radius]])
    idx = 1 + np.arange((n_theta - 1) * n_phi).reshape(n_theta - 1, n_phi)
    nxt = np.roll(idx, -1, axis=1)
    tris = [np.stack([np.zeros(n_phi, int), idx[0], nxt[0]], 1)]
    for i in range(n_theta - 2):
        tris += [np.stack([idx[i], idx[i + 1], nxt[i + 1]], 1), np.stack([idx[i], nxt[i + 1], nxt[i]], 1)]
    tris.append(np.stack([np.full(n_phi, len(v) - 1), nxt[-1], idx[-1]], 1))
    return v, np.vstack(tris)


def test_listener_weights_of_translation_and_breathing_on_a_sphere():
    R = 0.1
    v, t = _uv_sphere(R)
    a = vertex_vector_areas(v, t)
    assert np.abs(a.sum(axis=0)).max() < 1e-12  # closed surface
    assert abs(np.linalg.norm(a, axis=1).sum() / (4 * np.pi * R**2) - 1) < 5e-3
    d = np.array([1.0, 2.0, 2.0]) / 3.0
    shapes = np.stack([np.tile(d, len(v)), (v / R).reshape(-1)], axis=1)  # translation along d, breathing
    model = type("M", (), {"vertices": v, "triangles": t, "shapes": shapes})()
    w = listener_weights(model, 3 * d)
    # cosine-weighted facing area: int_{n.d > 0} (n.d) (n.u) dA
    assert abs(w[0] / (2 * np.pi * R**2 / 3) - 1) < 5e-3  # translation u = d: int cos^2 over a hemisphere
    assert abs(w[1] / (np.pi * R**2) - 1) < 5e-3  # breathing u = n: the projected area


# ------------------------------------------------------------------------------------- WAV
def test_wav_round_trip(tmp_path, plate):
    _, x = _struck(plate, duration=0.3)
    path = tmp_path / "strike.wav"
    gain = write_wav(path, x, headroom_db=3.0, fade_out_s=0.0)
    with wave.open(str(path), "rb") as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate(), w.getnframes()) == (1, 2, FS, len(x))
    y, fs = read_wav(path)
    assert fs == FS
    np.testing.assert_allclose(y, gain * x * 32767 / 32768, atol=1.0 / 32768)
    assert abs(np.abs(y).max() - 10 ** (-3 / 20)) < 2e-4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["strike.wav"]  # no temporary left
    assert write_wav(tmp_path / "silent.wav", np.zeros(100)) == 0.0
    assert np.all(read_wav(tmp_path / "silent.wav")[0] == 0)
    (tmp_path / "silent.wav").unlink()
    faded = tmp_path / "faded.wav"
    write_wav(faded, x, fade_out_s=0.01)
    assert np.abs(read_wav(faded)[0][-3:]).max() < 1e-3


def test_bad_input_gets_clear_errors(tmp_path, plate):
    with pytest.raises(InputError, match="listener direction"):
        ModalSound(plate, listener=(0, 0, 0))
    with pytest.raises(InputError, match="sample_rate"):
        ModalSound(plate, sample_rate=44100.5)
    snd = ModalSound(plate)
    with pytest.raises(SimulationError, match="dqdot"):
        snd.add_impact(0.0, np.full(plate.mode_count, np.nan))
    with pytest.raises(InputError, match="one entry per model mode"):
        snd.add_impact(0.0, np.ones(3))
    with pytest.raises(SimulationError, match="impact time"):
        snd.add_impact(-1.0, np.ones(plate.mode_count))
    with pytest.raises(SimulationError, match="off the surface"):
        snd.add_impulses(0.0, plate.vertex_count, (0, 0, 1))
    with pytest.raises(SimulationError, match="off the surface"):
        snd.add_impulses(0.0, SimpleNamespace(triangle=0, barycentric=(0.5, 0.5, 0.5)), (0, 0, 1))
    with pytest.raises(SimulationError, match="impulses"):
        snd.add_impulses(0.0, 0, (0, np.inf, 1))
    with pytest.raises(SimulationError, match="impulses"):
        snd.add_impulses(0.0, [0, 1], (0, 0, 1))
    with pytest.raises(InputError, match="damping"):
        ModalSound(plate, damping=(-1.0, 0.0))
    with pytest.raises(InputError, match="duration"):
        snd.render(0.0)
    with pytest.raises(InputError, match="method"):
        snd.render(0.1, method="fast")
    with pytest.raises(InputError, match="NaN"):
        write_wav(tmp_path / "x.wav", [0.0, np.nan])
    with pytest.raises(InputError, match="cannot write WAV"):
        write_wav(tmp_path / "missing" / "x.wav", [0.0, 1.0])
    with pytest.raises(InputError, match="cannot read WAV"):
        read_wav(tmp_path / "x.wav")
    assert list(tmp_path.iterdir()) == []


def test_sound_modules_import_numpy_only():
    heavy = "{'scipy', 'skfem', 'dolfinx', 'matplotlib'}"
    code = ("import sys, modalfem.runtime.sound, modalfem.runtime.synthesis, modalfem.runtime.wav\n"
            f"print(sorted({{m.split('.')[0] for m in sys.modules}} & {heavy}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
