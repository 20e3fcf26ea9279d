"""Contact of the surface vertices with static obstacles (plane / ground, sphere, box; ``runtime.obstacles``).

``Obstacles([...])`` is an opt-in effect; ``ModalSolver.collide`` turns it into ``Contacts`` (the
vertices within a margin of an obstacle, with gap [m] and obstacle normal), and the step
(``step_with_contacts``) splits itself at contact events so that the answer does not depend on dt
(tested at dt = 1e-4 ... 1 s against analytic references: bounce apex e^2 H, no energy gain, stop
distance v0^2 / (2 mu g)):

* an impact is resolved at its predicted time inside the step (the body flies freely to it), with
  restitution on the approach velocity at that instant: never on a velocity holding a later part of
  the step's gravity (which made e = 0.8 at dt = 1 s bounce to 4.6 m instead of 0.64 m);
* resting and sliding contact is a sustained-contact sub-step: the contact impulse acts at its middle
  like a contact force held over it, so its normal impulse holds the step's load (m g dt at rest) and
  friction is clamped to the Coulomb disc of that impulse (friction acts from the first contact step);
  a sub-step in which friction stops the sliding is shortened to the stopping instant;
* the velocity of a contact vertex is that of the flexible body, ``v + w x r + R Phi_j qdot``
  (the modal part only with ``modal=True``), and its response to contact impulses is the flexible
  one. The solve is matrix-free sequential impulses in generalised velocity space V = (v, w, qdot)
  (compiled, ``runtime._contact_kernels``): each contact's Jacobian rows ``J_i = [I, -[r_i]x, R Phi_i]``
  (3 x (6 + r)) are formed once per solve, an impulse changes V by ``W J_i^T delta`` with
  ``W = diag(I/m, Iw^-1, I_r)`` (mass-normalised modes), so a sweep costs O(6 + r) per contact and no
  contacts x contacts matrix is formed. The impulses change v, L and qdot consistently with what the
  solve saw, so hits make the body ring with energy taken from the impact, never from nowhere;
* no contact solve adds kinetic energy: a Gauss-Seidel update towards a target <= 0 only removes
  energy, a bounce target is ``-e`` times the approach, and a solve that would still add some
  (restitution near 1 with mixed bouncing and resting contacts, truncated sweeps, friction) is
  scaled back to the largest multiple of its impulses that does not (``resolve_contacts``);
* friction: the tangential impulse along the sliding velocity that stops it, accumulated per contact
  and clamped to the Coulomb disc ``|jt| <= friction * jn`` (sliding friction opposes sliding);
* the sustained solve leaves out the modes faster than its sub-step (``omega span > 1``): their
  mid-step velocity says nothing of the velocity at the end, and kicking them every step made a resting
  steel bar gain ~1e-9 J per step (which the energy guard then halved away, ~15 sub-steps per step);
  impacts still act on every mode. When it leaves out every mode (rigid response), its gaps and lever arms are
  those of the rest shape: the left-out modes swing the vertices about it, and a vertex their swing leaves inside
  is the push-out's, which shrinks the swing (with the deformed gaps a resting body sank while a mode held a
  vertex up, and lifting it back later had nothing left to pay with). It starts from one common normal
  impulse at all its contacts (the value meeting their mean target, found matrix-free), so a body resting on a
  face converges in a few sweeps.
  When no mode takes part (all faster than the sub-step, or ``modal=False``) it is the compiled rigid-body
  solve ``_contact_body_kernels.resolve_rigid`` (the body's six velocities in registers; it stops on a
  velocity tolerance, 1e-12 of the problem's velocity scale, and skips smaller updates: a body resting on a
  face then costs one sweep).

Contact finding is compiled too and does not reconstruct the whole surface: the rigid positions
``c + R X_j`` are tested against each obstacle with the margin grown by a bound of the deformation
(``sqrt(3) sum_i |q_i| max |Phi_i|``), and only those candidates get their exact deformed positions, in one
call (``_contact_body_kernels.find``; impact prediction, mid-step gaps and push-out are one call each too).
Contacts found by ``ModalSolver.collide`` at the very state and dt of the step are reused by the step's first
search (``ModalSolver.advance``), and the rotation matrix, skipped modes and deformation bound are kept for
the last state seen.

Box edges. A body face lying across a box's edge touches it between its vertices, where no vertex contact can
hold it (a bar whose centre of mass is over its last supported row, a block or plate across a box narrower than
it: the energy guard split every step, up to hundreds of sub-steps). With a box among the obstacles,
``find_contacts`` also clips the box's 12 edges against the body's surface triangles near it
(``_contact_edge_kernels.edge_contacts``): where an edge passes under a face within the margin, the clipped ends
are contacts, each a barycentric point of the face (``_EdgePoints``: its rows, velocity and push-out are those of
the weighted sum of the face's vertices) against the plane through the edge point whose normal is the face's
outward normal reversed. Such points are appended to the body's vertices for the kernels (contact vertex
``nv + i``); the step record names them by their face's vertex of largest weight. A vertex contact at the box's
edge (within the margin of two of its face planes) whose vertex is a corner of such a face is left to the face's
edge contacts (the box's nearest feature to it, and so its normal, changes with the step's motion and pushed the
body sideways against them). Without a box nothing of this runs. The rigid sustained solve then sweeps to
convergence when there are box-edge contacts (``_contact_body_kernels.RIGID_SWEEPS``): a body resting on a few
rows and edges needs more than ten sweeps.

After the step, vertices left inside an obstacle (impact times are predicted without the rotation and
the modes) are pushed out by translating the body along the obstacle normal, so no vertex ends
inside (e.g. below the ground); the potential energy this lift adds is taken from the kinetic energy, or, when
that is too small (a body at rest whose fast modes swung vertices into the support), the vibration is shrunk
instead (``_contact_step_kernels.push_and_pay``).

Fused step: the commonest contact step, a body resting or sliding on static obstacles in one sustained sub-step
(rigid response, gravity-like loads, no impact predicted within the step, no friction stop inside it, no energy
gained) is done by one compiled call (``sustained_step``: ``_contact_step_kernels.sustained_step``) with the same
operations in the same order as the Python event loop + ``push_out`` + the energy guard, so the state is the
same bit for bit (tests/runtime/test_contact_fast.py). Contacts touching and approaching at the start (a sliding
body's every other step) get the Python impact solve first, then the compiled rest. Any other step is declined
untouched and takes the Python path. The pieces both compute (deformation bound, skipped modes, the push-out's
energy payment, the guard's energy, the stop share) are the same compiled functions.

Energy guard: impact times are predicted without the rotation and the modes, and a push-out of a body
too slow to pay for its lift costs energy; both shrink with the step. With gravity as the only load,
``ModalSolver.step`` therefore redoes a contact step that ends with more kinetic + modal + gravitational
energy than it began with (beyond 1e-10 of the step's energy scale) as two half steps, at most 10
halvings deep. With other loads (wind, point forces, pseudo-forces) the energy is not conserved by the
loads themselves and no guard applies.

Bounce of a flexible body. An impulse acts on the mass-normalised modes through the mode shapes
alone: the instantaneous modal compliance at a vertex, ``|Phi_j^T n|^2`` [1/kg], does not depend on
the stiffness. Where it is large against the rigid one (a thin bell's lip: 76 against 12 1/kg
along the bell's axis, 169 against 8 1/kg across it), much of an impact's energy goes into
ringing and the body bounces less than a rigid one of the same restitution (physical for a hit
shorter than the modal periods); where it is comparable (a steel block's corner: 2.2 against
0.8 1/kg), the bounce is nearly the rigid one: the modes spring back and the vertices hit again
in the next steps, returning the momentum (numbers in tests/runtime/test_contact.py).
"""

from __future__ import annotations

import functools
import math
import threading
import weakref
from dataclasses import dataclass

import numpy as np

from modalfem.runtime.state import restore, snapshot

__all__ = [
    "MAX_EVENTS",
    "Contacts",
    "find_contacts",
    "merge_contacts",
    "normal_velocities",
    "push_out",
    "resolve_contacts",
    "step_with_contacts",
    "sustained_step",
]


@dataclass
class Contacts:
    """Vertex contacts found by ``find_contacts`` for one step.

    Attributes:
        vertex: (k,) surface vertex indices.
        normal: (k, 3) obstacle normals (world, pointing out of the obstacle).
        gap: (k,) signed distances [m] at the start of the step (negative = inside).
        effect: (k,) index into ``effects``.
        effects: the ``Obstacles`` effects the contacts came from.
        impulses: (k,) normal impulses [N s] applied by the last resolve (for sound and logging); after
            ``ModalSolver.step``, the total normal impulse of each listed vertex over the step.
        obstacle: (k,) index of the obstacle within its effect's ``obstacles`` (None: unknown).
        tangential: (k, 3) friction impulses [N s] (world) of the last resolve.
        points: None, or the box-edge contacts' body points (``_EdgePoints``): contacts whose ``vertex`` is
            ``nv + i`` are points on a body face over a box edge (``_contact_edge_kernels``), i indexing it;
            the step record names them by their face's nearest vertex.
    """

    vertex: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    effect: np.ndarray
    effects: list
    impulses: np.ndarray | None = None
    obstacle: np.ndarray | None = None
    tangential: np.ndarray | None = None
    points: object = None

    def subset(self, keep) -> Contacts:
        """The contacts selected by the boolean mask or index array ``keep``."""
        return Contacts(self.vertex[keep], self.normal[keep], self.gap[keep], self.effect[keep], self.effects,
                        obstacle=None if self.obstacle is None else self.obstacle[keep], points=self.points)

    @property
    def count(self) -> int:
        return len(self.vertex)

    def copy(self) -> Contacts:
        """An independent copy (the arrays copied, the effects shared)."""
        def c(a):
            return None if a is None else np.array(a, copy=True)

        return Contacts(c(self.vertex), c(self.normal), c(self.gap), c(self.effect), self.effects,
                        impulses=c(self.impulses), obstacle=c(self.obstacle), tangential=c(self.tangential),
                        points=self.points)


# ---------------------------------------------------------------------------------------- step record
def merge_contacts(into: Contacts, earlier: Contacts) -> None:
    """Fold the step record ``earlier`` (an earlier part of the same step) into ``into`` in place: one entry
    per (vertex, effect, obstacle), normal impulses [N s] summed, normal and gap of the later part."""
    record: list = []
    for part in (earlier, into):
        if part.impulses is not None and part.obstacle is not None:
            _accumulate(record, part, part.gap)
    _write_record(into, record)


def _accumulate(record: list, c: Contacts, gap) -> None:
    """Add the contacts of ``c`` that pushed (impulse > 0) to a step record (see ``_write_record``); box-edge
    contacts are recorded under their face's vertex of largest weight (merged with that vertex's own)."""
    sel = c.impulses > 0.0
    vertex = c.vertex
    if c.points is not None:
        vertex = c.points.names(vertex)
    if len(sel) and sel.all():
        record.append((vertex, c.effect, c.obstacle, c.normal, np.asarray(gap), c.impulses))
    elif sel.any():
        record.append((vertex[sel], c.effect[sel], c.obstacle[sel], c.normal[sel], np.asarray(gap)[sel],
                       c.impulses[sel]))
    else:
        return
    if c.points is not None:  # names may repeat: an empty part makes _write_record merge them
        record.append(_NO_PART)


_NO_PART = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3)),
            np.zeros(0), np.zeros(0))


def _write_record(contacts: Contacts, record: list) -> None:
    """Set ``contacts`` to a step record: the parts (vertex, effect, obstacle, normal, gap, impulse) merged
    to one entry per (vertex, effect, obstacle) in order of first appearance, impulses [N s] summed,
    normal and gap of the last appearance."""
    contacts.tangential = None
    if not record:
        contacts.vertex = np.zeros(0, dtype=np.int64)
        contacts.effect = np.zeros(0, dtype=np.int64)
        contacts.obstacle = np.zeros(0, dtype=np.int64)
        contacts.normal, contacts.gap, contacts.impulses = np.zeros((0, 3)), np.zeros(0), np.zeros(0)
        return
    if len(record) == 1:  # one part: from one contact search, one entry per (vertex, effect, obstacle) already
        v, e, o, n, g, j = record[0]
        contacts.vertex, contacts.effect, contacts.obstacle = (a.astype(np.int64) for a in (v, e, o))
        contacts.normal, contacts.gap = n.reshape(-1, 3), g
        contacts.impulses = np.asarray(j, dtype=np.float64)
        return
    v, e, o, n, g, j = (np.concatenate([p[i] for p in record]) for i in range(6))
    v, e, o = v.astype(np.int64), e.astype(np.int64), o.astype(np.int64)
    key = (v * (int(e.max()) + 1) + e) * (int(o.max()) + 1) + o
    if len(record) == 1 and len(np.unique(key)) == len(key):
        first, inv = np.arange(len(key)), np.arange(len(key))
    else:
        _, first, inv = np.unique(key, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # groups by first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    slot = rank[inv.reshape(-1)]
    last = np.empty(len(order), dtype=np.int64)
    last[slot] = np.arange(len(key))  # later parts overwrite earlier ones
    contacts.vertex, contacts.effect, contacts.obstacle = v[last], e[last], o[last]
    contacts.normal, contacts.gap = n[last].reshape(-1, 3), g[last]
    contacts.impulses = np.bincount(slot, weights=j, minlength=len(order))


# ---------------------------------------------------------------------------------------- geometry
class _Plan:
    """The obstacles of a list of ``Obstacles`` effects flattened for the kernels (one entry per obstacle)."""

    def __init__(self, effects) -> None:
        self.effects = tuple(effects)
        self.kinds = np.concatenate([e.kinds for e in effects])
        self.params = np.ascontiguousarray(np.concatenate([e.params for e in effects]))
        counts = [len(e.kinds) for e in effects]
        self.first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)  # per effect
        self.effect = np.repeat(np.arange(len(effects)), counts)  # per obstacle
        self.obstacle = np.concatenate([np.arange(c) for c in counts])
        self.margin = np.repeat([e.margin for e in effects], counts).astype(np.float64)
        self.restitution = np.array([e.restitution for e in effects])  # per effect
        self.friction = np.array([e.friction for e in effects])
        self.threshold = np.array([e.bounce_threshold for e in effects])
        self.modal = np.array([e.modal for e in effects], dtype=bool)
        self.iterations = max(e.iterations for e in effects)
        from modalfem.runtime.obstacles import BOX
        self.boxes = bool((self.kinds == BOX).any())  # box edges to search (``_with_edges``)
        from modalfem.runtime._contact_body_kernels import RIGID_SWEEPS
        self.rigid_sweeps = max(self.iterations, RIGID_SWEEPS)  # (with box-edge contacts: ``_sweeps``)


class _EdgePoints:
    """The body points of box-edge contacts (``_contact_edge_kernels.edge_contacts``) appended to the body's
    vertices and their obstacles appended to a plan's, so that every per-contact kernel takes them as vertices:
    contact vertex ``nv + i`` is point i, at rest ``rest[nv + i] = sum_a w_a X_a`` with the modes
    ``vm[nv + i] = sum_a w_a Phi_a`` (its velocity and Jacobian rows the same combination of its face's vertices'),
    against obstacle row ``no + i``: the plane through the edge point with the face's normal reversed.

    Attributes: rest (nv + p, 3) [m], vm (nv + p, r, 3), kinds, params, margin (no + p): the extended arrays;
    nv, no: the body's vertex count and the plan's obstacle count; major (p,): each point's face vertex of
    largest weight (the name the step record gives it). ``rest`` and ``vm`` live in one buffer per body (the
    body's part copied once, not per step: 18 MB of modes for 50k vertices and 30 modes); the points that last
    wrote their rows into it own it, and others write theirs again (p rows) when asked."""

    def __init__(self, body, plan, rows, vertices, weights, normal, offset) -> None:
        nv, p = body.vertex_count, len(offset)
        self.nv, self.no = nv, len(plan.kinds)
        self._body = weakref.ref(body)
        self.major = vertices[np.arange(p), np.argmax(weights, axis=1)]
        self.weights, self.vertices = weights, vertices
        from modalfem.runtime.obstacles import PLANE
        self.kinds = np.concatenate([plan.kinds, np.full(p, PLANE, dtype=plan.kinds.dtype)])
        self.params = np.zeros((self.no + p, plan.params.shape[1]))
        self.params[:self.no] = plan.params
        self.params[self.no:, 0:3] = normal
        self.params[self.no:, 3] = offset
        self.margin = np.concatenate([plan.margin, plan.margin[rows]])
        self._views = None

    def _own(self):
        """(rest, vm) views of the body's buffer holding this object's points."""
        body = self._body()
        nv, p = self.nv, len(self.major)
        buf = _EDGE_BUFFERS.get(body)
        if buf is None or buf[0].shape[0] < nv + p:
            rest, vm = body.rest, vertex_modes(body)
            cap = nv + max(64, 2 * p)
            buf = [np.empty((cap, 3), dtype=rest.dtype), np.empty((cap,) + vm.shape[1:], dtype=vm.dtype), None]
            buf[0][:nv] = rest
            buf[1][:nv] = vm
            _EDGE_BUFFERS[body] = buf
        if buf[2] is not self or self._views is None or self._views[0].base is not buf[0]:
            rest, vm = buf[0], buf[1]
            rest[nv:nv + p] = np.einsum("pa,pad->pd", self.weights, rest[self.vertices])
            vm[nv:nv + p] = np.einsum("pa,pard->prd", self.weights, vm[self.vertices])
            buf[2] = self
            self._views = (rest[:nv + p], vm[:nv + p])
        return self._views

    @property
    def rest(self) -> np.ndarray:
        return self._own()[0]

    @property
    def vm(self) -> np.ndarray:
        return self._own()[1]

    def names(self, vertex: np.ndarray) -> np.ndarray:
        """Contact vertices with the points replaced by their face's vertex of largest weight."""
        edge = vertex >= self.nv
        if not edge.any():
            return vertex
        out = vertex.copy()
        out[edge] = self.major[vertex[edge] - self.nv]
        return out


_PLANS: dict = {}
def _sweeps(plan, c: Contacts) -> int:
    """Most sweeps of the rigid sustained solve of the contacts ``c``: to convergence with box-edge contacts
    (``_contact_body_kernels.RIGID_SWEEPS``), else the effects' ``iterations``."""
    return int(plan.iterations if c.points is None else plan.rigid_sweeps)


_EDGE_BUFFERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # body -> [rest, vm, owner] (_EdgePoints)


def _plan(effects) -> _Plan:
    if len(effects) == 1:  # the common case, without building a key tuple (called several times a step)
        e = effects[0]
        p = _PLANS.get(id(e))
        if p is not None and p.effects[0] is e:
            return p
        key = id(e)
    else:
        key = tuple(id(e) for e in effects)
        p = _PLANS.get(key)
    if p is None or len(p.effects) != len(effects) or any(a is not b for a, b in zip(p.effects, effects)):
        if len(_PLANS) > 64:
            _PLANS.clear()
        p = _PLANS[key] = _Plan(effects)
    return p


_MODAL: list = [None, b"", None, 0.0]  # body, q bytes, skip, bound: for the last q seen (a resting body's is fixed)


def _modal_terms(body, q: np.ndarray):
    """``(_skip, deformation_bound)`` of ``q``, kept for the last (body, q) seen."""
    key = q.tobytes()
    m = _MODAL
    if m[0] is not body or m[1] != key:  # (compiled: the same operations as the fused step's)
        from modalfem.runtime._contact_step_kernels import modal_terms
        m[2], m[3] = modal_terms(q, _row_scale(body), float(body.radius))
        m[0], m[1] = body, key
    return m[2], m[3]


def _row_scale(body) -> np.ndarray:
    """The modes' largest vertex displacement per unit q (r,) float64 [m / (sqrt(kg) m)]."""
    s = body.__dict__.get("_contact_row_scale")
    if s is None:
        s = body.__dict__["_contact_row_scale"] = np.ascontiguousarray(body._row_scale[:-1], dtype=np.float64)
    return s


def _skip(body, q: np.ndarray) -> np.ndarray:
    """Modes whose contribution is negligible (as in ``ModalBody.positions``); do not modify the result."""
    return _modal_terms(body, q)[0]


def deformation_bound(body, q: np.ndarray) -> float:
    """An upper bound [m] of every vertex's deformation ``|Phi_j q|`` (plus rounding slack)."""
    return _modal_terms(body, q)[1]


_VERTEX_MODES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def vertex_modes(body) -> np.ndarray:
    """The mode shapes vertex-major (nv, r, 3) in the body's dtype [m/sqrt(kg)], built on first use and kept
    while the body lives: a contact reads all r modes of one vertex from one cache line instead of r lines
    3 nv apart (the body's modes-major layout is the one the reconstruction streams). Costs one more copy
    of the shapes (50k vertices x 30 modes: 18 MB in float32)."""
    vm = _VERTEX_MODES.get(body)
    if vm is None:
        vm = _VERTEX_MODES[body] = np.ascontiguousarray(np.moveaxis(body._modes3, 0, 1))
    return vm


def local_positions(body, q: np.ndarray, vertex: np.ndarray) -> np.ndarray:
    """Deformed positions ``X_j + Phi_j q`` (k, 3) [m] of vertices in body axes (float64)."""
    from modalfem.runtime import _contact_kernels as K
    return K.local_positions(vertex, body.rest, vertex_modes(body), q, _skip(body, q))


def _world(body, state, vertex: np.ndarray, R: np.ndarray) -> np.ndarray:
    from modalfem.runtime import _contact_kernels as K
    return K.world_positions(local_positions(body, state.q, vertex), R, state.position)


def find_contacts(solver, state, effects, dt=None, *, accel=None) -> Contacts:
    """Surface vertices within the margin of an obstacle (see ``ModalSolver.collide``).

    Args:
        solver: the ``ModalSolver``.
        state: current state.
        effects: the ``Obstacles`` effects.
        dt: the coming step [s] or None; widens the margin by what the body can travel in it.
        accel: acceleration of the centre of mass from the loads (3,) [m/s^2] or None; widens the
            margin by |a| dt^2 (twice the distance it adds over dt).
    """
    from modalfem.runtime import _contact_body_kernels as KB
    body = solver.body
    plan = _plan(effects)
    R = _rotation(state)
    reach = 0.0
    if dt is not None:
        v, L = state.velocity, state.angular_momentum
        speed = math.sqrt(float(v @ v))
        if L[0] != 0.0 or L[1] != 0.0 or L[2] != 0.0:
            w = R @ (body.inertia_inv @ (R.T @ L))
            speed += math.sqrt(float(w @ w)) * body.radius
        reach = 2.0 * speed * float(dt)
        if accel is not None:
            reach += math.sqrt(float(accel @ accel)) * float(dt) ** 2
    margin = plan.margin + reach
    q = state.q
    rest = body.rest
    vs, og, gap, nrm = _find_buffers(rest.shape[0] * len(plan.kinds))
    n = KB.find_into(plan.kinds, plan.params, margin, rest, vertex_modes(body), q, _skip(body, q), R, state.position,
                     deformation_bound(body, q), vs, og, gap, nrm)
    og = og[:n]  # (the buffers are this thread's and reused by its next search: the contacts get copies)
    c = Contacts(vs[:n].copy(), nrm[:n].copy(), gap[:n].copy(), plan.effect[og], list(effects),
                 obstacle=plan.obstacle[og])
    if plan.boxes:
        c = _with_edges(body, plan, margin, q, R, state.position, c)
    c._found = (_fingerprint(state).tobytes(), None if dt is None else float(dt), accel)
    return c


_FIND = threading.local()  # this thread's output buffers of KB.find_into


def _find_buffers(rows: int) -> tuple:
    """This thread's (vertex, obstacle, gap, normal) buffers of ``KB.find_into`` with at least ``rows`` rows (grown
    as needed; per thread, so that solvers stepped on several threads never share them)."""
    b = getattr(_FIND, "b", None)
    if b is None or len(b[0]) < rows:
        rows = max(rows, 16)
        b = _FIND.b = (np.empty(rows, dtype=np.int64), np.empty(rows, dtype=np.int64), np.empty(rows),
                       np.empty((rows, 3)))
    return b


def _with_edges(body, plan, margin, q, R, position, c: Contacts) -> Contacts:
    """``c`` with the box-edge contacts (``_contact_edge_kernels.edge_contacts``) appended, if any."""
    from modalfem.runtime import _contact_edge_kernels as KE
    og, verts, w, nrm, gap, offset = KE.edge_contacts(plan.kinds, plan.params, margin, plan.margin, body.rest,
                                                       vertex_modes(body),
                                                       q, _skip(body, q), R, position, deformation_bound(body, q),
                                                       body.triangles)
    if len(og) == 0:
        return c
    nv = body.vertex_count
    row = plan.first[c.effect] + c.obstacle
    keep = unique_edge_points(body, og, verts, w, row, c.vertex)
    if not keep.all():
        og, verts, w, nrm, gap, offset = og[keep], verts[keep], w[keep], nrm[keep], gap[keep], offset[keep]
        if len(og) == 0:
            return c
    boxed = np.flatnonzero(np.isin(row, og))
    if len(boxed):
        near = near_box_edge(plan.params[row[boxed]], plan.margin[row[boxed]],
                             body.rest[c.vertex[boxed]] @ R.T + position)
        if near.any():
            at = boxed[near]
            drop = left_to_edges(og, verts, nv, row[at], c.vertex[at])
            if drop.any():
                keep = np.ones(c.count, dtype=bool)
                keep[at[drop]] = False
                c = Contacts(c.vertex[keep], c.normal[keep], c.gap[keep], c.effect[keep], c.effects,
                             obstacle=c.obstacle[keep])
    pts = _EdgePoints(body, plan, og, verts, w, nrm, offset)
    return Contacts(np.concatenate([c.vertex, nv + np.arange(len(og))]), np.concatenate([c.normal, nrm]),
                    np.concatenate([c.gap, gap]), np.concatenate([c.effect, plan.effect[og]]), c.effects,
                    obstacle=np.concatenate([c.obstacle, plan.obstacle[og]]), points=pts)


def unique_edge_points(body, og, verts, w, row, vertex) -> np.ndarray:
    """Which box-edge contacts (``_contact_edge_kernels.edge_contacts``: box labels ``og`` (p,), face vertices
    ``verts`` (p, 3), weights ``w`` (p, 3)) to keep: one per body point (a clipped end on a triangle side shared by
    two triangles, or at a vertex of several, is found once per triangle; repeated contacts slow the sweeps down: a
    plate resting across a box's edges had its steps split), and none at a vertex with its own contact with that
    box (vertex contacts' labels ``row`` (k,) and vertices ``vertex`` (k,)): that contact is it. Returns (p,) bool."""
    x = np.einsum("pa,pad->pd", w, body.rest[verts])
    scale = 1e-9 * float(body.radius)
    key = np.concatenate([og[:, None].astype(np.float64), np.round(x / scale)], axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    keep = np.zeros(len(og), dtype=bool)
    keep[first] = True
    at_vertex = w.max(axis=1) >= 1.0 - 1e-9
    if at_vertex.any():
        nv = body.vertex_count
        own = np.isin(og * nv + verts[np.arange(len(og)), np.argmax(w, axis=1)], row * nv + vertex)
        keep &= ~(at_vertex & own)
    return keep


def near_box_edge(params: np.ndarray, margin: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(k,) bool: points ``x`` (k, 3) [m] (world) within ``margin`` (k,) [m] of two face planes of their boxes
    (``params`` (k, >= 15): the boxes' encodings), i.e. at one of the box's edges."""
    axes = params[:, 6:15].reshape(-1, 3, 3)  # box -> world rotation, row-major
    local = np.abs(np.einsum("kji,kj->ki", axes, x - params[:, 0:3])) - params[:, 3:6]
    return (np.abs(local) <= margin[:, None]).sum(axis=1) >= 2


def left_to_edges(og, verts, nv: int, row, vertex) -> np.ndarray:
    """(k,) bool: vertex contacts (labels ``row``, vertices ``vertex``) at their box's edge (``near_box_edge``) whose
    vertex is a corner of a face with edge contacts on that box (``og``, ``verts``): they are left to the face's edge
    contacts. The box's nearest feature to such a vertex changes with a step's motion (at the mid-step state of a
    0.1 s step, a vertex 30 nm inside a box's edge is nearest its side), and the sideways push of its slanted or side
    normal fought theirs."""
    return np.isin(row * nv + vertex, ((og * nv)[:, None] + verts).ravel())


def _geometry(body, c: Contacts):
    """(rest (n, 3), vertex-major modes (n, r, 3)) of the contacts' body points: the body's vertices, with the
    box-edge points appended when ``c`` has any."""
    if c.points is None:
        return body.rest, vertex_modes(body)
    return c.points._own()


def _obstacles(plan, c: Contacts):
    """(row (k,), kinds, params, margin): each contact's obstacle row in the obstacle arrays, with the box-edge
    contacts' planes appended when ``c`` has any."""
    row = plan.first[c.effect] + c.obstacle
    pts = c.points
    if pts is None:
        return row, plan.kinds, plan.params, plan.margin
    edge = c.vertex >= pts.nv
    row = np.where(edge, pts.no + c.vertex - pts.nv, row)
    return row, pts.kinds, pts.params, pts.margin


def _fingerprint(state) -> np.ndarray:
    """The pose, velocities and modes of a state in one array (to recognise contacts found at it: compared as
    bytes, ~3 us faster than ``np.array_equal``; stricter only on the sign of a zero, where the contacts are then
    found again)."""
    return np.concatenate((state.position, state.orientation, state.velocity, state.angular_momentum, state.q))


def _fresh(contacts: Contacts, state, dt: float, accel) -> bool:
    """``contacts`` were found by ``find_contacts`` at exactly this state, for a step dt [s] and the load
    acceleration ``accel`` (to rounding), and not changed since."""
    found = getattr(contacts, "_found", None)
    if found is None or found[1] != dt or contacts.impulses is not None:
        return False
    a = found[2]
    if (a is None) != (accel is None):
        return False
    if a is not None:
        d = a - accel
        if float(d @ d) > 1e-24 * float(accel @ accel):  # the same load to rounding
            return False
    return found[0] == _fingerprint(state).tobytes()


_ROTATION: list = [b"", None]


def _rotation(state) -> np.ndarray:
    """``state.rotation()`` (3, 3), kept for the last orientation seen (do not modify the result)."""
    key = state.orientation.tobytes()
    if key != _ROTATION[0]:  # (the compiled quat_to_matrix: the same expressions, ~4 us less a call)
        R = np.empty((3, 3))  # (a new array each time: callers may hold the last one)
        _matrix()(state.orientation, R)
        _ROTATION[1] = R
        _ROTATION[0] = key
    return _ROTATION[1]


@functools.cache
def _matrix():
    """``_contact_step_kernels.matrix_into`` (``rotation.quat_to_matrix`` compiled, the same expressions)."""
    from modalfem.runtime._contact_step_kernels import matrix_into

    return matrix_into


def _gaps(effects, contacts: Contacts, body, state, skip=None):
    """Gaps (k,) [m] and normals (k, 3) of the contact vertices at ``state`` against the obstacle each
    contact belongs to (the modes ``skip`` (r,) bool left out; default: those of negligible contribution)."""
    from modalfem.runtime import _contact_body_kernels as KB
    plan = _plan(effects)
    q = state.q
    row, kinds, params, _ = _obstacles(plan, contacts)
    rest, vm = _geometry(body, contacts)
    return KB.gaps_at(contacts.vertex, row, kinds, params, rest, vm, q, _skip(body, q) if skip is None else skip,
                      _rotation(state), state.position)


def _seen(body, plan, contacts: Contacts, span: float):
    """The modes a sustained sub-step of span [s] leaves out of its gaps (r,) bool, or None (only the negligible
    ones): all of them when its solve is rigid (``_rigid_response``). The solve leaves out the modes faster than
    the sub-step; they swing the vertices about the rest shape, and gaps holding their deformation let the body
    sink while they hold a vertex up (a plate resting on a box's corner vertex sank ~10 nm below its rest shape,
    which the push-out then had to lift with no energy left to pay: the energy guard ran out of halvings and
    accepted rises of ~6e-7 J). The swing a vertex is left inside with is the push-out's (it shrinks the
    vibration)."""
    if not _rigid_response(body, plan, contacts, span):
        return None
    r = body.mode_count
    s = _RIGID_SKIP.get(r)
    if s is None:
        s = _RIGID_SKIP[r] = np.ones(r, dtype=bool)
    return s


_RIGID_SKIP: dict = {}


def _system(solver, state, contacts: Contacts, slow: float | None = None):
    """Contact rows of one body: (J, WJ (k, 3, m), V (m,), R, Iw_inv, nm), m = 6 + nm; with ``slow`` [s] only
    the modes with ``omega slow <= 1`` (the modes are sorted by frequency: a prefix)."""
    from modalfem.runtime import _contact_kernels as K
    body = solver.body
    k = contacts.count
    R = _rotation(state)
    Iw_inv = R @ body.inertia_inv @ R.T
    plan = _plan(contacts.effects)
    modal = plan.modal[contacts.effect]
    nm = body.mode_count if modal.any() else 0
    if slow is not None and nm:
        nm = int(np.searchsorted(body.omega, 1.0 / slow, side="right"))
    m = 6 + nm
    J = np.empty((k, 3, m))
    WJ = np.empty((k, 3, m))
    rest, vm = _geometry(body, contacts)
    q = state.q
    K.rows(contacts.vertex, K.local_positions(contacts.vertex, rest, vm, q, _skip(body, q)), modal, vm, R, body.mass,
           Iw_inv, m, J, WJ, np.arange(k))
    V = np.concatenate([state.velocity, Iw_inv @ state.angular_momentum, state.qdot[:nm]])
    return J, WJ, V, R, Iw_inv, nm


_ONE = np.zeros(1, dtype=np.int64)


def normal_velocities(solver, state, contacts: Contacts) -> np.ndarray:
    """Normal velocities (k,) [m/s] of the contact vertices (flexible: with the modal part where the
    contact's effect is ``modal``); negative = approaching the obstacle. The same products in the same order
    as the solve's rows (bit-identical to ``n . J V``) without storing the rows."""
    from modalfem.runtime import _contact_body_kernels as KB
    k = contacts.count
    if k == 0:
        return np.zeros(0)
    body = solver.body
    modal = _plan(contacts.effects).modal[contacts.effect]
    nm = body.mode_count if modal.any() else 0
    q = state.q
    R = _rotation(state)
    rest, vm = _geometry(body, contacts)
    return KB.normal_velocities(contacts.vertex, rest, vm, q, _skip(body, q), modal, R, nm,
                                np.ascontiguousarray(contacts.normal, dtype=np.float64), state.velocity,
                                _angular_velocity(body, R, state.angular_momentum), state.qdot)


def _angular_velocity(body, R: np.ndarray, L: np.ndarray) -> np.ndarray:
    """World angular velocity ``R I^-1 R^T L`` (3,) [rad/s] as the normal velocities use it (numpy products: the
    fused step is handed this very vector)."""
    return (R @ body.inertia_inv @ R.T) @ L


def resolve_contacts(solver, state, contacts: Contacts, dt: float, *, accel=None, sustained: bool = False) -> None:
    """Sequential impulses over all contacts (in place on ``state``); see the module docstring.

    Works in generalised velocity space. V = (v, w, qdot) [m/s, rad/s, sqrt(kg) m/s] with the kinetic
    energy 0.5 V^T W^-1 V, W = diag(I/m, Iw^-1, I_r) (mass-normalised modes). The world velocity of
    contact vertex j is ``u_j = v + w x r_j + R Phi_j qdot`` = J_j V (the modal columns only for
    ``modal`` obstacles); an impulse lambda_j (3,) [N s] changes V by ``W J_j^T lambda_j``, i.e. v, L and
    qdot consistently with the velocities the solve saw (the contacts couple through V: the Delassus
    operator ``J W J^T`` is never formed). The kinetic energy changes by
    ``dV^T W^-1 V0 + 0.5 dV^T W^-1 dV``; should an unconverged or frictional solve make that positive,
    the impulses are scaled down to the largest multiple that does not add energy, so no contact solve
    adds energy.

    Two kinds of solve:

    * impact (default): instantaneous, on the velocities now. Target normal velocity ``-e vn0`` for
      a contact approaching faster than ``bounce_threshold`` (restitution of the approach velocity
      at this instant, which holds no gravity of a later time), 0 for a slower one touching, and for
      a vertex still ``gap > 0`` away an approach of up to ``gap / dt``;
    * ``sustained``: the contact impulse of a (sub)step of length dt whose loads give the centre of
      mass the acceleration ``accel`` [m/s^2], applied at the middle of the step (``state`` is the
      mid-step state, ``contacts.gap`` the mid-step gaps). It acts like a contact force held over the
      step: the solve sees the end-of-step velocities ``u + accel dt / 2`` and requires the end gap
      ``gap + dt/2 u_end_n - a_n dt^2 / 8 >= 0``; the normal impulse includes the whole step's load
      (m g dt for a body at rest), so the Coulomb disc of this step's friction is the right one. For a
      single contact the energy changes by ``-lambda_n gap_0 / dt <= 0`` (gap_0 at the step start).

    Args:
        solver: the ``ModalSolver``.
        state: state at the instant of the impulses (changed in place).
        contacts: the contacts (``impulses`` and ``tangential`` are written).
        dt: the (sub)step [s].
        accel: (3,) [m/s^2] load acceleration of the centre of mass (sustained solves).
        sustained: the solve kind (see above).
    """
    from modalfem.runtime import _contact_kernels as K
    k = contacts.count
    contacts.impulses = np.zeros(k)
    contacts.tangential = np.zeros((k, 3))
    if k == 0:
        return
    body = solver.body
    plan = _plan(contacts.effects)
    n = np.ascontiguousarray(contacts.normal, dtype=np.float64)
    gap = contacts.gap
    mu = plan.friction[contacts.effect]
    if sustained and _rigid_response(body, plan, contacts, dt):
        _resolve_rigid(body, state, contacts, plan, n, mu, dt, accel)
        return
    J, WJ, V, R, _, nm = _system(solver, state, contacts, dt if sustained else None)
    zeros = np.zeros(k, dtype=np.int64)
    msz = np.array([6 + nm])
    shift = np.zeros((k, 3))
    if sustained:
        a = np.zeros(3) if accel is None else np.asarray(accel, dtype=np.float64)
        shift[:] = 0.5 * dt * a  # predicted end-of-step velocities without contact
        target = 0.25 * dt * (n @ a) - 2.0 * gap / dt
    else:
        u = K.contact_velocities(zeros, zeros - 1, J, J, V, _ONE, msz)
        vn0 = np.einsum("ka,ka->k", n, u)
        e = plan.restitution[contacts.effect]
        thr = plan.threshold[contacts.effect]
        target = np.where(gap > 0, -gap / dt, 0.0)
        bounce = (vn0 < -thr) & (e > 0)
        target = np.where(bounce, np.maximum(target, -e * vn0), target)
    V0 = V.copy()
    lam = np.zeros((k, 3))
    jt = np.zeros((k, 3))
    lam_n = np.zeros(k)
    K.solve(zeros, zeros - 1, J, WJ, J, WJ, V, _ONE, msz, n, np.ascontiguousarray(target), mu, shift,
            plan.iterations, lam, jt, lam_n, sustained)
    dV = V - V0
    Iw = R @ body.inertia @ R.T
    dv, dw, dq = dV[0:3], dV[3:6], dV[6:]
    # energy change of V0 -> V0 + s dV: s work + 0.5 s^2 quad (work = lambda . u_now, quad = lambda . A lambda)
    work = float(body.mass * (dv @ state.velocity) + dw @ state.angular_momentum + dq @ state.qdot[:nm])
    quad = float(body.mass * (dv @ dv) + dw @ (Iw @ dw) + dq @ dq)
    if work + 0.5 * quad > 1e-12 * quad:  # would add energy: keep the largest share that does not
        scale = min(1.0, -2.0 * (1.0 - 1e-9) * work / quad) if work < 0.0 and quad > 0.0 else 0.0
        dV *= scale
        lam_n *= scale
        jt *= scale
    state.velocity += dV[0:3]
    state.angular_momentum += Iw @ dV[3:6]
    if nm:  # the same impulses move the modes: qdot += sum_i phi_i^T R^T lambda_i
        state.qdot[:nm] += dV[6:]
    contacts.impulses = lam_n
    contacts.tangential = jt


def _rigid_response(body, plan, contacts: Contacts, dt: float) -> bool:
    """The sustained solve of a sub-step dt [s] acts on no mode: none modal, or all faster than 1 / dt."""
    return body.mode_count == 0 or not (body.omega[0] <= 1.0 / dt and plan.modal[contacts.effect].any())


def _resolve_rigid(body, state, contacts: Contacts, plan, n, mu, dt: float, accel) -> None:
    """The sustained solve of ``resolve_contacts`` when no mode takes part: one compiled call
    (``_contact_body_kernels.resolve_rigid``: the rigid-body solve on V = (v, w) and the same energy guard)."""
    from modalfem.runtime import _contact_body_kernels as KB
    k = contacts.count
    q = state.q
    lam_n = np.empty(k)
    jt = np.empty((k, 3))
    rest, vm = _geometry(body, contacts)
    KB.resolve_rigid(contacts.vertex, rest, vm, q, _seen(body, plan, contacts, dt),
                     _rotation(state), body.inertia, body.inertia_inv, float(body.mass), state.velocity,
                     state.angular_momentum, n,
                     np.ascontiguousarray(contacts.gap, dtype=np.float64), mu,
                     _ZERO3 if accel is None else np.asarray(accel, dtype=np.float64), float(dt),
                     _sweeps(plan, contacts), lam_n, jt)
    contacts.impulses = lam_n
    contacts.tangential = jt


_ZERO3 = np.zeros(3)


#: most sub-steps (impact events, friction stops) in one step; beyond, the rest of the step is one
#: sustained-contact sub-step (which never adds energy either)
MAX_EVENTS = 32


def _crossings(gap, vn, normal, accel, thr, horizon):
    """First downward zero crossings of the contacts' gaps ``gap + vn t + an t^2 / 2`` [m] in
    (0, horizon] [s] (an = normal . accel): ``(t_fast, j, t_slow)``, the earliest crossing faster than the
    contact's bounce threshold and its contact index ((None, -1) if none), and the earliest slower one (None
    if none). A contact touching or inside (gap <= 0) and not leaving faster than its threshold is a slow
    crossing now (t = 0), for the sustained solve; a fast one at t = 0 is the impact solve's, not an event.
    The roots are taken in the cancellation-free form q = -(b + sign(b) sqrt(D)) / 2, t = q / a and c / q
    (a = an / 2, b = vn, c = gap); compiled (``_contact_body_kernels.crossings``).
    """
    from modalfem.runtime import _contact_body_kernels as KB
    t_fast, j, t_slow = KB.crossings(gap, vn, normal, accel, thr, float(horizon))
    return (None if j < 0 else t_fast), j, (None if math.isnan(t_slow) else t_slow)


def step_with_contacts(solver, state, contacts: Contacts, loads, dt: float) -> None:
    """Advance ``state`` in place by dt [s] with contact (what ``ModalSolver.step`` calls).

    The step is split at events:

    1. impacts: contacts touching now (gap <= 1e-9 margin) and approaching are resolved at once by an
       impact solve (restitution applied to the approach velocity at this instant);
    2. the next impact within the rest of the step is predicted from each contact's gap, normal
       velocity and the load acceleration (``gap + vn t + a_n t^2 / 2`` crossing 0 faster than the
       bounce threshold); the body flies freely to it and 1. repeats there. A body dropped from
       height H thus hits with the exact speed sqrt(2 g H) and leaves with e times it, whatever dt.
       If a slower crossing (a landing below the bounce threshold, resting contact) comes first, the
       time up to the impact is a sustained-contact sub-step (3.) instead of free flight;
    3. otherwise the rest of the step is one sustained-contact sub-step: free half, the sustained
       solve at the middle (the step's contact force as an impulse: normal impulse with the step's
       load, friction on it), free half. If the friction stops the sliding within it, the sub-step
       is shortened to the stopping time (from the tangential momentum of the centre of mass and the
       friction the solve found) and the rest is stepped again, so a block stops where Coulomb
       friction stops it, also when one step holds the whole slide.

    Every sub-step conserves energy in free flight and every solve only removes it. At most
    ``MAX_EVENTS`` sub-steps. The vertices touched and their total normal impulses [N s] over the step
    are written into ``contacts`` (``vertex``, ``normal``, ``gap``, ``effect``, ``obstacle``,
    ``impulses``).
    """
    body = solver.body
    effects = contacts.effects
    accel = np.zeros(3) if loads is None else loads.force / body.mass
    plan = _plan(effects)
    record: list = []

    def keep(c: Contacts, gap) -> None:
        _accumulate(record, c, gap)

    t_left, events, forced, event_vertex = float(dt), 0, None, -1
    points = None
    # the contacts handed in are reused when found at this very state for this step (ModalSolver.advance)
    reuse = contacts if _fresh(contacts, state, t_left, accel) else None
    while t_left > 1e-12 * dt:
        c = find_contacts(solver, state, effects, t_left, accel=accel) if reuse is None else reuse
        reuse = None
        points = c.points
        if c.count == 0:
            solver.advance_free(state, loads, t_left)
            break
        slop = 0.1 * plan.margin[plan.first[c.effect] + c.obstacle]
        thr = plan.threshold[c.effect]
        vn = normal_velocities(solver, state, c)
        # touching: at the ground to rounding (1e-9 of the margin), or the vertex a flight stopped at
        touching = ((c.gap <= 1e-8 * slop) | (c.vertex == event_vertex)) & (vn < 0.0)
        if touching.any():  # 1. impacts now
            sub = c.subset(touching)
            resolve_contacts(solver, state, sub, t_left)
            keep(sub, sub.gap)
            vn = normal_velocities(solver, state, c)
        span = t_left if forced is None else forced
        forced = None
        t_hit, j, t_slow = _crossings(c.gap, vn, c.normal, accel, thr, span)
        event_vertex = -1
        if t_hit is not None and events < MAX_EVENTS:
            event_vertex = int(c.vertex[j])
            events += 1
            if t_slow is None or t_slow >= t_hit:  # 2. fly to the next impact
                flown, deepest = _fly(solver, state, loads, c, t_hit, slop)
                t_left -= flown
                if deepest >= 0:
                    event_vertex = deepest
                continue
            span = t_hit  # a slow landing first: sustained contact up to the impact
        # 3. sustained contact over the sub-step [0, span]: impulse at its middle
        saved = snapshot(state)
        v_start = state.velocity.copy()
        solver.advance_free(state, loads, 0.5 * span)
        gap_mid, n_mid = _gaps(effects, c, body, state, _seen(body, plan, c, span))
        mid = Contacts(c.vertex, n_mid, gap_mid, c.effect, effects, obstacle=c.obstacle, points=c.points)
        resolve_contacts(solver, state, mid, span, accel=accel, sustained=True)
        stop = _stop_fraction(body, mid, v_start, state.velocity, accel, span)
        if stop is not None and events < MAX_EVENTS:  # the sliding ends inside: step to that instant
            restore(state, saved)
            forced = stop * span
            events += 1
            reuse = c  # the same state and t_left: the same contacts
            continue
        keep(mid, gap_mid)
        solver.advance_free(state, loads, 0.5 * span)
        t_left -= span
    _write_record(contacts, record)
    contacts.points = points


def sustained_step(solver, state, contacts: Contacts, loads, dt: float) -> bool:
    """The contact part of ``ModalSolver.step`` (``step_with_contacts``, ``push_out`` and the energy guard) in one
    compiled call (``_contact_step_kernels.sustained_step``) when it is a single sustained sub-step: loads a
    constant force through the centre of mass (``loads`` not None, no torque, no modal force: the caller
    checks), the contacts' response rigid over dt [s] (``_rigid_response``), no impact predicted within the
    step, no friction stop inside it, and no energy gained. Contacts touching and approaching at the start get
    the impact solve of ``step_with_contacts`` (``resolve_contacts``, Python) before the compiled rest (undone
    if that then declines). Returns True when the step was done (``state`` advanced
    by dt, ``contacts`` holding the step record as ``step_with_contacts`` writes it), False with nothing
    changed otherwise (the caller then takes the Python path, whose result it would have been bit for bit)."""
    from modalfem.runtime import _contact_step_kernels as KS
    body = solver.body
    effects = contacts.effects
    accel = loads.force / body.mass
    c = contacts if _fresh(contacts, state, float(dt), accel) else find_contacts(solver, state, effects, dt,
                                                                                   accel=accel)
    k = c.count
    plan = _plan(effects)
    if k == 0 or not _rigid_response(body, plan, c, dt):
        return False
    omega2, axes, moments, eps = _fast_terms(body)
    co = solver.__dict__.get("_half_coefficients")
    if co is None or co[0] != dt:  # the integrator's coefficients of dt / 2 as one (6, r) array
        co = solver.__dict__["_half_coefficients"] = (dt, np.stack(solver.integrator.coefficients(0.5 * dt)))
    gap_mid = np.empty(k)
    n_mid = np.empty((k, 3))
    lam_n = np.empty(k)
    vm = vertex_modes(body)
    if c.points is None:  # (no box edges: nothing more to form)
        kinds, params, margin, local, rest_c, vm_c = (plan.kinds, plan.params, plan.margin, c.obstacle, body.rest,
                                                      vm)
    else:
        row, kinds, params, margin = _obstacles(plan, c)
        local = row - plan.first[c.effect]
        rest_c, vm_c = _geometry(body, c)

    def fused(after_impact: bool, own0: float, e0: float) -> int:
        return KS.sustained_step(kinds, params, plan.first, margin, plan.threshold, plan.friction,
                                 plan.modal, c.vertex, c.effect, local, c.gap, c.normal, body.rest,
                                 vm, _row_scale(body), float(body.radius), omega2, float(body.mass),
                                 body.inertia, body.inertia_inv, axes, moments, eps, co[1], loads.force, loads.torque,
                                 loads.modal, accel, float(dt), _sweeps(plan, c), 4, state.position,
                                 state.orientation, state.velocity, state.angular_momentum,
                                 _angular_velocity(body, _rotation(state), state.angular_momentum), state.q,
                                 state.qdot, gap_mid, n_mid, lam_n, after_impact, own0, e0, rest_c, vm_c,
                                 len(plan.kinds))

    done = fused(False, 0.0, 0.0)
    if done == 2:  # contacts touching and approaching: the impact solve of step_with_contacts' 1., then fused
        own0, e0 = guard_energy(solver, state, loads)
        saved = snapshot(state)
        slop = 0.1 * plan.margin[plan.first[c.effect] + c.obstacle]
        sub = c.subset((c.gap <= 1e-8 * slop) & (normal_velocities(solver, state, c) < 0.0))
        resolve_contacts(solver, state, sub, float(dt))
        if fused(True, own0, e0) != 1:
            restore(state, saved)
            return False
        record: list = []
        _accumulate(record, sub, sub.gap)
        _accumulate(record, Contacts(c.vertex, n_mid, gap_mid, c.effect, effects, impulses=lam_n,
                                     obstacle=c.obstacle, points=c.points), gap_mid)
        _write_record(contacts, record)
        contacts.points = c.points
        return True
    if done != 1:
        return False
    if c.points is not None:  # box-edge contacts: recorded under their faces' vertices (as step_with_contacts)
        record = []
        _accumulate(record, Contacts(c.vertex, n_mid, gap_mid, c.effect, effects, impulses=lam_n,
                                     obstacle=c.obstacle, points=c.points), gap_mid)
        _write_record(contacts, record)
        contacts.points = c.points
        return True
    # the step record, as _accumulate + _write_record write it: the contacts that pushed
    sel = lam_n > 0.0
    if not sel.all():
        if not sel.any():
            _write_record(contacts, [])
            contacts.points = None
            return True
        c = c.subset(sel)
        gap_mid, n_mid, lam_n = gap_mid[sel], n_mid[sel], lam_n[sel]
    contacts.vertex = c.vertex.astype(np.int64, copy=False)
    contacts.effect = c.effect.astype(np.int64, copy=False)
    contacts.obstacle = c.obstacle.astype(np.int64, copy=False)
    contacts.normal, contacts.gap, contacts.impulses, contacts.tangential = n_mid, gap_mid, lam_n, None
    contacts.points = None
    return True


_FAST: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _fast_terms(body) -> tuple:
    """(omega^2 (r,), principal axes (3, 3) as rows, principal moments (3,), the shapes' machine epsilon),
    kept while the body lives."""
    fast = _FAST.get(body)
    if fast is None:
        fast = _FAST[body] = (np.ascontiguousarray(body.omega, dtype=np.float64) ** 2,
                              np.ascontiguousarray(body.principal_axes.T, dtype=np.float64),
                              np.ascontiguousarray(body.principal_moments, dtype=np.float64),
                              _eps(body.shapes_t.dtype))
    return fast


def guard_energy(solver, state, loads) -> tuple[float, float]:
    """``(solver.energy(state), that - loads.force . position)`` [J]: the energy guard's measure, by the compiled
    function the fused step uses (``_contact_step_kernels.energy``)."""
    from modalfem.runtime import _contact_step_kernels as KS
    body = solver.body
    force = _ZERO3 if loads is None else loads.force
    own, e = KS.energy(float(body.mass), body.inertia_inv, _fast_terms(body)[0], state.position, state.orientation,
                       state.velocity, state.angular_momentum, state.q, state.qdot, force)
    return float(own), float(e)


def _fly(solver, state, loads, c: Contacts, h: float, slop: np.ndarray, tries: int = 8):
    """Free flight of at most h [s] that ends with no contact vertex deeper than its slop inside.

    The impact time was predicted without the rotation and the modes; if the flight ends with a vertex
    inside, it is shortened to where that vertex's gap crosses zero (secant from the start of the flight
    on the exact free trajectory). Returns (time flown [s], index of the vertex that stopped the flight
    or -1).
    """
    saved = snapshot(state)
    t, stopper = h, -1
    for _ in range(tries):
        solver.advance_free(state, loads, t)
        gap, _ = _gaps(c.effects, c, solver.body, state)
        excess = gap + slop
        if excess.min() >= 0.0:
            return t, stopper
        i = int(np.argmin(excess))
        stopper = int(c.vertex[i])
        restore(state, saved)
        g0 = c.gap[i]
        t = 0.999 * t * g0 / (g0 - gap[i]) if g0 > 0.0 else 0.0
        if t <= 1e-12 * h:
            break
    return 0.0, stopper


def _stop_fraction(body, mid: Contacts, v_start, v_after, accel, span):
    """Share (0, 1) of a sustained sub-step after which the friction of ``mid``'s solve stops the sliding
    of the centre of mass, or None when it does not stop inside (still sliding at the end, not sliding,
    or stopping in the first 1e-3 of the sub-step, where the difference is below 5e-4 mu g span^2).

    Sliding is the velocity of the centre of mass tangent to the most loaded contact's normal; with
    saturated friction (total ``sum mu_i lambda_n,i`` over the sub-step) and the tangential load
    acceleration a_t, it stops at ``t_s = m |v_t0| / (F_max - m a_t . d)``, d the sliding direction.
    """
    from modalfem.runtime import _contact_step_kernels as KS
    share = KS.stop_share(float(body.mass), np.ascontiguousarray(mid.normal, dtype=np.float64), mid.impulses,
                          _plan(mid.effects).friction[mid.effect], v_start, v_after,
                          np.asarray(accel, dtype=np.float64), float(span))
    return None if math.isnan(share) else float(share)


_EPS: dict = {}


def _eps(dtype) -> float:
    """Machine epsilon of ``dtype`` (``np.finfo`` costs ~10 us a call)."""
    e = _EPS.get(dtype)
    if e is None:
        e = _EPS[dtype] = float(np.finfo(dtype).eps)
    return e


def push_out(solver, state, contacts: Contacts, passes: int = 4, *, accel=None) -> None:
    """Translate the body so that no surface vertex is inside an obstacle (in place).

    The contact solve works on velocities and the impact times are predicted without the rotation and
    the modes, so a vertex may end a step slightly inside. Lifting the body out by a shift d changes
    its potential energy in the load field by ``-m accel . d`` [J]; with ``accel`` (3,) [m/s^2] given,
    that gain is taken from the kinetic energy (all velocities scaled by one factor), so the
    correction creates no energy; when the motion cannot pay, the body's vibration that put the vertices inside is
    shrunk instead (``_contact_step_kernels.push_and_pay``).
    Only the vertices that may be inside (rigid position within the deformation bound) are evaluated.
    The deformation is summed in float64 here; a float32 body's ``positions(precise=True)`` rounds it to
    float32 (~6e-8 of it), so a vertex is pushed to at least that rounding slack above the obstacle.
    """
    from modalfem.runtime import _contact_body_kernels as KB
    from modalfem.runtime import _contact_step_kernels as KS
    body = solver.body
    plan = _plan(contacts.effects)
    q = state.q
    pts = contacts.points  # the box-edge points of the step's last contact search (each held out of its plane)
    kinds, params = (plan.kinds, plan.params) if pts is None else (pts.kinds, pts.params)
    rest, vm = _geometry(body, contacts)
    no, nv = len(plan.kinds), body.vertex_count
    if accel is not None:  # with the payment (KS.push_and_pay: the fused step's very function)
        KS.push_and_pay(kinds, params, rest, vm, _row_scale(body), float(body.radius),
                        _eps(body.shapes_t.dtype), _fast_terms(body)[0], _rotation(state), state.position,
                        float(body.mass), np.asarray(accel, dtype=np.float64), body.inertia_inv, state.velocity,
                        state.angular_momentum, q, state.qdot, int(passes), no, nv)
        return
    bound = deformation_bound(body, q)
    slack = 4.0 * (body.mode_count + 2) * _eps(body.shapes_t.dtype) * bound
    KB.push_shift(kinds, params, rest, vm, q, _skip(body, q), _rotation(state), state.position, bound, slack,
                  int(passes), no, nv)
