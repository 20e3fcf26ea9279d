"""Contact cases of ``modalfem bench runtime``: modal bodies resting on the ground and a pile of bodies.

Real models, built once per run into a temporary folder (``build_models``) and loaded by the child
processes of ``runtime_bench`` (one core each):

* ``bar``: a free steel bar 0.4 x 0.1 x 0.1 m (box mesh 40 x 10 x 10, P1, 12 modes, scikit-fem + SciPy);
  its boundary surface (~1.8k vertices) rests flat on the ground on a 0.4 x 0.1 m face;
* ``tall``: a steel bar 0.1 x 0.1 x 0.3 m with 30 modes computed on a coarse P2 mesh (3 x 3 x 9 boxes)
  and carried to a fine render surface of ~50k vertices (``reduction.embed.carry_modes``); it stands
  on its 0.1 x 0.1 m end (~3.7k contacts);
* the pile: 20 bodies (small bars, tuning forks, bells from ``modalfem.mesh`` generators, 8 modes
  each) dropped into a box (ground and four walls as static obstacles), stepped by a ``world.World`` (its solid
  contact solve: ``world.modal_contacts`` and ``world._kernels``).

Every case times the free step of the same bodies (``ModalSolver.step`` without effects) in the same
process, so the contact cost is a ratio to it.
"""

from __future__ import annotations

import os
import time

import numpy as np

__all__ = ["build_models", "measure_pile", "measure_resting", "pile_world"]

BAR = {"size": (0.4, 0.1, 0.1), "cells": (40, 10, 10), "k": 12}
TALL = {"size": (0.1, 0.1, 0.3), "cells": (3, 3, 9), "k": 30, "h": 1.67e-3}
PILE_COUNT = 20
PILE_DT = 1e-3  # [s]
PILE_STEPS = 600
PILE_MARGIN = 2e-3  # [m] contact margin of the pile
PILE_SWEEPS = 10  # most sweeps of the pile's contact solve (what the former runtime.pairs.ContactGroup did)
GOALS = {"bar": 5000.0, "tall": 300.0, "pile": 200.0}  # steps/s


def _box_surface(size, h):
    """Closed triangulated surface of an axis-aligned box [0, size] with spacing ~h [m], outward triangles."""
    size = np.asarray(size, dtype=float)
    n = np.maximum(1, np.round(size / h).astype(int))
    pts, tris = [], []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        gu, gv = np.meshgrid(np.linspace(0, size[u], n[u] + 1), np.linspace(0, size[v], n[v] + 1), indexing="ij")
        for side in (0.0, size[axis]):
            p = np.zeros(gu.shape + (3,))
            p[..., u], p[..., v], p[..., axis] = gu, gv, side
            base = sum(len(q) for q in pts)
            idx = base + np.arange(gu.size).reshape(gu.shape)
            a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
            t = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
            pts.append(p.reshape(-1, 3))
            tris.append(t)
    x = np.concatenate(pts)
    t = np.concatenate(tris)
    key = np.round(x / (1e-6 * h)).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    x, t = x[first], inv.reshape(-1)[t]
    # outward: the normal points away from the box centre
    nrm = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
    flip = np.einsum("ij,ij->i", nrm, x[t].mean(axis=1) - 0.5 * size) < 0
    t[flip] = t[flip][:, [0, 2, 1]]
    return x, t


def build_models(folder: str) -> dict:
    """Compute the models of the contact cases into ``folder`` (``.npz`` model files); returns their paths."""
    import modalfem
    from modalfem.mesh import bell, box, tuning_fork
    from modalfem.mesh.surface import mass_properties
    from modalfem.model import ModalModel
    from modalfem.reduction.embed import carry_modes

    out = {}

    def modes(mesh, k, degree=1):
        return modalfem.modes(mesh, modalfem.STEEL, k=k, degree=degree, backend="skfem", solver="scipy")

    mesh = box(size=BAR["size"], cells=BAR["cells"])
    ModalModel.from_modes(modes(mesh, BAR["k"]), mesh, modalfem.STEEL, damping=(0.0, 1e-7),
                          rotation_coupling=False).save(os.path.join(folder, "bar.npz"))
    out["bar"] = os.path.join(folder, "bar.npz")
    mesh = box(size=TALL["size"], cells=TALL["cells"])
    res = modes(mesh, TALL["k"], degree=2)
    x, t = _box_surface(TALL["size"], TALL["h"])
    mp = mass_properties(mesh, modalfem.STEEL.rho)
    mat = {"name": "steel", "E": modalfem.STEEL.E, "nu": modalfem.STEEL.nu, "rho": modalfem.STEEL.rho}
    ModalModel(vertices=x, triangles=t, shapes=carry_modes(res, mesh, x), omega=np.asarray(res.omega), mass=mp.mass,
               center_of_mass=mp.center_of_mass, inertia=mp.inertia, material=mat, damping=(0.0, 1e-7),
               provenance={"source": "coarse P2 3x3x9 modes carried to a fine box surface"}).save(
        os.path.join(folder, "tall.npz"))
    out["tall"] = os.path.join(folder, "tall.npz")
    for name, mesh in (("small_bar", box(size=(0.12, 0.03, 0.02), cells=(8, 2, 2))),
                       ("fork", tuning_fork(h=0.003)), ("bell", bell(diameter=0.08, height=0.064, thickness=0.004,
                                                                     h=0.006))):
        ModalModel.from_modes(modes(mesh, 8), mesh, modalfem.STEEL, damping=(0.0, 1e-7),
                              rotation_coupling=False).save(os.path.join(folder, name + ".npz"))
        out[name] = os.path.join(folder, name + ".npz")
    return out


def _timeit(fn, *, repeats: int = 5, min_time: float = 0.2) -> tuple[float, float]:
    """Seconds per call of ``fn``: the medians over ``repeats`` rounds of wall time and of the process's CPU time
    (the CPU time holds up better on a shared machine: time spent waiting for a core is not counted)."""
    fn()
    t0 = time.perf_counter()
    fn()
    one = max(time.perf_counter() - t0, 1e-7)
    n = max(1, int(min_time / one))
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(n):
            fn()
        wall.append((time.perf_counter() - t0) / n)
        cpu.append((time.process_time() - c0) / n)
    return float(np.median(wall)), float(np.median(cpu))


def _profile(fn, n: int, top: int = 6) -> list:
    """cProfile of ``n`` calls of ``fn`` on the process's CPU clock (a wall clock charges the time the process
    waits for a core to whatever function was running): the ``top`` functions by own time, (name (file),
    seconds per call)."""
    import cProfile
    import pstats

    prof = cProfile.Profile(time.process_time)
    prof.enable()
    for _ in range(n):
        fn()
    prof.disable()
    stats = pstats.Stats(prof)
    return [(f"{f[2]} ({os.path.basename(f[0])})", float(v[2]) / n) for f, v in
            sorted(stats.stats.items(), key=lambda kv: -kv[1][2])[:top]]


def measure_resting(path: str, *, dt: float = 1e-3, settle: int = 300) -> dict:
    """A body resting on the ground: free step vs contact step (``ModalSolver.advance`` with gravity and the
    ground), after ``settle`` steps of settling; seconds per step, contact count."""
    import modalfem.runtime as rt

    load0 = os.getloadavg()[0]
    body = rt.load(path)
    free = rt.ModalSolver(body)
    fs = free.state(angular_velocity=(1.0, 2.0, 3.0))
    fs.qdot[:] = 1e-3
    t_free, c_free = _timeit(lambda: free.step(fs, fs, None, None, dt))
    solver = rt.ModalSolver(body, effects=[rt.Gravity(), rt.Obstacles([rt.Ground(0.0)])])
    st = solver.state()
    st.position[2] -= body.positions(st, precise=True)[:, 2].min()
    for _ in range(settle):
        solver.advance(st, dt)
    contacts = solver.collide(st, dt)
    t_contact, c_contact = _timeit(lambda: solver.advance(st, dt))
    top = _profile(lambda: solver.advance(st, dt), 50)
    gap = body.positions(st, precise=True)[:, 2].min()
    return {"nv": body.vertex_count, "r": body.mode_count, "contacts": int(contacts.count), "free": t_free,
            "contact": t_contact, "free_cpu": c_free, "contact_cpu": c_contact, "min_gap": float(gap), "profile": top,
            "load": [load0, os.getloadavg()[0]]}


def pile_world(paths: dict, *, count: int = PILE_COUNT):
    """The pile's ``World`` (``count`` bodies above a box of ground and four walls) and each body's model, in order."""
    from modalfem import world as mw
    from modalfem.effects import Contact, Gravity
    from modalfem.model import ModalModel
    from modalfem.runtime.rotation import quat_from_axis_angle

    kinds = ["small_bar", "fork", "bell"]
    models = {k: ModalModel.load(paths[k]) for k in kinds}
    rng = np.random.default_rng(1)
    bodies = []
    for i in range(count):
        axis = rng.normal(size=3)
        pos = (-0.12 + 0.12 * (i % 3), -0.06 + 0.12 * ((i // 3) % 2), 0.08 + 0.1 * (i // 6))
        bodies.append(mw.Modal(models[kinds[i % 3]], name=f"{kinds[i % 3]}{i}", position=pos,
                               orientation=quat_from_axis_angle(axis / np.linalg.norm(axis), rng.uniform(0, np.pi)),
                               velocity=0.2 * rng.normal(size=3)))
    walls = [mw.Ground(0.0), mw.Plane((1, 0, 0), (-0.25, 0, 0)), mw.Plane((-1, 0, 0), (0.25, 0, 0)),
             mw.Plane((0, 1, 0), (0, -0.2, 0)), mw.Plane((0, -1, 0), (0, 0.2, 0))]
    world = mw.World(bodies=bodies, obstacles=walls,
                     effects=[Gravity(), Contact(restitution=0.3, friction=0.4, margin=PILE_MARGIN,
                                                 iterations=PILE_SWEEPS)])
    return world, [models[kinds[i % 3]] for i in range(count)]


def measure_pile(paths: dict, *, count: int = PILE_COUNT, steps: int = PILE_STEPS, dt: float = PILE_DT) -> dict:
    """``count`` modal bodies dropped into a box (ground and four walls: static obstacles of a ``World``), ``steps``
    world steps: seconds per step (wall and CPU), largest contact counts, sweeps of the solve, intersecting triangle
    pairs at the end (the exact test), beside the free step of the same bodies (``ModalSolver.step`` without
    effects) in the same process. Momentum of every body-body impulse and the no-energy-gain rule are tested in
    tests/world/test_modal_contacts.py, not here."""
    import modalfem.runtime as rt

    load0 = os.getloadavg()[0]
    world, pile_models = pile_world(paths, count=count)
    state = world.state()
    free = [rt.ModalSolver(rt.ModalBody(m, dtype=np.float64)) for m in pile_models]
    fst = [f.state() for f in free]
    for f, st, b in zip(free, fst, state.bodies.values()):
        st.assign(b)

    def free_step():
        for f, st in zip(free, fst):
            f.step(st, st, None, None, dt)

    t_free, c_free = _timeit(free_step)
    # the whole run once, untimed, on a second world of the same pile: every kernel the run reaches is compiled (or
    # loaded from numba's disk cache) before the timing (the coherent search's partial re-walks first run ~100 steps
    # in: with one warm-up step, a fresh clone's first run compiled them inside the timed loop and read 25 steps/s
    # for ~100)
    warm, _ = pile_world(paths, count=count)
    warm_state = warm.state()
    for _ in range(steps):
        warm.step(warm_state, warm_state, None, dt)
    contacts = pair_contacts = 0
    sweeps = []
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        rep = world.step(state, state, None, dt)
        contacts = max(contacts, rep.contacts.get("solid", 0))
        pair_contacts = max(pair_contacts, len(rep.exchanged))
        sweeps.append(rep.sweeps)
    elapsed = (time.perf_counter() - t0) / steps
    elapsed_cpu = (time.process_time() - c0) / steps
    top = _profile(lambda: world.step(state, state, None, dt), 20)
    heights = [float(st.position[2]) for st in state.bodies.values()]
    return {"count": count, "steps": steps, "dt": dt, "step": elapsed, "free": t_free, "step_cpu": elapsed_cpu,
            "free_cpu": c_free, "contacts": contacts, "pair_contacts": pair_contacts,
            "sweeps": [float(np.mean(sweeps)), int(np.max(sweeps)), PILE_SWEEPS],
            "intersections": sum(k for _, _, k in world.intersections(state)), "max_height": max(heights),
            "vertices": int(sum(world._modal[n]["body"].vertex_count for n in state.bodies)), "profile": top,
            "load": [load0, os.getloadavg()[0]]}
