"""Ready-made cloth scenes (issue 6): drape, rotating sphere, twist, pile, flag, fast sphere.

Each builder returns a ``Setup``: the ``ClothScene``, a suggested step ``dt`` [s] and step count, and
the sphere obstacles (for gap checks and pictures). ``n`` is the number of vertices per side of the
square cloth; ``config`` overrides ``CollisionConfig`` fields (e.g. ``culling=False``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from modalfem.cloth.mesh import grid
from modalfem.cloth.model import ClothMaterial, ClothModel, Handle
from modalfem.cloth.scene import ClothScene
from modalfem.cloth.wind import Wind
from modalfem.errors import SimulationError

__all__ = ["MATERIAL", "SCENES", "Setup", "drape", "fast_sphere", "flag", "intersections", "pile", "rotating_sphere",
           "twist"]

#: the scenes' cloth: 0.2 kg/m^2, E h = 100 N/m (a soft knit), kb = 1e-5 N m
MATERIAL = ClothMaterial(areal_density=0.2, young=2e5, poisson=0.3, thickness=5e-4, bending_stiffness=1e-5,
                         name="knit")
GRAVITY = (0.0, 0.0, -9.81)
THICKNESS = 4e-3  # collision thickness [m]


@dataclass
class Setup:
    """A scene ready to step.

    Attributes:
        name: scene name.
        scene: the ``ClothScene``.
        dt: suggested time step [s].
        steps: suggested number of steps.
        obstacles: the kinematic obstacles given to the pipeline.
        spheres: ``t -> [(center (3,) [m], radius [m]), ...]`` for pictures and gap checks.
    """

    name: str
    scene: ClothScene
    dt: float
    steps: int
    obstacles: tuple = ()
    spheres: object = field(default=lambda t: [])

    def advance(self, *, max_halvings: int = 3) -> int:
        """Advance the scene by ``dt``; a step the collision pipeline cannot make collision-free is taken
        as two half steps instead (recursively, at most ``max_halvings`` times). Smaller steps move the
        scripted handles less: impact zones caught between two handles (which no rigid motion can
        follow) shrink or vanish. Every step taken is still collision-free by the pipeline's guarantee.

        Returns:
            Number of steps taken (1 when the full step succeeded).

        Raises:
            SimulationError: still unresolved after ``max_halvings`` halvings, or a non-finite state.
        """
        return _advance(self.scene, self.dt, int(max_halvings))


def intersections(setup: Setup) -> int:
    """Intersections now, by the independent check: intersecting cloth triangle pairs
    (``modalfem.collision.tritri.intersecting_pairs``, exact, coplanar pairs included) plus vertices
    inside an obstacle."""
    from modalfem.collision.tritri import intersecting_pairs

    sc = setup.scene
    count = len(intersecting_pairs(sc.x, sc.model.mesh.triangles))
    for ob in setup.obstacles:
        count += int(np.sum(ob.signed_distance(sc.x, sc.t) < 0))
    return count


def _advance(scene: ClothScene, dt: float, halvings: int) -> int:
    t, x = scene.t, scene.x
    try:
        scene.step(dt)
        return 1
    except SimulationError:
        # only a step the pipeline refused (state untouched) is retried
        if halvings <= 0 or scene.t != t or scene.x is not x:
            raise
    return _advance(scene, 0.5 * dt, halvings - 1) + _advance(scene, 0.5 * dt, halvings - 1)


def _config(collisions: bool, overrides: dict):
    if not collisions:
        return None
    from modalfem.collision.pipeline import CollisionConfig

    kw = {"thickness": THICKNESS, "friction": 0.3}
    kw.update(overrides)
    return CollisionConfig(**kw)


def _obstacle_types():
    from modalfem.collision.obstacles import Plane, Sphere

    return Plane, Sphere


def _sphere_fn(spheres):
    return lambda t: [(s.center_at(t), s.radius) for s in spheres]


def drape(n: int = 32, *, collisions: bool = True, smoothing: float = 0.02, **config) -> Setup:
    """A 1 m square cloth falling from 5 cm onto a 0.3 m ball resting on the ground."""
    Plane, Sphere = _obstacle_types()
    ball = Sphere(center=(0.5, 0.5, 0.3), radius=0.3)
    obst = (ball, Plane(point=(0, 0, 0), normal=(0, 0, 1)))
    m = grid((1.0, 1.0), (n, n), origin=(0.0, 0.0, 0.65))
    model = ClothModel(m, MATERIAL, mass_damping=0.1)
    sc = ClothScene(model, gravity=GRAVITY, collisions=_config(collisions, config),
                    obstacles=obst if collisions else (),
                    smoothing=smoothing)
    return Setup("drape", sc, 1 / 100, 100, obst, _sphere_fn([ball]))


def rotating_sphere(n: int = 24, *, collisions: bool = True, smoothing: float = 0.02, spin: float = 4.0,
                    **config) -> Setup:
    """A 0.6 m cloth lying on a ball spinning about z at ``spin`` [rad/s]: friction carries it round."""
    Plane, Sphere = _obstacle_types()
    ball = Sphere(center=(0.0, 0.0, 0.3), radius=0.3, angular_velocity=(0.0, 0.0, spin))
    obst = (ball, Plane(point=(0, 0, 0), normal=(0, 0, 1)))
    m = grid((0.6, 0.6), (n, n), origin=(-0.3, -0.3, 0.6 + 1.5 * THICKNESS))
    model = ClothModel(m, MATERIAL, mass_damping=0.1)
    config.setdefault("friction", 0.8)
    sc = ClothScene(model, gravity=GRAVITY, collisions=_config(collisions, config),
                    obstacles=obst if collisions else (),
                    smoothing=smoothing)
    return Setup("rotating sphere", sc, 1 / 100, 100, obst, _sphere_fn([ball]))


def twist(n: int = 24, *, collisions: bool = True, smoothing: float = 0.02, turns: float = 2.0,
          duration: float = 2.0, approach: float = -0.05, dt: float = 1 / 100, **config) -> Setup:
    """A 0.5 m square held at two opposite edges; one edge turns ``turns`` times about the axis through both
    edge midpoints in ``duration`` [s] while the edges approach each other by ``approach`` [m] (negative:
    they move apart, which keeps the wound sheet from jamming). Collision thickness 2 mm by default.

    The wound sheet brings the turning edge's scripted vertices into impact zones: such a zone follows
    their finite rotation over the step (``modalfem.collision.zones.follow_finite_motion``). A zone
    caught between the pinned and the turning edge cannot follow both and may leave pairs unresolved
    (``SimulationError`` from ``ClothScene.step``): ``Setup.advance`` then takes the step in halves."""
    m = grid((0.5, 0.5), (n, n), origin=(-0.25, -0.25, 0.5))
    p = m.points
    left = np.flatnonzero(np.isclose(p[:, 0], -0.25))
    right = np.flatnonzero(np.isclose(p[:, 0], 0.25))
    rate = 2 * np.pi * turns / duration
    rest = p[right].copy()
    c0 = np.array([0.25, 0.0, 0.5])

    def path(t: float) -> np.ndarray:
        s = min(t, duration)
        a = rate * s
        d = rest - c0
        ca, sa = np.cos(a), np.sin(a)
        rot = np.stack([d[:, 0], d[:, 1] * ca - d[:, 2] * sa, d[:, 1] * sa + d[:, 2] * ca], 1)
        return rot + c0 - np.array([approach * s / duration, 0.0, 0.0])

    handles = (Handle.pin(p, left), Handle(right, path))
    model = ClothModel(m, MATERIAL, mass_damping=0.2, handles=handles)
    steps = int(duration / dt + 0.5)
    config.setdefault("thickness", 2e-3)
    sc = ClothScene(model, collisions=_config(collisions, config), smoothing=smoothing)
    return Setup("twist", sc, dt, steps, (), lambda t: [])


def pile(n: int = 32, *, collisions: bool = True, smoothing: float = 0.02, **config) -> Setup:
    """A 1 m square hung vertically (slightly wavy) with its lower edge 2 cm above the ground, let go:
    it folds into a pile on the ground."""
    Plane, _ = _obstacle_types()
    obst = (Plane(point=(0, 0, 0), normal=(0, 0, 1)),)
    m = grid((1.0, 1.0), (n, n), origin=(0.0, 0.0, 0.02), plane="xz")
    x0 = m.points.copy()
    x0[:, 1] = 0.03 * np.sin(2 * np.pi * x0[:, 0] / 0.5) * (0.2 + x0[:, 2])  # a wave so it folds
    model = ClothModel(m, MATERIAL, mass_damping=0.1)
    sc = ClothScene(model, gravity=GRAVITY, collisions=_config(collisions, config),
                    obstacles=obst if collisions else (),
                    smoothing=smoothing, x0=x0)
    return Setup("pile", sc, 1 / 100, 80, obst, lambda t: [])


def flag(n: int = 16, *, collisions: bool = True, smoothing: float = 0.02, wind_speed: float = 6.0, **config) -> Setup:
    """A 0.6 m x 0.4 m flag pinned along its pole (z axis), in a gusty wind along +x."""
    m = grid((0.6, 0.4), (n, max(2, round(n * 2 / 3))), origin=(0.0, 0.0, 1.0), plane="yz")
    pole = np.flatnonzero(np.isclose(m.points[:, 1], 0.0))

    def gust(x, t):
        w = np.zeros_like(x)
        w[:, 0] = wind_speed * (1.0 + 0.3 * np.sin(2 * np.pi * (1.5 * t - x[:, 1])))
        w[:, 1] = 0.5
        return w

    model = ClothModel(m, MATERIAL, mass_damping=0.2, handles=(Handle.pin(m.points, pole),))
    sc = ClothScene(model, gravity=GRAVITY, wind=Wind(gust, drag=1.0), collisions=_config(collisions, config),
                    smoothing=smoothing)
    return Setup("flag", sc, 1 / 100, 150, (), lambda t: [])


def fast_sphere(n: int = 24, *, collisions: bool = True, smoothing: float = 0.02, speed: float = 10.0,
                **config) -> Setup:
    """A 1 m cloth hanging from its two top corners, hit in the middle by a 0.15 m ball at ``speed`` [m/s]."""
    _, Sphere = _obstacle_types()
    m = grid((1.0, 1.0), (n, n), origin=(-0.5, 0.0, 0.3), plane="xz")
    corners = np.flatnonzero(np.isclose(m.points[:, 2], 1.3) & np.isclose(np.abs(m.points[:, 0]), 0.5))
    ball = Sphere(center=(0.0, -0.4, 0.8), radius=0.15, velocity=(0.0, speed, 0.0))
    obst = (ball,)
    model = ClothModel(m, MATERIAL, mass_damping=0.1, handles=(Handle.pin(m.points, corners),))
    sc = ClothScene(model, gravity=GRAVITY, collisions=_config(collisions, config),
                    obstacles=obst if collisions else (),
                    smoothing=smoothing)
    return Setup("fast sphere", sc, 1 / 400, 30, obst, _sphere_fn([ball]))


SCENES = {"drape": drape, "rotating_sphere": rotating_sphere, "twist": twist, "pile": pile, "flag": flag,
          "fast_sphere": fast_sphere}
