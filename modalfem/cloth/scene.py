"""A cloth scene: one ``ClothModel`` stepped with only the effects asked for.

Per step ``dt`` from state ``(x, v, t)``:

1. external forces: gravity ``m g`` (if ``gravity`` is given) and wind (if ``wind`` is given);
2. the implicit backward Euler velocity update (``ImplicitEuler.step_velocity``), handle vertices
   driven to their scripted position at ``t + dt``. With collisions, vertices resting on (or moving
   into) a plane or sphere obstacle (closer than twice the collision thickness) get their normal
   velocity prescribed to the obstacle's in the solve (Baraff-Witkin constraint filtering), so the
   cloth above feels the support inside the implicit step instead of compressing against vertices
   the pipeline stops afterwards; a constraint whose impulse held the vertex on (adhesion) is
   released for the next step. Constraints on triangle-mesh obstacles (a World's boxes) use the closest
   triangle. Their Coulomb friction (coefficient ``CollisionConfig.friction``) acts inside the same solve, as
   a tangential damping of each contact vertex towards its obstacle's surface velocity bounded by ``mu J``
   (``ImplicitEuler.step_velocity``'s ``friction``), so the sheet's stiffness shares it and it only removes
   energy. This is not collision handling: the pipeline
   still guarantees a collision-free step;
3. if ``collisions`` is given: ``CollisionPipeline.resolve`` (repulsion, CCD, impact zones; handle
   vertices have infinite mass there), then stage (d), the smoothing of the collision velocity
   change ``dv`` by ``(M + dt s K) dv_s = M dv`` (``smoothing`` = s [s], 0 to skip). Smoothing can
   move vertices the pipeline had made safe, so the smoothed velocities go through the pipeline once
   more and its answer is what is used (if that second call cannot resolve everything, the first,
   unsmoothed answer is kept): the step stays collision-free by the pipeline's guarantee, and
   smoothing only shapes the response;
4. ``x += dt v``, ``t += dt``.

Nothing runs that was not asked for: no gravity, no wind, no collisions by default.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from modalfem.cloth.model import ClothModel, non_finite
from modalfem.cloth.solver import ImplicitEuler, LinearSolveInfo
from modalfem.cloth.wind import PressureWind, Wind
from modalfem.errors import InputError, SimulationError

__all__ = ["ClothScene", "StepStats"]


@dataclass
class StepStats:
    """What one ``ClothScene.step`` did.

    Attributes:
        seconds: wall time [s] per stage: ``forces`` (gravity, wind), ``implicit`` (assembly and linear
            solve), ``collisions`` (first pipeline call), ``smoothing`` (solve and second pipeline call),
            ``total``.
        linear: the implicit step's ``LinearSolveInfo``.
        collision: the pipeline's ``CollisionStats`` of the first call (None without collisions).
        recheck: the ``CollisionStats`` of the call after smoothing (None if not run).
        smooth_iterations: CG iterations of the smoothing solve (0 if not run or not CG).
        collision_velocity_change: (n, 3) [m/s] the velocity change the collision handling (pipeline and
            smoothing) made to the implicit step's answer (None without collisions); ``m dv`` is the impulse
            the cloth received from contacts (a ``World`` gives it back to the bodies the cloth touched).
    """

    seconds: dict = field(default_factory=dict)
    linear: LinearSolveInfo | None = None
    collision: object | None = None
    recheck: object | None = None
    smooth_iterations: int = 0
    collision_velocity_change: np.ndarray | None = None


class ClothScene:
    """Cloth + optional gravity, wind, obstacles and collisions.

    Args:
        model: the cloth.
        gravity: acceleration (3,) [m/s^2], e.g. ``(0, 0, -9.81)``, or a ``modalfem.effects.Gravity``; None for none.
        wind: a ``Wind`` (linear drag D), or a ``modalfem.effects.Wind`` (pressure ``0.5 rho C |s| s``); None for
            none.
        collisions: a ``modalfem.collision.pipeline.CollisionConfig``; None for no collision handling.
        obstacles: kinematic obstacles for the pipeline (``modalfem.collision.obstacles``).
        smoothing: post-collision smoothing time s [s] (>= 0; 0 skips stage (d)).
        linear_solver: ``"cg"`` or ``"splu"`` (see ``ImplicitEuler``).
        x0: start positions (n, 3) [m] (default: the rest shape).
        v0: start velocities (n, 3) [m/s] (default: 0).
        strict_start: raise ``SceneError`` (instead of a warning) if the cloth starts in intersection.
        contact_constraints: with collisions, prescribe the normal velocity of vertices resting on
            plane/sphere obstacles in the implicit solve (see module docstring).

    Attributes:
        x, v, t: current positions [m], velocities [m/s], time [s].
        initial_intersections: intersecting pairs found at the start (0 without collisions).

    Raises:
        InputError: bad gravity, smoothing or start arrays.
        SceneError: starting intersection with ``strict_start``.
    """

    def __init__(
        self,
        model: ClothModel,
        *,
        gravity=None,
        wind: Wind | None = None,
        collisions=None,
        obstacles: Sequence = (),
        smoothing: float = 0.0,
        linear_solver: str = "cg",
        x0=None,
        v0=None,
        strict_start: bool = False,
        contact_constraints: bool = True,
    ):
        self.model = model
        n = model.mesh.point_count
        from modalfem import effects as fx

        if isinstance(gravity, fx.Gravity):  # the public effect, or a vector
            gravity = gravity.g
        if isinstance(wind, fx.Wind):
            wind = PressureWind(wind)
        self.gravity = None
        if gravity is not None:
            g = np.asarray(gravity, dtype=float)
            if g.shape != (3,) or not np.all(np.isfinite(g)):
                raise InputError(f"gravity must be 3 finite numbers [m/s^2], got {gravity!r}")
            self.gravity = g
        if wind is not None and not isinstance(wind, Wind):
            raise InputError(f"wind must be a modalfem.cloth.wind.Wind, got {type(wind).__name__}")
        self.wind = wind
        s = float(smoothing)
        if not np.isfinite(s) or s < 0:
            raise InputError(f"smoothing must be finite and >= 0 s, got {smoothing!r}")
        self.smoothing = s
        self.x = self._array("x0", model.mesh.points if x0 is None else x0, n)
        self.v = self._array("v0", np.zeros((n, 3)) if v0 is None else v0, n)
        self.t = 0.0
        self.solver = ImplicitEuler(model, linear_solver=linear_solver)
        self.pipeline = None
        self.initial_intersections = 0
        if collisions is not None:
            from modalfem.collision.pipeline import CollisionPipeline

            self.pipeline = CollisionPipeline(model.mesh.triangles, config=collisions, obstacles=obstacles)
            self.initial_intersections = self.pipeline.check_initial(self.x, t=self.t, strict=strict_start)
        elif len(obstacles):
            raise InputError("obstacles given without a collision config: pass collisions=CollisionConfig(...)")
        self.obstacles = tuple(obstacles)
        self.contact_constraints = bool(contact_constraints)
        self._released = np.zeros(n, bool)
        self._proximity = {}  # id(triangle mesh obstacle) -> its SurfaceProximity (contact constraints)
        self._pinned_masses = model.masses.copy()
        self._pinned_masses[model.handle_indices] = np.inf

    @staticmethod
    def _array(name: str, a, n: int) -> np.ndarray:
        try:
            a = np.array(a, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"{name} must be an ({n}, 3) array of numbers, got {type(a).__name__}") from None
        if a.shape != (n, 3):
            raise InputError(f"{name} must have shape ({n}, 3) (one row per cloth vertex), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InputError(f"{name} has {non_finite(a)}")
        return a

    def external_forces(self, x: np.ndarray, v: np.ndarray, t: float):
        """Gravity + wind forces (n, 3) [N] at state ``(x, v, t)`` and the wind damping blocks (or None)."""
        f = np.zeros_like(x)
        if self.gravity is not None:
            f += self.model.masses[:, None] * self.gravity
        blocks = None
        if self.wind is not None:
            fw, blocks = self.wind.forces(x, v, self.model.mesh.triangles, t)
            f += fw
        return f, blocks

    def contacts(self, x: np.ndarray, v: np.ndarray, t: float, dt: float):
        """Contact constraints for the implicit step, or None: ``(indices (k,), unit normals (k, 3), normal
        velocities (k,) [m/s], obstacle surface velocities (k, 3) [m/s])``, the velocities at ``t + dt``.

        A free vertex (not a handle, not released) is constrained when it lies within twice the collision
        thickness of an obstacle and rests on it or approaches it: planes and spheres by their signed distance,
        triangle meshes (``TriangleMeshObstacle``, e.g. a World's boxes) by the closest triangle, in front of
        it only (the triangle's normal side: a vertex behind an open mesh is the pipeline's to handle), the
        normal that triangle's and the surface velocity its material's at the closest point over the step."""
        if self.pipeline is None or not self.contact_constraints:
            return None
        h = self.pipeline.config.thickness
        free = ~self._released
        free[self.model.handle_indices] = False
        out = [], [], [], []
        for ob in self.obstacles:
            if all(hasattr(ob, a) for a in ("signed_distance", "normal_at", "velocity_at")):
                near = np.flatnonzero(free & (ob.signed_distance(x, t) < 2.0 * h))
                if not near.size:
                    continue
                nrm = ob.normal_at(x[near], t)
                vo = ob.velocity_at(x[near], t + dt)
            elif hasattr(ob, "triangles") and hasattr(ob, "positions"):
                near, nrm, vo = self._mesh_contacts(ob, x, free, t, dt, 2.0 * h)
                if not near.size:
                    continue
            else:
                continue
            un = np.sum(vo * nrm, axis=1)
            keep = np.sum(v[near] * nrm, axis=1) - un <= 0.1 * h / dt  # resting or approaching
            for a, b in zip(out, (near, nrm, un, vo)):
                a.append(b[keep])
            free[near[keep]] = False
        if not out[0]:
            return None
        return tuple(np.concatenate(a) for a in out)

    def _mesh_contacts(self, ob, x: np.ndarray, free: np.ndarray, t: float, dt: float, reach: float):
        """Free vertices within ``reach`` [m] in front of triangle mesh ``ob`` at ``t``: (indices, unit normals
        of their closest triangles, the velocity [m/s] of the closest points over ``[t, t + dt]``)."""
        from modalfem.world.proximity import SurfaceProximity

        V0 = ob.positions(t)
        prox = self._proximity.get(id(ob))
        if prox is None:
            prox = self._proximity[id(ob)] = SurfaceProximity(ob.triangles, V0)
        cand = np.flatnonzero(free)
        hits = prox.query(x[cand], V0, reach)
        front = hits.gap >= 0.0
        tri = ob.triangles[hits.triangle[front]]
        w = hits.bary[front]
        Vd = (ob.positions(t + dt) - V0) / dt
        vo = np.einsum("kj,kjd->kd", w, Vd[tri])
        return cand[hits.point[front]], hits.normal[front], vo

    def energy(self) -> dict:
        """Kinetic, elastic and gravitational (``-m g . x``) energies [J] now, and their total."""
        m = self.model.masses
        out = {
            "kinetic": float(0.5 * np.sum(m * np.sum(self.v**2, axis=1))),
            "elastic": self.model.elastic_energy(self.x),
            "gravity": 0.0 if self.gravity is None else float(-np.sum(m * (self.x @ self.gravity))),
        }
        out["total"] = sum(out.values())
        return out

    def implicit_velocity(self, dt: float, st: StepStats | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """Stages 1-2 of a step from the current state: the new velocities (n, 3) [m/s] of the implicit step
        (forces, handles, contact constraints and their friction) before collision handling, the contact
        constraints released by it (n,) bool, and the wall-clock time after the forces (for ``StepStats``).
        Nothing of the scene changes (a ``World`` runs its own collision stage on them)."""
        st = st if st is not None else StepStats()
        x, v, t = self.x, self.v, self.t
        f, blocks = self.external_forces(x, v, t)
        t1 = time.perf_counter()
        idx, pos = self.model.handle_targets(t + dt)
        vh = (pos - x[idx]) / dt
        con = self.contacts(x, v, t, dt)
        fric = None
        if con is not None and self.pipeline.config.friction > 0:  # v_eps: the contacts' resting speed
            fric = (self.pipeline.config.friction, con[3], 0.1 * self.pipeline.config.thickness / dt)
        v_new, st.linear = self.solver.step_velocity(x, v, f, dt, fixed=idx, fixed_velocity=vh, damping_blocks=blocks,
                                                     contacts=con, friction=fric)
        released = np.zeros_like(self._released)
        if con is not None:
            released[con[0][st.linear.contact_impulses < 0]] = True
        return v_new, released, t1

    def step(self, dt: float) -> StepStats:
        """Advance by ``dt`` [s]; returns ``StepStats``.

        The scene (x, v, t and the released contacts) changes only if the step succeeds.

        Raises:
            SimulationError: dt <= 0, non-finite state, a handle path that is not finite or has the wrong
                shape at t + dt (named), or collisions the pipeline left unresolved.
        """
        try:
            dt = float(dt)
        except (TypeError, ValueError):
            raise SimulationError(f"time step must be a number [s], got {dt!r}") from None
        if not (np.isfinite(dt) and dt > 0):
            raise SimulationError(f"time step must be finite and > 0 s, got {dt!r}")
        st = StepStats()
        t0 = time.perf_counter()
        x, t = self.x, self.t
        v_new, released, t1 = self.implicit_velocity(dt, st)
        idx = self.model.handle_targets(t + dt)[0]
        t2 = time.perf_counter()
        t3 = t4 = t2
        if self.pipeline is not None:
            v_col, st.collision = self.pipeline.resolve(x, v_new, self._pinned_masses, dt, t=t)
            last = st.collision
            t3 = time.perf_counter()
            if self.smoothing > 0 and st.collision.touched is not None and st.collision.touched.any():
                dv = self.solver.smooth(v_col - v_new, dt, strength=self.smoothing, fixed=idx)
                st.smooth_iterations = self.solver.smooth_iterations
                v_smooth, st.recheck = self.pipeline.resolve(x, v_new + dv, self._pinned_masses, dt, t=t)
                if not st.recheck.unresolved or st.collision.unresolved:
                    v_col, last = v_smooth, st.recheck  # else keep the unsmoothed, collision-free answer
            t4 = time.perf_counter()
            if last.unresolved:
                raise SimulationError(f"collision pipeline left {last.unresolved} colliding pairs at t = {t:.4g} s")
            st.collision_velocity_change = v_col - v_new
            v_new = v_col
        x_new = x + dt * v_new
        if not np.all(np.isfinite(x_new)):
            raise SimulationError(f"cloth positions became NaN/inf at t = {t + dt:.4g} s")
        # all-or-nothing: the scene changes only once the step has succeeded
        self.x, self.v, self.t = x_new, v_new, t + dt
        self._released = released
        t5 = time.perf_counter()
        st.seconds = {"forces": t1 - t0, "implicit": t2 - t1, "collisions": t3 - t2, "smoothing": t4 - t3,
                      "total": t5 - t0}
        return st
