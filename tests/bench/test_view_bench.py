"""``modalfem bench view``: the test surface, the table, and a quick run in headless Chromium."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

from modalfem.bench import view_bench as vb


@pytest.mark.parametrize("nv", [2000, 10_000])
def test_torus_is_a_closed_oriented_surface_of_about_nv_vertices(nv):
    X, T = vb._torus(nv)
    assert abs(len(X) - nv) <= 0.05 * nv and len(T) == 2 * len(X)
    edges = Counter(tuple(e) for t in T for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])))
    assert all(n == 1 and edges[(b, a)] == 1 for (a, b), n in edges.items())  # each edge once each way
    # outward: the signed volume is that of the torus, 2 pi^2 R r^2 (polyhedral, a little less)
    vol = np.einsum("ij,ij->i", X[T[:, 0]], np.cross(X[T[:, 1]], X[T[:, 2]])).sum() / 6
    assert 0.95 < vol / (2 * np.pi**2 * 0.1 * 0.04**2) <= 1.0


def test_render_reports_ratios_within_each_size():
    cases = [{"kind": "q", "nv": 100, "r": 20, "bytes": 175, "server_ms": 0.1, "received": 60.0, "applied": 60.0,
              "deform_ms": 0.5, "fps": 40.0},
             {"kind": "positions", "nv": 100, "r": 20, "bytes": 2000, "server_ms": 0.2, "received": 50.0,
              "applied": 50.0, "deform_ms": 0.2, "fps": 10.0},
             {"kind": "viser", "nv": 100, "r": 20, "bytes": 1200, "server_ms": 0.3, "received": None, "applied": None,
              "deform_ms": None, "fps": 30.0}]
    text = vb.render(cases, command="c", date="d", machine="m", load=(0.5, 0.7), versions={"chromium": "1"})
    assert text.startswith(vb.SECTION + "\n")
    assert "| 100 | positions | 2000 | 0.20 | 50.0 | 0.20 | 10.0 | 0.25x |" in text
    assert "| 100 | viser | 1200 | 0.30 | - | - | 30.0 | 0.75x |" in text
    assert "load average (1 min) 0.50 before, 0.70 after" in text


@pytest.mark.browser
def test_quick_run_writes_a_wellformed_section(tmp_path):
    if not os.path.exists(vb.CHROMIUM):
        pytest.skip(f"no Chromium at {vb.CHROMIUM} (Debian: apt-get install chromium, as scripts/setup.sh does)")
    pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkept\n")
    # own process: a Playwright sync session may already run in this one (the browser fixtures)
    run = subprocess.run([sys.executable, "-m", "modalfem", "bench", "view", "--quick", "--out", str(out)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    text = out.read_text()
    assert "## Other\n\nkept" in text and vb.SECTION in text
    rows = [line for line in text.splitlines() if line.startswith("| 19")]
    assert [r.split("|")[2].strip() for r in rows][:2] == ["q", "positions"]
    for r in rows:
        fps = float(r.split("|")[7])
        assert fps > 0
    q_bytes, pos_bytes = (int(r.split("|")[3]) for r in rows[:2])
    assert pos_bytes > 12 * 1900 * 4 / 3 > q_bytes  # base64 float32 positions vs 20 numbers
