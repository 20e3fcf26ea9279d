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
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from modalfem import effects as fx
from modalfem.cloth.wind import PressureWind
from modalfem.errors import InputError, SimulationError
from modalfem.runtime.effects import windward_pressure
from modalfem.world import _kernels, _tet_kernels
from modalfem.world.bodies import Cloth, ClothState, Modal, Tet
from modalfem.world.obstacles import Box, Ground, Plane, Sphere, TriangleMesh
from modalfem.world.pair_restitution import pair_restitution
from modalfem.world.proximity import EdgeProximity, SurfaceProximity
from modalfem.world.tetcontact import STIFFNESS, CoupledTetSolver, PenaltyContacts
from modalfem.world.tetgroup import between, pair_owners

__all__ = ["Stage", "StepReport", "World", "WorldControl", "WorldState"]

#: impacts slower than this [m/s] do not bounce and are not heard (resting contact)
BOUNCE_THRESHOLD = 0.05
#: fraction of a penetration depth [m] undone per step by the solid contact solve (its push-out speed is
#: ``PUSH_OUT * depth / dt``)
PUSH_OUT = 0.2
#: modes with omega dt above this take no part in the velocity-level contact between modal bodies
SLOW = 0.5
#: a tet body's penalty contacts with one modal body hold its approach within a 1 / DEPTH_SHARE part of the skin
#: (their stiffness summed at least ``DEPTH_SHARE (travel + |g| dt^2) / dhat`` times its mass / dt^2)
DEPTH_SHARE = 4.0
#: a tet step whose contacts (with obstacles or modal bodies) end deeper than this part of the skin is redone with them
#: stiffer (up to TET_RETRIES times), so no contact ends beyond the skin
MAX_DEPTH = 0.5
TET_RETRIES = 6
#: a tet edge meets a modal edge in a tet step only where the line between their closest points is within ~60
#: degrees of the modal surface's outward side at its edge (the cosine at least this): the contact's sign (which
#: side the tet edge must stay on) is read from that side, and it is ill-defined where they are near perpendicular
#: (a foam vertex on a steel bar's edge, between its two foam edges in line: two contacts with opposite normals,
#: which no stiffness could satisfy; the step ended with +1.3 J in them at dt = 7 ms). Closest points near an edge's
#: end are kept: a foam edge folding round the bar's corner, 0.6 mm from the end of the bar's 50 mm edge, crossed
#: it at 5 and 20 ms when the pairs within 5 % of an end were left out
EDGE_ALIGN = 0.5
#: the slip speed [m/s] below which a contact between two tet bodies stepped together sticks (their friction in the
#: implicit step, ``PenaltyContacts.set_friction``: a slip below ``FRICTION_SLIP dt`` per step is elastic)
FRICTION_SLIP = 1e-4


def _top_speed(s) -> float:
    """The fastest vertex's speed [m/s] of tet state ``s`` (0 without vertices)."""
    return float(np.sqrt(np.einsum("ij,ij->i", s.v, s.v)).max()) if len(s.v) else 0.0


def _tet_reach(vmax: float, margin: float, dt: float) -> float:
    """How far [m] a tet body whose fastest vertex moves at ``vmax`` [m/s] may meet something in a step of ``dt``
    [s]: its contact's skin ``margin`` [m] twice, twice that vertex's travel and gravity's ``g dt^2``."""
    return margin + margin + 2.0 * vmax * dt + 9.81 * dt * dt


def _contacts_of(modal: list, body: str) -> np.ndarray:
    """Indices (int64, in order) of a tet body's modal contacts ``modal`` ((body, ids, weights) each) with ``body``."""
    return np.array([i for i, (b, _, _) in enumerate(modal) if b == body], dtype=np.int64)

@dataclass
class WorldState:
    """Changing state: ``time`` [s], one state per body (``bodies[name]``: ``runtime.State`` for a modal
    body, ``tet.TetState`` for a tet body, ``ClothState`` for a cloth) and ``contacts``, the impulses [N s] of the
    last step's solid contacts by contact (the next step's solve starts from them: resting contact converges in a
    few sweeps, and a step from a copied state repeats exactly)."""

    time: float
    bodies: dict
    contacts: dict = field(default_factory=dict)

    def copy(self) -> WorldState:
        return WorldState(self.time, {k: v.copy() for k, v in self.bodies.items()}, dict(self.contacts))

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
    """

    seconds: dict = field(default_factory=dict)
    contacts: dict = field(default_factory=dict)
    exchanged: list = field(default_factory=list)
    sweeps: int = 0


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


class World:
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
        self._surf = {n: SurfaceProximity(self._modal[n]["body"].triangles, self._modal[n]["body"].rest)
                      for n in self._modal_contact}
        self._solid = self._modal_contact + [n for n, t in self._tet.items() if t["contact"] is not None]
        self._tris = {n: self._modal[n]["body"].triangles for n in self._modal_contact}
        self._tris.update({n: self._tet[n]["triangles"] for n in self._solid if n in self._tet})
        self._edges = {n: EdgeProximity(self._tris[n], self._modal[n]["body"].rest) for n in self._modal_contact}
        self._edges.update({n: self._tet[n]["edges"] for n in self._solid if n in self._tet})
        self._surf.update({n: self._tet[n]["proximity"] for n in self._solid if n in self._tet})
        self._world_obstacles = {}
        for n in self._modal_contact:
            obs = [o for o in self.obstacles if self._shared or o.moving or isinstance(o, TriangleMesh)]
            if obs:
                self._world_obstacles[n] = obs
        # a tet body meets the modal bodies inside its implicit step (moving penalty obstacles, ``_tet_contacts``),
        # and the tet bodies it may touch in one implicit step with them (``_tet_groups``), so only modal pairs are in
        # the solid solve
        self._tet_modal = {n: [m for m in self._modal_contact] for n in self._solid if n in self._tet}
        self._groups = {}  # tet bodies stepped together (``_tet_group``), made when first needed
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

    def _build_tet(self, b: Tet, eff: list) -> dict:
        from modalfem import tet
        from modalfem.mesh.surface import boundary_surface
        from modalfem.tet import effects as te

        inner, names = [], []
        wind = None
        for e in eff:
            if isinstance(e, fx.Gravity):
                inner.append(te.Gravity(e.g))
            elif isinstance(e, fx.Damping):
                inner.append(te.RayleighDamping(e.alpha, e.beta))
            elif isinstance(e, fx.Wind):
                wind = _TetWind(e)
                inner.append(wind)
            else:
                continue
            names.append(e.name)
        if b.pins is not None and len(b.pins):
            p = b.model.rest_points[b.pins] + (0.0 if b.position is None else b.position)
            inner.append(tet.Pins(b.pins, p))
        contact = self._one(b.name, fx.Contact)
        penalty = None
        if contact is not None:
            penalty = PenaltyContacts(b.model.point_count)
            inner.append(penalty)
            names.append("contact")
        solver = (tet.TetSolver if penalty is None else CoupledTetSolver)(
            b.model, effects=inner, newton_max=b.newton_max, linear_solver=b.linear_solver)
        surf = boundary_surface(b.model.mesh)
        if wind is not None:
            wind.bind(surf)
        masses = b.model.masses.copy()
        if b.pins is not None:
            masses[b.pins] = np.inf
        tris = np.ascontiguousarray(surf.triangles)
        out = {"solver": solver, "effects": tuple(names), "surface": surf.mesh_vertices, "triangles": tris,
               "wind": wind, "masses": masses, "penalty": penalty, "contact": contact, "pipeline": None,
               "proximity": SurfaceProximity(tris, surf.vertices), "edges": EdgeProximity(tris, surf.vertices)}
        sc = self._one(b.name, fx.SelfCollision)
        if sc is not None:
            from modalfem.collision.pipeline import CollisionConfig, CollisionPipeline

            out["pipeline"] = CollisionPipeline(tris, config=CollisionConfig(
                thickness=self._thickness(b.name), friction=0.0 if contact is None else contact.friction))
            names.append("self-collision")
            out["effects"] = tuple(names)
        return out

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
        return {"scene": scene, "effects": tuple(names), "masses": masses}

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
                sc = self._cloth[b.name]["scene"]
                out[b.name] = ClothState(sc.x.copy(), sc.v.copy(), sc._released.copy())
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
        # all stages succeeded: only now does state_out change (a modal body's scratch state is copied into
        # the caller's state object; the other kinds' new states are handed over)
        bodies = dict(state_out.bodies)
        for name, new in ctx.out.bodies.items():
            old = bodies.get(name)
            if name in self._modal and old is not None and old is not new:
                old.assign(new)
                old.time = new.time
            else:
                bodies[name] = new
        state_out.bodies = bodies
        state_out.contacts = ctx.contacts
        state_out.time = state_in.time + dt
        return report

    def _step_solo(self, state_in: WorldState, state_out: WorldState, dt: float) -> StepReport:
        """The step of a world of one modal body whose plan is its step alone, without strikes: the solver steps
        straight into the caller's state (``ModalSolver.step`` is all-or-nothing itself), so the world adds no
        scratch state, copy or stage bookkeeping to the free step."""
        name = self._solo
        report = StepReport()
        t0 = time.perf_counter()
        self._modal_body_step(name, state_in.bodies[name], state_out.bodies[name], None, dt, report)
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

    def _stage_tet_step(self, ctx) -> None:
        from modalfem.tet import TetControl, TetState

        dt = ctx.dt
        for key in [k for k in ctx.contacts if k[0] == _REACTION_KEY]:  # this step's are set below
            del ctx.contacts[key]
        starts = {}
        for name, t in self._tet.items():
            s = ctx.state_in.bodies[name].copy()
            for p, J in self._strikes(ctx, name):
                i = _vertex(name, p, len(s.x))
                if np.isfinite(t["masses"][i]):
                    s.v[i] += J / t["masses"][i]
            if t["wind"] is not None:
                t["wind"].update(s.x, s.v, ctx.state_in.time)
            starts[name] = s
        for names in self._tet_groups(ctx, starts):
            if len(names) == 1:
                name = names[0]
                t, s = self._tet[name], starts[name]
                ctl = TetControl(*ctx.control.scripted[name]) if name in ctx.control.scripted else None
            else:  # tet bodies that may touch in this step: one implicit step over their stacked vertices
                name, t = self._tet_group(names)
                s = TetState(np.concatenate([starts[n].x for n in names]), np.concatenate([starts[n].v for n in names]),
                             starts[names[0]].t)
                ctl = None
                if any(n in ctx.control.scripted for n in names):
                    cv, cp = zip(*[(np.asarray(ctx.control.scripted[n][0]) + o, np.asarray(ctx.control.scripted[n][1]))
                                   for n, o in t["members"] if n in ctx.control.scripted])
                    ctl = TetControl(np.concatenate(cv), np.concatenate(cp))
            obstacles = self._tet_contacts(ctx, name, s, t) if t["penalty"] is not None else None
            out, kept = s.copy(), None
            for attempt in range(TET_RETRIES + 1):
                try:
                    t["solver"].step(s, out, dt, control=ctl)
                except SimulationError as exc:
                    raise SimulationError(f"tet body {name!r}: {exc}") from None
                if obstacles is None:
                    break
                # a stiffened retry must not end with more energy than the attempt it redoes: where a soft vertex is
                # wedged between contacts pushing it opposite ways (foam between the ground and a heavy bar's
                # tilted face), stiffening them in turn flung it ~9 cm in one 5 ms step and stored +23 J in them
                energy = self._tet_end_energy(ctx, name, t, out) if kept is not None else None
                if kept is not None and energy > kept[2]:
                    out, t["penalty"].k = kept[0], kept[1]
                    t["penalty"].stiffen(np.ones(len(kept[1])))  # (drops the cached depths)
                    break
                pen = t["penalty"]
                if attempt == TET_RETRIES or not (pen.depths(out.x) > MAX_DEPTH * pen.dhat).any():
                    break
                kept = (out, pen.k.copy(), self._tet_end_energy(ctx, name, t, out) if energy is None else energy)
                self._tet_too_deep(pen, out.x)
                out = s.copy()
            if obstacles is not None:
                group = (t,) if "members" in t else ()  # (a body alone: looked up by name)
                self._tet_reaction(ctx, name, out, *group)
                self._tet_friction(ctx, name, out, obstacles, *group)
                if "members" not in t:
                    self._tet_restitution(ctx, name, s, out)
                else:
                    self._group_restitution(ctx, t, s, out)
                    pair_restitution(self, ctx, t, s, out, _REACTION_KEY)  # tet-tet (pair_restitution.py)
                self._tet_record(ctx, name, t, out)
            if len(names) == 1:
                ctx.out.bodies[name] = out
                ctx.start[name] = s  # the start the step used (strikes applied)
                ctx.done.add(name)
                continue
            for (n, o), a, b in zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:]):
                ctx.out.bodies[n] = TetState(out.x[a:b].copy(), out.v[a:b].copy(), out.t)
                ctx.start[n] = starts[n]
                ctx.done.add(n)

    def _tet_end_energy(self, ctx, name: str, t: dict, out) -> float:
        """The energy [J] a tet step ``out`` of ``name`` (a body or a group ``t``) ends with, to compare attempts of
        one step: its bodies' (kinetic, elastic, vertex potentials), its penalty contacts' and the kinetic energy of
        the modal bodies it pushes (their start velocity plus gravity's and the reaction's in the step)."""
        from modalfem.tet import TetState

        def own(e):  # (a body's solver holds its penalty contacts as a vertex term: counted once, below)
            return e["total"] - e.get(type(pen).__name__.lower(), 0.0)

        pen = t["penalty"]
        if "members" in t:
            e = sum(own(self._tet[n]["solver"].energies(TetState(out.x[a:b], out.v[a:b], out.t)))
                    for (n, _), a, b in zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:]))
        else:
            e = own(t["solver"].energies(out))
        e += pen.penalty_energy(out.x)  # (also sets pen.u, the modal bodies' displacements, for these positions)
        modal = t["modal_contacts"][1]
        touched = [b for b in self._tet_modal.get(name, ()) if len(_contacts_of(modal, b))]
        for b, u, S in zip(touched, pen.u, pen.inertia):
            body, st = self._modal[b]["body"], ctx.state_in.bodies[b]
            V = np.concatenate([st.velocity + np.asarray(self._modal[b]["g"]) * ctx.dt, body.angular_velocity(st)])
            V = V + u / ctx.dt
            e += 0.5 * ctx.dt**2 * float(V @ S @ V)
        return e

    def _group_restitution(self, ctx, t: dict, s, out) -> None:
        """``_tet_restitution`` of each member of a group with the modal bodies it touches: its own vertices (views
        into the group's states, changed in place), its contacts with them, the energy stored in its own
        elasticity and in the contacts of its vertices."""
        from modalfem.tet import TetState

        pen = t["penalty"]
        n_obstacle, modal = t["modal_contacts"]
        if not modal:
            return
        owner = t["solver"].owner[pen.vid[:, 0]]
        f = pen.forces(out.x)
        psi = _tet_kernels.penalty(pen.depths(out.x), pen.k, pen.eps)[0]
        for i, ((n, _), a, b) in enumerate(zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:])):
            rows = n_obstacle + np.flatnonzero(owner[n_obstacle:n_obstacle + len(modal)] == i)
            view = {"masses": t["masses"][a:b], "solver": self._tet[n]["solver"], "contact": self._tet[n]["contact"],
                    "modal_contacts": (0, [modal[r - n_obstacle] for r in rows]),
                    "penalty": _MemberContacts(f[rows], pen.nrm[rows], float(psi[owner == i].sum()))}
            self._tet_restitution(ctx, n, TetState(s.x[a:b], s.v[a:b], s.t), TetState(out.x[a:b], out.v[a:b], out.t),
                                  view)

    def _tet_groups(self, ctx, starts: dict) -> list:
        """The tet bodies in groups stepped together (``tetgroup.touching``): those with contact whose surfaces'
        boxes, each grown by what it may travel in the step plus its margins, overlap; every other body alone."""
        from modalfem.world.tetgroup import touching

        boxes = {}
        for n, t in self._tet.items():
            if t["penalty"] is None:
                continue
            s = starts[n]
            xs = s.x[t["surface"]]
            r = _tet_reach(_top_speed(s), t["contact"].margin, ctx.dt)
            boxes[n] = (xs.min(0) - r, xs.max(0) + r)
        return touching(list(self._tet), boxes)

    def _tet_group(self, names: list) -> tuple:
        """``(key, entry)`` of the tet bodies ``names`` stepped as one (made once per set of bodies): an entry like
        a tet body's (stacked vertices, surfaces, masses; one ``JointTetSolver`` and ``PenaltyContacts``) with
        ``members``: (name, first stacked vertex) each. Its contact takes the largest margin and the smallest
        friction and restitution of its members'."""
        key = "+".join(names)
        g = self._groups.get(key)
        if g is not None:
            return key, g
        import dataclasses

        from modalfem.world.tetgroup import JointTetSolver

        ts = [self._tet[n] for n in names]
        n_total = sum(self.by_name[n].model.point_count for n in names)
        pen = PenaltyContacts(n_total)
        solver = JointTetSolver([t["solver"] for t in ts], pen)
        offs = solver.offsets[:-1]
        surface = np.concatenate([t["surface"] + o for t, o in zip(ts, offs)])
        s_off = np.concatenate([[0], np.cumsum([len(t["surface"]) for t in ts])])
        tris = np.concatenate([t["triangles"] + o for t, o in zip(ts, s_off[:-1])])
        rest = np.concatenate([self.by_name[n].model.rest_points[t["surface"]] for n, t in zip(names, ts)])
        cs = [t["contact"] for t in ts]
        contact = dataclasses.replace(cs[0], margin=max(c.margin for c in cs), friction=min(c.friction for c in cs),
                                      restitution=min(c.restitution for c in cs))
        g = {"solver": solver, "penalty": pen, "masses": np.concatenate([t["masses"] for t in ts]), "surface": surface,
             "triangles": tris, "contact": contact, "wind": None, "pipeline": None,
             "proximity": SurfaceProximity(tris, rest), "edges": EdgeProximity(tris, rest),
             "members": [(n, int(o)) for n, o in zip(names, offs)]}
        self._groups[key] = g
        self._tet_modal[key] = list(self._modal_contact)
        return key, g

    def _tet_pair_contacts(self, t: dict, s, r: float, u: np.ndarray) -> tuple:
        """The contacts of a group's tet bodies with each other within ``r`` [m] at the start ``s`` (stacked), ``u``
        (n, 3) [m] the predicted motion: ``tetgroup.pair_contacts``, edges on edges as ``EDGE_ALIGN``."""
        from modalfem.world.tetgroup import pair_contacts

        return pair_contacts([(self._tet[n], o) for n, o in t["members"]], s.x, r, EDGE_ALIGN, u)

    def _last_force(self, ctx, name: str, t: dict, kind: str):
        """The last step's contact force [N] by vertex of ``kind`` (``"obstacle force"``, ``"pair force"``), for a
        group stacked from its members' (zero where a member has none); None without any."""
        if "members" not in t:
            return ctx.state_in.contacts.get((_REACTION_KEY, name, kind))
        parts = [ctx.state_in.contacts.get((_REACTION_KEY, n, kind)) for n, _ in t["members"]]
        if all(p is None for p in parts):
            return None
        return np.concatenate([np.zeros(self.by_name[n].model.point_count) if p is None else p
                               for p, (n, _) in zip(parts, t["members"])])

    def _tet_record(self, ctx, name: str, t: dict, out) -> None:
        """Keep what the next step and ``energy`` read: the energy stored in the penalty contacts, the forces by
        vertex of the obstacles' and of the group's bodies on each other (per member body in a group; a
        contact's energy counts for the body of its first vertex)."""
        pen = t["penalty"]
        n_obstacle, modal = t["modal_contacts"]
        f = pen.forces(out.x)
        n = len(out.x)
        start = n_obstacle + len(modal)
        obstacle = np.bincount(pen.verts[:n_obstacle, 0], weights=f[:n_obstacle], minlength=n)
        pair = np.bincount(pen.verts[start:, 0], weights=f[start:], minlength=n)
        if "members" not in t:
            ctx.contacts[(_REACTION_KEY, name)] = pen.penalty_energy(out.x)
            ctx.contacts[(_REACTION_KEY, name, "obstacle force")] = obstacle
            return
        psi = _tet_kernels.penalty(pen.depths(out.x), pen.k, pen.eps)[0]
        first = np.bincount(t["solver"].owner[pen.vid[:, 0]], weights=psi, minlength=len(t["members"]))
        for i, ((m, _), a, b) in enumerate(zip(t["members"], t["solver"].offsets[:-1], t["solver"].offsets[1:])):
            ctx.contacts[(_REACTION_KEY, m)] = float(first[i])
            ctx.contacts[(_REACTION_KEY, m, "obstacle force")] = obstacle[a:b]
            ctx.contacts[(_REACTION_KEY, m, "pair force")] = pair[a:b]

    def _surface_now(self, ctx, name: str) -> np.ndarray:
        """World surface vertices of a body: at the step end if it has stepped, else at the start."""
        if name in self._modal:
            st = ctx.out.bodies[name] if name in ctx.done else ctx.state_in.bodies[name]
            return self._modal[name]["body"].positions(st, precise=True)
        st = ctx.out.bodies[name] if name in ctx.done else ctx.state_in.bodies[name]
        return st.x[self._tet[name]["surface"]]

    def _modal_prediction(self, ctx, name: str):
        """World surface vertices (n, 3) [m] of modal body ``name`` at the step start and at its free step end (its
        own step without contacts: gravity, spin, modes, strikes), and that end state: the moving obstacle a tet
        body's step meets. The body's displacement by the tet's reaction is an unknown of that step
        (``tetcontact``), so the reaction's impulse at the step start moves it exactly as solved."""
        m = self._modal[name]
        body, s = m["body"], ctx.state_in.bodies[name]
        x0 = np.array(body.positions(s, precise=True), dtype=np.float64)
        ctl = self._strike_control(ctx, name)
        p = s.copy()
        try:
            m["solver"].step(s, p, ctl, None, ctx.dt)
        except SimulationError as exc:
            raise SimulationError(f"modal body {name!r}: {exc}") from None
        return x0, np.array(body.positions(p, precise=True), dtype=np.float64), p

    def _tet_contacts(self, ctx, name: str, s, t: dict | None = None) -> list:
        """Set this step's penalty contacts of tet body ``name`` (start state ``s``) with the obstacles and with
        the modal bodies' surfaces, the latter as moving obstacles at their predicted step end (tet vertices on
        modal faces, modal vertices on tet faces), so the tet's elasticity and these contacts are solved together
        in its implicit step; the modal bodies take the reaction (``_tet_reaction``). Returns the obstacle of
        each contact (for its friction, ``_tet_friction``; None: a contact between two tet bodies). ``t``: a group
        of tet bodies stepped together (``_tet_group``; ``s`` their stacked state), whose contacts with each other
        follow the obstacles' and the modal bodies' (``_tet_pair_contacts``)."""
        t = self._tet[name] if t is None else t
        c = t["contact"]
        dt, t1 = ctx.dt, ctx.state_in.time + ctx.dt
        dhat = c.margin
        sv = t["surface"]
        xs = s.x[sv]
        vmax = _top_speed(s)
        reach = _tet_reach(vmax, c.margin, dt)
        verts, ws, ps, ns, p0s, touched = [], [], [], [], [], []

        def add(ids, w, p, n, p0, o):  # (up to 4 vertices per contact: two tet bodies' in a group)
            verts.append(np.column_stack([ids, -np.ones((len(ids), 4 - ids.shape[1]), np.int64)]) if ids.ndim == 2
                         else np.column_stack([ids, -np.ones((len(ids), 3), np.int64)]))
            ws.append(np.column_stack([w, np.zeros((len(w), 4 - w.shape[1]))]))
            ps.append(p)
            ns.append(n)
            p0s.append(p if p0 is None else p0)
            touched.extend(o.points() if isinstance(o, _ModalSurface) else [o] * len(p))

        for o in self.obstacles:
            r = reach + (0.0 if not o.moving else float(np.linalg.norm(o.path.velocity(ctx.state_in.time, dt))) * dt)
            if isinstance(o, TriangleMesh):
                Vo = o.vertices + o.offset(t1)
                h = self._obstacle_surf[self.obstacles.index(o)].query(xs, Vo, r)
                if len(h.point):
                    p = np.einsum("kj,kjd->kd", h.bary, Vo[o.triangles[h.triangle]])
                    add(sv[h.point][:, None], np.ones((len(p), 1)), p, h.normal, None, o)
            else:
                gap, n = o.signed_distance(xs, t1)
                idx = np.flatnonzero(gap < r)
                if len(idx):
                    n = np.asarray(n)[idx]
                    add(sv[idx][:, None], np.ones((len(idx), 1)), xs[idx] - gap[idx, None] * n, n, None, o)
        n_obstacle = len(touched)
        modal = []  # per modal contact: (body, modal vertex ids (3,), weights (3,))
        ends = {}  # modal body -> (its free end state, how far its surface travels in the step [m])
        for m in self._tet_modal.get(name, ()):
            x0, x1, end = self._modal_prediction(ctx, m)
            travel = float(np.sqrt(np.einsum("ij,ij->i", x1 - x0, x1 - x0)).max())
            ends[m] = (end, travel)
            r = reach + travel + c.margin
            lo, hi = x1.min(0) - r, x1.max(0) + r
            if np.any(lo > xs.max(0)) or np.any(hi < xs.min(0)):
                continue
            tri = self._tris[m]
            h = self._surf[m].query(xs, x1, r)  # tet vertices on the modal faces (normal: out of the modal body)
            if len(h.point):
                T = tri[h.triangle]
                add(sv[h.point][:, None], np.ones((len(h.point), 1)), np.einsum("kj,kjd->kd", h.bary, x1[T]),
                    h.normal, np.einsum("kj,kjd->kd", h.bary, x0[T]), _ModalSurface(m, x0, x1, T, h.bary))
                modal.extend((m, T[i], h.bary[i]) for i in range(len(T)))
            h = t["proximity"].query(x1, xs, r)  # modal vertices on the tet faces (normal: out of the tet)
            if len(h.point):
                T = t["triangles"][h.triangle]
                ids = np.column_stack([h.point, h.point, h.point])
                one = np.tile([1.0, 0.0, 0.0], (len(h.point), 1))
                add(sv[T], h.bary, x1[h.point], -h.normal, x0[h.point], _ModalSurface(m, x0, x1, ids, one))
                modal.extend((m, ids[i], one[i]) for i in range(len(ids)))
            # tet edges on modal edges near each other (surfaces resting on each other, where an edge can cross a
            # face with every vertex outside: a soft tet's edge folding round the modal body's edge in a large
            # step), within what both travel in the step
            e = t["edges"].edges
            h = self._edges[m].query(xs[e[:, 0]], xs[e[:, 1]], x1, r)
            if len(h.mine):  # normals well out of the modal surface (else the contact's sign is ill-defined)
                side = self._edges[m].sides(x1, h.other)
                side /= np.maximum(np.linalg.norm(side, axis=1), 1e-300)[:, None]
                ok = np.einsum("ij,ij->i", h.normal, side) >= EDGE_ALIGN
                h = type(h)(h.mine[ok], h.other[ok], h.s[ok], h.t[ok], h.gap[ok], h.normal[ok])
            if len(h.mine):
                E = self._edges[m].edges[h.other]
                ids = np.column_stack([E, E[:, 0]])
                wm = np.column_stack([1.0 - h.t, h.t, np.zeros(len(h.t))])
                add(sv[e[h.mine]], np.column_stack([1.0 - h.s, h.s]), np.einsum("kj,kjd->kd", wm, x1[ids]),
                    h.normal, np.einsum("kj,kjd->kd", wm, x0[ids]), _ModalSurface(m, x0, x1, ids, wm))
                modal.extend((m, ids[i], wm[i]) for i in range(len(ids)))
        if "members" in t:  # the group's bodies with each other: relative positions (signed weights), plane at 0
            pv, pw, pn = self._tet_pair_contacts(t, s, reach + c.margin, dt * s.v)
            if len(pv):
                verts.append(pv)
                ws.append(pw)
                ps.append(np.zeros((len(pv), 3)))
                ns.append(pn)
                p0s.append(ps[-1])
                touched.extend([None] * len(pv))
        t["modal_contacts"] = (n_obstacle, modal)
        pen = t["penalty"]
        if not verts:
            pen.set(np.zeros((0, 4), np.int64), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), dhat)
            return []
        V, W = np.concatenate(verts), np.concatenate(ws)
        vid = np.where(V >= 0, V, 0)
        P, N, P0 = np.concatenate(ps), np.concatenate(ns), np.concatenate(p0s)
        # a contact with an obstacle already inside the skin at the step start is held where it is: a push out of
        # the skin would throw a body placed on the ground. Not with a modal body: its weight on a few vertices
        # would sink it by its force / stiffness every step (~0.1 mm per step for a 8 kg bar on a soft block)
        g0 = np.einsum("cd,cd->c", np.einsum("cj,cjd->cd", W, s.x[vid]) - P0, N)
        rows = np.arange(len(g0))
        # two tet bodies of a group: never held inside the skin (a resting pair crept through the surface, which
        # with a tet body is a crossing): their penalty is the same potential at every step, ``dhat`` off the surface
        pair = rows >= n_obstacle + len(modal)
        hold = rows < n_obstacle
        # a modal (or tet-tet) contact whose point is more than a skin behind the other surface at the step start is
        # the wrong feature (a tet vertex under a thin bell's rim closest to its inner wall: 2.8 mm "behind" it;
        # pushed out of it in one step, that was +9.6 mJ in the landing step of tutorials/world.py), not a
        # crossing: the surfaces are intersection-free at every step end
        keep = (rows < n_obstacle) | (g0 >= -dhat)
        if not keep.all():
            sel = np.flatnonzero(keep[n_obstacle:n_obstacle + len(modal)])
            modal = [modal[i] for i in sel]
            t["modal_contacts"] = (n_obstacle, modal)
            touched = [o for o, kk in zip(touched, keep) if kk]
            V, W, vid, P, N, g0, hold, pair = (V[keep], W[keep], vid[keep], P[keep], N[keep], g0[keep], hold[keep],
                                               pair[keep])
        P = P - np.where(hold, dhat - np.clip(g0, 0.0, dhat), 0.0)[:, None] * N
        m = t["masses"][vid]
        inv = np.where((V >= 0) & np.isfinite(m), W**2 / np.where(np.isfinite(m), m, 1.0), 0.0).sum(1)
        k = np.where(inv > 0, STIFFNESS / np.where(inv > 0, inv, 1.0) / dt**2, 0.0)
        last = self._last_force(ctx, name, t, "obstacle force")  # [N] by vertex, last step
        if last is not None and n_obstacle:  # (a soft body's vertices bear the weight of what rests on it too)
            k[:n_obstacle] = np.maximum(k[:n_obstacle], DEPTH_SHARE * last[V[:n_obstacle, 0]] / dhat)
        last = self._last_force(ctx, name, t, "pair force") if pair.any() else None
        if last is not None:  # the same for the group's bodies resting on each other (by the contact's first vertex)
            k[pair] = np.maximum(k[pair], DEPTH_SHARE * last[V[pair, 0]] / dhat)
        # each modal body's rigid displacement by the reaction is solved with the tet (``tetcontact``): no explicit
        # limit on the stiffness; its contacts share the body's weight and hold its approach (the tet's too) in a
        # part of the skin: at least DEPTH_SHARE (approach + |g| dt^2) / dhat times its mass / dt^2, summed
        bodies, arms, inertia = np.full(len(k), -1, np.int64), np.zeros((len(k), 6)), []
        for b in self._tet_modal.get(name, ()):
            sel = n_obstacle + _contacts_of(modal, b)
            if not len(sel):
                continue
            body, (end, travel) = self._modal[b]["body"], ends[b]
            R = ctx.state_in.bodies[b].rotation()
            S = np.zeros((6, 6))
            S[:3, :3] = body.mass * np.eye(3)
            S[3:, 3:] = R @ body.inertia @ R.T
            approach = travel + vmax * dt + float(np.linalg.norm(self._modal[b]["g"])) * dt * dt
            last = ctx.state_in.contacts.get((_REACTION_KEY, name, "force"), {}).get(b, 0.0)  # [N]
            force = max(approach * body.mass / dt**2, last)
            share = DEPTH_SHARE * force / dhat / len(sel)
            k[sel] = np.maximum(k[sel], share)
            arms[sel] = np.column_stack([N[sel], np.cross(P[sel] - end.position, N[sel])])
            bodies[sel] = len(inertia)
            inertia.append(S / dt**2)
        pen.set(V, W, P, N, k, dhat, bodies=bodies, arms=arms, inertia=inertia)
        if pair.any() and c.friction > 0:
            # the group's bodies rub on each other inside the step (a lagged potential: the normal forces at the start),
            # so a body resting on another on a slope sticks: friction applied to the end velocities alone let the
            # step's tangential push move it every step (a cube on a cube on foam crept ~1 mm/s at 10 ms steps).
            # Below a slip of eps per step a contact sticks elastically
            rows = np.flatnonzero(pair)
            eps = max(FRICTION_SLIP * dt, 10.0 * t["solver"].tol * t["solver"].model.size)
            pen.set_friction(rows, c.friction * pen.forces(s.x)[rows], s.x, eps)
        return touched

    def _tet_restitution(self, ctx, name: str, s, out, t: dict | None = None) -> None:
        """Restitution between tet body ``name`` (start ``s``, end ``out``) and the modal bodies it meets, on the
        bodies' relative motion (Poisson): an impact starts when their contacts first push (the relative velocity
        ``v0`` of the tet's centre of mass and the modal body noted); while the pair approaches, the normal impulse
        adds up (``J_c``); when it stops approaching, the pair takes ``e J_c`` more, equal and opposite, through the
        tet's centre of mass (all its vertices alike: no strain) and the modal body's. Capped so that the relative
        motion's kinetic energy after it, plus what the tet stored in the impact (elastic, contact, vibration), is at
        most ``e^2`` times the impact's ``mu v0^2 / 2`` (mu the reduced mass): the energy the implicit step's
        damping took is given back, never more; the elasticity of a soft body returns what it stored itself. When
        the contacts let go, the pair is topped up once more, to ``e v0`` apart under the same cap: at steps much
        shorter than the impact, the tet's elastic return after the end of compression takes many steps, and the
        implicit step's damping of it (0.19 v0 of the rebound of a stiff block at dt = 0.1 ms) is given back too.
        ``t``: a member of a group's view (``_group_restitution``; ``s`` and ``out`` its slices of the group's)."""
        t = self._tet[name] if t is None else t
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        m = t["masses"]
        if not modal or not np.all(np.isfinite(m)):
            return
        pen = t["penalty"]
        f = pen.forces(out.x)[n_obstacle:]
        M = float(m.sum())
        Vt = m @ out.v / M
        en = t["solver"].energies(out)
        stored = en["elastic"] + pen.penalty_energy(out.x) + en["kinetic"] - 0.5 * M * float(Vt @ Vt)
        for b in self._tet_modal[name]:
            sel = _contacts_of(modal, b)
            J = ((f[sel] * ctx.dt)[:, None] * pen.nrm[n_obstacle + sel]).sum(0) if len(sel) else np.zeros(3)
            key = (_REACTION_KEY, name, "impact", b)
            rec = ctx.state_in.contacts.get(key)
            if not np.any(J) and rec is None:
                continue
            mb = self._modal[b]
            cb = self._one(b, fx.Contact)
            e = t["contact"].restitution if cb is None else min(t["contact"].restitution, cb.restitution)
            sb = ctx.state_in.bodies[b]
            Vb = sb.velocity + mb["g"] * ctx.dt + (ctx.dV[b][:3] if b in ctx.dV else 0.0)
            if rec is None:  # the impact starts: the relative velocity and the tet's stored energy before it
                V0 = m @ s.v / M
                e0 = t["solver"].energies(s)
                rec = (V0 - sb.velocity, e0["elastic"] + e0["kinetic"] - 0.5 * M * float(V0 @ V0), np.zeros(3), False)
            v_start, stored0, Jc, done = rec
            Jc = Jc + J
            ended = not np.any(J)  # the contacts let go: the impact's record is not carried on
            if not ended:
                ctx.contacts[key] = (v_start, stored0, Jc, done)
            nJ = float(np.linalg.norm(Jc))
            if (done and not ended) or e <= 0 or nJ == 0:
                continue
            nh = Jc / nJ  # on the tet, out of the modal body
            vn = float((Vt - Vb) @ nh)
            if vn < 0:  # still approaching
                continue
            mu = 1.0 / (1.0 / M + 1.0 / mb["body"].mass)
            v0 = max(-float(v_start @ nh), 0.0)
            vmax = math.sqrt(max(e * e * v0 * v0 - 2.0 * max(stored - stored0, 0.0) / mu, 0.0))
            lam = max(0.0, mu * (vmax - vn) if ended else min(e * nJ, mu * (vmax - vn)))
            if not ended:
                ctx.contacts[key] = (v_start, stored0, Jc, True)
            if lam == 0:
                continue
            out.v += lam * nh / M
            dV = np.zeros(6 + mb["body"].mode_count)
            dV[:3] = -lam * nh / mb["body"].mass
            ctx.dV[b] = ctx.dV[b] + dV if b in ctx.dV else dV
            ctx.report.exchanged.append((b, name, -lam * nh, np.cross(sb.position, -lam * nh)))

    @staticmethod
    def _tet_too_deep(pen, x: np.ndarray) -> bool:
        """True, and the contacts that ended deeper than ``MAX_DEPTH`` of the skin stiffened to end at a quarter of
        it (their force held), when the step is to be redone."""
        depth = pen.depths(x)
        over = depth > MAX_DEPTH * pen.dhat
        if not over.any():
            return False
        pen.stiffen(np.where(over, depth / (0.25 * pen.dhat), 1.0))
        return True

    def _tet_reaction(self, ctx, name: str, out, t: dict | None = None) -> None:
        """The modal bodies take the opposite of the impulses the tet body's penalty contacts with them gave it in
        its implicit step (``f dt`` along the normal at each contact's modal point): generalised velocity changes
        at the step start (``ctx.dV``, merged with the solid solve's), reported in ``StepReport.exchanged``. Their
        rigid part is the body's displacement solved in the step (``tetcontact``) over dt. ``t``: a group's entry
        (``_tet_group``; the impulses reported as from the member body each contact's vertices belong to)."""
        t = self._tet[name] if t is None else t
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        if not modal:
            return
        pen = t["penalty"]
        f = pen.forces(out.x)[n_obstacle:]
        J = -(f * ctx.dt)[:, None] * pen.nrm[n_obstacle:]  # on the modal body
        ctx.contacts[(_REACTION_KEY, name, "force")] = {  # [N] by body: the next step's stiffness holds it
            b: float(f[_contacts_of(modal, b)].sum()) for b in self._tet_modal[name]}
        for b in self._tet_modal[name]:
            sel = _contacts_of(modal, b)
            sel = sel[f[sel] > 0]
            for src, part in self._by_member(t, name, n_obstacle + sel):
                part = part - n_obstacle
                ids = np.array([modal[i][1] for i in part])
                w = np.array([modal[i][2] for i in part])
                self._modal_impulses(ctx, b, ids, w, J[part], src)

    def _by_member(self, t: dict, name: str, rows: np.ndarray) -> list:
        """``(body, rows)``: the contact ``rows`` (penalty indices) by the tet body of their first vertex (a group's
        members; else ``name``), bodies without rows left out."""
        if not len(rows):
            return []
        if "members" not in t:
            return [(name, rows)]
        owner = t["solver"].owner[t["penalty"].vid[rows, 0]]
        return [(n, rows[owner == i]) for i, (n, _) in enumerate(t["members"]) if np.any(owner == i)]

    def _modal_impulses(self, ctx, b: str, ids: np.ndarray, w: np.ndarray, J: np.ndarray, src: str) -> np.ndarray:
        """Impulses ``J`` (k, 3) [N s] on modal body ``b`` at its surface points ``sum_j w_j vertex_j`` (ids, w
        (k, 3)) at the step start, from body ``src``: added to ``ctx.dV[b]`` (rigid: v, omega; the modes the
        step resolves, as ``_ContactBuilder``), and reported as exchanged."""
        body = self._modal[b]["body"]
        s = ctx.state_in.bodies[b]
        R = s.rotation()
        phi = np.einsum("kj,kjcr->kcr", w, body.vertex_shapes(ids.reshape(-1)).reshape(ids.shape + (3, -1)))
        rest = np.einsum("kj,kjc->kc", w, body.rest[ids])
        r = (rest + np.einsum("kcr,r->kc", phi, s.q)) @ R.T
        Jsum = J.sum(0)
        L = np.cross(r, J).sum(0)
        dq = np.einsum("kcr,kc->r", np.einsum("ab,kbr->kar", R, phi), J) * (body.omega * ctx.dt <= SLOW)
        dV = np.concatenate([Jsum / body.mass, R @ body.inertia_inv @ R.T @ L, dq])
        ctx.dV[b] = ctx.dV[b] + dV if b in ctx.dV else dV
        ctx.report.exchanged.append((b, src, Jsum, np.cross(r + s.position, J).sum(0)))
        return dV

    def _tet_friction(self, ctx, name: str, out, obstacles: list, t: dict | None = None) -> None:
        """Coulomb friction of the tet's penalty contacts: the tangential velocity of a contact's point relative to
        the obstacle's (or modal body's) surface shrinks by at most ``mu f dt / m_eff`` (f the penalty force at the
        step end), the change spread over the point's vertices by their weights; a modal body takes the opposite
        impulse. The end velocities change, not the end positions: friction moving single vertices by ``dt dv``
        stored the shear against their neighbours as elastic energy (a steel bar landing on a soft block with
        friction 0.5 gained ~5 mJ per 1 ms step, 2.4 % of the scene's energy); the tet's next implicit step takes
        the slowed vertices with its elasticity. A group's bodies (``t``, ``_tet_group``) rub on each other alike,
        each contact's impulses equal and opposite on the two (signed weights); what each received from the other,
        with the penalty's impulses, is reported in ``StepReport.exchanged``."""
        t = self._tet[name] if t is None else t
        pen = t["penalty"]
        mu = t["contact"].friction
        if not pen.count:
            return
        f = pen.forces(out.x)
        act = np.flatnonzero(f > 0)
        ctx.report.contacts["tet"] = ctx.report.contacts.get("tet", 0) + len(act)
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        start = n_obstacle + len(modal)  # the group's bodies with each other from here
        J = np.zeros((pen.count, 3))
        if pen.fric is not None:  # rubbing inside the step: not again here; its impulses for the report
            rows, F = pen.friction_forces(out.x)
            J[rows] = F * ctx.dt
            act = np.setdiff1d(act, rows)
        if mu > 0:
            J = J + self._tet_friction_pass(ctx, name, out, obstacles, t, f, act, mu)
        if "members" in t and start < pen.count:
            self._pair_exchange(ctx, t, out, f, J, start)

    def _pair_exchange(self, ctx, t: dict, out, f: np.ndarray, J: np.ndarray, start: int) -> None:
        """Report what each body of a group received from each other (the penalty's ``f dt n`` and the friction
        impulse ``J`` of the contacts from ``start``, spread by their signed weights): one entry per ordered pair
        of members in contact, each side summed on its own vertices."""
        pen = t["penalty"]
        rows = np.arange(start, pen.count)
        rows = rows[(f[rows] > 0) | np.any(J[rows] != 0.0, axis=1)]
        if not len(rows):
            return
        imp = (f[rows] * ctx.dt)[:, None] * pen.nrm[rows] + J[rows]  # on the point (sum_j w_j x_j)
        owner, first, other = pair_owners(t["solver"], pen, rows)  # (k, 4), (k,), (k,)
        names = [n for n, _ in t["members"]]
        for a in range(len(names)):
            for b in range(len(names)):
                sel = between(first, other, a, b)
                if a == b or not len(sel):
                    continue
                on_a = np.where(owner[sel] == a, pen.w[rows[sel]], 0.0)  # (k, 4): the weights of a's vertices
                Jv = on_a[:, :, None] * imp[sel][:, None, :]  # (k, 4, 3) on each of a's vertices
                x = out.x[pen.vid[rows[sel]]]
                ctx.report.exchanged.append((names[a], names[b], Jv.sum((0, 1)), np.cross(x, Jv).sum((0, 1))))

    def _tet_friction_pass(self, ctx, name: str, out, obstacles: list, t: dict, f: np.ndarray, act: np.ndarray,
                           mu: float) -> np.ndarray:
        """The friction of ``_tet_friction`` (``mu`` > 0): end velocities changed in place; the impulses (c, 3)."""
        pen = t["penalty"]
        n_obstacle, modal = t.get("modal_contacts", (0, []))
        # the obstacles' surface velocities at the contacts' points (the positions do not change below), per
        # obstacle at once; a modal body's point moves as predicted over the step
        vo = np.zeros((pen.count, 3))
        extra = np.zeros(pen.count)  # [1/kg]: a modal body's translation takes the opposite impulse
        pt = np.einsum("cj,cjd->cd", pen.w, out.x[pen.vid])
        if n_obstacle:
            ob = act[act < n_obstacle]
            for o in {id(obstacles[c]): obstacles[c] for c in ob}.values():
                sel = np.array([c for c in ob if obstacles[c] is o], dtype=np.int64)
                vo[sel] = np.asarray(o.velocity(pt[sel], ctx.state_in.time, ctx.dt))
        md = act[(act >= n_obstacle) & (act < n_obstacle + len(modal))]
        if len(md):
            vo[md] = np.array([obstacles[c].velocity(None, 0.0, ctx.dt) for c in md]).reshape(-1, 3)
            inv_mass = {b: 1.0 / self._modal[b]["body"].mass for b in self._tet_modal[name]}
            extra[md] = [inv_mass[modal[c - n_obstacle][0]] for c in md]
        # in contact order, each contact seeing the velocities the ones before left (compiled)
        J = _tet_kernels.friction(act.astype(np.int64), pen.verts, pen.w, t["masses"], extra, out.v, vo,
                                  pen.nrm, f, float(mu), float(ctx.dt))
        back = {}  # modal body -> contacts with an impulse: the opposite impulses, given once per body below
        for c in md[np.any(J[md] != 0.0, axis=1)] if len(md) else ():
            back.setdefault(modal[c - n_obstacle][0], []).append(c)
        for mb, cs in back.items():
            for src, part in self._by_member(t, name, np.array(cs, dtype=np.int64)):
                self._modal_impulses(ctx, mb, np.array([modal[c - n_obstacle][1] for c in part]),
                                     np.array([modal[c - n_obstacle][2] for c in part]), -J[part], src)
        return J

    def _kick(self, ctx, kind: str, other: str, data, J: np.ndarray) -> None:
        """Impulse ``J`` (3,) [N s] on solid body ``other`` at its contact point, at its step end (see
        ``_reaction``): a modal body's rigid motion, a tet body's vertices by their weights."""
        ids, w, pt = data
        if kind == "modal":
            st = ctx.out.bodies[other]
            st.velocity += J / self._modal[other]["body"].mass
            st.angular_momentum += np.cross(pt - st.position, J)
            return
        t = self._tet[other]
        vid = t["surface"][np.asarray(ids)]  # surface-local -> mesh vertex ids
        m = t["masses"][vid]
        dv = np.where(np.isfinite(m), 1.0, 0.0)[:, None] * (w / np.where(np.isfinite(m), m, 1.0))[:, None] * J
        ctx.out.bodies[other].v[vid] += dv

    def _stage_tet_self(self, ctx) -> None:
        dt = ctx.dt
        for name, t in self._tet.items():
            if t["pipeline"] is None:
                continue
            x0 = ctx.start[name].x
            out = ctx.out.bodies[name]
            sv = t["surface"]
            v = (out.x[sv] - x0[sv]) / dt
            v_new, stats = t["pipeline"].resolve(x0[sv], v, t["masses"][sv], dt, t=ctx.state_in.time)
            if stats.unresolved:
                raise SimulationError(f"tet body {name!r}: self-collision left {stats.unresolved} colliding pairs")
            out.v[sv] += v_new - v
            out.x[sv] = x0[sv] + dt * v_new

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

    def _stage_contacts(self, ctx) -> None:
        """Modal bodies against each other and against moving and mesh obstacles (a tet body meets modal bodies and
        other tet bodies in its implicit step): one compiled sequential-impulse solve (see the module docstring).
        Modal bodies against each other and static planes are found and written by ``modal_contacts.ModalContacts``
        (compiled); the rest by ``_ContactBuilder``."""
        dt = ctx.dt
        t0 = ctx.state_in.time
        names = self._modal_contact
        seg, V_parts, pos, speed = {}, [], {}, {}
        n_off = 0
        fast = self._fast
        blocks = {}  # the compiled modal contacts' bodies: their velocity blocks and speed bounds in one call
        if fast is not None:
            Vf, sf = fast.velocity_blocks(ctx.state_in.bodies, {n: self._modal[n]["g"] for n in fast.names}, dt)
            o = 0
            for i, n in enumerate(fast.names):
                blocks[n] = (Vf[o:o + 6 + fast.nm[i]], float(sf[i]))
                o += 6 + fast.nm[i]
        for name in names:
            if name in blocks:
                V_parts.append(blocks[name][0])
                if name in ctx.dV:  # the reaction of tet bodies' contacts with it (``_tet_reaction``)
                    V_parts[-1] = V_parts[-1] + ctx.dV[name]
                speed[name] = blocks[name][1]
                seg[name] = (n_off, len(blocks[name][0]))
            elif name in self._modal:
                m = self._modal[name]
                s = ctx.state_in.bodies[name]
                body = m["body"]
                w = body.angular_velocity(s)
                V_parts.append(np.concatenate([s.velocity + m["g"] * dt, w, s.qdot]))
                if name in ctx.dV:  # the reaction of tet bodies' contacts with it (``_tet_reaction``)
                    V_parts[-1] += ctx.dV[name]
                speed[name] = float(np.linalg.norm(s.velocity) + np.linalg.norm(w) * body.radius
                                    + np.linalg.norm(m["g"]) * dt)
                if body.mode_count:
                    u = (s.qdot @ body.shapes_t).reshape(-1, 3)  # each vertex's deformation velocity
                    speed[name] += float(np.sqrt((u * u).sum(1)).max())
                seg[name] = (n_off, 6 + body.mode_count)
            else:
                out = ctx.out.bodies[name]
                V_parts.append(out.v.reshape(-1).copy())
                pos[name] = ctx.start[name].x[self._tet[name]["surface"]]
                speed[name] = float(np.sqrt(np.einsum("ij,ij->i", out.v, out.v)).max())
                seg[name] = (n_off, 3 * len(out.v))
            n_off += seg[name][1]
        V = np.concatenate(V_parts)

        def where(name):  # world surface of a modal body at the step start, computed once when needed
            x = pos.get(name)
            if x is None:
                x = pos[name] = self._modal[name]["body"].positions(ctx.state_in.bodies[name], precise=True)
            return x

        builder = _ContactBuilder(self, ctx, seg, names)
        driven = False  # a moving obstacle in contact: it may do work on the bodies (no energy rule then)
        for name, obs in self._world_obstacles.items():  # modal bodies: moving obstacles and meshes (all if shared)
            c = None
            for o in obs:
                tag = self.obstacles.index(o)
                if tag in self._fast_planes:
                    continue
                if c is None:
                    c = self._one(name, fx.Contact)
                x = where(name)
                reach = c.margin + speed[name] * dt
                if o.moving:
                    reach += float(np.linalg.norm(o.path.velocity(t0, dt))) * dt
                if isinstance(o, TriangleMesh):
                    hits = self._obstacle_surf[tag].query(x, o.vertices + o.offset(t0), reach)
                    idx, gap, nrm = hits.point, hits.gap, hits.normal
                else:
                    gap_all, n_all = o.signed_distance(x, t0)
                    idx = np.flatnonzero(gap_all < reach)
                    gap, nrm = gap_all[idx], np.asarray(n_all)[idx]
                if len(idx):
                    builder.obstacle(name, idx, gap, nrm, np.asarray(o.velocity(x[idx], t0, dt)), c, tag=tag)
                    driven |= o.moving
        for i, a in enumerate(names):  # every pair with a tet body: vertices on faces both ways, edges on edges
            for b in names[i + 1:]:
                if fast is not None and a in self._modal and b in self._modal:
                    continue  # compiled below
                if a in self._tet or b in self._tet:
                    continue  # in the tet's implicit step (``_tet_contacts``; never here today: names are modal)
                ca, cb = self._one(a, fx.Contact), self._one(b, fx.Contact)
                reach = max(ca.margin, cb.margin) + (speed[a] + speed[b]) * dt
                xa, xb = where(a), where(b)
                lo = np.maximum(xa.min(0), xb.min(0)) - reach
                hi = np.minimum(xa.max(0), xb.max(0)) + reach
                if np.any(lo > hi):
                    continue
                for p, q, xp, xq, cp, cq in ((a, b, xa, xb, ca, cb), (b, a, xb, xa, cb, ca)):
                    near = np.flatnonzero(np.all((xp >= lo) & (xp <= hi), axis=1))
                    if len(near):
                        h = self._surf[q].query(xp[near], xq, reach)
                        if len(h.point):
                            builder.general(p, near[h.point][:, None], np.ones((len(h.point), 1)), q,
                                            self._tris[q][h.triangle], h.bary, h.gap, h.normal, cp, cq)
                # edges against edges only within the margin (surfaces at rest on each other, where an edge can
                # cross a face with every vertex outside); approaching surfaces are held by their vertices
                ea = self._edges[a].edges
                a0, a1 = xa[ea[:, 0]], xa[ea[:, 1]]
                sel = np.flatnonzero(np.all((np.minimum(a0, a1) <= hi) & (np.maximum(a0, a1) >= lo), axis=1))
                if len(sel):
                    h = self._edges[b].query(a0[sel], a1[sel], xb, max(ca.margin, cb.margin))
                    if len(h.mine):
                        builder.general(a, ea[sel[h.mine]], np.column_stack([1.0 - h.s, h.s]), b,
                                        self._edges[b].edges[h.other], np.column_stack([1.0 - h.t, h.t]),
                                        h.gap, h.normal, ca, cb)
        fdata = None
        if fast is not None:
            fdata = fast.collect(ctx.state_in.bodies, {n: seg[n][0] for n in fast.names}, speed, dt,
                                 {n: names.index(n) for n in fast.names}, ctx.state_in.contacts.get(_FAST_KEY))
        kp = builder.count
        k = kp + (len(fdata["gap"]) if fdata is not None else 0)
        ctx.report.contacts["solid"] = k
        ctx.contacts = {key: v for key, v in ctx.contacts.items() if key[0] == _REACTION_KEY}
        if k == 0:
            return
        data = _merge(builder.arrays() if kp else None, fdata)
        n = data["normal"]
        lam_n, lam_t = np.zeros(k), np.zeros((k, 3))
        old_lam = np.zeros((k, 3))
        for c, key in enumerate(builder.keys):  # warm start: the impulses these contacts had in the last step
            old = ctx.state_in.contacts.get(key)
            if old is not None:
                old_lam[c] = old
        if fdata is not None:
            old_lam[kp:] = fdata["warm"]
        lam_n[:] = np.maximum(np.einsum("ij,ij->i", old_lam, n), 0.0)
        t = old_lam - np.einsum("ij,ij->i", old_lam, n)[:, None] * n
        tn = np.sqrt(np.einsum("ij,ij->i", t, t))
        lim = data["mu"] * lam_n
        lam_t[:] = t * np.where(tn <= lim, 1.0, lim / np.where(tn > 0, tn, 1.0))[:, None]
        lam, bounce, sweeps = _solve(V, data, lam_n, lam_t, dt, None if driven else
                                     self._inverse_mass_blocks(ctx, seg, names))
        ctx.report.sweeps = sweeps
        ctx.contacts.update({key: lam[c] for c, key in enumerate(builder.keys) if lam_n[c] > 0.0})
        if fdata is not None:
            fk = fdata["keys"]
            held = lam_n[kp:] > 0.0
            order = np.argsort(fk[held], kind="stable")
            ctx.contacts[_FAST_KEY] = (fk[held][order], lam[kp:][held][order])
        dV = data["dV"]
        for name, (o, nd) in seg.items():
            if name in self._modal:
                ctx.dV[name] = dV[o:o + nd] + ctx.dV.get(name, 0.0)  # taken at the step start by the modal step
            else:  # a tet body's end velocities, and its positions with them (x = x_start + dt v)
                dv = dV[o:o + nd].reshape(-1, 3)
                out = ctx.out.bodies[name]
                out.v += dv
                out.x += dt * dv
        # what each body received from each other body (the other received the opposite), per pair
        uniq, J, L = _kernels.exchanged(data["body"], data["other"], data["point"], lam, len(names))
        if len(uniq):  # per pair sums in contact order
            for i, kk in enumerate(uniq.tolist()):
                ctx.report.exchanged.append((names[kk // len(names)], names[kk % len(names)], J[i], L[i]))
        for name in self._sounds:  # what sounding bodies hear: the modal kick of the contacts that bounced
            if name in seg:
                i = names.index(name)
                sel = np.flatnonzero(bounce & ((data["body"] == i) | (data["other"] == i)))
                if len(sel):
                    dq = builder.modal_change(name, sel[sel < kp], lam) if np.any(sel < kp) else 0.0
                    if fdata is not None and name in fast.names and np.any(sel >= kp):
                        dq = dq + fast.modal_change(name, fdata, sel[sel >= kp] - kp, lam[kp:])
                    ctx.impacts[name] = dq

    def _inverse_mass_blocks(self, ctx, seg: dict, names: list) -> tuple:
        """Per body ``(offset, size, mass, inertia, shift)`` to measure the energy of velocity changes: a modal
        body's mass [kg] and world inertia [kg m^2] (its modal coordinates have unit mass), a tet body's vertex
        masses (inf, pinned: 0) and no inertia; ``shift`` (3,) [m/s] is ``g dt``, which the solve's velocities hold
        but the energy must not count: a velocity change dv at the step start moves the body by ``dv dt`` in the
        gravity field, which costs ``-m g . dv dt``, so the energy change is ``dv . M (V - g dt) + 0.5 dv . M dv``.
        Returns ``(fast, out)``: the compiled modal contacts' bodies as arrays for ``_kernels.modal_energy_change``
        (offsets, sizes, masses, rotations at the step start, body-axes inertias, shifts; None without them), and
        the list of the other bodies' tuples."""
        fast = self._fast
        quick = None
        if fast is not None and all(n in seg for n in fast.names):
            quick = (np.array([seg[n][0] for n in fast.names], dtype=np.int64), 6 + fast.nm, fast.mass,
                     fast.rotations, fast.inertia, np.array([self._modal[n]["g"] for n in fast.names]) * ctx.dt)
        out = []
        for name in names:
            if quick is not None and name in fast.index:
                continue
            o, nd = seg[name]
            if name in self._modal:
                g = self._modal[name]["g"]  # its gravity effects' sum, formed at build
            else:
                g = np.zeros(3)
                for e in self.effects_of(name):
                    if isinstance(e, fx.Gravity):
                        g += np.asarray(e.g)
            if name in self._modal:
                body = self._modal[name]["body"]
                R = ctx.state_in.bodies[name].rotation()
                out.append((o, nd, body.mass, R @ body.inertia @ R.T, g * ctx.dt))
            else:
                m = self._tet[name]["masses"]
                out.append((o, nd, np.where(np.isfinite(m), m, 0.0), None, g * ctx.dt))
        return quick, out

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
        the step pumps energy between the aliased vibration and the cloth)."""
        d = self._deform
        moved = np.flatnonzero(np.any(dv != 0.0, axis=1) & np.isfinite(d["masses"]))
        total = 0
        if len(moved):
            reach = 2.0 * d["thickness"]
            best = {}
            for n in d["motions"]:
                xs = self._surface_now(ctx, n)
                prox = self._surf[n] if n in self._modal else self._tet[n]["proximity"]
                tri_all = self._modal[n]["body"].triangles if n in self._modal else self._tet[n]["triangles"]
                h = prox.query(x1[moved], xs, reach)
                for i, tri, w, g in zip(h.point, h.triangle, h.bary, h.gap):
                    if i not in best or abs(g) < best[i][3]:
                        best[i] = (n, tri_all[tri], w, abs(g), np.einsum("j,jd->d", w, xs[tri_all[tri]]))
            owner = {m: d["offsets"][m] for m in d["members"]}
            per = {}
            for i, (n, tri, w, _, pt) in best.items():
                v = moved[i]
                J = -d["masses"][v] * dv[v]  # what the solid receives
                kind = "modal" if n in self._modal else "tet"
                self._kick(ctx, kind, n, (tri, w, pt), J)
                src = next(m for m, (a, k) in owner.items() if a <= v < a + k)
                J0, L0 = per.get((n, src), (np.zeros(3), np.zeros(3)))
                per[(n, src)] = (J0 + J, L0 + np.cross(pt, J))
                total += 1
            for (n, src), (J, L) in per.items():
                ctx.report.exchanged.append((n, src, J, L))
        ctx.report.contacts["reaction"] = total

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


class _MemberContacts:
    """A group member's contacts with the modal bodies, as ``_tet_restitution`` reads them: their forces [N] and
    normals at the step end, and the energy [J] stored in the contacts of its vertices."""

    def __init__(self, f: np.ndarray, nrm: np.ndarray, stored: float) -> None:
        self.f, self.nrm, self.stored = f, nrm, stored

    def forces(self, x: np.ndarray) -> np.ndarray:
        return self.f

    def penalty_energy(self, x: np.ndarray) -> float:
        return self.stored


class _StepContext:
    def __init__(self, state_in: WorldState, out: WorldState, control: WorldControl, dt: float) -> None:
        self.state_in, self.out, self.control, self.dt = state_in, out, control, dt
        self.start = {}
        self.done = set()
        self.dV = {}
        self.cloth_dv = {}
        self.impacts = {}
        self.contacts = dict(state_in.contacts)  # kept unless the solid solve runs
        self.report = None


#: the control of a step given none (never changed: stages only read it)
_NO_CONTROL = WorldControl()


#: step the modal bodies with gravity alone in one compiled call (``_modal_step.ModalBatch``); False: each by its
#: solver (the same arithmetic; tests compare the two)
MODAL_BATCH = True
#: the key of the compiled modal contacts' impulses in ``WorldState.contacts``: (sorted int64 keys, (k, 3) [N s])
_FAST_KEY = "modal contacts"
#: ``WorldState.contacts[(_REACTION_KEY, tet body)]``: the energy [J] stored in the tet body's penalty contacts at
#: the end of the last step (``World.energy``'s ``contact``); ``[(_REACTION_KEY, tet body, "force")]``: the normal
#: force [N] its contacts bore from each modal body (the next step's stiffness is sized to hold it), ``[(...,
#: "obstacle force")]`` its vertices' from the obstacles (n,) [N];
#: ``[(_REACTION_KEY, tet body, "impact", modal body)]``: an impact in progress (``_tet_restitution``)
_REACTION_KEY = "tet reaction"


def _merge(a: dict | None, b: dict | None) -> dict:
    """The solve arrays of the Python builder's contacts followed by the compiled modal contacts'."""
    if a is None or b is None:
        return dict(a if b is None else b)
    out = {key: np.concatenate([a[key], b[key]]) for key in (
        "off", "nd", "normal", "gap", "vobs_n", "mu", "restitution", "margin", "body", "other", "point", "J", "WJt")}
    out["ptr"] = np.concatenate([a["ptr"], b["ptr"][1:] + a["ptr"][-1]])
    out["jptr"] = np.concatenate([a["jptr"], b["jptr"] + len(a["J"])])
    out["iterations"] = max(a["iterations"], b["iterations"])
    return out


#: the solve stops once a sweep changes no contact's velocity by more than this fraction of the velocity that
#: closes its skin (half its margin) in one step
VELOCITY_STOP = 1e-2


def _solve(V: np.ndarray, data: dict, lam_n: np.ndarray, lam_t: np.ndarray, dt: float, blocks: tuple | None):
    """The sequential-impulse solve in place on ``V`` from the warm start ``lam_n``, ``lam_t``; then no gain: the
    kinetic energy change of the impulses ``dV^T M V0 + 0.5 dV^T M dV`` (summed over the bodies, ``blocks`` as
    ``World._inverse_mass_blocks``; None: no energy rule, a moving obstacle may do work) is made <= 0 by scaling
    every impulse back (equal and opposite impulses stay so). Returns ``(lam (k, 3), bounce (k,), sweeps)`` and
    leaves ``data["dV"]``."""
    ptr, off, nd, jptr, J, WJt = (data[key] for key in ("ptr", "off", "nd", "jptr", "J", "WJt"))
    K = data.get("K")  # the compiled modal contacts' come with their entries
    if K is None:
        K = _kernels.effective_masses(ptr, off, nd, jptr, J, WJt)
    u = _kernels.contact_velocities(V, ptr, off, nd, jptr, J)
    n = data["normal"]
    vn = np.einsum("ij,ij->i", u, n) - data["vobs_n"]
    gap = data["gap"]
    skin = 0.5 * data["margin"]
    target = np.where(gap > skin, -(gap - skin) / dt, PUSH_OUT * (skin - gap) / dt)
    e = data["restitution"]
    bounce = (vn < -BOUNCE_THRESHOLD) & (e > 0) & (gap <= data["margin"])
    target = np.where(bounce, np.maximum(target, -e * vn), target) + data["vobs_n"]
    V0 = V.copy()
    _kernels.apply_impulses(V, ptr, off, nd, jptr, WJt, lam_n[:, None] * n + lam_t)
    vtol = VELOCITY_STOP * float(np.min(skin)) / dt
    sweeps = _kernels.sequential_impulses(V, ptr, off, nd, jptr, J, WJt, K, n, target, data["mu"],
                                          int(data["iterations"]), lam_n, lam_t, vtol)
    lam = lam_n[:, None] * n + lam_t
    dV = V - V0
    work = quad = 0.0
    if blocks is not None and blocks[0] is not None:
        work, quad = _kernels.modal_energy_change(dV, V0, *blocks[0])
    for o, m, mass, inertia, shift in blocks[1] if blocks is not None else ():
        dv, v0 = dV[o:o + m], V0[o:o + m]
        if inertia is not None:  # modal: (v, w, qdot)
            work += (mass * float(dv[:3] @ (v0[:3] - shift)) + float(dv[3:6] @ (inertia @ v0[3:6]))
                     + float(dv[6:] @ v0[6:]))
            quad += mass * float(dv[:3] @ dv[:3]) + float(dv[3:6] @ (inertia @ dv[3:6])) + float(dv[6:] @ dv[6:])
        else:
            dv, v0 = dv.reshape(-1, 3), v0.reshape(-1, 3) - shift
            work += float(mass @ np.einsum("ij,ij->i", dv, v0))
            quad += float(mass @ np.einsum("ij,ij->i", dv, dv))
    if blocks is not None and work + 0.5 * quad > 1e-12 * quad:  # the impulses would add energy: scale them back (never below 0)
        scale = min(1.0, -2.0 * (1.0 - 1e-9) * work / quad) if work < 0.0 and quad > 0.0 else 0.0
        dV *= scale
        lam *= scale
        V[:] = V0 + dV
    data["dV"] = dV
    return lam, bounce, sweeps


def _vertex(name: str, p, n: int) -> int:
    if isinstance(p, (int, np.integer)) and 0 <= int(p) < n:
        return int(p)
    raise SimulationError(f"control impulse on {name!r}: the point must be a vertex index in [0, {n}), got {p!r}")


class _ContactBuilder:
    """Entries of the compiled solve (see ``modalfem.world._kernels``), built a batch of contacts at a time: in a
    batch every contact has the same entry layout (a modal side is one entry of 6 + r velocities, a tet side one
    entry of 3 per vertex of the touched point), so the arrays are assembled with numpy, not per contact."""

    def __init__(self, world: World, ctx: _StepContext, seg: dict, names: list) -> None:
        self.w, self.ctx, self.seg, self.names = world, ctx, seg, names
        self.count = 0
        self.n_entries = 0
        self.jlen = 0
        self.batches = []  # per batch: dict of arrays
        self.keys = []  # per contact: what identifies it from step to step (warm start)
        self.iterations = 1
        self._modal_frames = {}

    def _modal_frame(self, name: str):
        f = self._modal_frames.get(name)
        if f is None:
            m = self.w._modal[name]
            s = self.ctx.state_in.bodies[name]
            R = s.rotation()
            Iw_inv = R @ m["body"].inertia_inv @ R.T
            f = (R, Iw_inv, s)
            self._modal_frames[name] = f
        return f

    def _entries_modal(self, name: str, verts: np.ndarray, w: np.ndarray, sign: float):
        """(k,) entries for points sum_j w_j vertex_j of a modal body: J (k, 3, 6 + r), WJt (k, 6 + r, 3), r (k, 3),
        sign R Phi (k, 3, r)."""
        body = self.w._modal[name]["body"]
        R, Iw_inv, s = self._modal_frame(name)
        phi = np.einsum("kj,kjcr->kcr", w, body.vertex_shapes(verts.reshape(-1)).reshape(verts.shape + (3, -1)))
        rest = np.einsum("kj,kjc->kc", w, body.rest[verts])
        r = (rest + np.einsum("kcr,r->kc", phi, s.q)) @ R.T
        k, nm = len(r), body.mode_count
        J = np.zeros((k, 3, 6 + nm))
        J[:, :, 0:3] = np.eye(3)
        S = np.zeros((k, 3, 3))
        S[:, 0, 1], S[:, 0, 2] = -r[:, 2], r[:, 1]
        S[:, 1, 0], S[:, 1, 2] = r[:, 2], -r[:, 0]
        S[:, 2, 0], S[:, 2, 1] = -r[:, 1], r[:, 0]
        J[:, :, 3:6] = -S
        Rphi = np.einsum("ab,kbr->kar", R, phi)
        # modes the step resolves (omega dt <= SLOW) join the contact; faster ones would swing back within the
        # step, so a velocity-level contact cannot predict them: they take no part (the sound still hears
        # them: ``modal_change``)
        J[:, :, 6:] = Rphi * (body.omega * self.ctx.dt <= SLOW)
        WJt = np.transpose(J, (0, 2, 1)).copy()
        WJt[:, 0:3, :] /= body.mass
        WJt[:, 3:6, :] = np.einsum("ab,kbc->kac", Iw_inv, S)  # Iw^-1 (-[r]x)^T = Iw^-1 [r]x
        return sign * J, sign * WJt, r + s.position, sign * Rphi

    def _side(self, name: str, verts: np.ndarray, w: np.ndarray, sign: float):
        """One side of k contacts at points sum_j w_j verts_j (verts (k, m)): entry arrays ``off`` (k, e), ``nd`` (e,),
        ``J`` (k, sum 3 nd) and ``WJt`` (k, sum 3 nd) flattened per contact, the points (k, 3) and the modal
        matrices (k, 3, r) (None for a tet side)."""
        o0, _ = self.seg[name]
        k = len(verts)
        if name in self.w._modal:
            J, WJt, p, full = self._entries_modal(name, verts, w, sign)
            nd = J.shape[2]
            return (np.full((k, 1), o0, dtype=np.int64), np.array([nd]), J.reshape(k, -1), WJt.reshape(k, -1), p,
                    full)
        t = self.w._tet[name]
        ids = t["surface"][verts]  # surface-local -> mesh vertex ids (k, m)
        m = ids.shape[1]
        masses = t["masses"][ids]
        inv = np.where(np.isfinite(masses), 1.0 / np.where(np.isfinite(masses), masses, 1.0), 0.0)
        p = np.einsum("kj,kjd->kd", w, self.ctx.start[name].x[ids])
        eye = np.eye(3)
        J = (sign * w)[:, :, None, None] * eye  # (k, m, 3, 3)
        WJt = (sign * w * inv)[:, :, None, None] * eye
        return (o0 + 3 * ids, np.full(m, 3), J.reshape(k, -1), WJt.reshape(k, -1), p, None)

    def _add(self, a, side_a, b, side_b, n, gap, vobs_n, ca, cb, other):
        k = len(gap)
        if k == 0:
            return
        off = [side_a[0]] + ([side_b[0]] if side_b is not None else [])
        nd = [side_a[1]] + ([side_b[1]] if side_b is not None else [])
        J = [side_a[2]] + ([side_b[2]] if side_b is not None else [])
        W = [side_a[3]] + ([side_b[3]] if side_b is not None else [])
        full = [side_a[5]] + ([side_b[5]] if side_b is not None else [])
        off = np.concatenate(off, axis=1)  # (k, e)
        nd = np.concatenate(nd)  # (e,)
        e = len(nd)
        per = int((3 * nd).sum())  # J data per contact
        jstart = np.concatenate([[0], np.cumsum(3 * nd)[:-1]])
        self.batches.append({
            "ptr": self.n_entries + e * np.arange(1, k + 1), "off": off.reshape(-1), "nd": np.tile(nd, k),
            "jptr": (self.jlen + per * np.arange(k)[:, None] + jstart[None, :]).reshape(-1),
            "J": np.concatenate(J, axis=1).reshape(-1), "WJt": np.concatenate(W, axis=1).reshape(-1),
            "normal": np.asarray(n, dtype=float).reshape(k, 3), "gap": np.asarray(gap, dtype=float),
            "vobs_n": np.asarray(vobs_n, dtype=float),
            "mu": np.full(k, ca.friction if cb is None else math.sqrt(ca.friction * cb.friction)),
            "restitution": np.full(k, ca.restitution if cb is None else min(ca.restitution, cb.restitution)),
            "margin": np.full(k, ca.margin if cb is None else max(ca.margin, cb.margin)),
            "body": np.full(k, self.names.index(a)), "other": np.full(k, other), "point": side_a[4],
            "full": full, "modal_names": [a] + ([b] if b is not None else []), "first": self.count})
        self.n_entries += e * k
        self.jlen += per * k
        self.count += k
        self.iterations = max(self.iterations, ca.iterations, 0 if cb is None else cb.iterations)

    def obstacle(self, name, idx, gap, nrm, vobs, contact, tag: int = 0) -> None:
        side = self._side(name, idx[:, None], np.ones((len(idx), 1)), 1.0)
        nrm = np.asarray(nrm, dtype=float)
        self._add(name, side, None, None, nrm, gap, np.einsum("ij,ij->i", vobs, nrm), contact, None, -1)
        self.keys.extend((name, "obstacle", tag, int(i)) for i in idx)

    def general(self, a, verts_a, w_a, b, verts_b, w_b, gap, nrm, ca, cb) -> None:
        """Contacts between points sum_j w_a[:, j] verts_a[:, j] of body a and sum_j w_b verts_b of body b (normal
        from b to a). A contact is known from step to step by body a's feature (vertex or edge) and body b."""
        side_a = self._side(a, verts_a, w_a, 1.0)
        side_b = self._side(b, verts_b, w_b, -1.0)
        self._add(a, side_a, b, side_b, nrm, gap, np.zeros(len(gap)), ca, cb, self.names.index(b))
        self.keys.extend((a, b, *map(int, f)) for f in np.asarray(verts_a))

    def arrays(self) -> dict:
        cat = {key: np.concatenate([bt[key] for bt in self.batches]) for key in (
            "ptr", "off", "nd", "jptr", "J", "WJt", "normal", "gap", "vobs_n", "mu", "restitution", "margin", "body",
            "other", "point")}
        cat["ptr"] = np.concatenate([[0], cat["ptr"]]).astype(np.int64)
        for key in ("off", "nd", "jptr"):
            cat[key] = cat[key].astype(np.int64)
        cat["normal"] = np.ascontiguousarray(cat["normal"])
        cat["iterations"] = self.iterations
        cat["keys"] = self.keys
        return cat

    def modal_change(self, name: str, sel: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """The modal velocity change (r,) the impulses of contacts ``sel`` give every mode of modal body ``name``
        (what its sound hears)."""
        dq = None
        chosen = {int(c) for c in sel}
        for bt in self.batches:
            for side, nm in enumerate(bt["modal_names"]):
                full = bt["full"][side]
                if nm != name or full is None:
                    continue
                rows = [c - bt["first"] for c in range(bt["first"], bt["first"] + len(bt["gap"])) if c in chosen]
                if rows:
                    add = np.einsum("kcr,kc->r", full[rows], lam[np.asarray(rows) + bt["first"]])
                    dq = add if dq is None else dq + add
        return dq if dq is not None else np.zeros(self.w._modal[name]["body"].mode_count)


class _ModalSurface:
    """A point of a modal body's surface as a tet contact's obstacle (for friction): its velocity over the step
    from the start to the predicted end positions."""

    def __init__(self, name: str, x0: np.ndarray, x1: np.ndarray, ids: np.ndarray, w: np.ndarray) -> None:
        self.name = name
        self.d = np.einsum("kj,kjd->kd", w, x1[ids] - x0[ids])  # displacement over the step [m]

    def points(self) -> list:
        return [_ModalPoint(d) for d in self.d]


class _ModalPoint:
    def __init__(self, d: np.ndarray) -> None:
        self.d = d

    def velocity(self, x, t: float, dt: float) -> np.ndarray:
        return self.d[None] / dt


class _TetWind:
    """Wind on a tet body's surface: pressure ``0.5 rho C s^2`` on the faces the air meets, held over a step
    (a vertex load of the implicit step, updated at each step start)."""

    kind = "vertex"

    def __init__(self, wind: fx.Wind) -> None:
        self.wind = wind
        self.f = None

    def bind(self, surf) -> None:
        self.surface_vertices = surf.mesh_vertices
        self.triangles = surf.triangles

    def update(self, x: np.ndarray, v: np.ndarray, t: float) -> None:
        sv = self.surface_vertices
        xs, vs = x[sv], v[sv]
        T = self.triangles
        a = xs[T[:, 0]]
        cr = np.cross(xs[T[:, 1]] - a, xs[T[:, 2]] - a)
        w_rel = self.wind.at(xs[T].mean(axis=1), t) - vs[T].mean(axis=1)
        F = windward_pressure(cr, w_rel, self.wind.density, self.wind.drag)  # the modal runtime's law
        f = np.zeros((len(x), 3))
        for k in range(3):
            np.add.at(f, sv[T[:, k]], F / 3.0)
        self.f = f

    def energy(self, x: np.ndarray, masses: np.ndarray) -> float:
        return -float(np.sum(self.f * x))

    def gradient(self, x: np.ndarray, masses: np.ndarray) -> np.ndarray:
        return -self.f

    def hessian_diagonal(self, x: np.ndarray, masses: np.ndarray):
        return None


class _ObstacleMotion:
    """A moving obstacle's surface positions over time (the cloth pipeline's ``motion``)."""

    def __init__(self, o) -> None:
        self.o = o

    def __call__(self, t: float) -> np.ndarray:
        return self.o.surface(t)[0]
