"""The World: one contract for modal, tet and cloth bodies, one effect vocabulary, only the asked-for stages,
two-way contact between every pair of body kinds (momentum exchanged sums to zero, no energy gain, no
intersection by the exact triangle-triangle test)."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact, Damping, Gravity, PseudoForces, SelfCollision, Sound, Wind
from modalfem.errors import InputError, SimulationError

from _world import BAR, total_momentum


# ----------------------------------------------------------------------------- vocabulary and refusals
def test_self_collision_on_a_modal_body_is_refused_by_name(bar_model):
    with pytest.raises(InputError, match=r"self-collision cannot act on modal body 'bar'.*takes gravity"):
        mw.World(bodies=[mw.Modal(bar_model, name="bar")], effects=[SelfCollision(bodies=["bar"])])


def test_an_effect_that_acts_on_no_body_is_refused(bar_model):
    with pytest.raises(InputError, match="acts on no body.*tet or cloth"):
        mw.World(bodies=[mw.Modal(bar_model, name="bar")], effects=[SelfCollision()])


@pytest.mark.parametrize("make, msg", [
    (lambda m: dict(bodies=[mw.Modal(m, name="a"), mw.Modal(m, name="a")]), "duplicate body name"),
    (lambda m: dict(bodies=[mw.Modal(m, name="a")], effects=[Gravity(bodies=["b"])]), "names body 'b'"),
    (lambda m: dict(bodies=[mw.Modal(m, name="a")], effects=[object()]), "unknown effect object"),
    (lambda m: dict(bodies=[mw.Modal(m, name="a")], obstacles=["floor"]), "unknown obstacle type"),
    (lambda m: dict(bodies=[]), "at least one body"),
    (lambda m: dict(bodies=[mw.Modal(m, name="a")], effects=[Contact(), Contact()]), "2 contact effects"),
    (lambda m: dict(bodies=[mw.Modal(m, name="a")], effects=[Wind(lambda x, t: x * 0)]), "constant wind"),
])
def test_bad_worlds_get_one_line(bar_model, make, msg):
    with pytest.raises(InputError, match=msg) as e:
        mw.World(**make(bar_model))
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("make, msg", [
    (lambda: Gravity((0, 0)), "3 finite numbers"),
    (lambda: Contact(restitution=1.5), "restitution must be <= 1"),
    (lambda: Contact(friction=-1), "friction must be >= 0"),
    (lambda: Damping(alpha=float("nan")), "finite"),
    (lambda: Sound(listener=(0, 0, 0)), "not be zero"),
    (lambda: mw.Sphere((0, 0, 0), -1.0), "radius must be > 0"),
    (lambda: mw.Path([(1.0, (0, 0, 0)), (0.5, (1, 0, 0))]), "increasing"),
    (lambda: mw.Modal("no/such/file.npz", name="x"), "no/such/file.npz"),
    (lambda: mw.Ground(0.0).__class__(float("inf")), "finite"),
])
def test_bad_effects_and_obstacles_get_one_line(make, msg):
    with pytest.raises(Exception, match=msg) as e:
        make()
    assert "\n" not in str(e.value)


def test_pseudo_forces_on_a_tet_body_are_refused(block_model):
    with pytest.raises(InputError, match="pseudo-forces cannot act on tet body 'block'"):
        mw.World(bodies=[mw.Tet(block_model, name="block")], effects=[PseudoForces(bodies=["block"])])


# ----------------------------------------------------------------------------- only what is asked for runs
STAGES = ("_stage_contacts", "_stage_modal_step", "_stage_tet_step", "_stage_tet_self", "_stage_cloth_step",
          "_stage_deformable", "_stage_sound")


def _count_stages(monkeypatch):
    calls = {s: 0 for s in STAGES}
    for s in STAGES:
        orig = getattr(mw.World, s)

        def counted(self, ctx, _orig=orig, _s=s):
            calls[_s] += 1
            return _orig(self, ctx)

        monkeypatch.setattr(mw.World, s, counted)
    return calls


def test_a_free_modal_body_runs_the_modal_step_only(bar_model, monkeypatch):
    from modalfem import runtime as rt

    calls = _count_stages(monkeypatch)
    hit = {"wind": 0, "collide": 0}
    monkeypatch.setattr(rt.Wind, "loads", lambda *a, **k: hit.__setitem__("wind", hit["wind"] + 1))
    orig = rt.ModalSolver.collide
    monkeypatch.setattr(rt.ModalSolver, "collide", lambda *a, **k: (hit.__setitem__("collide", hit["collide"] + 1),
                                                                     orig(*a, **k))[1])
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar")])
    assert [s.name for s in w.plan] == ["modal step"] and w.plan[0].effects == ()
    s = w.state()
    for _ in range(3):
        w.step(s, s, None, 1e-3)
    assert calls == {**{k: 0 for k in STAGES}, "_stage_modal_step": 3}
    assert hit == {"wind": 0, "collide": 0}


def test_each_effect_adds_exactly_its_stages(bar_model, block_model, cloth_model):
    def plan(**kw):
        w = mw.World(**kw)
        return [(s.name, s.effects) for s in w.plan]

    bar, block = mw.Modal(bar_model, name="bar"), mw.Tet(block_model, name="block")
    assert plan(bodies=[bar], effects=[Gravity()]) == [("modal step", ("gravity",))]
    # contact with a static ground is the modal runtime's own
    assert plan(bodies=[bar], obstacles=[mw.Ground()], effects=[Contact()]) == [("modal step", ("contact",))]
    # a moving obstacle brings the compiled modal contact solve
    moving = mw.Sphere((0, 0, -1), 0.5, path=lambda t: (0, 0, t))
    assert plan(bodies=[bar], obstacles=[moving], effects=[Contact()])[0] == ("modal contacts", ("contact",))
    assert plan(bodies=[bar], effects=[Sound()]) == [("modal step", ()), ("sound", ("sound",))]
    assert plan(bodies=[block], effects=[Wind((1, 0, 0)), Damping(alpha=1.0)]) == [
        ("tet step", ("damping", "wind"))]
    assert plan(bodies=[block], effects=[SelfCollision()]) == [("tet step", ("self-collision",)),
                                                                ("tet self-collision", ("self-collision",))]
    sheet = mw.Cloth(cloth_model, name="sheet")
    assert plan(bodies=[sheet], effects=[Gravity()]) == [("cloth step", ("gravity",))]
    assert plan(bodies=[sheet, bar], effects=[Gravity(), Contact()]) == [
        ("modal step", ("gravity",)), ("cloth step", ("gravity",)), ("cloth collisions", ("contact",))]


def test_stages_not_in_the_plan_are_never_called(bar_model, block_model, cloth_model, monkeypatch):
    calls = _count_stages(monkeypatch)
    w = mw.World(bodies=[mw.Tet(block_model, name="block"), mw.Cloth(cloth_model, name="sheet", x0=None)],
                 effects=[Gravity(bodies=["sheet"])])
    s = w.state()
    w.step(s, s, None, 1e-3)
    assert calls == {**{k: 0 for k in STAGES}, "_stage_tet_step": 1, "_stage_cloth_step": 1}


# ----------------------------------------------------------------------------- the contract
def test_step_writes_state_out_and_leaves_state_in(bar_model):
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0, 0, 1))], effects=[Gravity()])
    s0 = w.state()
    s1 = w.state()
    w.step(s0, s1, None, 0.01)
    assert s0.time == 0.0 and s0["bar"].position[2] == 1.0
    assert s1.time == pytest.approx(0.01) and s1["bar"].position[2] == pytest.approx(1.0 - 0.5 * 9.81 * 1e-4)


def test_control_errors_name_the_body(bar_model):
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar")])
    s = w.state()
    with pytest.raises(SimulationError, match="unknown body 'bell'"):
        w.step(s, s, w.control().add_impulse("bell", 0, (0, 0, 1)), 1e-3)
    with pytest.raises(SimulationError, match="time step"):
        w.step(s, s, None, 0.0)
    with pytest.raises(SimulationError, match="scripted vertices need a tet body"):
        w.step(s, s, w.control().script("bar", [0], [[0, 0, 0]]), 1e-3)


# ----------------------------------------------------------------------------- modal with modal
def _two_bars(bar_model, gap, speed, e=0.0, mu=0.0, **kw):
    a = mw.Modal(bar_model, name="a", position=(0.0, 0.0, 0.0), velocity=(speed, 0, 0))
    b = mw.Modal(bar_model, name="b", position=(BAR[0] + gap, 0.0, 0.01), velocity=(-speed, 0, 0))
    return mw.World(bodies=[a, b], effects=[Contact(restitution=e, friction=mu, **kw)])


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2, 0.1])
def test_modal_bodies_collide_without_tunnelling_momentum_or_energy_gain(bar_model, dt):
    speed = 2.0
    w = _two_bars(bar_model, gap=0.02, speed=speed)
    s = w.state()
    p0 = total_momentum(w, s)
    e0 = sum(w.energy(s, n)["total"] for n in ("a", "b"))
    exchanged = 0
    for _ in range(int(round(0.05 / dt)) + 2):
        r = w.step(s, s, None, dt)
        for a, b, J, _ in r.exchanged:
            exchanged += 1
        assert w.intersections(s) == []
        e = sum(w.energy(s, n)["total"] for n in ("a", "b"))
        assert e <= e0 * (1 + 1e-9)
    assert exchanged > 0
    # equal and opposite impulses: the total momentum is that of the start, to rounding
    scale = bar_model.mass * speed
    assert np.abs(total_momentum(w, s) - p0).max() <= 1e-12 * scale
    # they did not pass through each other, and e = 0 took (nearly) all of the approach: what is left is below
    # what the unconverged sweeps of redundant face contacts leave (1 % of the approach)
    assert s["a"].position[0] < s["b"].position[0]
    assert s["b"].velocity[0] - s["a"].velocity[0] >= -0.01 * 2 * speed


def test_a_modal_body_rests_on_another_under_gravity(bar_model):
    lower = mw.Modal(bar_model, name="lower", position=(0, 0, 0.025))
    upper = mw.Modal(bar_model, name="upper", position=(0.02, 0.01, 0.08))
    w = mw.World(bodies=[lower, upper], obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(restitution=0.0, friction=0.6)])
    s = w.state()
    for _ in range(400):
        w.step(s, s, None, 1e-3)
    assert w.intersections(s) == []
    # at rest on top: the upper bar's centre 1.5 bar heights above the ground (to the contact skin)
    assert s["upper"].position[2] == pytest.approx(0.075, abs=2e-3)
    assert abs(s["upper"].velocity[2]) < 0.05
