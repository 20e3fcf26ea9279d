"""Scene files end to end: load -> build -> run -> summary, plans and stage calls, events, Ctrl-C, caching."""

import json
import math

import numpy as np
import pytest

from modalfem.cli import main
from modalfem.errors import SceneError
from modalfem.scene import (
    build_scene,
    find_scene,
    load_scene,
    run_scene,
    scene_from_text,
)
from modalfem.scene.build import _gusty
from modalfem.world.world import World

HEAD = 'schema = "modalfem.scene/1"\n'
OFF = '[outputs]\nparaview = false\nvideo = "none"\ngltf = false\nsound = false\n'

BLOCK = """
[[bodies]]
kind = "tet"
name = "block"
mesh = {{ generator = "box", size = [0.1, 0.1, 0.05], cells = [1, 1, 1] }}
material = {{ E = 1e5, nu = 0.3, rho = 100.0 }}
position = [0.0, 0.0, {z}]
"""
CLOTH = """
[[bodies]]
kind = "cloth"
name = "sheet"
grid = { size = [0.2, 0.2], vertices = [4, 4], origin = [-0.05, -0.05, 0.3] }
material = { areal_density = 0.2, young = 2e5, thickness = 5e-4 }
"""
BAR = """
[[bodies]]
kind = "modal"
name = "bar"
mesh = {{ generator = "box", size = [0.2, 0.02, 0.02], cells = [6, 1, 1] }}
material = "steel"
modes = 3
degree = 1
position = [0.0, 0.0, {z}]
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def time_block(dt=1e-3, duration=0.02, frame_rate=500.0):
    return f"[time]\ndt = {dt}\nduration = {duration}\nframe_rate = {frame_rate}\n"


def test_free_fall_momentum_frames_and_files(tmp_path):
    """A tet block falling freely: its momentum after T is m g T (implicit Euler is exact for a uniform
    acceleration of an unstrained body, up to the Newton tolerance: a last update below tol * size [m] leaves
    the velocity within tol * size / dt), one frame per 1/frame_rate plus t = 0, every file written."""
    p = write(tmp_path, HEAD + time_block() + BLOCK.format(z=1.0) + '[[effects]]\nkind = "gravity"\n' + OFF)
    res = run_scene(p, tmp_path / "out", quiet=True)
    s = res.summary
    assert not res.interrupted and s["time"]["steps_run"] == 20
    assert s["frames"] == 20 // 2 + 1 and np.allclose(np.diff(s["frame_times"]), 2e-3)
    m = 100.0 * 0.1 * 0.1 * 0.05
    pz = s["bodies"]["block"]["momentum_end"][2]
    from modalfem.tet import TetSolver

    sc, base = load_scene(p)
    model = build_scene(sc, base).world.by_name["block"].model
    tol = TetSolver(model).tol
    assert abs(pz - (-m * 9.81 * 0.02)) <= m * tol * model.size / 1e-3
    assert s["plan"] == ["tet step: block [gravity]"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["plan.txt", "scene.toml", "summary.json"]
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["format"] == "modalfem.run/1"
    assert (tmp_path / "out" / "scene.toml").read_text() == p.read_text()


@pytest.fixture
def stage_calls(monkeypatch):
    """Count the calls of every World stage method (wrapped on the class before the world is built)."""
    calls = {}
    for name in [n for n in dir(World) if n.startswith("_stage_")]:
        orig = getattr(World, name)

        def spy(self, ctx, _orig=orig, _name=name):
            calls[_name] = calls.get(_name, 0) + 1
            return _orig(self, ctx)

        monkeypatch.setattr(World, name, spy)
    return calls


def test_run_calls_exactly_the_planned_stages(tmp_path, stage_calls):
    text = (HEAD + time_block(duration=0.005) + BLOCK.format(z=0.0) + CLOTH
            + '[[obstacles]]\nkind = "ground"\n[[effects]]\nkind = "gravity"\n[[effects]]\nkind = "contact"\n'
            + '[[effects]]\nkind = "self-collision"\nbodies = ["sheet"]\n' + OFF)
    res = run_scene(write(tmp_path, text), tmp_path / "out", quiet=True)
    plan = [line.split(":")[0] for line in res.summary["plan"]]
    assert plan == ["tet step", "cloth step", "cloth collisions"]
    assert stage_calls == {"_stage_tet_step": 5, "_stage_cloth_step": 5, "_stage_deformable": 5}
    assert res.summary["intersections"]["total"] == 0


def test_plan_command_prints_the_plan_and_nothing_else(tmp_path, capsys):
    text = HEAD + time_block() + BLOCK.format(z=0.2) + '[[effects]]\nkind = "gravity"\n[[effects]]\nkind = "wind"\n' \
        'velocity = [3.0, 0.0, 0.0]\n' + OFF
    assert main(["plan", str(write(tmp_path, text))]) == 0
    out = capsys.readouterr().out
    assert out == "1. tet step: block [gravity, wind]\n"
    assert not (tmp_path / "out").exists()


def test_strike_event_gives_its_impulse_at_its_time(tmp_path):
    """A free modal bar (no gravity) struck at t = 10 ms: its momentum is 0 before and exactly J after.

    The strike at the edge vertex (0.1, 0, 0.02) points at the centre of mass (0.1, 0.01, 0.01), so the bar
    does not spin: a spinning body's sound is modulated by its rotation (sidebands at the spin rate), which
    would move the peaks off the modes by more than the 2 bins checked here."""
    text = (HEAD + time_block(duration=0.02) + BAR.format(z=0.5) + '[[effects]]\nkind = "sound"\n'
            '[[events]]\nkind = "strike"\nbody = "bar"\ntime = 0.01\npoint = [0.1, 0.0, 0.02]\n'
            'impulse = [0.0, 0.001, -0.001]\n' + OFF)
    res = run_scene(write(tmp_path, text), tmp_path / "out", quiet=True)
    s = res.summary
    p = np.array(s["bodies"]["bar"]["momentum_end"])
    assert np.allclose(p, [0.0, 0.001, -0.001], rtol=0, atol=1e-15)
    t = np.array(s["frame_times"])
    mom = s["energy"]["total_J"]["bar"]
    assert all(e == mom[0] for e, tt in zip(mom, t) if tt < 0.01 - 1e-12)  # nothing moves before the strike
    assert max(mom) > mom[0]
    snd = s["sound"]["bar"]
    assert snd["peaks_hz"], "the strike must be heard"
    for f, near in zip(snd["peaks_hz"], snd["nearest_mode_hz"]):
        assert abs(f - near) <= 2 * snd["bin_hz"]


def test_modal_modes_are_cached_by_content(tmp_path):
    text = HEAD + time_block(duration=0.002) + BAR.format(z=0.5) + OFF
    p = write(tmp_path, text)
    s1, base = load_scene(p)
    first = build_scene(s1, base).cached["bar"]
    again = build_scene(s1, base).cached["bar"]
    assert (first, again) in {("computed", "cache"), ("cache", "cache")}
    other = build_scene(load_scene(write(tmp_path, text.replace("modes = 3", "modes = 4"), "t.toml"))[0], base)
    assert other.cached["bar"] == "computed" or first == "cache"
    assert len(other.world.by_name["bar"].model.omega) == 4


def test_modal_position_is_a_translation_of_the_mesh(tmp_path):
    s, base = load_scene(write(tmp_path, HEAD + time_block() + BAR.format(z=0.5) + OFF))
    built = build_scene(s, base)
    x, _ = built.world.surface(built.state, "bar")
    rest = built.world.by_name["bar"].model.vertices
    assert np.allclose(x, rest + [0.0, 0.0, 0.5], atol=1e-12)
    assert x[:, 0].min() == pytest.approx(0.0, abs=1e-12)  # the box generator's corner stays at x = 0


def test_interrupt_keeps_the_frames_so_far(tmp_path):
    p = write(tmp_path, HEAD + time_block() + BLOCK.format(z=1.0) + '[[effects]]\nkind = "gravity"\n' + OFF)
    res = run_scene(p, tmp_path / "out", quiet=True, interrupt_after=7)
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert res.interrupted and s["interrupted"] is True
    assert s["time"]["steps_run"] == 7 and s["frames"] == 1 + 7 // 2
    assert s["time"]["simulated"] == pytest.approx(7e-3)


def test_bad_scene_leaves_no_output_folder(tmp_path, capsys):
    text = HEAD + time_block() + BLOCK.format(z=1.0).replace("nu = 0.3", "nu = 0.7") + OFF
    code = main(["run", str(write(tmp_path, text)), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("modalfem: error: s.toml: bodies[0].material.nu: must be less than 0.5")
    assert not (tmp_path / "out").exists()
    assert [q.name for q in tmp_path.iterdir()] == ["s.toml"]


def test_overlapping_bodies_at_start_are_refused(tmp_path):
    text = HEAD + time_block() + BLOCK.format(z=0.0) + BLOCK.format(z=0.02).replace('"block"', '"block2"') + OFF
    s, base = load_scene(write(tmp_path, text))
    with pytest.raises(SceneError, match=r"bodies\[1\]: 'block2' overlaps 'block' at t = 0"):
        build_scene(s, base, label="s.toml")


def test_body_inside_an_obstacle_is_refused(tmp_path):
    text = HEAD + time_block() + BLOCK.format(z=-0.01) + '[[obstacles]]\nkind = "ground"\n' + OFF
    s, base = load_scene(write(tmp_path, text))
    with pytest.raises(SceneError, match=r"bodies\[0\]: 'block' starts 10 mm inside obstacles\[0\] \(ground\)"):
        build_scene(s, base, label="s.toml")


def test_examples_by_name_and_did_you_mean():
    assert find_scene("bell-drop").name == "bell-drop.toml"
    with pytest.raises(SceneError, match=r"did you mean 'bell-drop'\?"):
        find_scene("bell-dorp")


def test_run_list_prints_one_example_per_line_name_first(capsys):
    assert main(["run", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert any(line.startswith("bell-drop  ") for line in lines)
    from modalfem.scene import examples

    assert [line.split()[0] for line in lines] == list(examples())


def test_gust_is_a_smooth_pulse_on_the_steady_wind():
    class G:
        start, duration, velocity = 1.0, 0.5, (0.0, 4.0, 0.0)

    w = _gusty(np.array([2.0, 0.0, 0.0]), [G()])
    x = np.zeros((5, 3))
    assert np.allclose(w(x, 0.5), [2.0, 0.0, 0.0])           # before
    assert np.allclose(w(x, 1.25), [2.0, 4.0, 0.0])          # the peak, half way
    assert np.allclose(w(x, 1.125), [2.0, 2.0, 0.0])         # 1 - cos(pi/2) = 1 -> half the peak
    assert np.allclose(w(x, 1.6), [2.0, 0.0, 0.0])           # after
    assert w(x, 1.25).shape == (5, 3)


@pytest.mark.parametrize("snippet, message", [
    ('schema = "modalfem.scene/2"\n', "schema: modalfem.scene/2 is newer than this modalfem reads"),
    ("", "missing key 'schema'"),
])
def test_schema_version(snippet, message):
    with pytest.raises(SceneError, match=message):
        scene_from_text(snippet + time_block() + BLOCK.format(z=0.0), label="s.toml")


def test_frame_rate_is_derived_into_steps_per_frame(tmp_path):
    s, base = load_scene(write(tmp_path, HEAD + time_block(dt=1e-3, duration=0.1, frame_rate=30.0)
                               + BLOCK.format(z=0.0) + OFF))
    built = build_scene(s, base)
    assert built.steps == 100 and built.frame_every == round(1 / (30 * 1e-3)) == 33
    assert math.isclose(built.dt, 1e-3)


def test_the_readme_scene_is_valid():
    """The scene file shown in the README validates (so the example users copy works)."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    s = scene_from_text(block, label="README.md")
    assert [b.kind for b in s.bodies] == ["modal"] and [e.kind for e in s.events] == ["strike"]


def test_ctrl_c_keeps_complete_frames_and_says_so(tmp_path):
    """A real SIGINT to `modalfem run` during the steps: exit 130, one line saying the frames so far are valid,
    the folder in place with a ParaView series and a GIF of exactly the frames the summary counts."""
    import os
    import signal
    import subprocess
    import sys
    import time
    import xml.etree.ElementTree as ET

    from PIL import Image

    text = (HEAD + time_block(duration=2.0, frame_rate=100.0) + BLOCK.format(z=3.0)
            + '[[effects]]\nkind = "gravity"\n[outputs]\nvideo = "gif"\ngltf = false\nsound = false\n'
            + "video_size = [160, 90]\n")
    p = write(tmp_path, text)
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "modalfem", "run", str(p), "--out", str(out)],
                            stderr=subprocess.PIPE, text=True, env=env)
    lines = []
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line)
        if "steps/s" in line:
            proc.send_signal(signal.SIGINT)
            break
    rest = proc.communicate(timeout=240)[1]
    err = (rest or "").strip().splitlines()
    assert proc.returncode == 130, lines + err
    assert len([e for e in err if "interrupted" in e]) == 1 and "valid" in err[-1], err
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] and 0 < s["time"]["steps_run"] < 2000
    assert s["frames"] >= 1 + 200 // 10
    refs = [d.get("file") for d in ET.parse(out / "scene.pvd").getroot().iter("DataSet")]
    times = sorted({float(d.get("timestep")) for d in ET.parse(out / "scene.pvd").getroot().iter("DataSet")})
    assert len(times) == s["frames"] and all((out / f).is_file() for f in refs)
    assert Image.open(out / "preview.gif").n_frames == s["frames"]
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]  # no temporaries left


def test_orientations_rotate_rest_shapes_about_their_centre(tmp_path):
    c, sn = math.cos(math.pi / 4), math.sin(math.pi / 4)
    text = (HEAD + time_block() + BLOCK.format(z=0.5).replace("position", f"orientation = [{c}, {sn}, 0.0, 0.0]\n"
                                                               "position")
            + CLOTH.replace("origin = [-0.05, -0.05, 0.3] }", "origin = [0.3, 0.0, 0.3] }")
            + f"orientation = [{c}, {sn}, 0.0, 0.0]\n"
            + '[[obstacles]]\nkind = "box"\ncenter = [2.0, 0.0, 0.5]\nhalf_extents = [0.3, 0.1, 0.1]\n'
            + f"rotation = [{c}, 0.0, 0.0, {sn}]\n" + OFF)
    s, base = load_scene(write(tmp_path, text))
    built = build_scene(s, base)
    block = built.state["block"].x
    assert np.allclose(np.ptp(block, axis=0), [0.1, 0.05, 0.1])            # 90 deg about x: on its side
    assert np.allclose(block.mean(0), [0.05, 0.05, 0.525])                  # about its centre, then moved
    sheet = built.state["sheet"].x
    assert np.allclose(np.ptp(sheet, axis=0), [0.2, 0.0, 0.2], atol=1e-12)  # 90 deg about x: upright
    assert np.allclose(sheet.mean(0), [0.4, 0.1, 0.3])
    R = built.world.obstacles[0].rotation
    assert np.allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    with pytest.raises(SceneError, match=r"bodies\[0\].orientation: a quaternion must not be zero"):
        scene_from_text(text.replace(f"orientation = [{c}, {sn}, 0.0, 0.0]", "orientation = [0, 0, 0, 0]", 1), label="s")


@pytest.mark.slow
def test_modal_pile_at_2ms_only_loses_energy_and_never_crosses(tmp_path):
    """Four modal bodies dropped into a box at dt = 2 ms: a body pressed between another and the ground meets both
    in one solve. (With the ground solved after the bodies, the fork wedged between the bars pumped the scene
    from 0.38 J to 1.04 J within 0.1 s and 636 triangle pairs crossed.)"""
    from modalfem.scene import examples

    text = examples()["modal-pile"][0].read_text().split("[outputs]")[0]
    text = text.replace("dt = 1e-3", "dt = 2e-3").replace("frame_rate = 30", "frame_rate = 50")
    assert "dt = 2e-3" in text and "frame_rate = 50" in text
    res = run_scene(write(tmp_path, text + OFF), tmp_path / "out", quiet=True, max_steps=200)
    s = res.summary
    total = np.sum([s["energy"]["total_J"][n] for n in s["bodies"]], axis=0)
    scale = total[0]
    assert np.all(np.diff(total) <= 1e-9 * scale), np.diff(total).max()
    assert s["intersections"]["total"] == 0 and s["intersections"]["checked_frames"] == s["frames"]
