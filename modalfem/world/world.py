"""``World``: modal, tet and cloth bodies, obstacles and effects advanced together by ``step``.

Contract (as Newton/Warp): the world and its bodies' models are fixed; a ``WorldState`` changes; a
``WorldControl`` holds the inputs of one step; ``world.step(state_in, state_out, control, dt)``.

The step plan is compiled once from the bodies and effects (``world.plan``), so a stage that was not asked
for is never called. In order:

1. ``tet step``: each tet body's implicit step (backward Euler with its gravity, wind, damping, pins and
   scripted vertices) to a predicted end state, with its contacts as penalty terms of the step: the obstacles,
   and the modal bodies' surfaces as moving obstacles at their free step end, whose rigid displacement by the
   reaction is solved in the same step (``tetcontact``: 6 unknowns per touched body, eliminated exactly), so the
   tet's elasticity, these contacts and the modal bodies' rigid motion are solved together at any dt; the modal
   bodies take the reaction (equal and opposite impulses at the contact points, given at their step start), and
   restitution between the pair as a Poisson impulse at the end of compression (``_tet_restitution``). Tet
   bodies that may touch in the step (boxes within reach) take one implicit step together (``tetgroup``): their
   contacts with each other are penalty terms over both bodies' vertices with weights summing to zero, and their
   friction a lagged potential of that step;
2. ``cloth step``: each cloth's implicit step (gravity, wind, damping, handles, constraint filtering on
   static planes, spheres, boxes and triangle meshes) to predicted velocities;
3. ``modal contacts``: one compiled sequential-impulse solve (``modalfem.world._kernels``) over the contacts
   of modal bodies' surface vertices with moving obstacles, triangle-mesh obstacles and the other modal
   bodies' surfaces, found at the step start within the margin plus what the bodies travel in the step
   (speculative contacts: a contact ``g`` [m] apart may approach by ``g / dt``, so nothing tunnels at any
   dt). Equal and opposite impulses act on both bodies' rigid and modal velocities (``J W J^T``, O(6 + r)
   work per contact and sweep, no contacts x contacts matrix). With a single solid body in contact, the static
   ground, planes, spheres and boxes are left to the modal runtime's own contact (impacts at their predicted
   time, sustained contact, friction stops: ``runtime.contact``); with two or more, every obstacle is in this
   solve, so a body pressed between another body and the ground meets both at once;
4. ``modal step``: each modal body's exact step (its gravity, wind, pseudo-forces, static obstacles);
5. ``deformable collisions``: one collision pipeline (repulsion, CCD, impact zones: zero false negatives)
   over the surfaces of every tet and cloth body that has contact or self-collision, with the obstacles and
   the modal bodies' surfaces as moving triangle meshes (from their start to their end positions), so no
   deformable surface crosses another surface, itself or an obstacle in the step. The momentum the
   pipeline gave the deformable vertices next to a modal body is given back to that body (equal and
   opposite impulses at the closest surface points: ``StepReport.exchanged``);
6. ``sound``: the impacts of sounding modal bodies are recorded (``world.sound(name)``).

Where the stages live (``World`` mixes them in): ``_tet_stage`` (1, and tet self-collision; its contacts in
``_tet_contacts``, reactions, friction and restitution in ``_tet_response``), ``_cloth_stage`` (the cloth build, 2 and
5), ``_solid_stage`` (3); sub-steps of a step near tet bodies in ``substeps``; construction, the plan, the step, 4, 6
and the reports here.
"""

from __future__ import annotations

import math
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba
import numpy as np

from modalfem import effects as fx
from modalfem.errors import InputError, SimulationError
from modalfem.runtime.state import restore, snapshot
from modalfem.world._cloth_stage import _ClothStage
from modalfem.world._shared import _REACTION_KEY, BOUNCE_THRESHOLD, PUSH_OUT, SLOW  # noqa: F401 (re-exported)
from modalfem.world._solid_stage import _SolidStage, apply_lift
from modalfem.world._tet_stage import FRICTION_SLIP, _TetStage  # noqa: F401 (re-exported)
from modalfem.world.bodies import Cloth, Modal, Tet
from modalfem.world.obstacles import Box, Ground, Plane, Sphere, TriangleMesh
from modalfem.world.proximity import EdgeProximity, SurfaceProximity
from modalfem.world.substeps import extents, merged_report, substep_count, taken_count

__all__ = ["Stage", "StepReport", "World", "WorldControl", "WorldState"]


@dataclass
class WorldState:
    """Changing state: ``time`` [s], one state per body (``bodies[name]``: ``runtime.State`` for a modal
    body, ``tet.TetState`` for a tet body, ``ClothState`` for a cloth) and ``contacts``, the impulses [N s] of the
    last step's solid contacts by contact (the next step's solve starts from them: resting contact converges in a
    few sweeps, and a step from a copied state repeats exactly).

    ``token``: set by the ``World`` step that wrote this state (its step and a CRC-32 of the time and the bodies'
    arrays; kept by ``copy``), None for any other state. A world with tet bodies keeps its solvers' caches from step
    to step only when a step starts from the state its last step ended in: the token names that step, and its
    checksum, recomputed at the next step's start, tells a state whose arrays were edited in place since (any
    edit but one in 2^32) from the one the step wrote (``World._restart_caches``)."""

    time: float
    bodies: dict
    contacts: dict = field(default_factory=dict)
    token: tuple | None = field(default=None, repr=False, compare=False)

    def copy(self) -> WorldState:
        return WorldState(self.time, {k: v.copy() for k, v in self.bodies.items()}, dict(self.contacts), self.token)

    def __getitem__(self, name: str):
        return self.bodies[name]


@dataclass
class WorldControl:
    """Inputs of one step: point impulses (strikes) and scripted tet vertices. Cleared by ``clear``."""

    impulses: list = field(default_factory=list)
    scripted: dict = field(default_factory=dict)

    def add_impulse(self, body: str, point, J) -> WorldControl:
        """An impulse ``J`` (3,) [N s] (world) at a surface point of ``body`` at the step start: a vertex
        index (tet, cloth: of the body's points; modal: of its surface) or a ``runtime.SurfacePoint``."""
        self.impulses.append((body, point, np.asarray(J, dtype=np.float64)))
        return self

    def script(self, body: str, vertices, positions) -> WorldControl:
        """Tet vertices ``vertices`` driven to ``positions`` (k, 3) [m] at the step end."""
        self.scripted[body] = (np.asarray(vertices, dtype=np.int64), np.asarray(positions, dtype=np.float64))
        return self

    def clear(self) -> None:
        self.impulses.clear()
        self.scripted.clear()


@dataclass(frozen=True)
class Stage:
    """One stage of the step plan: its name, the bodies it runs for and the effects it evaluates."""

    name: str
    bodies: tuple
    effects: tuple = ()

    def __str__(self) -> str:
        s = f"{self.name}: {', '.join(self.bodies)}"
        return s + (f" [{', '.join(self.effects)}]" if self.effects else "")


@dataclass
class StepReport:
    """What one step did: wall time per stage [s], contacts per kind, impulses exchanged between bodies.

    Attributes:
        seconds: stage name -> wall time [s].
        contacts: ``solid`` (contacts in the solid solve), ``modal_static`` (modal runtime contacts),
            ``cloth_reaction`` (cloth vertices pushing back on solids).
        exchanged: list of ``(body_a, body_b, impulse (3,) [N s], torque impulse (3,) [N m s])``: what body a
            received from body b in this step (body b received the opposite).
        sweeps: sequential-impulse sweeps of the solid solve.
        substeps: how many equal sub-steps the step was taken in (``world.substeps``; 1: not divided).
    """

    seconds: dict = field(default_factory=dict)
    contacts: dict = field(default_factory=dict)
    exchanged: list = field(default_factory=list)
    sweeps: int = 0
    substeps: int = 1


class World(_TetStage, _SolidStage, _ClothStage):
    """Bodies of any kinds, obstacles and effects, stepped together.

    Args:
        bodies: ``Modal``, ``Tet`` and ``Cloth`` bodies with unique names.
        obstacles: ``Ground``, ``Plane``, ``Sphere``, ``Box``, ``TriangleMesh`` (each optionally on a path).
        effects: effects from ``modalfem.effects`` (``Gravity``, ``Wind``, ``Damping``, ``Contact``,
            ``SelfCollision``, ``PseudoForces``, ``Sound``), global or per body.

    Raises:
        InputError: unknown or duplicate body names, an effect a body kind cannot take (named), an effect
            that acts on no body, bad obstacles.
    """

    def __init__(self, *, bodies: Sequence, obstacles: Sequence = (), effects: Sequence = ()) -> None:
        self.bodies = list(bodies)
        if not self.bodies:
            raise InputError("a world needs at least one body")
        names = [getattr(b, "name", None) for b in self.bodies]
        bad = [type(b).__name__ for b in self.bodies if not isinstance(b, (Modal, Tet, Cloth))]
        if bad:
            raise InputError(f"unknown body type(s) {', '.join(bad)}: use world.Modal, world.Tet or world.Cloth")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise InputError(f"duplicate body name(s): {', '.join(dup)}")
        self.by_name = {b.name: b for b in self.bodies}
        self.obstacles = list(obstacles)
        bad = [type(o).__name__ for o in self.obstacles if not isinstance(o, (Plane, Sphere, Box, TriangleMesh))]
        if bad:
            raise InputError(f"unknown obstacle type(s) {', '.join(bad)}: use world.Ground, Plane, Sphere, Box or "
                             "TriangleMesh")
        self.effects = list(effects)
        self._check_effects()
        self._build()

    # ------------------------------------------------------------------ effects
    def _check_effects(self) -> None:
        kinds = tuple(fx.EFFECTS.values())
        for e in self.effects:
            if not isinstance(e, kinds):
                raise InputError(f"unknown effect {type(e).__name__}: use one of modalfem.effects "
                                 f"({', '.join(c.__name__ for c in kinds)})")
            if e.bodies is not None:
                for n in e.bodies:
                    if n not in self.by_name:
                        raise InputError(f"effect {e.name} names body {n!r}, which is not in the world "
                                         f"(bodies: {', '.join(self.by_name)})")
                    kind = self.by_name[n].kind
                    if e.name not in fx.supported(kind):
                        raise InputError(f"effect {e.name} cannot act on {kind} body {n!r}: a {kind} body takes "
                                         f"{', '.join(fx.supported(kind))}")
            elif not any(e.name in fx.supported(b.kind) for b in self.bodies):
                raise InputError(f"effect {e.name} acts on no body of this world (it needs a "
                                 f"{' or '.join(k for k in ('modal', 'tet', 'cloth') if e.name in fx.supported(k))} "
                                 "body)")
        for cls in (fx.Damping, fx.Contact, fx.SelfCollision, fx.PseudoForces, fx.Sound):
            for b in self.bodies:
                n = sum(1 for e in self.effects if isinstance(e, cls) and e.applies_to(b.name)
                        and e.name in fx.supported(b.kind))
                if n > 1:
                    raise InputError(f"body {b.name!r} has {n} {cls.name} effects: give at most one per body")

    def effects_of(self, name: str) -> list:
        """The effects acting on body ``name`` (those its kind supports)."""
        kind = self.by_name[name].kind
        return [e for e in self.effects if e.applies_to(name) and e.name in fx.supported(kind)]

    def _one(self, name: str, cls):
        for e in self.effects_of(name):
            if isinstance(e, cls):
                return e
        return None

    # ------------------------------------------------------------------ build
    def _build(self) -> None:
        from modalfem import runtime as rt

        self._modal, self._tet, self._cloth = {}, {}, {}
        # with two or more solid bodies in contact, a modal body meets every obstacle in the one solve that holds
        # the bodies too: a body pressed between another body and the ground must see both at once (solved one
        # after the other, each undid the other's push: a fork wedged between two bars on the ground at
        # dt = 2 ms gained 2.7x the scene's energy and crossed them)
        self._shared = sum(1 for b in self.bodies if b.kind in ("modal", "tet") and self._one(b.name, fx.Contact)) > 1
        for b in self.bodies:
            eff = self.effects_of(b.name)
            if b.kind == "modal":
                self._modal[b.name] = self._build_modal(b, eff, rt)
            elif b.kind == "tet":
                self._tet[b.name] = self._build_tet(b, eff)
            else:
                self._cloth[b.name] = self._build_cloth(b, eff)
        # modal bodies in the compiled solve: against each other, moving and mesh obstacles
        self._modal_contact = [n for n in self._modal if self._one(n, fx.Contact)]
        # their surfaces' faces and edges, as the tet bodies' contacts (``_tet_contacts``) and the cloth's reaction
        # (``_reaction``) query them
        self._surf = {n: SurfaceProximity(self._modal[n]["body"].triangles, self._modal[n]["body"].rest)
                      for n in self._modal_contact}
        self._tris = {n: self._modal[n]["body"].triangles for n in self._modal_contact}
        self._edges = {n: EdgeProximity(self._tris[n], self._modal[n]["body"].rest) for n in self._modal_contact}
        self._world_obstacles = {}
        for n in self._modal_contact:
            obs = [o for o in self.obstacles if self._shared or o.moving or isinstance(o, TriangleMesh)]
            if obs:
                self._world_obstacles[n] = obs
        # a tet body meets the modal bodies inside its implicit step (moving penalty obstacles, ``_tet_contacts``),
        # and the tet bodies it may touch in one implicit step with them (``_tet_groups``), so only modal pairs are in
        # the solid solve
        self._tet_modal = {n: list(self._modal_contact) for n, t in self._tet.items() if t["contact"] is not None}
        self._groups = {}  # tet bodies stepped together (``_tet_group``), made when first needed
        self._last_step = None  # what names the last step (``_restart_caches``, ``WorldState.token``)
        self._pairs = [(a, b) for i, a in enumerate(self._modal_contact) for b in self._modal_contact[i + 1:]]
        # the modal bodies' contacts with each other and with static planes: compiled search and entries
        self._fast = None
        self._fast_planes = set()
        if self._modal_contact:
            from modalfem.world.modal_contacts import ModalContacts

            planes = [(i, o.normal, float(o.point @ o.normal)) for i, o in enumerate(self.obstacles)
                      if self._shared and isinstance(o, Plane) and not o.moving]
            self._fast_planes = {p[0] for p in planes}
            self._fast = ModalContacts({n: self._modal[n]["body"] for n in self._modal_contact},
                                       {n: self._one(n, fx.Contact) for n in self._modal_contact}, planes, slow=SLOW)
        self._obstacle_surf = {i: SurfaceProximity(o.triangles, o.vertices) for i, o in enumerate(self.obstacles)
                               if isinstance(o, TriangleMesh)}
        self._build_deformable()
        self._sounds = {}
        for n, m in self._modal.items():
            s = self._one(n, fx.Sound)
            if s is not None:
                self._sounds[n] = rt.ModalSound(m["body"].model, listener=s.listener, distance=s.distance,
                                                damping=m["body"].damping)
        self.plan = self._compile_plan()

    def _build_modal(self, b: Modal, eff: list, rt) -> dict:
        from modalfem.runtime import effects as rte

        damping = self._one(b.name, fx.Damping)
        body = rt.ModalBody(b.model, damping=None if damping is None else (damping.alpha, damping.beta),
                            dtype=np.float64)
        inner, names = [], []
        for e in eff:
            if isinstance(e, fx.Gravity):
                inner.append(rte.Gravity(e.g))
            elif isinstance(e, fx.Wind):
                if callable(e.velocity):
                    raise InputError(f"wind on modal body {b.name!r}: a modal body takes a constant wind velocity "
                                     "(3 numbers [m/s]); wind fields (x, t) act on cloth and tet bodies")
                inner.append(rte.Wind(e.velocity, density=e.density, drag=e.drag))
            elif isinstance(e, fx.PseudoForces):
                if body.coupling is None:
                    raise InputError(f"pseudo-forces on modal body {b.name!r}: its model file has no rotation "
                                     "coupling (rebuild it with ModalModel.from_modes)")
                inner.append(rt.PseudoForces(coriolis=e.coriolis, centripetal=e.centripetal, euler=e.euler))
            elif isinstance(e, fx.Damping):
                pass  # in the body's modal damping
            else:
                continue
            names.append(e.name)
        contact = self._one(b.name, fx.Contact)
        static = []
        if contact is not None and not self._shared:  # else: every obstacle in the solid solve (see _build)
            for o in self.obstacles:
                if o.moving:
                    continue
                if isinstance(o, Ground):
                    static.append(rt.Ground(o.height))
                elif isinstance(o, Plane):
                    static.append(rt.Plane(o.normal, o.point))
                elif isinstance(o, Sphere):
                    static.append(rt.Sphere(o.center, o.radius))
                elif isinstance(o, Box):
                    static.append(rt.Box(o.center, o.half, o.rotation))
            if static:
                inner.append(rt.Obstacles(static, restitution=contact.restitution, friction=contact.friction,
                                          margin=contact.margin, bounce_threshold=BOUNCE_THRESHOLD))
                names.append("contact")
        solver = rt.ModalSolver(body, effects=inner)
        g = np.zeros(3)
        for e in eff:
            if isinstance(e, fx.Gravity):
                g += np.asarray(e.g)
        from modalfem.runtime.state import State

        scratch = State.rest(body)
        return {"body": body, "solver": solver, "effects": tuple(names), "static": bool(static), "g": g,
                "scratch": scratch, "start": scratch.copy()}

    # ------------------------------------------------------------------ plan
    def _compile_plan(self) -> list:
        plan = []

        def effects(group):
            return tuple(sorted({e for g in group.values() for e in g["effects"]}))

        if self._tet:
            plan.append((Stage("tet step", tuple(self._tet), effects(self._tet)), self._stage_tet_step))
        if self._pairs or self._world_obstacles:
            plan.append((Stage("solid contacts", tuple(self._modal_contact), ("contact",)), self._stage_contacts))
        if self._modal:
            plan.append((Stage("modal step", tuple(self._modal), effects(self._modal)), self._stage_modal_step))
        selfc = tuple(n for n, t in self._tet.items() if t["pipeline"] is not None)
        if selfc:
            plan.append((Stage("tet self-collision", selfc, ("self-collision",)), self._stage_tet_self))
        if self._cloth:
            plan.append((Stage("cloth step", tuple(self._cloth), effects(self._cloth)), self._stage_cloth_step))
        if self._deform is not None:
            d = self._deform
            eff = ("contact",) if any(self._one(m, fx.Contact) for m in d["members"]) else ()
            if d["pipeline"].config.self_collision:
                eff += ("self-collision",)
            plan.append((Stage("cloth collisions", tuple(d["members"]) + tuple(d["motions"]), eff),
                         self._stage_deformable))
        if self._sounds:
            plan.append((Stage("sound", tuple(self._sounds), ("sound",)), self._stage_sound))
        self._plan = plan
        # a world of one modal body whose plan is its step alone
        self._solo = self.bodies[0].name if (len(self.bodies) == 1 and self.bodies[0].kind == "modal"
                                             and [s.name for s, _ in plan] == ["modal step"]) else None
        return [s for s, _ in plan]

    def describe_plan(self) -> str:
        """The step plan, one stage per line."""
        return "\n".join(f"{i + 1}. {s}" for i, s in enumerate(self.plan))

    # ------------------------------------------------------------------ states
    def state(self) -> WorldState:
        """The start state: every body where its definition places it, t = 0."""
        from modalfem import runtime as rt
        from modalfem.tet import TetState

        out = {}
        for b in self.bodies:
            if b.kind == "modal":
                body = self._modal[b.name]["body"]
                out[b.name] = rt.State.rest(body, position=b.position, orientation=b.orientation,
                                            velocity=b.velocity, angular_velocity=b.angular_velocity)
            elif b.kind == "tet":
                s = TetState.at_rest(b.model)
                if b.position is not None:
                    s.x += b.position
                if b.velocity is not None:
                    s.v[:] = b.velocity
                out[b.name] = s
            else:
                out[b.name] = self._cloth[b.name]["start"].copy()
        return WorldState(0.0, out)

    def control(self) -> WorldControl:
        return WorldControl()

    # ------------------------------------------------------------------ surfaces
    def surface(self, state: WorldState, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World surface of body ``name``: vertices (nv, 3) [m] and outward triangles (nt, 3)."""
        b = self.by_name[name]
        if b.kind == "modal":
            body = self._modal[name]["body"]
            return body.positions(state.bodies[name], precise=True).copy(), body.triangles
        if b.kind == "tet":
            t = self._tet.get(name)
            return state.bodies[name].x[t["surface"]], t["triangles"]
        return state.bodies[name].x, self._cloth[name]["scene"].model.mesh.triangles

    # ------------------------------------------------------------------ step
    def step(self, state_in: WorldState, state_out: WorldState, control: WorldControl | None, dt: float
             ) -> StepReport:
        """Advance every body by ``dt`` [s] from ``state_in`` into ``state_out`` (may be the same object).

        All or nothing: if a stage fails, ``state_out`` is left as it was and the error names the body.

        Raises:
            SimulationError: bad dt, a control naming an unknown body or point, a body's step failing.
        """
        try:
            dt = float(dt)
        except (TypeError, ValueError):
            raise SimulationError(f"time step must be a number [s], got {dt!r}") from None
        if not (math.isfinite(dt) and dt > 0):
            raise SimulationError(f"time step must be finite and > 0 s, got {dt!r}")
        control = control or _NO_CONTROL
        for body, _, J in control.impulses:
            if body not in self.by_name:
                raise SimulationError(f"control impulse on unknown body {body!r} (bodies: {', '.join(self.by_name)})")
            if J.shape != (3,) or not np.all(np.isfinite(J)):
                raise SimulationError(f"control impulse on {body!r} must be 3 finite numbers [N s], got {J.tolist()}")
        for body in control.scripted:
            if body not in self._tet:
                raise SimulationError(f"scripted vertices need a tet body, {body!r} is not one")
        if self._solo is not None and not control.impulses and self._solo in state_out.bodies:
            return self._step_solo(state_in, state_out, dt)
        self._restart_caches(state_in)
        heard = {n: snd.impact_count for n, snd in self._sounds.items()}
        try:
            report = self._step_divided(state_in, state_out, control, dt, heard)
        except BaseException:  # all or nothing: a failed step leaves no impact in the sounds either
            for n, snd in self._sounds.items():
                snd._forget(heard[n])
            raise
        if self._tet:
            self._last_step = object()
            state_out.token = (self._last_step, _checksum(state_out))
        return report

    def _step_divided(self, state_in: WorldState, state_out: WorldState, control: WorldControl, dt: float,
                      heard: dict) -> StepReport:
        """``step`` after its checks: in one pass, or in sub-steps (``world.substeps``) counted from the start
        state, or counted from the travel a single pass took (that pass then dropped, its sounds' impacts too:
        ``heard`` the sounds' impact counts before it)."""
        ext = extents(self, state_in) if self._tet and not control.scripted else None  # once for both counts
        n = 1 if control.scripted else substep_count(self, state_in, dt, ext)
        if n == 1:
            ctx, report = self._plan_pass(state_in, control, dt)  # (state_in is not written before _finish)
            n = taken_count(self, state_in, ctx.out.bodies, dt, ext) if self._tet_modal and not control.scripted else 1
            if n == 1:
                self._finish(ctx, state_out, dt)
                return report
            for name, snd in self._sounds.items():  # set moving within the step farther than its start velocities
                snd._forget(heard[name])  # said: that pass is dropped, the step taken again divided
        # a modal or tet body travelling far against a nearby tet body's surface (``world.substeps``)
        s = state_in.copy()
        reports = [self._step_plan(s, s, control if k == 0 else _NO_CONTROL, dt / n) for k in range(n)]
        self._hand_over(s.bodies, state_out)
        state_out.contacts = s.contacts
        state_out.time = state_in.time + dt
        return merged_report(reports)

    def _restart_caches(self, state_in: WorldState) -> None:
        """A step that does not continue from the state the last step ended in (a run started again from
        ``w.state()`` or any earlier state, or that state edited in place since) first clears the tet solvers' caches
        (``TetSolver.reset_caches``: the lagged coarse space, the SVD warm start, the previous step's velocity
        change), so a run from a given state repeats bit for bit on the same ``World`` object as on a new one. It
        continues when ``state_in.token`` names the last step and its checksum is the state's now (``WorldState``)."""
        if not self._tet:
            return
        token = state_in.token
        if token is not None and self._last_step is not None and token[0] is self._last_step and \
                token[1] == _checksum(state_in):
            return
        for t in list(self._tet.values()) + list(self._groups.values()):
            t["solver"].reset_caches()
        self._last_step = None

    def _step_plan(self, state_in: WorldState, state_out: WorldState, control: WorldControl, dt: float
                   ) -> StepReport:
        """One pass of the step plan (``step`` after its checks)."""
        ctx, report = self._plan_pass(state_in, control, dt)
        self._finish(ctx, state_out, dt)
        return report

    def _finish(self, ctx, state_out: WorldState, dt: float) -> None:
        """Hand a pass's results over to ``state_out`` (only after all its stages succeeded)."""
        self._hand_over(ctx.out.bodies, state_out)
        state_out.contacts = ctx.contacts
        state_out.time = ctx.state_in.time + dt

    def _plan_pass(self, state_in: WorldState, control: WorldControl, dt: float) -> tuple:
        """Run every stage of the plan from ``state_in``: ``(ctx, report)``, the new states in ``ctx.out`` (nothing
        handed over yet)."""
        ctx = _StepContext(state_in, WorldState(state_in.time, {}), control, dt)
        report = StepReport()
        ctx.report = report
        for stage, fn in self._plan:
            t0 = time.perf_counter()
            fn(ctx)
            report.seconds[stage.name] = time.perf_counter() - t0
        for b in self.bodies:  # bodies no stage moved (none today; kept for completeness)
            if b.name not in ctx.done:
                raise SimulationError(f"body {b.name!r} was not stepped (internal plan error)")
        return ctx, report  # all stages succeeded: only now may state_out change (``_finish``)

    def _hand_over(self, new_bodies: dict, state_out: WorldState) -> None:
        """Put a step's new body states into ``state_out``: a modal body's copied into the caller's state object,
        the other kinds' handed over."""
        bodies = dict(state_out.bodies)
        for name, new in new_bodies.items():
            old = bodies.get(name)
            if name in self._modal and old is not None and old is not new:
                old.assign(new)
                old.time = new.time
            else:
                bodies[name] = new
        state_out.bodies = bodies

    def _step_solo(self, state_in: WorldState, state_out: WorldState, dt: float) -> StepReport:
        """The step of a world of one modal body whose plan is its step alone, without strikes: the solver steps
        straight into the caller's state (``ModalSolver.step`` is all-or-nothing itself), so the world adds no
        scratch state, copy or stage bookkeeping to the free step."""
        name = self._solo
        report = StepReport()
        t0 = time.perf_counter()
        m = self._modal[name]
        if m["static"]:
            self._modal_body_step(name, state_in.bodies[name], state_out.bodies[name], None, dt, report)
        else:  # ``ModalSolver.step`` without its checks of dt (done above), a control and contacts (none here)
            s = state_out.bodies[name]
            saved = snapshot(s)
            try:
                m["solver"]._step(state_in.bodies[name], s, (), (), None, None, dt)
            except SimulationError as exc:
                restore(s, saved)
                raise SimulationError(f"modal body {name!r}: {exc}") from None
            except BaseException:
                restore(s, saved)
                raise
        report.seconds["modal step"] = time.perf_counter() - t0
        if state_out is not state_in:
            state_out.contacts = dict(state_in.contacts)
        state_out.time = state_in.time + dt
        return report

    def advance(self, state: WorldState, dt: float, control: WorldControl | None = None) -> StepReport:
        """``step(state, state, control, dt)``."""
        return self.step(state, state, control, dt)

    # ------------------------------------------------------------------ stages
    def _strikes(self, ctx, name: str):
        return [(p, J) for b, p, J in ctx.control.impulses if b == name]

    def _strike_control(self, ctx, name: str):
        """A modal solver's ``Control`` holding this step's strikes of body ``name`` (None without any)."""
        strikes = self._strikes(ctx, name)
        if not strikes:
            return None
        from modalfem import runtime as rt

        ctl = rt.Control()
        for p, J in strikes:
            ctl.add_impulse(p, J)
        return ctl

    def _stage_modal_step(self, ctx) -> None:
        dt = ctx.dt
        # the bodies with gravity alone and no static obstacles or strikes: one compiled call (``_modal_step``)
        batch = self.__dict__.get("_modal_batch")
        if batch is None:
            from modalfem.world._modal_step import ModalBatch

            batch = self._modal_batch = ModalBatch(self._modal)
        done = set(batch.step(ctx, {b for b, _, _ in ctx.control.impulses}) if MODAL_BATCH else ())
        for name, m in self._modal.items():
            if name in done:
                continue
            s = ctx.state_in.bodies[name]
            body = m["body"]
            dV = ctx.dV.get(name)
            if dV is not None:  # the contact impulses of the modal contact solve, at the step start
                m["start"].assign(s)
                s = m["start"]
                s.velocity += dV[0:3]
                R = s.rotation()
                s.angular_momentum += R @ (body.inertia @ (R.T @ dV[3:6]))
                s.qdot += dV[6:]
                apply_lift(ctx.lift, name, s.position)  # the part of dV holding the load (``gravity_lift``)
            strikes = self._strikes(ctx, name)
            ctl = self._strike_control(ctx, name)
            out = m["scratch"]  # reused every step; the caller's state receives a copy at the end of the step
            contacts = self._modal_body_step(name, s, out, ctl, dt, ctx.report)
            if strikes and name in self._sounds:
                self._sounds[name].add_impulses(ctx.state_in.time, [p for p, _ in strikes],
                                                [J for _, J in strikes], rotation=s.rotation())
            if contacts is not None and name in self._sounds and contacts.count:
                # impacts only: a body resting under gravity takes ~m g dt every step, which recorded as
                # impacts is a buzz at the step rate (and a resting bell was ~820 impacts in 1000 steps)
                self._sounds[name].add_contacts(ctx.state_in.time, contacts, rotation=s.rotation(),
                                                min_impulse=5.0 * body.mass * float(np.linalg.norm(m["g"])) * dt)
            ctx.out.bodies[name] = out
            ctx.done.add(name)

    def _modal_body_step(self, name: str, s, out, ctl, dt: float, report: StepReport):
        """Modal body ``name`` from state ``s`` into ``out`` by its solver, with its static obstacles' contacts
        (counted in ``report``); returns those contacts (None without static obstacles)."""
        m = self._modal[name]
        solver = m["solver"]
        contacts = solver.collide(s, dt) if m["static"] else None
        try:
            solver.step(s, out, ctl, contacts, dt)
        except SimulationError as exc:
            raise SimulationError(f"modal body {name!r}: {exc}") from None
        if contacts is not None:
            report.contacts["modal_static"] = report.contacts.get("modal_static", 0) + contacts.count
        return contacts

    def _stage_sound(self, ctx) -> None:
        for name, snd in self._sounds.items():
            dq = ctx.impacts.get(name)
            if dq is not None:
                snd.add_impact(ctx.state_in.time, dq, rotation=ctx.state_in.bodies[name].rotation())

    # ------------------------------------------------------------------ outputs
    def sound(self, name: str):
        """The ``runtime.ModalSound`` recording the impacts of sounding modal body ``name``
        (``.render(duration)`` gives the pressure samples [Pa] at ``.sample_rate``)."""
        if name not in self._sounds:
            raise InputError(f"body {name!r} has no Sound effect (sounding bodies: {', '.join(self._sounds) or 'none'})")
        return self._sounds[name]

    def momentum(self, state: WorldState, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Linear (3,) [kg m/s] and angular momentum about the origin (3,) [kg m^2/s] of body ``name``."""
        s = state.bodies[name]
        if name in self._modal:
            return self._modal[name]["solver"].momentum(s)
        m = self.by_name[name].model.masses
        p = (m[:, None] * s.v).sum(axis=0)
        return p, (m[:, None] * np.cross(s.x, s.v)).sum(axis=0)

    def energy(self, state: WorldState, name: str) -> dict:
        """Energies [J] of body ``name``: kinetic, elastic, gravity (``-m g . x``), for a tet body with contact the
        energy stored in its penalty contacts (``contact``: with obstacles and modal bodies, ``sum k depth^2 / 2``
        at the last step's end), and their total."""
        s = state.bodies[name]
        g = np.zeros(3)
        for e in self.effects_of(name):
            if isinstance(e, fx.Gravity):
                g += np.asarray(e.g)
        if name in self._modal:
            m = self._modal[name]
            body = m["body"]
            out = {"kinetic": body.kinetic_energy_rigid(s) + 0.5 * float(s.qdot @ s.qdot),
                   "elastic": 0.5 * float(np.sum((body.omega * s.q) ** 2)),
                   "gravity": -body.mass * float(g @ s.position)}
        elif name in self._tet:
            m = self.by_name[name].model.masses
            e = self._tet[name]["solver"].energies(s)
            out = {"kinetic": e["kinetic"], "elastic": e["elastic"], "gravity": -float(m @ (s.x @ g))}
            if self._tet[name]["penalty"] is not None:  # stored in its contacts (obstacles', modal bodies')
                out["contact"] = float(state.contacts.get((_REACTION_KEY, name), 0.0))
        else:
            sc = self._cloth[name]["scene"]
            m = sc.model.masses
            out = {"kinetic": 0.5 * float(m @ np.sum(s.v**2, axis=1)), "elastic": sc.model.elastic_energy(s.x),
                   "gravity": -float(m @ (s.x @ g))}
        out["total"] = sum(out.values())
        return out

    def intersections(self, state: WorldState) -> list:
        """Intersecting triangle pairs between any two bodies' surfaces (the exact test,
        ``collision.tritri``): a list of ``(body_a, body_b, count)`` with count > 0."""
        from modalfem.collision.tritri import intersecting_pairs

        out = []
        names = [b.name for b in self.bodies]
        surf = {n: self.surface(state, n) for n in names}
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                xa, fa = surf[a]
                xb, fb = surf[b]
                lo = np.maximum(xa.min(0), xb.min(0))
                hi = np.minimum(xa.max(0), xb.max(0))
                if np.any(lo > hi):
                    continue
                k = len(intersecting_pairs(xa, fa, other_points=xb, other_triangles=fb))
                if k:
                    out.append((a, b, k))
        return out

    def penetrations(self, state: WorldState, *, tolerance: float) -> list:
        """Bodies' vertices inside the ground, planes, spheres and boxes (not triangle meshes) by more than
        ``tolerance`` [m]: a list of ``Penetration(body, obstacle index, count, deepest [m])``, empty when none is
        (``modalfem.world.penetration``, which says what depth the contacts allow)."""
        from modalfem.world.penetration import obstacle_penetrations

        return obstacle_penetrations(self, state, tolerance)


def _checksum(state: WorldState) -> int:
    """A 64-bit checksum of a state's time and every body state's arrays (each attribute holding one, in name order;
    read in place, nothing copied): ``WorldState.token``'s check that a state was not edited since the step that wrote
    it. Per array ``sum_i (2 i + 1) w_i`` mod 2^64 of its 64-bit words ``w_i`` (``_word_sum``, compiled:
    one pass; an edit of one word always changes it, several cancel one in ~2^64), chained FNV-style."""
    h = 0xCBF29CE484222325
    parts = [np.float64(state.time)]
    for name in sorted(state.bodies):
        parts.append(name)
        b = state.bodies[name]
        items = vars(b) if hasattr(b, "__dict__") else {f: getattr(b, f) for f in getattr(b, "__slots__", ())}
        for f in sorted(items):
            a = items[f]
            if isinstance(a, (np.ndarray, float)):
                parts += [f, np.asarray(a, dtype=np.float64) if isinstance(a, float) else a]
    for a in parts:
        if isinstance(a, str):
            v = zlib.crc32(a.encode())
        else:
            a = np.ascontiguousarray(a).reshape(-1)
            v = int(_word_sum(a.view(np.uint64))) if a.nbytes % 8 == 0 else zlib.crc32(a.view(np.uint8))
        h = ((h ^ v) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


@numba.njit(cache=True)
def _word_sum(w: np.ndarray) -> np.uint64:
    """``sum_i (2 i + 1) w_i`` mod 2^64 of 64-bit words ``w`` (n,) (``_checksum``)."""
    acc = np.uint64(0)
    for i in range(w.size):
        acc += w[i] * np.uint64(2 * i + 1)
    return acc


class _StepContext:
    def __init__(self, state_in: WorldState, out: WorldState, control: WorldControl, dt: float) -> None:
        self.state_in, self.out, self.control, self.dt = state_in, out, control, dt
        self.start = {}
        self.done = set()
        self.dV = {}
        self.lift = {}  # position changes [m] at the step start (``_solid_stage.gravity_lift``)
        self.cloth_dv = {}
        self.impacts = {}
        self.contacts = dict(state_in.contacts)  # kept unless the solid solve runs
        self.report = None
        self.tet_obstacles = set()  # (modal body, static obstacle index) pairs a tet step solved (``_modal_planes``)
        self.packed = None  # (names, arrays) of ``_shared.packed_states``


#: the control of a step given none (never changed: stages only read it)
_NO_CONTROL = WorldControl()


#: step the modal bodies with gravity alone in one compiled call (``_modal_step.ModalBatch``); False: each by its
#: solver (the same arithmetic; tests compare the two)
MODAL_BATCH = True
