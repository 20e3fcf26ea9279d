"""A validated ``Scene`` -> a ``modalfem.world.World``: meshes, materials, models (modes cached), obstacles,
effects and the events of each step.

Modal bodies given as mesh + material + modes get their modes computed on the first run
(``modalfem.modes``) and stored in the model cache under the SHA-256 of everything that determines them
(mesh points and cells, material, mode count, degree, damping, model format): the next run, or another
scene with the same body, loads the file instead. The cache is ``$MODALFEM_CACHE`` or
``~/.cache/modalfem/models``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from modalfem.errors import ModalfemError, SceneError

__all__ = ["BuiltScene", "build_scene", "cache_dir"]


def cache_dir() -> Path:
    """Where computed modal models are cached: ``$MODALFEM_CACHE`` or ``~/.cache/modalfem/models``."""
    env = os.environ.get("MODALFEM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "modalfem" / "models"


@dataclass
class BuiltScene:
    """A scene made real: the world, its start state and what happens when.

    Attributes:
        world: the ``World``.
        state: its state at t = 0.
        strikes: ``(time [s], body, surface vertex, impulse (3,) [N s])``, by time.
        steps: steps to run; frame_every: steps per output frame; dt: step [s].
        cached: body name -> "computed" | "cache" | "file" (where each modal model came from).
    """

    scene: object
    world: object
    state: object
    strikes: list
    steps: int
    frame_every: int
    dt: float
    cached: dict = field(default_factory=dict)


def build_scene(scene, base: Path, *, label: str = "scene", progress=None, check_start: bool = True) -> BuiltScene:
    """Build the world of ``scene`` (files relative to ``base``); ``progress(msg)`` hears the long steps.

    Raises:
        SceneError: a file that cannot be read as what it should be, a body a kind cannot take, bodies that
            overlap each other or an obstacle at t = 0 (each with the key path).
    """
    from modalfem import effects as fx
    from modalfem import world as mw

    say = progress or (lambda msg: None)

    def fail(where: str, problem: str):
        raise SceneError(f"{label}: {where}: {problem}")

    bodies, cached = [], {}
    for i, b in enumerate(scene.bodies):
        where = f"bodies[{i}]"
        try:
            if b.kind == "modal":
                model, cached[b.name] = _modal_model(b, base, say)
                com = np.asarray(model.center_of_mass, dtype=np.float64)
                shift = np.zeros(3) if b.position is None else np.asarray(b.position, dtype=np.float64)
                bodies.append(mw.Modal(model, name=b.name, position=com + shift, orientation=b.orientation,
                                       velocity=b.velocity, angular_velocity=b.angular_velocity))
            elif b.kind == "tet":
                from modalfem import tet

                mesh = _solid_mesh(b.mesh, base, say, b.name)
                if b.orientation is not None:
                    mesh = dataclasses.replace(mesh, points=_rotated(mesh.points, b.orientation))
                model = tet.tet_model(mesh, _material(b.material), energy=b.energy)
                bodies.append(mw.Tet(model, name=b.name, position=b.position, velocity=b.velocity))
            else:
                model = _cloth_model(b, base)
                x0 = model.mesh.points + (np.asarray(b.position) if b.position is not None else 0.0)
                v0 = None if b.velocity is None else np.tile(np.asarray(b.velocity, float), (model.mesh.point_count, 1))
                bodies.append(mw.Cloth(model, name=b.name, x0=x0, v0=v0))
        except ModalfemError as exc:
            fail(where, _first_line(exc))
    obstacles = []
    for i, o in enumerate(scene.obstacles):
        try:
            obstacles.append(_obstacle(o, base))
        except ModalfemError as exc:
            fail(f"obstacles[{i}]", _first_line(exc))
    gusts = [e for e in scene.events if e.kind == "gust"]
    effects = []
    for i, e in enumerate(scene.effects):
        kw = {k: v for k, v in e.model_dump().items() if k != "kind"}
        try:
            if e.kind == "wind" and gusts:
                kw["velocity"] = _gusty(np.asarray(e.velocity, float), gusts)
            effects.append(fx.EFFECTS[e.kind](**kw))
        except ModalfemError as exc:
            fail(f"effects[{i}]", _first_line(exc))
    # warnings of the world's construction (e.g. the cloth pipeline's "starts in intersection") are held until
    # the start check passed: a scene it refuses gets its one error line, not a warning line before it
    with warnings.catch_warnings(record=True) as held:
        try:
            world = mw.World(bodies=bodies, obstacles=obstacles, effects=effects)
        except ModalfemError as exc:
            raise SceneError(f"{label}: {_first_line(exc)}") from None
    state = world.state()
    names = [b.name for b in scene.bodies]
    if check_start:
        _check_start(world, state, scene, names, fail)
    for w in held:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    strikes = []
    for i, ev in enumerate(scene.events):
        if ev.kind == "strike":
            model = world.by_name[ev.body].model
            d = np.linalg.norm(model.vertices - np.asarray(ev.point), axis=1)
            strikes.append((ev.time, ev.body, int(np.argmin(d)), np.asarray(ev.impulse, float)))
    strikes.sort(key=lambda s: s[0])
    t = scene.time
    steps = max(1, round(t.duration / t.dt))
    frame_every = max(1, round(1.0 / (t.frame_rate * t.dt)))
    return BuiltScene(scene, world, state, strikes, steps, frame_every, t.dt, cached)


def _first_line(exc: BaseException) -> str:
    s = str(exc)
    return s.splitlines()[0] if s else type(exc).__name__


def _path(base: Path, name: str) -> Path:
    p = Path(name)
    return p if p.is_absolute() else base / p


def _material(m):
    from modalfem.material import MATERIALS, Material

    if isinstance(m, str):
        return MATERIALS[m]
    return Material(E=m.E, nu=m.nu, rho=m.rho)


def _solid_mesh(spec, base: Path, say, name: str):
    from modalfem.mesh import generators as gen

    if hasattr(spec, "file"):
        from modalfem.mesh.solid import is_surface_file

        p = _path(base, spec.file)
        if is_surface_file(p):
            from modalfem.mesh.solid import from_surface

            say(f"tetrahedralising {p.name} for {name!r}")
            return from_surface(p, h=spec.h, unit_scale=spec.unit_scale).mesh
        from modalfem.mesh.io import read

        return read(p, unit_scale=spec.unit_scale)
    kw = {k: v for k, v in spec.model_dump().items() if k != "generator"}
    if spec.generator in ("box", "plate"):
        kw = {"size": tuple(kw["size"]), "cells": tuple(kw["cells"])}
    if spec.generator != "box" and spec.generator != "plate":
        say(f"meshing a {spec.generator} for {name!r} (gmsh)")
    return getattr(gen, spec.generator)(**{k: v for k, v in kw.items() if v is not None})


def _modal_model(b, base: Path, say):
    from modalfem.model import ModalModel

    if b.model is not None:
        return ModalModel.load(_path(base, b.model)), "file"
    mesh = _solid_mesh(b.mesh, base, say, b.name)
    material = _material(b.material)
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.points, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.cells, dtype=np.int64).tobytes())
    h.update(json.dumps({"E": material.E, "nu": material.nu, "rho": material.rho, "k": b.modes,
                         "degree": b.degree, "damping": list(b.damping), "format": _model_format()},
                        sort_keys=True).encode())
    key = h.hexdigest()[:32]
    path = cache_dir() / f"{key}.npz"
    if path.is_file():
        try:
            return ModalModel.load(path), "cache"
        except ModalfemError:
            pass  # a damaged cache entry is recomputed and replaced
    import modalfem

    say(f"computing {b.modes} modes of {b.name!r} ({mesh.point_count} points; cached after)")
    res = modalfem.modes(mesh, material, k=b.modes, degree=b.degree)
    model = ModalModel.from_modes(res, mesh, material, damping=tuple(b.damping))
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path)
    return model, "computed"


def _model_format() -> str:
    from modalfem.model import ModalModel

    return f"modal-model/{ModalModel.SCHEMA_VERSION}"


def _cloth_model(b, base: Path):
    from modalfem.cloth.mesh import grid, read_cloth
    from modalfem.cloth.model import ClothMaterial, ClothModel, Handle

    if b.grid is not None:
        g = b.grid
        mesh = grid(tuple(g.size), tuple(g.vertices), origin=tuple(g.origin), plane=g.plane)
    else:
        mesh = read_cloth(_path(base, b.mesh), unit_scale=b.unit_scale)
    if b.orientation is not None:
        mesh = dataclasses.replace(mesh, points=_rotated(mesh.points, b.orientation))
    m = b.material
    material = ClothMaterial(areal_density=m.areal_density, young=m.young, poisson=m.poisson,
                             thickness=m.thickness, bending_stiffness=m.bending_stiffness)
    handles = ()
    if b.pins:
        p = mesh.points
        ext = p.max(0) - p.min(0)
        tol = 1e-9 * max(float(ext.max()), 1e-12)
        sel = np.zeros(len(p), bool)
        for side in b.pins:
            axis = "xyz".index(side[1])
            if ext[axis] <= tol:
                raise SceneError(f"pins: the sheet is flat along {side[1]}, so side {side!r} is every vertex")
            v = p[:, axis]
            sel |= (v <= v.min() + tol) if side[0] == "-" else (v >= v.max() - tol)
        idx = np.flatnonzero(sel)
        shift = np.asarray(b.position, float) if b.position is not None else np.zeros(3)
        rest = p[idx] + shift
        handles = (Handle(idx, lambda t, rest=rest: rest),)
    return ClothModel(mesh, material, mass_damping=b.mass_damping, stiffness_damping=b.stiffness_damping,
                      handles=handles)


def _obstacle(o, base: Path):
    from modalfem import world as mw

    path = None if getattr(o, "path", None) is None else [(w.t, tuple(w.offset)) for w in o.path]
    if o.kind == "ground":
        return mw.Ground(o.height, size=o.size)
    if o.kind == "plane":
        return mw.Plane(o.normal, o.point, path=path, size=o.size)
    if o.kind == "sphere":
        return mw.Sphere(o.center, o.radius, path=path)
    if o.kind == "box":
        return mw.Box(o.center, o.half_extents, path=path,
                      rotation=None if o.rotation is None else _matrix(o.rotation))
    from modalfem.mesh.surface_read import read_surface

    v, f = read_surface(_path(base, o.file), unit_scale=o.unit_scale)
    return mw.TriangleMesh(v + np.asarray(o.offset), f, path=path)


def _matrix(q) -> np.ndarray:
    from modalfem.runtime.rotation import quat_to_matrix

    q = np.asarray(q, dtype=np.float64)
    return quat_to_matrix(q / np.linalg.norm(q))


def _rotated(points: np.ndarray, q) -> np.ndarray:
    """``points`` rotated by quaternion ``q`` about their mean."""
    c = points.mean(axis=0)
    return (points - c) @ _matrix(q).T + c


def _gusty(base_velocity: np.ndarray, gusts: list):
    """A wind field ``(x, t) -> (k, 3)`` [m/s]: the steady wind plus 1 - cos pulses."""
    pulses = [(g.start, g.duration, np.asarray(g.velocity, float)) for g in gusts]

    def velocity(x, t):
        w = base_velocity.copy()
        for start, length, peak in pulses:
            s = (t - start) / length
            if 0.0 < s < 1.0:
                w = w + peak * 0.5 * (1.0 - math.cos(2.0 * math.pi * s))
        return np.broadcast_to(w, np.shape(x))

    return velocity


def _check_start(world, state, scene, names: list, fail) -> None:
    """Bodies may not overlap each other (exact triangle test) or start inside an obstacle."""
    for a, b, k in world.intersections(state):
        fail(f"bodies[{names.index(b)}]", f"{b!r} overlaps {a!r} at t = 0 ({k} crossing triangle pairs): move one")
    for i, name in enumerate(names):
        x, _ = world.surface(state, name)
        size = float(np.max(x.max(0) - x.min(0)))
        for j, o in enumerate(world.obstacles):
            d, _ = o.signed_distance(x, 0.0)
            deepest = float(-np.min(d))
            if deepest > 1e-6 * size:
                fail(f"bodies[{i}]", f"{name!r} starts {deepest * 1e3:.3g} mm inside obstacles[{j}] "
                                     f"({scene.obstacles[j].kind}) at t = 0: move it")
