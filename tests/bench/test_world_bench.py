"""``modalfem bench world``: the section it writes, and a quick run."""

from __future__ import annotations

import pytest

from modalfem.bench import world_bench as wb


def test_render_states_the_ratio_and_the_intersections():
    cases = [{"case": "free", "what": "1 modal bar", "solver": 20000.0, "world": 18000.0},
             {"case": "stack", "what": "3 bars", "rate": 50.0, "contacts": 200.0, "intersections": 0},
             {"case": "tets", "what": "cube on foam", "rate": 80.0, "tet_ms": 11.5, "contacts": 40.0,
              "intersections": 0},
             {"case": "mixed", "what": "bar, block, cloth", "rate": 40.0, "stages": {"tet step": 10.0, "sound": 0.1},
              "intersections": 2}]
    text = wb.render(cases, command="c", date="d", machine="m", load=(0.5, 0.7))
    assert text.startswith(wb.SECTION + "\n")
    assert "| 1 modal bar | 20,000 | 18,000 | 0.90x |" in text
    assert "- 3 bars: 50 steps/s, 200 contacts per step in the solid solve, 0 intersecting" in text
    assert ("- cube on foam: 80.0 steps/s, tet step (the joint step of the tet group) 11.50 ms per step, 40 tet "
            "contacts per step, 0 intersecting") in text
    assert "(tet step 10.00 ms, sound 0.10 ms per step), 2 intersecting" in text


@pytest.mark.slow
def test_quick_run_measures_every_case():
    cases = wb.measure(seconds=0.2, quick=True)
    assert [c["case"] for c in cases] == ["free", "stack", "tets", "mixed"]
    assert cases[0]["solver"] > 0 and cases[0]["world"] > 0
    assert cases[1]["contacts"] > 0 and cases[1]["intersections"] == 0
    assert cases[2]["tet_ms"] > 0 and cases[2]["contacts"] > 0 and cases[2]["intersections"] == 0
    assert {"tet step", "cloth step", "cloth collisions", "solid contacts", "modal step"} <= set(cases[3]["stages"])
