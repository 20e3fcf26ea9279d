"""``modalfem bench record``: the section it writes, and a quick run."""

from __future__ import annotations

import pytest

from modalfem.bench import cli as bench_cli
from modalfem.bench import record_bench as rb


def test_render_states_each_writer_and_the_ratio_to_the_painter():
    result = {"cases": {"ParaView (.vtu per body + scene.pvd)": (2.0, 1.5, 30000),
                        "GIF preview 640 x 360": (5.0, 4.9, 4000)},
              "peer": 50.0, "frames": 10, "seconds": 0.3, "triangles": {"bar": 80}, "vertices": {"bar": 42}}
    text = rb.render(result, command="c", date="d", machine="m", load=(0.5, 0.7))
    assert text.startswith(rb.SECTION + "\n")
    assert "| ParaView (.vtu per body + scene.pvd) | 2.00 | 1.50 | 3,000 |" in text
    assert "| GIF preview 640 x 360 | 5.00 | 4.90 | 400 |" in text
    assert "0.10x the matplotlib painter's time per frame (10.0x faster)" in text
    assert "bar 42 vertices / 80 triangles" in text
    assert "MP4 not measured" in text  # no MP4 row: the section says why


@pytest.mark.slow
def test_quick_run_measures_every_writer_and_the_peer():
    assert "record" in bench_cli.available()
    r = rb.measure(quick=True, repeat=1)
    assert r["frames"] == 7 and r["peer"] > 0
    labels = list(r["cases"])
    assert labels[0].startswith("ParaView") and labels[1].startswith("GIF") and labels[-1].startswith("sound")
    for total, frames, size in r["cases"].values():
        assert total >= frames > 0 and size > 0
