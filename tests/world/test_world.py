"""The World: one contract for modal, tet and cloth bodies, one effect vocabulary, only the asked-for stages,
two-way contact between every pair of body kinds (momentum exchanged sums to zero, no energy gain, no
intersection by the exact triangle-triangle test)."""

from __future__ import annotations

import numpy as np
import pytest
from _world import BAR, total_momentum

from modalfem import world as mw
from modalfem.effects import (
    Contact,
    Damping,
    Gravity,
    PseudoForces,
    SelfCollision,
    Sound,
    Wind,
)
from modalfem.errors import InputError, SimulationError


# ----------------------------------------------------------------------------- vocabulary and refusals
def test_self_collision_on_a_modal_body_is_refused_by_name(bar_model):
    with pytest.raises(InputError, match=r"self-collision cannot act on modal body 'bar'.*takes gravity"):
        mw.World(bodies=[mw.Modal(bar_model, name="bar")], effects=[SelfCollision(bodies=["bar"])])


def test_an_effect_that_acts_on_no_body_is_refused(bar_model):
    with pytest.raises(InputError, match="acts on no body.*tet or cloth"):
        mw.World(bodies=[mw.Modal(bar_model, name="bar")], effects=[SelfCollision()])


@pytest.mark.parametrize("make, msg", [
    (lambda m: {"bodies": [mw.Modal(m, name="a"), mw.Modal(m, name="a")]}, "duplicate body name"),
    (lambda m: {"bodies": [mw.Modal(m, name="a")], "effects": [Gravity(bodies=["b"])]}, "names body 'b'"),
    (lambda m: {"bodies": [mw.Modal(m, name="a")], "effects": [object()]}, "unknown effect object"),
    (lambda m: {"bodies": [mw.Modal(m, name="a")], "obstacles": ["floor"]}, "unknown obstacle type"),
    (lambda m: {"bodies": []}, "at least one body"),
    (lambda m: {"bodies": [mw.Modal(m, name="a")], "effects": [Contact(), Contact()]}, "2 contact effects"),
    (lambda m: {"bodies": [mw.Modal(m, name="a")], "effects": [Wind(lambda x, t: x * 0)]}, "constant wind"),
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
    solo = mw.World._step_solo  # a lone modal body's step (the modal step without the world's bookkeeping)

    def counted_solo(self, *args):
        calls["_stage_modal_step"] += 1
        return solo(self, *args)

    monkeypatch.setattr(mw.World, "_step_solo", counted_solo)
    return calls


def test_a_free_modal_body_runs_the_modal_step_only(bar_model, monkeypatch):
    from modalfem import runtime as rt

    calls = _count_stages(monkeypatch)
    hit = {"wind": 0, "collide": 0}
    from modalfem.runtime import effects as rte

    monkeypatch.setattr(rte.Wind, "loads", lambda *a, **k: hit.__setitem__("wind", hit["wind"] + 1))
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
    assert plan(bodies=[bar], obstacles=[moving], effects=[Contact()])[0] == ("solid contacts", ("contact",))
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
    for _ in range(round(0.05 / dt) + 2):
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


# ----------------------------------------------------------------------------- tet with obstacles, modal, tet
def test_a_tet_block_comes_to_rest_on_the_ground_above_it(block_model):
    c = Contact(friction=0.5)
    w = mw.World(bodies=[mw.Tet(block_model, name="block", position=(0, 0, 0.05))], obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), c, Damping(alpha=2.0)])
    s = w.state()
    for _ in range(300):
        w.step(s, s, None, 2e-3)
    from modalfem.world.tetcontact import STIFFNESS

    z = s["block"].x[:, 2]
    # on the ground, within the skin: at most the whole weight on the softest contact spring below the surface
    m = block_model.masses
    depth = m.sum() * 9.81 / (STIFFNESS * m.min() / 2e-3**2)
    assert -depth <= z.min() <= c.margin
    assert np.abs(s["block"].v).max() < 0.05


def _bar_into_block(bar_model, block_model, speed, friction=0.0):
    bar = mw.Modal(bar_model, name="bar", position=(0.15, 0.15, 0.14), velocity=(0, 0, -speed))
    block = mw.Tet(block_model, name="block")
    return mw.World(bodies=[bar, block], effects=[Contact(friction=friction)])


@pytest.mark.parametrize("friction", [0.0, 0.5])
def test_modal_and_tet_exchange_equal_and_opposite_impulses(bar_model, block_model, friction):
    speed = 1.0
    w = _bar_into_block(bar_model, block_model, speed, friction)
    s = w.state()
    p0 = total_momentum(w, s)
    got = np.zeros(3)
    for _ in range(120):
        r = w.step(s, s, None, 1e-3)
        for a, b, J, _ in r.exchanged:
            got += J if a == "block" else -J
        assert w.intersections(s) == []
    assert got[2] < -0.5 * bar_model.mass * speed * 0.1  # the block was pushed down, hard
    # free bodies, no gravity: the impulses are equal and opposite, so the total momentum stays but for what the
    # tet's implicit step leaves unconverged: Newton stops at vertex updates below tol * size, a velocity error of
    # up to tol * size / dt on each vertex
    solver = w._tet["block"]["solver"]
    bound = 120 * block_model.masses.sum() * solver.tol * block_model.size / 1e-3
    assert np.abs(total_momentum(w, s) - p0).max() <= bound
    # the bar slowed down and the free block was set moving the same way (no gravity: nothing else acts)
    assert s["bar"].velocity[2] > -0.9 * speed
    assert (block_model.masses @ s["block"].v)[2] < -0.05 * bar_model.mass * speed


def test_a_bar_dropped_on_a_soft_block_loses_energy_and_never_crosses_it(bar_model, block_model):
    bar = mw.Modal(bar_model, name="bar", position=(0.15, 0.15, 0.2))
    w = mw.World(bodies=[bar, mw.Tet(block_model, name="block")], obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(restitution=0.0, friction=0.5)])
    s = w.state()

    def energy():
        return sum(w.energy(s, n)["total"] for n in ("bar", "block"))

    e0 = energy()
    peak = e0
    for i in range(500):
        w.step(s, s, None, 1e-3)
        peak = max(peak, energy())
        if i % 10 == 0:
            assert w.intersections(s) == []
    # the penalty skin stores a little energy while it acts and gives it back; beyond that nothing is gained
    assert peak <= e0 * 1.02
    assert energy() < 0.9 * e0
    assert s["bar"].position[2] > 0.1  # on top of the block, not through it


def test_two_tet_blocks_collide_and_part(block_model):
    a = mw.Tet(block_model, name="a", velocity=(1.0, 0, 0))
    b = mw.Tet(block_model, name="b", position=(0.32, 0.0, 0.02), velocity=(-1.0, 0, 0))
    w = mw.World(bodies=[a, b], effects=[Contact(friction=0.0)])
    s = w.state()
    p0 = total_momentum(w, s)
    for _ in range(150):
        w.step(s, s, None, 1e-3)
        assert w.intersections(s) == []
    m = block_model.masses.sum()
    solver = w._tet["a"]["solver"]
    assert np.abs(total_momentum(w, s) - p0).max() <= 2 * 150 * m * solver.tol * block_model.size / 1e-3  # as above
    va = (block_model.masses @ s["a"].v) / m
    vb = (block_model.masses @ s["b"].v) / m
    assert va[0] < 0.5 and vb[0] > -0.5  # stopped or bounced back


# ----------------------------------------------------------------------------- cloth with modal and tet
@pytest.mark.slow
def test_cloth_draped_on_a_modal_bar_pushes_it_down(bar_model, cloth_model):
    from modalfem.cloth.model import ClothModel

    bar = mw.Modal(bar_model, name="bar", position=(0.15, 0.05, 0.0))
    sheet = mw.Cloth(cloth_model, name="sheet", x0=cloth_model.mesh.points + (0.0, 0.0, 0.04))
    assert isinstance(cloth_model, ClothModel)
    w = mw.World(bodies=[bar, sheet], effects=[Gravity(bodies=["sheet"]), Contact(thickness=2e-3)])
    s = w.state()
    p_cloth0 = w.momentum(s, "sheet")[0]
    received = np.zeros(3)
    for _ in range(150):
        r = w.step(s, s, None, 2e-3)
        for a, b, J, _ in r.exchanged:
            assert {a, b} == {"bar", "sheet"}
            received += J if a == "bar" else -J
        assert w.intersections(s) == []
    # the bar (no gravity of its own) was pushed down by the cloth lying on it
    assert received[2] < 0 and s["bar"].velocity[2] < 0
    assert w.momentum(s, "bar")[0][2] == pytest.approx(received[2], rel=1e-9, abs=1e-15)
    # the cloth lies on the bar (its flaps hang down and swing under it): cloth vertices over the top face, none
    # inside the bar
    xb, _ = w.surface(s, "bar")
    x = s["sheet"].x
    foot = np.all((x[:, :2] > xb[:, :2].min(0)) & (x[:, :2] < xb[:, :2].max(0)), axis=1)
    assert (foot & (x[:, 2] > xb[:, 2].max())).sum() >= 3
    assert not (foot & (x[:, 2] > xb[:, 2].min()) & (x[:, 2] < xb[:, 2].max())).any()
    del p_cloth0


@pytest.mark.slow
def test_cloth_falls_on_a_tet_block_and_stays_above_it(block_model, cloth_model):
    sheet = mw.Cloth(cloth_model, name="sheet", x0=cloth_model.mesh.points + (0.0, 0.05, 0.13))
    w = mw.World(bodies=[mw.Tet(block_model, name="block"), sheet], obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(thickness=2e-3)])
    s = w.state()
    pushed = np.zeros(3)
    for _ in range(120):
        r = w.step(s, s, None, 2e-3)
        for a, b, J, _ in r.exchanged:
            if {a, b} == {"block", "sheet"}:
                pushed += J if a == "block" else -J
        assert w.intersections(s) == []
    assert pushed[2] < 0  # the cloth pushed the block down
    top = s["block"].x[:, 2].max()
    inside = (s["sheet"].x[:, 0] > 0.02) & (s["sheet"].x[:, 0] < 0.28) & (s["sheet"].x[:, 1] > 0.02) & \
        (s["sheet"].x[:, 1] < 0.28)
    assert inside.any() and s["sheet"].x[inside, 2].min() > top - 0.01


# ----------------------------------------------------------------------------- effects on each kind
def test_wind_pushes_every_kind_downwind(bar_model, block_model, cloth_model):
    sheet = mw.Cloth(cloth_model, name="sheet", x0=cloth_model.mesh.points @ np.array([[1, 0, 0], [0, 0, 1],
                                                                                       [0, 1, 0]]))
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0, 2, 0)),
                         mw.Tet(block_model, name="block", position=(0, -2, 0)), sheet],
                 effects=[Wind((0, 20.0, 0))])
    s = w.state()
    for _ in range(10):
        w.step(s, s, None, 1e-3)
    for n in ("bar", "block", "sheet"):
        assert w.momentum(s, n)[0][1] > 0, n


def test_a_moving_sphere_pushes_a_resting_bar(bar_model):
    pusher = mw.Sphere((-0.2, 0.0, 0.0), 0.05, path=[(0.0, (0, 0, 0)), (1.0, (0.5, 0, 0))])
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar")], obstacles=[pusher], effects=[Contact(friction=0.0)])
    s = w.state()
    for _ in range(400):
        w.step(s, s, None, 1e-3)
        x, _ = w.surface(s, "bar")
        gap, _ = pusher.signed_distance(x, s.time)
        assert gap.min() > -1e-6
    assert s["bar"].velocity[0] > 0.3  # carried along at about the sphere's 0.5 m/s


def test_a_struck_bar_sounds_at_its_modes(bar_model):
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar")], effects=[Sound(bodies=["bar"])])
    s = w.state()
    w.step(s, s, w.control().add_impulse("bar", 3, (0.0, 0.0, -0.05)), 1e-3)
    snd = w.sound("bar")
    p = snd.render(0.25)
    spec = np.abs(np.fft.rfft(p * np.hanning(len(p))))
    f = np.fft.rfftfreq(len(p), 1.0 / snd.sample_rate)
    peak = f[np.argmax(spec)]
    hz = snd.kept_hz
    assert np.min(np.abs(hz - peak)) <= 2 * snd.sample_rate / len(p)


# ----------------------------------------------------------------------------- one vocabulary for the kind solvers too
def test_every_kind_solver_takes_the_public_effects(bar_model, block_model, cloth_model):
    from modalfem import runtime as rt
    from modalfem import tet
    from modalfem.cloth.scene import ClothScene

    body = rt.ModalBody(bar_model, dtype=np.float64)
    solver = rt.ModalSolver(body, effects=[Gravity((0, 0, -2.0)), Wind((3.0, 0, 0))])
    s = solver.state()
    solver.step(s, s, None, None, 0.01)
    assert s.velocity[2] == pytest.approx(-0.02) and s.velocity[0] > 0
    ts = tet.TetSolver(block_model, effects=[Gravity((0, 0, -2.0)), Damping(alpha=0.0)])
    st = tet.TetState.at_rest(block_model)
    ts.step(st, st, 0.01)
    assert (block_model.masses @ st.v)[2] / block_model.masses.sum() == pytest.approx(-0.02, rel=1e-6)
    cs = ClothScene(cloth_model, gravity=Gravity((0, 0, -2.0)))
    cs.step(0.01)
    assert np.mean(cs.v[:, 2]) == pytest.approx(-0.02, rel=1e-3)
    with pytest.raises(InputError, match="self-collision on a single tet solver"):
        tet.TetSolver(block_model, effects=[SelfCollision()])
    with pytest.raises(InputError, match="cannot act on a modal body"):
        rt.ModalSolver(body, effects=[SelfCollision()])
    with pytest.raises(InputError, match="damping to ModalBody"):
        rt.ModalSolver(body, effects=[Damping(alpha=1.0)])


def test_a_step_from_a_copied_state_repeats_exactly(bar_model):
    # modal bodies only: the tet solver's own caches (SVD and CG warm starts) repeat a step to its tolerances only
    lower = mw.Modal(bar_model, name="lower", position=(0, 0, 0.025))
    upper = mw.Modal(bar_model, name="upper", position=(0.02, 0.01, 0.08))
    w = mw.World(bodies=[lower, upper], obstacles=[mw.Ground(0.0)], effects=[Gravity(), Contact()])
    s = w.state()
    for _ in range(60):
        w.step(s, s, None, 1e-3)
    assert s.contacts  # resting contacts carry their impulses into the next step
    a, b = s.copy(), s.copy()
    for _ in range(5):
        w.step(a, a, None, 1e-3)
        w.step(b, b, None, 1e-3)
    for n in ("lower", "upper"):
        assert np.array_equal(a[n].position, b[n].position) and np.array_equal(a[n].qdot, b[n].qdot)


def test_a_lone_modal_body_steps_exactly_as_its_solver(bar_model):
    """The lone-body path (World._step_solo) is ModalSolver.step: same bits after a spinning flight under
    gravity, into the caller's state in place or into another state."""
    from modalfem import runtime as rt
    from modalfem.effects import Gravity

    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", angular_velocity=(0.3, 2.0, -1.0))], effects=[Gravity()])
    assert w._solo == "bar"
    solver = rt.ModalSolver(rt.ModalBody(bar_model), effects=[Gravity()])
    s = w.state()
    other = w.state()
    ref = s["bar"].copy()
    for _ in range(12):
        w.step(s, s, None, 1e-3)
        solver.step(ref, ref, None, None, 1e-3)
    w.step(s, other, None, 1e-3)
    solver.step(ref, ref, None, None, 1e-3)
    for a in ("q", "qdot", "position", "velocity", "angular_momentum"):
        assert np.array_equal(getattr(other["bar"], a), getattr(ref, a)), a
    assert other.time == pytest.approx(13e-3) and s.time == pytest.approx(12e-3)


def test_resting_contact_is_not_heard_as_impacts(bar_model):
    """A bar landing on the ground makes a few impacts; lying there it takes ~m g dt every step, which must not be
    recorded as an impact per step (a buzz at the step rate)."""
    from modalfem.effects import Contact, Gravity, Sound

    z0 = -float(bar_model.vertices[:, 2].min()) + float(bar_model.center_of_mass[2]) + 2e-3
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0.0, 0.0, z0))], obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(restitution=0.3), Sound()])
    s = w.state()
    for _ in range(150):  # a 2 mm drop lands in ~20 ms and settles
        w.step(s, s, None, 1e-3)
    landed = w.sound("bar").impact_count
    assert 1 <= landed <= 40
    for _ in range(200):
        w.step(s, s, None, 1e-3)
    assert abs(float(w.momentum(s, "bar")[0][2])) < 1e-3 * bar_model.mass * 9.81 * 0.35   # at rest
    assert w.sound("bar").impact_count == landed


def test_two_touching_cloths_without_self_collision_are_refused():
    """Contact between two cloths is the pipeline's self-collision test over both, which tests each cloth against
    itself too: a world without SelfCollision on them says so instead of switching it on unasked."""
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothMaterial, ClothModel
    from modalfem.effects import Contact, Gravity, SelfCollision

    knit = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4)
    a = ClothModel(grid((0.2, 0.2), (4, 4)), knit)
    b = ClothModel(grid((0.2, 0.2), (4, 4), origin=(0.0, 0.0, 0.05)), knit)
    bodies = [mw.Cloth(a, name="a"), mw.Cloth(b, name="b")]
    with pytest.raises(InputError, match=r"cloths a, b touch each other.*add self-collision for a, b"):
        mw.World(bodies=bodies, effects=[Gravity(), Contact()])
    with pytest.raises(InputError, match=r"add self-collision for b"):
        mw.World(bodies=bodies, effects=[Gravity(), Contact(), SelfCollision(bodies=["a"])])
    w = mw.World(bodies=bodies, effects=[Gravity(), Contact(), SelfCollision()])
    assert [s.name for s in w.plan] == ["cloth step", "cloth collisions"]
    assert mw.World(bodies=bodies, effects=[Gravity(), Contact(bodies=["a"])]).plan  # one cloth touching: fine


def test_a_lone_modal_body_step_that_fails_leaves_the_state_as_it_was(bar_model):
    """All or nothing on the lone-body path too: a step that goes non-finite raises one line naming the body and
    leaves the output state bit for bit as it was (in another state and in place)."""
    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", velocity=(0.1, 0.0, 0.0))])
    assert w._solo == "bar"
    s, other = w.state(), w.state()
    w.step(s, other, None, 1e-3)
    s["bar"].qdot[0] = np.inf
    for out in (other, s):
        before = {a: getattr(out["bar"], a).copy() for a in ("q", "qdot", "position", "velocity", "angular_momentum")}
        t_before = out.time
        with pytest.raises(SimulationError, match="modal body 'bar'.*non-finite"):
            w.step(s, out, None, 1e-3)
        for a, v in before.items():
            assert np.array_equal(getattr(out["bar"], a), v), a
        assert out.time == t_before


def test_a_step_that_fails_leaves_no_impact_in_the_sounds(bar_model):
    """All or nothing for the sounds too: a strike on a sounding bar is recorded in its modal step; when a later
    stage of that step fails, the step raises and the sound holds no impact of it (the same step then succeeding
    records the strike once)."""
    from modalfem.effects import Sound

    w = mw.World(bodies=[mw.Modal(bar_model, name="bar", position=(0.0, 0.0, 0.5))], obstacles=[mw.Ground(0.0)],
                 effects=[Gravity(), Contact(), Sound()])
    assert w._solo is None and [s.name for s in w.plan][-1] == "sound"
    plan = list(w._plan)

    def broken(ctx):
        raise SimulationError("sound stage failed (test)")

    w._plan = plan[:-1] + [(plan[-1][0], broken)]
    s = w.state()
    with pytest.raises(SimulationError, match="failed"):
        w.step(s, s, w.control().add_impulse("bar", 0, (0.0, 0.0, -0.1)), 1e-3)
    assert w.sound("bar").impact_count == 0
    w._plan = plan
    w.step(s, s, w.control().add_impulse("bar", 0, (0.0, 0.0, -0.1)), 1e-3)
    assert w.sound("bar").impact_count == 1
