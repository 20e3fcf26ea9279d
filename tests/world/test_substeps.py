"""``modalfem.world.substeps``: a World step in which a modal body near a tet body would travel more than
``TRAVEL_SHARE`` of the tet's smallest rest surface edge is taken as equal sub-steps (the scene that needs it:
test_tet_squeeze.py at 10-50 ms). Expected counts come from the scene's numbers (speed, dt, the cube's 2 cm cells)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact
from modalfem.mesh import box
from modalfem.world.substeps import TRAVEL_SHARE

CELL = 0.02  # [m] the cube's cells: its smallest surface edge


@pytest.fixture(scope="module")
def cube():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(3 * CELL, 3 * CELL, 3 * CELL), cells=(3, 3, 3)),
                         Material(E=1e6, nu=0.3, rho=1000.0))


def _world(bar_model, cube, speed, height=0.1):
    """The bar (no gravity, no spin) moving down at ``speed`` [m/s] with its centre ``height`` [m] over the cube's
    top face."""
    bar = mw.Modal(bar_model, name="bar", position=(0.0, 0.0, 3 * CELL + height), velocity=(0.0, 0.0, -speed))
    return mw.World(bodies=[bar, mw.Tet(cube, name="cube", position=(-1.5 * CELL, -1.5 * CELL, 0.0))],
                    effects=[Contact()])


@pytest.mark.parametrize("speed, dt", [(0.1, 1e-3), (2.1, 2e-2), (0.9, 5e-2)])
def test_the_step_is_divided_so_the_bar_travels_at_most_half_a_cube_cell_per_sub_step(bar_model, cube, speed, dt):
    w = _world(bar_model, cube, speed)
    s = w.state()
    r = w.step(s, s, None, dt)
    assert r.substeps == max(1, math.ceil(speed * dt / (TRAVEL_SHARE * CELL)))
    assert s.time == pytest.approx(dt, abs=1e-15)


def test_a_divided_step_is_its_sub_steps_taken_one_by_one(bar_model, cube):
    """The bar landing on the cube in a 20 ms step at 1.4 m/s (3 sub-steps): the same states, bit for bit, as three
    6.67 ms steps, and what the bar received from the cube summed over them."""
    dt, speed = 2e-2, 1.4
    n = math.ceil(speed * dt / (TRAVEL_SHARE * CELL))
    a = _world(bar_model, cube, speed, height=0.04)  # the bar's bottom 1.5 cm over the cube: it lands in the step
    b = _world(bar_model, cube, speed, height=0.04)
    sa, sb = a.state(), b.state()
    r = a.step(sa, sa, None, dt)
    assert r.substeps == n == 3
    ex = {}
    for _ in range(n):
        rb = b.step(sb, sb, None, dt / n)
        assert rb.substeps == 1
        for x, y, J, _ in rb.exchanged:
            ex[(x, y)] = ex.get((x, y), 0.0) + J
    assert np.array_equal(sa["cube"].x, sb["cube"].x) and np.array_equal(sa["cube"].v, sb["cube"].v)
    assert np.array_equal(sa["bar"].position, sb["bar"].position)
    assert np.array_equal(sa["bar"].velocity, sb["bar"].velocity)
    got = {(x, y): J for x, y, J, _ in r.exchanged}
    assert set(got) == set(ex) and ("bar", "cube") in got  # (it landed)
    for k in ex:
        assert np.allclose(got[k], ex[k], rtol=1e-12, atol=0.0)


def test_a_bar_far_from_the_tet_or_a_step_with_scripted_vertices_is_not_divided(bar_model, cube):
    w = _world(bar_model, cube, 2.0, height=1.0)  # 1 m over the cube: out of reach within 20 ms
    s = w.state()
    assert w.step(s, s, None, 2e-2).substeps == 1
    w = _world(bar_model, cube, 2.0)
    s = w.state()
    top = np.flatnonzero(np.isclose(cube.rest_points[:, 2], 0.0))
    ctl = w.control().script("cube", top, s["cube"].x[top])
    assert w.step(s, s, ctl, 2e-2).substeps == 1


class _Counted(np.ndarray):
    """Vertex positions that count how often they are gathered by an index array (``x[surface]``)."""

    gathers = 0

    def __getitem__(self, key):
        if isinstance(key, np.ndarray):
            _Counted.gathers += 1
        return super().__getitem__(key)


def test_the_sub_step_count_reads_each_tet_surface_once(bar_model, cube):
    """Two tet cubes and a modal bar: ``substep_count`` gathers each tet's surface vertices once for both its counts
    (bar against tet, tet against tet), not once per count (before: twice per tet and step)."""
    from modalfem.world.substeps import substep_count

    bar = mw.Modal(bar_model, name="bar", position=(0.0, 0.0, 3 * CELL + 0.1), velocity=(0.0, 0.0, -1.0))
    w = mw.World(bodies=[bar, mw.Tet(cube, name="a", position=(-1.5 * CELL, -1.5 * CELL, 0.0)),
                         mw.Tet(cube, name="b", position=(-1.5 * CELL, -1.5 * CELL, -3.5 * CELL))],
                 effects=[Contact()])
    s = w.state()
    for n in ("a", "b"):
        s.bodies[n].x = s.bodies[n].x.view(_Counted)
    _Counted.gathers = 0
    n = substep_count(w, s, 2e-2)
    assert _Counted.gathers == 2
    assert n >= 2  # (the bar, in reach, travels 2 cm in the step: at least twice half a 2 cm cell)


def test_a_step_reads_the_tet_extents_once_for_both_of_its_counts(bar_model, cube, monkeypatch):
    """A World step with a modal body near a tet body counts its sub-steps twice: from the start velocities
    (``substep_count``) and from the travel the single pass took (``taken_count``). Both read the tet's surface box
    and fastest vertex at the step start, which the pass does not change: one ``extents`` per step (before: two),
    and both counts get that one."""
    from modalfem.world import substeps
    from modalfem.world import world as world_module

    calls = {"extents": 0, "substep_count": [], "taken_count": []}
    real_extents, real_sub, real_taken = substeps.extents, substeps.substep_count, substeps.taken_count

    def counted_extents(w, st):
        calls["extents"] += 1
        return real_extents(w, st)

    def sub(w, st, dt, ext=None):
        calls["substep_count"].append(ext)
        return real_sub(w, st, dt, ext)

    def taken(w, st, out, dt, ext=None):
        calls["taken_count"].append(ext)
        return real_taken(w, st, out, dt, ext)

    monkeypatch.setattr(world_module, "extents", counted_extents)
    monkeypatch.setattr(world_module, "substep_count", sub)
    monkeypatch.setattr(world_module, "taken_count", taken)
    w = _world(bar_model, cube, 0.1, height=0.03)
    s = w.state()
    for _ in range(3):
        w.step(s, s, None, 1e-3)
    assert calls["extents"] == 3
    assert len(calls["substep_count"]) == 3 and len(calls["taken_count"]) == 3
    for a, b in zip(calls["substep_count"], calls["taken_count"]):
        assert a is b and set(a) == {"cube"}
        lo, hi, vmax = a["cube"]
        assert np.all(lo <= hi) and vmax >= 0.0
