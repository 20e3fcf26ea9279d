"""The page's JavaScript modal runtime (modalfem/web/modal.js) against the Python runtime, run in node."""

from __future__ import annotations

import json
import shutil
import subprocess
from importlib import resources

import numpy as np
import pytest

from modalfem.runtime.integrator import transition

NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="node is not installed (it runs modalfem/web/modal.js here)")


def _run_js(body: str, data) -> object:
    """Run ``body`` in node with ``R`` = modal.js's exports and ``data`` parsed from JSON; it prints JSON."""
    path = resources.files("modalfem.web").joinpath("modal.js")
    script = f"const R = require({json.dumps(str(path))}); const data = JSON.parse(process.argv[1]);\n{body}"
    out = subprocess.run([NODE, "-e", script, json.dumps(data)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def _regimes():
    """(lam [rad^2/s^2], mu [1/s], h [s]) across every branch of the transition."""
    cases = []
    for omega in (0.0, 1e-3, 2.0, 6283.0, 1.2e5):
        lam = omega * omega
        for mu in (0.0, 1e-6, 0.5 * omega, 2.0 * omega * (1 - 1e-9), 2.0 * omega, 2.0 * omega * (1 + 1e-9),
                   2.0 * omega + 3.0, 1e4):
            for h in (1e-6, 1 / 44100, 1 / 60, 0.7, 50.0):
                cases.append((lam, mu, h))
    return cases


def test_transition_matches_the_python_integrator_in_every_regime():
    cases = _regimes()
    got = np.array(_run_js("console.log(JSON.stringify(data.map(c => R.transition1(c[0], c[1], c[2]))));", cases))
    want = np.array([np.concatenate(transition(lam, mu, h)[:4]) for lam, mu, h in cases])
    # a12 = S and a21 = -lam S are products (no cancellation): relative agreement. a11 = C + a S and
    # a22 = C - a S are sums of terms of size <= 1 that cancel where damping is heavy (both codes
    # alike): absolute agreement to a few rounding units of those terms.
    for col in (1, 2):
        np.testing.assert_allclose(got[:, col], want[:, col], rtol=1e-12, atol=0)
    for col in (0, 3):
        np.testing.assert_allclose(got[:, col], want[:, col], rtol=0, atol=1e-14)


def test_state_steps_keep_the_exact_solution_and_impulses_project_on_the_targets():
    omega, mu, masses = [300.0, 2000.0, 9000.0], [0.5, 4.0, 30.0], [0.2, 1.5, 3.0]
    body = """
    const s = new R.ModalState(data.omega, data.mu, data.masses);
    const targets = data.targets.map(t => Float32Array.from(t));
    const dv = R.impulseRates(targets, s.masses, [0, 1, 2], [0.2, 0.3, 0.5], [0.1, -0.2, 0.3]);
    s.kick(dv);
    const e0 = s.energy();
    for (let n = 0; n < 1000; n++) s.step(1e-3 / 7);
    const w1 = Array.from(s.w), v1 = Array.from(s.v);
    const t = s.copy(); t.reset();
    console.log(JSON.stringify({dv: Array.from(dv), w1, v1, e0, rest: Array.from(t.w).concat(Array.from(t.v))}));
    """
    rng = np.random.default_rng(3)
    targets = rng.normal(size=(3, 9))  # 3 modes x 3 vertices x 3 components
    out = _run_js(body, {"omega": omega, "mu": mu, "masses": masses, "targets": targets.tolist()})
    t32 = targets.astype(np.float32).astype(np.float64).reshape(3, 3, 3)
    point = np.einsum("k,ikc->ic", [0.2, 0.3, 0.5], t32)
    dv = point @ np.array([0.1, -0.2, 0.3]) / np.array(masses)
    np.testing.assert_allclose(out["dv"], dv, rtol=1e-14)
    # 1000 steps of 1/7 ms against the closed form of a free damped oscillator from (0, dv) at t = 1/7 s
    t = 1e-3 / 7 * 1000
    om, m = np.array(omega), np.array(mu)
    wd = np.sqrt(om**2 - m**2 / 4)
    w = dv / wd * np.exp(-m * t / 2) * np.sin(wd * t)
    v = dv * np.exp(-m * t / 2) * (np.cos(wd * t) - m / (2 * wd) * np.sin(wd * t))
    np.testing.assert_allclose(out["w1"], w, rtol=1e-9, atol=1e-12 * np.abs(dv / wd).max())
    np.testing.assert_allclose(out["v1"], v, rtol=1e-9, atol=1e-12 * np.abs(dv).max())
    assert out["e0"] == pytest.approx(0.5 * np.sum(np.array(masses) * dv**2), rel=1e-14)
    assert out["rest"] == [0.0] * 6
