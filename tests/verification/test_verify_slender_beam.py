"""Slender steel beam 1 m x 20 mm x 20 mm against Euler-Bernoulli, rod and St-Venant torsion theory.

Modes are matched by LABEL (read from the shapes by ``modalfem.eigen.labels``), never by index, so a
mis-ordered or mislabelled spectrum fails. P2 tetrahedra throughout; each solve takes ~1-4 s.
"""

from __future__ import annotations

import pytest
from _verify import BACKENDS, by_label, rel, solve_box

from modalfem import STEEL, theory

L, A = 1.0, 0.02
SECTION = theory.rectangle_section(A, A)
TOL = 0.005  # 0.5 %


@pytest.mark.parametrize("backend", BACKENDS)
def test_cantilever_first_three_bending_pairs(backend, capsys):
    res = solve_box((L, A, A), (40, 2, 2), backend=backend, k=6, fixed="x0")
    got = by_label(res)
    assert sorted(got) == sorted(f"bending-{d} {n}" for d in "yz" for n in (1, 2, 3)), res.labels
    for d in "yz":
        eb = theory.euler_bernoulli_omegas(STEEL, L, SECTION, direction=d, count=3) / (2 * 3.141592653589793)
        for n in (1, 2, 3):
            e = rel(got[f"bending-{d} {n}"], eb[n - 1])
            with capsys.disabled():
                print(f"\n[{backend}] cantilever bending-{d} {n}: {got[f'bending-{d} {n}']:.3f} Hz, EB {eb[n - 1]:.3f} Hz, "
                      f"error {100 * e:+.3f} %")
            assert abs(e) < TOL


@pytest.mark.parametrize("backend", BACKENDS)
def test_free_free_first_two_bending_pairs(backend, capsys):
    res = solve_box((L, A, A), (40, 2, 2), backend=backend, k=4)
    assert res.rigid_mode_count == 6
    got = by_label(res)
    assert sorted(got) == sorted(f"bending-{d} {n}" for d in "yz" for n in (1, 2)), res.labels
    for d in "yz":
        eb = theory.euler_bernoulli_omegas(STEEL, L, SECTION, direction=d, boundary="free-free", count=2)
        eb = eb / (2 * 3.141592653589793)
        for n in (1, 2):
            e = rel(got[f"bending-{d} {n}"], eb[n - 1])
            with capsys.disabled():
                print(f"\n[{backend}] free-free bending-{d} {n}: error vs EB {100 * e:+.3f} %")
            assert abs(e) < TOL


@pytest.mark.parametrize("boundary", ["clamped-free", "free-free"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_axial_and_torsion(backend, boundary, capsys):
    """20 x 4 x 4 cells: four across the section resolve the torsion (2 x 2 gives +1.6 %)."""
    fixed = "x0" if boundary == "clamped-free" else None
    k = 14 if boundary == "clamped-free" else 16  # torsion 1 and axial 1 sit above ~5 bending pairs
    res = solve_box((L, A, A), (20, 4, 4), backend=backend, k=k, fixed=fixed)
    got = by_label(res)
    ax = theory.axial_omegas(STEEL, L, boundary=boundary, count=1)[0] / (2 * 3.141592653589793)
    to = theory.torsion_omegas(STEEL, L, SECTION, boundary=boundary, count=1)[0] / (2 * 3.141592653589793)
    assert "axial 1" in got and "torsion 1" in got, res.labels
    ea, et = rel(got["axial 1"], ax), rel(got["torsion 1"], to)
    with capsys.disabled():
        print(f"\n[{backend}] {boundary}: axial 1 {got['axial 1']:.2f} Hz ({100 * ea:+.3f} %), "
              f"torsion 1 {got['torsion 1']:.2f} Hz ({100 * et:+.3f} %)")
    assert abs(ea) < TOL and abs(et) < TOL
