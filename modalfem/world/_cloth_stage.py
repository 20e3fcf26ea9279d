"""The cloth stages of ``World`` (a mixin): the cloth bodies' build and implicit step, and the one collision
pipeline over the deformable surfaces with the solids as moving triangle meshes, whose impulses act back on them
(see ``modalfem.world.world``)."""

from __future__ import annotations

import numpy as np

from modalfem import effects as fx
from modalfem.cloth.wind import PressureWind
from modalfem.errors import InputError, SimulationError
from modalfem.world._shared import _vertex
from modalfem.world.bodies import Cloth, ClothState
from modalfem.world.obstacles import Plane, Sphere


class _Motion:
    """A solid's surface between two instants, linear in time (the cloth pipeline's moving obstacle)."""

    def __init__(self, x: np.ndarray) -> None:
        self.t0, self.t1 = 0.0, 1.0
        self.x0 = self.x1 = x

    def set(self, t0: float, x0: np.ndarray, t1: float, x1: np.ndarray) -> None:
        self.t0, self.x0, self.t1, self.x1 = t0, x0, t1, x1

    def __call__(self, t: float) -> np.ndarray:
        if self.t1 <= self.t0:
            return self.x1
        s = min(max((t - self.t0) / (self.t1 - self.t0), 0.0), 1.0)
        return (1.0 - s) * self.x0 + s * self.x1


class _ClothStage:
    """``World``'s cloth stage methods (they read the world's build: ``_cloth``, ``_deform`` ...)."""

    def _build_cloth(self, b: Cloth, eff: list) -> dict:
        import dataclasses

        from modalfem.cloth.scene import ClothScene
        from modalfem.collision import obstacles as co
        from modalfem.collision.pipeline import CollisionConfig

        model = b.model
        names = []
        g = None
        wind = None
        for e in eff:
            if isinstance(e, fx.Gravity):
                g = np.asarray(e.g) if g is None else g + np.asarray(e.g)
            elif isinstance(e, fx.Wind):
                if wind is not None:
                    raise InputError(f"cloth {b.name!r} has two wind effects: give at most one per cloth")
                wind = PressureWind(e)
            elif isinstance(e, fx.Damping):
                model = dataclasses.replace(model, mass_damping=e.alpha, stiffness_damping=e.beta)
            else:
                continue
            names.append(e.name)
        contact = self._one(b.name, fx.Contact)
        config, analytic = None, []
        if contact is not None:  # the constraint filtering of the implicit step on static obstacles
            config = CollisionConfig(thickness=self._thickness(b.name), friction=contact.friction,
                                     self_collision=False)
            for o in self.obstacles:
                if isinstance(o, Plane) and not o.moving:
                    analytic.append(co.Plane(o.point, o.normal))
                elif isinstance(o, Sphere) and not o.moving:
                    analytic.append(co.Sphere(o.center, o.radius))
                elif not o.moving:  # boxes and triangle meshes: by their closest triangle
                    analytic.append(co.TriangleMeshObstacle(*o.surface(0.0)))
        x0 = b.x0 if b.x0 is not None else model.mesh.points
        scene = ClothScene(model, gravity=g, wind=wind, collisions=config, obstacles=analytic,
                           smoothing=0.0, linear_solver=b.linear_solver, x0=x0, v0=b.v0)
        masses = model.masses.copy()
        masses[model.handle_indices] = np.inf
        # the start state (``World.state``): the scene's positions change with every step
        start = ClothState(scene.x.copy(), scene.v.copy(), scene._released.copy())
        return {"scene": scene, "effects": tuple(names), "masses": masses, "start": start}

    def _thickness(self, name: str) -> float:
        sc, c = self._one(name, fx.SelfCollision), self._one(name, fx.Contact)
        if sc is not None and sc.thickness is not None:
            return sc.thickness
        return c.thickness if c is not None else 2e-3

    def _build_deformable(self) -> None:
        """One collision pipeline over every tet surface and cloth with contact or self-collision; obstacles
        and modal surfaces (with contact) as triangle meshes moving over each step."""
        from modalfem.collision import obstacles as co
        from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline

        members = [n for n in self._cloth if self._one(n, fx.Contact) or self._one(n, fx.SelfCollision)]
        self._deform = None
        if not members:
            return
        tris, offs, masses = [], {}, []
        n = 0
        for name in members:
            c = self._cloth[name]
            tris.append(np.asarray(c["scene"].model.mesh.triangles, dtype=np.int64) + n)
            masses.append(c["masses"])
            k = len(c["masses"])
            offs[name] = (n, k)
            n += k
        touching = [m for m in members if self._one(m, fx.Contact)]
        lacking = [m for m in touching if not self._one(m, fx.SelfCollision)]
        if len(touching) > 1 and lacking:
            # one pipeline over the cloths: contact between them is its self-collision test, which also tests each
            # cloth against itself; a world does what it is asked, so say so instead of switching it on unasked
            raise InputError(f"cloths {', '.join(touching)} touch each other, which the collision pipeline tests as "
                             f"one surface (each cloth against itself too): add self-collision for "
                             f"{', '.join(lacking)}, or contact on one cloth only")
        selfc = any(self._one(m, fx.SelfCollision) for m in members) or len(touching) > 1
        obstacles, motions = [], {}
        if touching:
            for o in self.obstacles:
                if isinstance(o, Plane) and not o.moving:
                    obstacles.append(co.Plane(o.point, o.normal))
                elif isinstance(o, Sphere) and not o.moving:
                    obstacles.append(co.Sphere(o.center, o.radius))
                else:
                    V, F = o.surface(0.0)
                    obstacles.append(co.TriangleMeshObstacle(V, F, motion=_ObstacleMotion(o) if o.moving else None))
            for m in self._modal_contact:
                body = self._modal[m]["body"]
                mot = _Motion(body.rest)
                motions[m] = mot
                obstacles.append(co.TriangleMeshObstacle(body.rest, body.triangles, motion=mot))
            for m, t in self._tet.items():
                if t["contact"] is not None:
                    x = self.by_name[m].model.rest_points[t["surface"]]
                    mot = _Motion(x)
                    motions[m] = mot
                    obstacles.append(co.TriangleMeshObstacle(x, t["triangles"], motion=mot))
        h = min(self._thickness(m) for m in members)
        frictions = [self._one(m, fx.Contact).friction for m in touching]
        config = CollisionConfig(thickness=h, friction=float(np.mean(frictions)) if frictions else 0.0,
                                 self_collision=selfc)
        self._deform = {"members": members, "offsets": offs, "masses": np.concatenate(masses),
                        "pipeline": CollisionPipeline(np.concatenate(tris), config=config, obstacles=obstacles,
                                                      n_vertices=n),
                        "motions": motions, "thickness": h}

    def _stage_cloth_step(self, ctx) -> None:
        dt = ctx.dt
        for name, c in self._cloth.items():
            sc = c["scene"]
            s = ctx.state_in.bodies[name]
            sc.x, sc.v, sc.t, sc._released = s.x.copy(), s.v.copy(), ctx.state_in.time, s.released.copy()
            for p, J in self._strikes(ctx, name):
                i = _vertex(name, p, len(sc.x))
                if np.isfinite(c["masses"][i]):
                    sc.v[i] += J / c["masses"][i]
            try:
                v_new, released, _ = sc.implicit_velocity(dt)
            except SimulationError as exc:
                raise SimulationError(f"cloth {name!r}: {exc}") from None
            ctx.start[name] = ClothState(sc.x.copy(), sc.v.copy(), s.released)
            ctx.out.bodies[name] = ClothState(sc.x + dt * v_new, v_new, released)
            ctx.done.add(name)

    def _stage_deformable(self, ctx) -> None:
        d = self._deform
        dt, t0 = ctx.dt, ctx.state_in.time
        for n, mot in d["motions"].items():  # solid surfaces from their start to their (final) end positions
            if n in self._modal:
                body = self._modal[n]["body"]
                x0 = body.positions(ctx.state_in.bodies[n], precise=True).copy()
                x1 = body.positions(ctx.out.bodies[n], precise=True).copy()
            else:
                sv = self._tet[n]["surface"]
                x0, x1 = ctx.start[n].x[sv].copy(), ctx.out.bodies[n].x[sv].copy()
            mot.set(t0, x0, t0 + dt, x1)
        x0 = np.concatenate([ctx.start[m].x for m in d["members"]])
        v = np.concatenate([ctx.out.bodies[m].v for m in d["members"]])
        v_new, stats = d["pipeline"].resolve(x0, v, d["masses"], dt, t=t0)
        if stats.unresolved:
            raise SimulationError(f"the collision pipeline left {stats.unresolved} colliding pairs at t = {t0:.4g} s "
                                  f"(cloth {', '.join(d['members'])})")
        v_new, stats = self._smoothed(x0, v, v_new, stats, dt, t0)
        dv = v_new - v
        ctx.report.contacts["cloth"] = int(stats.touched.sum()) if stats.touched is not None else 0
        for name in d["members"]:
            o, k = d["offsets"][name]
            out = ctx.out.bodies[name]
            out.v = v_new[o:o + k].copy()
            out.x = ctx.start[name].x + dt * out.v
            if not np.all(np.isfinite(out.x)):
                raise SimulationError(f"cloth {name!r}: positions became NaN/inf at t = {t0 + dt:.4g} s")
        if d["motions"]:
            self._reaction(ctx, x0 + dt * v_new, dv)

    def _smoothed(self, x0: np.ndarray, v: np.ndarray, v_col: np.ndarray, stats, dt: float, t0: float):
        """The pipeline's velocity change ``v_col - v`` of each cloth smoothed over its sheet, ``(M + dt s K) dv_s =
        M dv`` (its ``smoothing`` s [s], as ``ClothScene`` stage (d)), and the smoothed velocities put through the
        pipeline again; ``(velocities, stats)`` of that re-check when it resolved everything, else ``(v_col,
        stats)`` unchanged. The pipeline's impulses act on single vertices: a vertex stopped by a sheet landing
        on it moves dt |dv| (~1 cm at 1 m/s and dt = 10 ms) against its neighbours, and that strain was stored
        as elastic energy (the second sheet of cloth-pile landing: +20 % of the scene's energy in one step, of
        which +0.042 J elastic in the sheet it hit)."""
        d = self._deform
        if stats.touched is None or not stats.touched.any():
            return v_col, stats
        dv = v_col - v
        smooth = dv.copy()
        done = False
        for name in d["members"]:
            s = self.by_name[name].smoothing
            o, k = d["offsets"][name]
            if s > 0.0 and np.any(dv[o:o + k]):
                sc = self._cloth[name]["scene"]  # its solver holds the stiffness of this step's implicit solve
                smooth[o:o + k] = sc.solver.smooth(dv[o:o + k], dt, strength=s, fixed=sc.model.handle_indices)
                done = True
        if not done:
            return v_col, stats
        v_s, again = d["pipeline"].resolve(x0, v + smooth, d["masses"], dt, t=t0)
        return (v_s, again) if not again.unresolved else (v_col, stats)

    def _reaction(self, ctx, x1: np.ndarray, dv: np.ndarray) -> None:
        """Give the solid bodies back the momentum the pipeline gave the cloth vertices next to them: equal and
        opposite impulses at the closest points of their end surfaces (a modal body's rigid motion only: the
        pipeline saw its vibrating surface at the step's two ends, and feeding impulses into modes faster than
        the step pumps energy between the aliased vibration and the cloth). Each moved vertex kicks the body whose
        surface is closest (ties: the first body), in the order of the first body each vertex is near, then by
        vertex; every sum runs in that order."""
        d = self._deform
        moved = np.flatnonzero(np.any(dv != 0.0, axis=1) & np.isfinite(d["masses"]))
        ctx.report.contacts["reaction"] = 0
        if not len(moved):
            return
        reach = 2.0 * d["thickness"]
        names = list(d["motions"])
        hits = []  # per body: (vertex (k,), body (k,), |gap| (k,), triangle (k, 3), weights (k, 3), point (k, 3))
        for b, n in enumerate(names):
            xs = self._surface_now(ctx, n)
            prox = self._surf[n] if n in self._modal else self._tet[n]["proximity"]
            tri_all = self._modal[n]["body"].triangles if n in self._modal else self._tet[n]["triangles"]
            h = prox.query(x1[moved], xs, reach)
            T = tri_all[h.triangle]
            hits.append((h.point, np.full(len(h.point), b), np.abs(h.gap), T, h.bary,
                         np.einsum("kj,kjd->kd", h.bary, xs[T])))
        i, body, gap, tri, w, pt = (np.concatenate(a) for a in zip(*hits))
        if not len(i):
            return
        # the closest body of each vertex (ties: the first), in the order (first body near it, vertex)
        order = np.lexsort((body, gap, i))
        win = order[np.r_[True, i[order][1:] != i[order][:-1]]]  # by vertex
        first = np.minimum.reduceat(body[order], np.flatnonzero(np.r_[True, i[order][1:] != i[order][:-1]]))
        win = win[np.lexsort((i[win], first))]
        i, body, tri, w, pt = i[win], body[win], tri[win], w[win], pt[win]
        v = moved[i]
        J = -d["masses"][v][:, None] * dv[v]  # what each solid receives
        src = np.zeros(len(v), np.int64)
        members = list(d["members"])
        for m, name in enumerate(members):
            o, k = d["offsets"][name]
            src[(v >= o) & (v < o + k)] = m
        for b in np.unique(body):
            sel = np.flatnonzero(body == b)
            self._kicks(ctx, names[b], tri[sel], w[sel], pt[sel], J[sel])
        key = body * len(members) + src
        _, at = np.unique(key, return_index=True)
        L = np.cross(pt, J)
        for k in key[np.sort(at)]:
            sel = np.flatnonzero(key == k)
            Js = np.cumsum(np.concatenate([np.zeros((1, 3)), J[sel]]), axis=0)[-1]
            Ls = np.cumsum(np.concatenate([np.zeros((1, 3)), L[sel]]), axis=0)[-1]
            ctx.report.exchanged.append((names[k // len(members)], members[k % len(members)], Js, Ls))
        ctx.report.contacts["reaction"] = len(v)

    def _kicks(self, ctx, other: str, tri: np.ndarray, w: np.ndarray, pt: np.ndarray, J: np.ndarray) -> None:
        """Impulses ``J`` (k, 3) [N s] on solid body ``other`` at its surface points ``pt`` (k, 3) [m] (triangles
        ``tri`` (k, 3) of its surface, weights ``w`` (k, 3)), at its step end, added in order: a modal body's rigid
        motion, a tet body's vertices by their weights."""
        if other in self._modal:
            st = ctx.out.bodies[other]
            mass = self._modal[other]["body"].mass
            st.velocity[...] = np.cumsum(np.concatenate([st.velocity[None], J / mass]), axis=0)[-1]
            st.angular_momentum[...] = np.cumsum(np.concatenate([st.angular_momentum[None],
                                                                 np.cross(pt - st.position, J)]), axis=0)[-1]
            return
        t = self._tet[other]
        vid = t["surface"][tri]  # surface-local -> mesh vertex ids (k, 3)
        m = t["masses"][vid]
        ok = np.isfinite(m)
        dv = np.where(ok, 1.0, 0.0)[:, :, None] * (w / np.where(ok, m, 1.0))[:, :, None] * J[:, None, :]
        np.add.at(ctx.out.bodies[other].v, vid.reshape(-1), dv.reshape(-1, 3))


class _ObstacleMotion:
    """A moving obstacle's surface positions over time (the cloth pipeline's ``motion``)."""

    def __init__(self, o) -> None:
        self.o = o

    def __call__(self, t: float) -> np.ndarray:
        return self.o.surface(t)[0]
