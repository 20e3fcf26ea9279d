"""The example scenes shipped with modalfem: each runs (short) and its summary tells physical facts.

Every example of ``modalfem.scene.run.examples()`` is run from a copy whose outputs are all off (this tests
the physics; the writers have their own tests), for a number of steps that keeps each test to a few seconds
(``_STEPS``; an example missing there runs its full length), and its summary is checked:

- the exact triangle-triangle check ran on every frame and found no crossing pair;
- the plan holds exactly the stages the scene's bodies and effects need;
- energy: without external work (no strikes, no wind) the total never exceeds the start beyond rounding;
  a strike adds at most ``0.5 |J|^2 w_max`` with ``w_max`` a bound of the struck body's point mobility from
  its model (``1/m + max |r|^2 / lambda_min(I) + max_v sum_i |phi_i(v)|^2``, valid for a body at rest);
- momentum: a short run inside the free-flight phase ends with ``p = m g t`` exactly;
- sound: every spectral peak lies within a few FFT bins of one of the body's mode frequencies.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

from modalfem.scene.run import examples, run_scene

G = 9.81

#: steps run per example in the tests (None: the full duration). Each is past the first impacts and strikes.
_STEPS = {
    "bell-drop": None,        # 1000 steps, 1 ms: lands at 0.09 s, struck at 0.5 s, rests
    "block-on-bell": 450,     # block lands at ~0.11 s, bell struck at 0.4 s
    "cloth-on-plate": 160,    # cloth lands on the plate at ~0.1 s, first strike at 0.3 s
    "cloth-pile": None,       # 120 steps: both sheets fall, fold and settle
    "flag": None,             # 300 steps, both gusts
    "modal-pile": 250,        # every body has landed by 0.25 s
}
_SLOW = {"cloth-on-plate", "block-on-bell", "modal-pile"}

_OFF = '\n[outputs]\nvideo = "none"\nparaview = false\ngltf = false\nsound = false\n'


def _quiet_copy(name: str, folder) -> tuple:
    """A copy of example ``name`` with every output off, and the parsed scene."""
    import tomllib

    path, _ = examples()[name]
    text = path.read_text()
    head = re.split(r"^\[outputs\]", text, flags=re.M)[0]
    copy = folder / f"{name}.toml"
    copy.write_text(head + _OFF)
    d = tomllib.loads(text)
    quiet = tomllib.loads(copy.read_text())
    assert {k: v for k, v in quiet.items() if k != "outputs"} == {k: v for k, v in d.items() if k != "outputs"}
    return copy, d


def _models(copy):
    """name -> ModalModel of the modal bodies (from the session's model cache)."""
    from modalfem.scene.build import build_scene
    from modalfem.scene.load import load_scene

    scene, base = load_scene(copy)
    built = build_scene(scene, base, check_start=False)
    return {b.name: built.world.by_name[b.name].model for b in scene.bodies if b.kind == "modal"}


def _mobility_bound(model) -> float:
    """An upper bound [1/kg] of ``n^T W n`` over surface points and unit directions n of a modal body at rest
    (W the point mobility: translation, rotation about the centre of mass and every mode)."""
    r = model.vertices - np.asarray(model.center_of_mass)
    rot = float(np.max(np.sum(r * r, axis=1))) / float(np.min(np.linalg.eigvalsh(model.inertia)))
    phi = np.asarray(model.shapes).reshape(len(model.vertices), 3, -1)
    modal = float(np.max(np.sum(phi * phi, axis=(1, 2))))
    return 1.0 / model.mass + rot + modal


def _expected_stages(d: dict) -> set:
    kinds = {b["kind"] for b in d["bodies"]}
    effects = {e["kind"] for e in d.get("effects", [])}
    solids = sum(b["kind"] in ("modal", "tet") for b in d["bodies"])
    out = set()
    if "modal" in kinds:
        out.add("modal step")
    if "tet" in kinds:
        out.add("tet step")
    if "cloth" in kinds:
        out.add("cloth step")
        if effects & {"contact", "self-collision"}:
            out.add("cloth collisions")
    if "contact" in effects and solids >= 2:
        out.add("solid contacts")
    if "sound" in effects:
        out.add("sound")
    return out


#: the World method that runs each stage of a plan
_STAGE_METHODS = {"tet step": "_stage_tet_step", "solid contacts": "_stage_contacts", "modal step": "_stage_modal_step",
                  "tet self-collision": "_stage_tet_self", "cloth step": "_stage_cloth_step",
                  "cloth collisions": "_stage_deformable", "sound": "_stage_sound"}


def test_examples_are_the_six():
    assert set(examples()) == set(_STEPS), "a new example needs its step count in _STEPS"


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in _SLOW else n for n in _STEPS])
def test_example_runs_and_its_summary_holds(name, tmp_path, monkeypatch):
    from modalfem.world.world import World

    calls = {}
    for method in set(_STAGE_METHODS.values()) | {"_step_solo"}:
        orig = getattr(World, method)

        def spy(self, *args, _orig=orig, _m=method):
            calls[_m] = calls.get(_m, 0) + 1
            return _orig(self, *args)

        monkeypatch.setattr(World, method, spy)
    copy, d = _quiet_copy(name, tmp_path)
    steps = _STEPS[name]
    res = run_scene(copy, tmp_path / "out", quiet=True, max_steps=steps)
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert s == json.loads(json.dumps(res.summary))
    assert not res.interrupted
    full = round(d["time"]["duration"] / d["time"]["dt"])
    assert s["time"]["steps_run"] == (full if steps is None else steps)

    # no surface crosses another, itself or an obstacle, in any frame
    assert s["intersections"]["checked_frames"] == s["frames"] >= 2
    assert s["intersections"]["total"] == 0, s["intersections"]["found"][:3]

    # exactly the stages the scene needs, and the run called exactly those, once per step
    assert {p.split(":")[0] for p in s["plan"]} == _expected_stages(d)
    ran = s["time"]["steps_run"]
    assert calls == {_STAGE_METHODS[p.split(":")[0]]: ran for p in s["plan"]}, calls

    # energy: only strikes and wind put energy in
    names = list(s["bodies"])
    total = np.sum([s["energy"]["total_J"][n] for n in names], axis=0)
    e0 = float(total[0])
    t_end = s["time"]["simulated"]
    strikes = [e for e in d.get("events", []) if e["kind"] == "strike" and e["time"] < t_end]
    wind = any(e["kind"] == "wind" for e in d.get("effects", []))
    models = _models(copy) if any(b["kind"] == "modal" for b in d["bodies"]) else {}
    rounding = 1e-9 * sum(float(np.max(np.abs(s["energy"]["total_J"][n]))) for n in names)
    if wind:
        # a stability bound only: air at most |w_max| cannot give the flag more kinetic energy than
        # 0.5 m (2 |w_max|)^2 (the sheet moving at twice the air speed, whipping) nor lift it above its pole
        m = sum(b["material"]["areal_density"] * b["grid"]["size"][0] * b["grid"]["size"][1]
                for b in d["bodies"] if b["kind"] == "cloth")
        w = np.linalg.norm([e["velocity"] for e in d["effects"] if e["kind"] == "wind"][0])
        w_max = w + sum(np.linalg.norm(e["velocity"]) for e in d["events"] if e["kind"] == "gust")
        lift = max(max(b["grid"]["size"]) for b in d["bodies"] if b["kind"] == "cloth")
        assert total.max() <= e0 + 0.5 * m * (2 * w_max) ** 2 + m * G * lift
    else:
        budget = 0.0
        for e in strikes:
            budget += 0.5 * float(np.dot(e["impulse"], e["impulse"])) * _mobility_bound(models[e["body"]])
        # cloth too: its implicit step only removes energy (backward Euler; contact constraints on the ground,
        # spheres and boxes; Coulomb friction as damping inside the solve: the friction pass after the solve
        # put cloth-pile's frames up to 0.4 % above the start, one 10 ms step +5 %). Not yet within a step: the
        # collision pipeline's impulses on single vertices, smoothed over each sheet, still store some shear
        # where one sheet lands on another (cloth-pile's second landing: +0.014 J in one step, by then well
        # below the start; frames are 40 ms apart)
        assert total.max() <= e0 + budget + rounding, (total.max() - e0, budget)

    # momentum: a body resting on the ground at the end has lost its momentum
    if name in ("bell-drop", "cloth-pile"):
        for n in names:
            m = models[n].mass if n in models else next(
                b["material"]["areal_density"] * b["grid"]["size"][0] * b["grid"]["size"][1]
                for b in d["bodies"] if b["name"] == n)
            assert np.linalg.norm(s["bodies"][n]["momentum_end"]) <= 1e-2 * m * G * t_end, n

    # sound: each peak within a few bins of one of the body's modes
    sounding = [n for n in names if n in s["sound"]]
    assert bool(sounding) == any(e["kind"] == "sound" for e in d.get("effects", []))
    for n in sounding:
        snd = s["sound"][n]
        f = np.asarray(s["bodies"][n]["frequencies_hz"])
        assert snd["peaks_hz"], n
        bin_hz = snd["bin_hz"]
        # the loudest line sits on a mode; the others may be broadened: a body resting on others has its rings
        # choked by the contact impulses, and a ring cut after a time T is a line about 1 / T wide with ripples
        # (sidelobes) across it; rings last at least 10 ms here (one step is 1 ms), so 100 Hz
        assert np.min(np.abs(f - snd["peaks_hz"][0])) <= 3 * bin_hz, (n, snd["peaks_hz"][0])
        for p in snd["peaks_hz"]:
            assert np.min(np.abs(f - p)) <= 3 * bin_hz + 1.0 / 0.01, (n, p)


@pytest.mark.parametrize("name", ["bell-drop", "modal-pile"])
def test_free_flight_momentum_is_m_g_t(name, tmp_path):
    """Before anything lands, every body's momentum is m g t (exact rigid motion under gravity)."""
    copy, d = _quiet_copy(name, tmp_path)
    dt = d["time"]["dt"]
    models = _models(copy)
    # the first landing: the lowest body falls its gap to the ground
    from modalfem.scene.build import build_scene
    from modalfem.scene.load import load_scene

    scene, base = load_scene(copy)
    built = build_scene(scene, base)
    gap = min(float(built.world.surface(built.state, n)[0][:, 2].min()) for n in models)
    t_land = math.sqrt(2 * gap / G)
    steps = int(0.8 * t_land / dt)
    assert steps >= 5
    res = run_scene(copy, tmp_path / "out", quiet=True, max_steps=steps)
    t = res.summary["time"]["simulated"]  # momentum_end is the last step's
    assert t > 0
    for n, model in models.items():
        p = np.asarray(res.summary["bodies"][n]["momentum_end"])
        expected = np.array([0.0, 0.0, -model.mass * G * t])
        assert np.allclose(p, expected, rtol=0, atol=1e-9 * model.mass * G * t), (n, p, expected)


def test_run_list_prints_one_line_per_example_name_first():
    out = subprocess.run([sys.executable, "-m", "modalfem", "run", "--list"], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    lines = out.splitlines()
    ex = examples()
    assert len(lines) == len(ex)
    for line, (name, (_, desc)) in zip(lines, ex.items()):
        assert line.split()[0] == name
        assert desc and line.endswith(desc)
