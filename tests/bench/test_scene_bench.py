"""``modalfem bench scene``: the ablation's arithmetic, its table, and a quick run on a tiny scene."""

from __future__ import annotations

import pytest

from modalfem.bench import scene_bench as sb

TINY = """schema = "modalfem.scene/1"

[time]
dt = 1e-3
duration = 0.05

[[bodies]]
kind = "tet"
name = "block"
mesh = { generator = "box", size = [0.1, 0.1, 0.1], cells = [1, 1, 1] }
material = { E = 1e5, nu = 0.3, rho = 100.0 }
position = [0.0, 0.0, 0.01]

[[bodies]]
kind = "cloth"
name = "sheet"
grid = { size = [0.2, 0.2], vertices = [3, 3], origin = [-0.05, -0.05, 0.3] }
material = { areal_density = 0.2, young = 1e5, thickness = 5e-4 }

[[obstacles]]
kind = "ground"

[[effects]]
kind = "gravity"

[[effects]]
kind = "contact"

[[effects]]
kind = "self-collision"

[[effects]]
kind = "damping"
alpha = 1.0
bodies = ["block"]

[[effects]]
kind = "wind"
velocity = [1.0, 0.0, 0.0]

[[events]]
kind = "gust"
start = 0.01
duration = 0.02
velocity = [2.0, 0.0, 0.0]
"""


def _case(drop, ms, stages, steps=100):
    return {"case": sb.ALL if drop is None else f"without {drop}", "drop": drop, "steps": steps,
            "wall": ms * steps / 1e3, "stages": {s: 1e-4 for s in stages}, "plan": list(stages),
            "stage_names": list(stages), "simulated": 0.1}


def test_cost_is_the_difference_to_the_mean_of_the_bracketing_full_runs():
    scene = {"scene": "s", "effects": ["gravity", "sound"], "cases": [
        _case(None, 2.0, ["modal step", "sound"]), _case("gravity", 1.5, ["modal step", "sound"]),
        _case("sound", 1.2, ["modal step"]), _case(None, 2.2, ["modal step", "sound"])]}
    s = sb.summarise(scene)
    assert s["base"] == pytest.approx(2.1) and s["noise"] == pytest.approx(0.2)
    rows = {r["effect"]: r for r in s["rows"]}
    assert rows["gravity"]["cost"] == pytest.approx(0.6) and rows["gravity"]["pct"] == pytest.approx(100 * 0.6 / 2.1)
    assert rows["sound"]["cost"] == pytest.approx(0.9) and rows["sound"]["gone"] == ["sound"]
    assert rows["gravity"]["gone"] == []
    text = sb.render([scene], command="c", date="d", machine="m", load=(0.5, 0.6), threads="t")
    assert text.startswith(sb.SECTION + "\n")
    assert rows["sound"]["own"] == pytest.approx(1e3 * 1e-4 / 100) and rows["gravity"]["own"] is None
    assert "| without sound | 833.3 | 1.200 | modal step | sound | 0.001 | +0.900 | +42.9 % |" in text
    assert "| without gravity | 666.7 | 1.500 | modal step; sound | none |  | +0.600 | +28.6 % |" in text
    assert "noise 0.200 ms/step (9.5 %)" in text and "different plans" not in text
    scene["cases"][-1]["plan"] = ["modal step"]  # the code changed between the bracketing runs
    assert "compiled different plans" in sb.render([scene], command="c", date="d", machine="m", load=(0, 0), threads="t")


def test_dropping_the_wind_drops_its_gusts(tmp_path):
    import warnings

    from modalfem.scene.load import scene_from_text

    scene = scene_from_text(TINY)
    with warnings.catch_warnings():  # the dict round trip of a scene is exact and silent (mesh unions included)
        warnings.simplefilter("error")
        assert sb._ablated(scene, "no-such-effect") == scene
    assert [e.kind for e in sb._ablated(scene, "contact").effects] == ["gravity", "self-collision", "damping", "wind"]
    assert len(sb._ablated(scene, "contact").events) == 1
    no_wind = sb._ablated(scene, "wind")
    assert "wind" not in [e.kind for e in no_wind.effects] and no_wind.events == []
    assert sb._ablated(scene, None) is scene


@pytest.mark.slow
def test_quick_run_has_a_row_per_effect_and_the_stages_each_effect_alone_needs(tmp_path):
    scene = tmp_path / "tiny.toml"
    scene.write_text(TINY)
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    assert sb.command([str(scene), "--quick", "--out", str(out)]) == 0
    text = out.read_text()
    assert "## Other\n\nkept" in text and sb.SECTION in text
    rows = [ln for ln in text.splitlines() if ln.startswith("| ") and not ln.startswith("| case")]
    names = [r.split("|")[1].strip() for r in rows]
    assert names == [sb.ALL, "without gravity", "without contact", "without self-collision", "without damping",
                     "without wind", sb.ALL]
    cells = {r.split("|")[1].strip(): [c.strip() for c in r.split("|")[2:-1]] for r in rows[1:-1]}
    for name, (rate, ms, plan, gone, own, cost, pct) in cells.items():
        assert float(rate.replace(",", "")) > 0 and float(ms) > 0, name
        assert cost and pct.endswith("%"), name
    # the world's plan: a tet body's self-collision stage exists only for self-collision; the deformable
    # collision stage serves contact and self-collision, so it stays when either one is left
    assert cells["without self-collision"][3] == "tet self-collision"
    assert "self-collision" not in cells["without self-collision"][2]
    assert cells["without contact"][3] == "none" and "cloth collisions [self-collision]" in cells["without contact"][2]
    assert cells["without gravity"][3] == "none" and "gravity" not in cells["without gravity"][2]
    assert cells["without damping"][3] == "none"
    assert "damping" not in cells["without damping"][2] and "damping" in rows[0]


def test_registered_and_a_bad_scene_is_one_line(tmp_path, capsys):
    from modalfem.bench import cli as bench_cli

    assert "scene" in bench_cli.available()
    out = tmp_path / "B.md"
    assert bench_cli.main(["scene", "bell-dorp", "--quick", "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("modalfem: error: ") and "did you mean 'bell-drop'" in err[0]
    assert not out.exists()
