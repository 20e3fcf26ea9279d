"""``modalfem bench surface``: the scan-damage helpers and a smoke run of ``--quick`` (the closed bunny
through gmsh, fTetWild and auto, each in a fresh process). Speed is not asserted."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.bench import surface_bench as sb


def _edge_counts(f):
    e = np.sort(f[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)[1]


def test_subdivide_keeps_a_closed_surface_closed_and_its_volume():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    f = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    v2, f2 = sb.subdivide(v, f)
    assert len(f2) == 16 and len(v2) == 4 + 6
    assert np.all(_edge_counts(f2) == 2)

    def volume(v, f):
        p = v[f]
        return np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6

    assert volume(v2, f2) == pytest.approx(volume(v, f), rel=1e-14)


def test_scan_like_makes_holes_fins_and_flips():
    from modalfem.mesh.surface_read import edge_stats

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    f = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    for _ in range(3):
        v, f = sb.subdivide(v, f)
    sv, sf = sb.scan_like(v, f, holes=2, hole_radius=0.1, fins=3, flips=5, spike=False)
    boundary, nonmanifold, flipped, _ = edge_stats(sf)
    assert boundary > 0 and nonmanifold == 3 and flipped > 0
    assert np.array_equal(sb.scan_like(v, f)[1], sb.scan_like(v, f)[1])  # deterministic


@pytest.mark.slow
def test_quick_bench_writes_its_section(tmp_path):
    out = tmp_path / "B.md"
    out.write_text("# Benchmarks\n\n## Other\n\nkeep me\n")
    assert sb.command(["--quick", "--out", str(out)]) == 0
    text = out.read_text()
    assert "keep me" in text and text.count(sb.SECTION) == 1
    rows = [r for r in text[text.index(sb.SECTION):].splitlines() if r.startswith("| bunny")]
    assert [r.split("|")[4].strip() for r in rows] == ["gmsh", "repair+gmsh", "ftetwild", "auto (gmsh)"]
    for r in rows:
        cells = [c.strip() for c in r.strip("|").split("|")]
        assert float(cells[4]) > 0 and int(cells[6]) > 0  # seconds, tets
        assert float(cells[7].split("->")[1]) >= 0.1  # worst quality after optimisation
