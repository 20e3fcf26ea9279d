"""Issue-6 scenes with the real collision pipeline: after every step, no intersection (independent
exact check, ``scenes.intersections``), no vertex inside an obstacle, no NaN, bounded energy. Small
cloths and short runs; the pile and the two-turn twist are marked slow."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from modalfem.cloth import scenes
from modalfem.errors import SceneError, SimulationError


def _run(setup, steps=None, *, e_max=None):
    """Step ``setup``; assert the invariants after every step; return (energies, max speed)."""
    sc = setup.scene
    assert sc.initial_intersections == 0
    e0 = sc.energy()["total"]
    energies, vmax = [e0], 0.0
    for _ in range(steps or setup.steps):
        sc.step(setup.dt)
        assert np.all(np.isfinite(sc.x)) and np.all(np.isfinite(sc.v))
        assert scenes.intersections(setup) == 0  # independent tri-tri test
        for ob in setup.obstacles:
            assert ob.signed_distance(sc.x, sc.t).min() >= -1e-9, f"cloth vertex inside {type(ob).__name__}"
        energies.append(sc.energy()["total"])
        vmax = max(vmax, float(np.linalg.norm(sc.v, axis=1).max()))
    if e_max is not None:
        assert max(energies) <= e_max
    return np.array(energies), vmax


def test_drape_over_a_sphere():
    s = scenes.drape(12)
    e, _ = _run(s, 40)
    # no energy source: total energy (kinetic + elastic + gravity) never grows
    assert e.max() <= e[0] + 1e-9
    x = s.scene.x
    ball = s.obstacles[0]
    # the cloth rests on the ball: its middle stays on top, its rim hangs below the ball's top
    mid = np.argmin(np.linalg.norm(s.scene.model.mesh.points[:, :2] - 0.5, axis=1))
    assert abs(ball.signed_distance(x[mid:mid + 1], s.scene.t)[0]) < 0.02
    assert x[:, 2].min() < 0.5


def test_cloth_on_a_rotating_sphere_is_carried_round():
    s = scenes.rotating_sphere(12)
    _run(s, 30)
    sc = s.scene
    spin = s.obstacles[0].angular_velocity[2]
    r = sc.x[:, :2] - s.obstacles[0].center[:2]
    lz = np.sum(sc.model.masses * (r[:, 0] * sc.v[:, 1] - r[:, 1] * sc.v[:, 0]))
    omega = lz / np.sum(sc.model.masses * np.sum(r * r, axis=1))
    # friction turns it the ball's way, never faster than the ball
    assert 0.2 * spin < omega < 1.05 * spin
    p0 = sc.model.mesh.points[:, :2] - s.obstacles[0].center[:2]
    far = np.linalg.norm(p0, axis=1) > 0.1
    ang = np.angle((r[far, 0] + 1j * r[far, 1]) / (p0[far, 0] + 1j * p0[far, 1]))
    assert 0.1 < ang.mean() < spin * sc.t


@pytest.mark.slow
def test_pile_on_the_ground():
    s = scenes.pile(12)
    e, _ = _run(s, 50)
    assert e.max() <= e[0] + 1e-9
    assert s.scene.x[:, 2].max() < 0.6  # it has collapsed


def test_flag_in_wind():
    s = scenes.flag(10)
    _, vmax = _run(s, 60)
    assert vmax < 30.0
    tip = np.isclose(s.scene.model.mesh.points[:, 1], 0.6)
    assert s.scene.x[tip, 0].mean() > 0.1  # blown downwind


def test_fast_sphere_hits_the_cloth():
    s = scenes.fast_sphere(10)
    _, vmax = _run(s)
    ball = s.obstacles[0]
    # the ball went through the cloth's rest plane and the cloth went with it (in front of the ball)
    assert ball.center_at(s.scene.t)[1] > 0.1
    assert s.scene.x[:, 1].max() > ball.center_at(s.scene.t)[1]
    assert vmax < 40.0


def test_twist_half_turn():
    s = scenes.twist(8, turns=0.5, duration=0.5, dt=1 / 50)
    _run(s, e_max=5.0)


def _helicoid_energy(material, width, rest, length, angle):
    """Membrane energy [J] of a ``width`` x ``rest`` [m] sheet twisted by ``angle`` [rad] as a helicoid of
    ``length`` [m] with no lateral contraction: the fibre at distance r from the axis stretches to
    ``sqrt(length^2 + (angle r)^2) / rest`` (uniaxial: energy density (mu + lambda / 2) (stretch - 1)^2).
    A contact-free configuration the twisted cloth could take, so it bounds the energy it settles to."""
    r = (np.arange(400) + 0.5) / 400 * width - 0.5 * width
    stretch = np.sqrt(length**2 + (angle * r) ** 2) / rest
    psi = (material.mu + 0.5 * material.lam) * (stretch - 1.0) ** 2
    return float(np.sum(psi) * width / 400 * rest)


@pytest.mark.slow
def test_twist_two_full_turns():
    # issue 6: the square held at two edges, one edge turned twice; after every step no intersection
    # (exact tri-tri), no NaN, energy bounded
    s = scenes.twist(8, turns=2.0, duration=2.0, dt=1 / 50)
    sc, model = s.scene, s.scene.model
    assert sc.initial_intersections == 0
    rim = 2 * np.pi * 0.25  # speed [m/s] of the turning edge's corners (one turn per second)
    kinetic = 0.5 * model.masses.sum() * rim**2
    px = model.mesh.points[:, 0]
    mid = np.flatnonzero(np.isclose(px, px[np.argmin(np.abs(px))]))  # the column nearest the middle
    mid = mid[np.argsort(model.mesh.points[mid, 1])]
    step = sc.step

    def checked_step(dt):  # the independent check after every (sub)step the scene takes
        stats = step(dt)
        assert np.all(np.isfinite(sc.x)) and np.all(np.isfinite(sc.v))
        assert scenes.intersections(s) == 0
        return stats

    sc.step = checked_step
    turned, prev, substeps = 0.0, None, 0
    for _ in range(s.steps):
        substeps += s.advance()  # halves a step the impact zones cannot resolve
        # energy bounded: below the contact-free helicoid twisted as far, plus the whole sheet moving
        # at the rim speed
        bound = _helicoid_energy(model.material, 0.5, 0.5, 0.5 + 0.05 * sc.t / 2.0, 2 * np.pi * sc.t) + kinetic
        assert sc.energy()["total"] <= bound
        # the cross-section half way between the edges turns with the sheet (unwrapped angle)
        d = sc.x[mid[-1], 1:] - sc.x[mid[0], 1:]
        ang = np.arctan2(d[1], d[0])
        if prev is not None:
            turned += (ang - prev + np.pi) % (2 * np.pi) - np.pi
        prev = ang
    assert sc.t == pytest.approx(2.0)
    assert substeps < 1.2 * s.steps  # the fail-safe stays the exception
    # the middle has wound about one turn (half the twist), and has narrowed towards the axis
    assert 0.5 < turned / (2 * np.pi) < 1.5
    assert np.linalg.norm(sc.x[mid, 1:] - [0.0, 0.5], axis=1).max() < 0.25


class _RefusingScene:
    """A stand-in scene whose steps longer than ``limit`` [s] are refused like an unresolved pipeline
    step (SimulationError, state untouched); with ``nan`` it instead corrupts the state first."""

    def __init__(self, limit, nan=False):
        self.limit, self.nan, self.t, self.x, self.steps = limit, nan, 0.0, np.zeros((1, 3)), []

    def step(self, dt):
        if dt > self.limit:
            if self.nan:
                self.x = np.full((1, 3), np.nan)
            raise SimulationError("collision pipeline left 1 colliding pairs")
        self.t += dt
        self.x = self.x + dt
        self.steps.append(dt)


def test_advance_halves_only_refused_steps():
    sc = _RefusingScene(limit=0.03)
    setup = scenes.Setup("stub", sc, 0.1, 1)
    assert setup.advance() == 4 and sc.steps == [0.025] * 4 and sc.t == pytest.approx(0.1)
    assert setup.advance(max_halvings=3) == 4
    with pytest.raises(SimulationError):
        setup.advance(max_halvings=1)  # 0.05 is still refused
    bad = _RefusingScene(limit=0.03, nan=True)
    with pytest.raises(SimulationError):
        scenes.Setup("stub", bad, 0.1, 1).advance()  # a state already changed is not retried
    assert bad.steps == []


def test_starting_intersection_is_reported_with_a_count():
    from modalfem.cloth.scene import ClothScene

    s = scenes.drape(8)
    x0 = s.scene.x.copy()
    x0[:, 2] = 0.4  # through the ball
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        sc = ClothScene(s.scene.model, collisions=s.scene.pipeline.config, obstacles=s.obstacles, x0=x0)
    assert sc.initial_intersections > 0
    assert any(str(sc.initial_intersections) in str(m.message) for m in w)
    with pytest.raises(SceneError, match="starts in intersection"):
        ClothScene(s.scene.model, collisions=s.scene.pipeline.config, obstacles=s.obstacles, x0=x0, strict_start=True)
