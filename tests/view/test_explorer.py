"""ModeExplorer physics and display, without a browser: strikes, slow-motion ringing, mode display, sound."""

from __future__ import annotations

import base64
import math

import numpy as np
import pytest

from modalfem.errors import InputError
from modalfem.model import ModalModel
from modalfem.view import ModeExplorer


def _explorer(model, **kw) -> ModeExplorer:
    return ModeExplorer(model, **kw)  # not started: no port, no thread; the methods work on their own


def _strike_reference(model, triangle, bary, impulse):
    """Phi(p)^T J from the model's arrays: J along the inward normal of the triangle."""
    tri = model.triangles[triangle]
    x = model.vertices[tri]
    n = np.cross(x[1] - x[0], x[2] - x[0])
    J = -impulse * n / np.linalg.norm(n)
    rows = np.concatenate([model.shapes[3 * v:3 * v + 3] for v in tri]).reshape(3, 3, -1)
    return np.einsum("k,kcr->cr", bary, rows).T @ J


def test_strike_changes_the_modal_velocities_by_phi_transpose_j(view_model):
    ex = _explorer(view_model, impulse=0.02)
    bary = np.array([0.2, 0.5, 0.3])
    out = ex.strike(0, 5, bary, (0.0, 0.0, -1.0))
    ref = _strike_reference(view_model, 5, bary, 0.02)
    np.testing.assert_allclose(ex.qdot, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    assert out["dqdot_norm"] == pytest.approx(np.linalg.norm(ref), rel=1e-12)
    assert np.abs(ex.qdot).max() > 0 and ex.strikes == 1
    assert f"magnified x{ex._gain:.3g}" in ex.viewer._status and "slow motion 1:" in ex.viewer._status
    ex.strike(0, 5, bary, (0.0, 0.0, -1.0))  # strikes add up
    np.testing.assert_allclose(ex.qdot, 2 * ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    ex.rest()
    assert not ex.qdot.any() and not ex.q.any()


def test_ringing_keeps_each_modes_energy_without_damping_and_runs_in_slow_motion(view_model):
    ex = _explorer(view_model)
    ex.strike(0, 0, np.array([1 / 3, 1 / 3, 1 / 3]), (0, 0, -1))
    omega = view_model.omega
    e0 = 0.5 * (ex.qdot**2 + omega**2 * ex.q**2)
    for k in range(240):
        ex.tick(1 / 60, k / 60)
    e1 = 0.5 * (ex.qdot**2 + omega**2 * ex.q**2)
    np.testing.assert_allclose(e1, e0, rtol=1e-9)  # exact per-mode steps: energy kept to roundoff
    # 4 s of wall time is 4 periods of the lowest mode: slow motion f_1 / DISPLAY_HZ
    assert ex.sim_time == pytest.approx(4 * 2 * math.pi / omega[0], rel=1e-12)
    assert ex.q[0] == pytest.approx(0.0, abs=1e-9 * np.abs(ex.qdot[0]) / omega[0])  # whole periods: back at q = 0


def test_damping_of_the_model_is_used():
    # the same block with Rayleigh damping: energy decays as exp(-mu_i t) per mode, mu_i = beta omega_i^2
    import modalfem
    from modalfem.mesh import box

    mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=3, degree=1, backend="skfem", solver="scipy")
    model = ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))
    ex = _explorer(model)
    ex.strike(0, 0, np.array([0.6, 0.2, 0.2]), (0, 0, -1))
    e0 = 0.5 * (ex.qdot**2 + model.omega**2 * ex.q**2)
    for k in range(120):
        ex.tick(1 / 60, k / 60)
    e1 = 0.5 * (ex.qdot**2 + model.omega**2 * ex.q**2)
    mu = 1e-7 * model.omega**2
    # over whole periods of a lightly damped mode the energy falls by exp(-mu t) to O((mu/omega)) accuracy
    ratio = e1[0] / e0[0]
    assert ratio == pytest.approx(math.exp(-mu[0] * ex.sim_time), rel=5 * mu[0] / model.omega[0] + 1e-9)


def test_shown_q_is_the_picked_mode_at_the_chosen_amplitude(view_model):
    ex = _explorer(view_model, mode=3, amplitude=0.1, animate=False)
    size = np.linalg.norm(view_model.vertices.max(0) - view_model.vertices.min(0))
    q = ex.shown_q(0.0)
    assert np.flatnonzero(q).tolist() == [2]
    u = (view_model.shapes @ q).reshape(-1, 3)
    assert np.linalg.norm(u, axis=1).max() == pytest.approx(0.1 * size, rel=1e-12)
    ex.select_mode(5)
    still = ex.shown_q(0.0)
    assert np.flatnonzero(still).tolist() == [5]
    ex.set_animate(True)  # q_6 = a sin(2 pi t): one cycle per second
    assert ex.shown_q(0.25)[5] == pytest.approx(still[5], rel=1e-12)
    assert abs(ex.shown_q(0.5)[5]) <= 1e-12 * abs(still[5])
    assert ex.shown_q(0.75)[5] == pytest.approx(-still[5], rel=1e-12)
    with pytest.raises(InputError, match="mode index"):
        ex.select_mode(8)


def test_strike_display_reaches_at_most_the_amplitude(view_model):
    ex = _explorer(view_model, amplitude=0.05)
    ex.set_amplitude(0.0)
    ex.set_amplitude(0.05)
    ex.set_animate(False)
    ex.select_mode(0)
    mode_part = ex.shown_q(0.0)  # nothing struck yet: the still mode shape alone
    ex.strike(0, 7, np.array([0.3, 0.3, 0.4]), (1, 0, 0))
    size = np.linalg.norm(view_model.vertices.max(0) - view_model.vertices.min(0))
    peak = 0.0
    for _ in range(600):  # 10 s of wall time
        ex.tick(1 / 60, 0.0)
        struck = ex.shown_q(0.0) - mode_part
        peak = max(peak, np.linalg.norm((view_model.shapes @ struck).reshape(-1, 3), axis=1).max())
    assert 0.2 * 0.05 * size < peak <= 0.05 * size * (1 + 1e-12)


def test_strike_sound_rings_at_the_model_frequencies(view_model):
    ex = _explorer(view_model)
    out = ex.strike(0, 2, np.array([0.5, 0.25, 0.25]), (0.3, -0.2, -1.0))
    snd = ex.viewer._sound
    pcm = np.frombuffer(base64.b64decode(snd["pcm16"]), "<i2").astype(np.float64)
    assert len(pcm) == round(out["sound_s"] * snd["rate"]) and np.abs(pcm).max() > 0.8 * 32767
    spec = np.abs(np.fft.rfft(pcm * np.hanning(len(pcm))))
    f = np.fft.rfftfreq(len(pcm), 1 / snd["rate"])
    hz = view_model.frequencies_hz[view_model.frequencies_hz < 20000]
    df = snd["rate"] / len(pcm)
    peaks = [f[i] for i in np.argsort(spec)[::-1][:3]]
    assert all(np.min(np.abs(hz - p)) <= 2 * df for p in peaks), (peaks, hz)


def test_bad_options_are_one_line(view_model):
    for kw, words in (({"mode": 0}, "mode must be in 1..8"), ({"mode": 9}, "mode must be in 1..8"),
                      ({"amplitude": -1}, "amplitude"), ({"impulse": 0.0}, "impulse")):
        with pytest.raises(InputError, match=words):
            ModeExplorer(view_model, **kw)


def test_a_still_picture_sends_no_frames_and_a_change_does(view_model):
    ex = _explorer(view_model, animate=False, amplitude=0.3)
    assert next(c for c in ex.viewer._controls if c["name"] == "amplitude")["max"] == 0.3  # --amplitude above 0.2
    ex.tick(1 / 60, 0.0)
    seq = ex.viewer._seq
    ex.tick(1 / 60, 0.1)
    assert ex.viewer._seq == seq  # same q: nothing published
    ex.select_mode(2)
    seq = ex.viewer._seq
    ex.tick(1 / 60, 0.2)
    assert ex.viewer._seq == seq + 1 and ex.viewer._frame()[1]["bodies"][0]["q"][2] != 0
