"""Contact of the surface vertices with static obstacles: plane (ground), sphere, box.

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
  one: the Delassus matrix of a contact pair (i, j) is the rigid ``I / m - [r_i]x Iw^-1 [r_j]x``
  plus, with ``modal=True``, the modal ``R Phi_i Phi_j^T R^T`` (mass-normalised modes: unit modal
  masses). The impulses then change v, L and qdot consistently with what the solve saw, so hits
  make the body ring with energy taken from the impact, never from nowhere;
* no contact solve adds kinetic energy: a Gauss-Seidel update towards a target <= 0 only removes
  energy, a bounce target is ``-e`` times the approach, and a solve that would still add some
  (restitution near 1 with mixed bouncing and resting contacts, truncated sweeps, friction) is
  scaled back to the largest multiple of its impulses that does not (``resolve_contacts``);
* friction: the tangential impulse along the sliding velocity that stops it, accumulated per contact
  and clamped to the Coulomb disc ``|jt| <= friction * jn`` (sliding friction opposes sliding).

After the step, vertices left inside an obstacle (impact times are predicted without the rotation and
the modes) are pushed out by translating the body along the obstacle normal, so no vertex ends
inside (e.g. below the ground); the potential energy this lift adds is taken from the kinetic energy.

Energy guard: impact times are predicted without the rotation and the modes, and a push-out of a body
too slow to pay for its lift costs energy; both shrink with the step. With gravity as the only load,
``ModalSolver.step`` therefore redoes a contact step that ends with more kinetic + modal + gravitational
energy than it began with (beyond 1e-10 of the step's energy scale) as two half steps, at most 10
halvings deep (a tumbling flexible steel block with e = 1 gained up to 1.5e-4 of its energy in one
10 ms step before; now <= 1e-8, rounding). With other loads (wind, point forces, pseudo-forces) the
energy is not conserved by the loads themselves and no guard applies.

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

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError
from modalfem.runtime.state import restore, snapshot

__all__ = [
    "Box",
    "Contacts",
    "merge_contacts",
    "Ground",
    "Obstacles",
    "Plane",
    "Sphere",
    "find_contacts",
    "MAX_EVENTS",
    "normal_velocities",
    "push_out",
    "resolve_contacts",
    "step_with_contacts",
]


def _vec(name, v, n=3) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be a finite {n}-vector, got {v!r}")
    return a


class Plane:
    """Half-space ``n . x >= offset`` is free; the body must stay on the side ``n`` points to.

    Args:
        normal: (3,) outward normal of the obstacle surface (normalised here).
        point: (3,) a point of the plane [m].
    """

    def __init__(self, normal=(0.0, 0.0, 1.0), point=(0.0, 0.0, 0.0)) -> None:
        n = _vec("plane normal", normal)
        if not np.linalg.norm(n) > 0:
            raise InputError("plane normal must be non-zero")
        self.normal = n / np.linalg.norm(n)
        self.offset = float(self.normal @ _vec("plane point", point))

    def signed_distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gap (n,) [m] (negative inside) and outward normal (n, 3) at points x (n, 3) [m]."""
        return x @ self.normal - self.offset, np.broadcast_to(self.normal, x.shape)


class Ground(Plane):
    """Horizontal ground plane z = height [m] (normal +z)."""

    def __init__(self, height: float = 0.0) -> None:
        super().__init__((0.0, 0.0, 1.0), (0.0, 0.0, float(height)))


class Sphere:
    """Solid sphere obstacle: center (3,) [m], radius [m] > 0."""

    def __init__(self, center, radius: float) -> None:
        self.center = _vec("sphere center", center)
        self.radius = float(radius)
        if not self.radius > 0:
            raise InputError(f"sphere radius must be > 0 [m], got {radius!r}")

    def signed_distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = x - self.center
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        n = d / np.where(r > 0, r, 1.0)[:, None]
        n[r == 0] = (0.0, 0.0, 1.0)
        return r - self.radius, n


class Box:
    """Solid box obstacle: center (3,) [m], half extents (3,) [m] > 0, rotation (3, 3) box -> world."""

    def __init__(self, center, half_extents, rotation=None) -> None:
        self.center = _vec("box center", center)
        self.half = _vec("box half extents", half_extents)
        if np.any(self.half <= 0):
            raise InputError(f"box half extents must be > 0 [m], got {self.half.tolist()}")
        self.rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64).reshape(3, 3)

    def signed_distance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = (x - self.center) @ self.rotation  # box axes
        q = np.abs(p) - self.half
        sign = np.where(p < 0, -1.0, 1.0)
        outside = np.maximum(q, 0.0)
        dout = np.sqrt(np.einsum("ij,ij->i", outside, outside))
        inside = dout == 0
        gap = np.where(inside, q.max(axis=1), dout)
        n_local = np.where(inside[:, None], 0.0, sign * outside / np.where(dout > 0, dout, 1.0)[:, None])
        k = np.argmax(q, axis=1)
        rows = np.flatnonzero(inside)
        n_local[rows, k[rows]] = sign[rows, k[rows]]
        return gap, n_local @ self.rotation.T


class Obstacles:
    """Opt-in contact effect: static obstacles touched by the surface vertices.

    Args:
        obstacles: list of ``Plane`` / ``Ground`` / ``Sphere`` / ``Box``.
        restitution: coefficient of restitution e in [0, 1].
        friction: Coulomb coefficient >= 0.
        iterations: sequential-impulse sweeps over the simultaneous contacts.
        margin: contacts are gathered within this distance [m] (plus what the body travels in dt).
        bounce_threshold: impacts slower than this [m/s] do not bounce (resting contact).
        modal: include the modes in the contact response (impacts excite vibration).
    """

    def __init__(self, obstacles, *, restitution: float = 0.3, friction: float = 0.5, iterations: int = 10,
                 margin: float = 1e-3, bounce_threshold: float = 0.05, modal: bool = True) -> None:
        self.obstacles = list(obstacles)
        if not self.obstacles or not all(hasattr(o, "signed_distance") for o in self.obstacles):
            raise InputError("Obstacles needs a non-empty list of Plane/Ground/Sphere/Box")
        if not 0.0 <= restitution <= 1.0:
            raise InputError(f"restitution must be in [0, 1], got {restitution!r}")
        if not friction >= 0.0:
            raise InputError(f"friction must be >= 0, got {friction!r}")
        if int(iterations) < 1:
            raise InputError(f"iterations must be >= 1, got {iterations!r}")
        if not (np.isfinite(margin) and margin > 0.0):
            raise InputError(f"margin must be finite and > 0 [m], got {margin!r}")
        if not (np.isfinite(bounce_threshold) and bounce_threshold >= 0.0):
            raise InputError(f"bounce_threshold must be finite and >= 0 [m/s], got {bounce_threshold!r}")
        if not np.isfinite(friction):
            raise InputError(f"friction must be finite, got {friction!r}")
        self.restitution, self.friction = float(restitution), float(friction)
        self.iterations, self.margin = int(iterations), float(margin)
        self.bounce_threshold, self.modal = float(bounce_threshold), bool(modal)


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
    """

    vertex: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    effect: np.ndarray
    effects: list
    impulses: np.ndarray | None = None
    obstacle: np.ndarray | None = None
    tangential: np.ndarray | None = None

    def subset(self, keep) -> Contacts:
        """The contacts selected by the boolean mask or index array ``keep``."""
        return Contacts(self.vertex[keep], self.normal[keep], self.gap[keep], self.effect[keep], self.effects,
                        obstacle=None if self.obstacle is None else self.obstacle[keep])

    @property
    def count(self) -> int:
        return len(self.vertex)

    def copy(self) -> Contacts:
        """An independent copy (the arrays copied, the effects shared)."""
        def c(a):
            return None if a is None else np.array(a, copy=True)

        return Contacts(c(self.vertex), c(self.normal), c(self.gap), c(self.effect), self.effects,
                        impulses=c(self.impulses), obstacle=c(self.obstacle), tangential=c(self.tangential))


def merge_contacts(into: Contacts, earlier: Contacts) -> None:
    """Fold the step record ``earlier`` (an earlier part of the same step) into ``into`` in place: one entry
    per (vertex, effect, obstacle), normal impulses [N s] summed, normal and gap of the later part."""
    record: dict = {}
    for part in (earlier, into):
        if part.impulses is not None and part.obstacle is not None:
            _accumulate(record, part, part.gap)
    _write_record(into, record)


def _accumulate(record: dict, c: Contacts, gap) -> None:
    """Add the contacts of ``c`` that pushed (impulse > 0) to a step record (see ``_write_record``)."""
    for i in np.flatnonzero(c.impulses > 0.0):
        key = (int(c.vertex[i]), int(c.effect[i]), int(c.obstacle[i]))
        prev = record.get(key)
        record[key] = (c.normal[i], gap[i], (0.0 if prev is None else prev[2]) + float(c.impulses[i]))


def _write_record(contacts: Contacts, record: dict) -> None:
    """Set ``contacts`` to a step record {(vertex, effect, obstacle): (normal, gap, total impulse [N s])}."""
    keys = list(record)
    contacts.vertex = np.array([k[0] for k in keys], dtype=np.int64)
    contacts.effect = np.array([k[1] for k in keys], dtype=np.int64)
    contacts.obstacle = np.array([k[2] for k in keys], dtype=np.int64)
    contacts.normal = np.array([record[k][0] for k in keys], dtype=np.float64).reshape(-1, 3)
    contacts.gap = np.array([record[k][1] for k in keys], dtype=np.float64)
    contacts.impulses = np.array([record[k][2] for k in keys], dtype=np.float64)
    contacts.tangential = None


def _positions64(body, state) -> np.ndarray:
    return body.positions(state, precise=True)


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
    body = solver.body
    x = _positions64(body, state)
    speed = float(np.linalg.norm(state.velocity) + np.linalg.norm(body.angular_velocity(state)) * body.radius)
    reach = 0.0
    if dt is not None:
        reach = 2.0 * speed * float(dt)
        if accel is not None:
            reach += float(np.linalg.norm(accel)) * float(dt) ** 2
    vs, ns, gs, es, os_ = [], [], [], [], []
    for ei, eff in enumerate(effects):
        margin = eff.margin + reach
        for oi, ob in enumerate(eff.obstacles):
            gap, n = ob.signed_distance(x)
            sel = np.flatnonzero(gap < margin)
            vs.append(sel)
            ns.append(np.asarray(n)[sel])
            gs.append(gap[sel])
            es.append(np.full(len(sel), ei))
            os_.append(np.full(len(sel), oi))
    return Contacts(np.concatenate(vs), np.concatenate(ns).reshape(-1, 3), np.concatenate(gs),
                    np.concatenate(es), list(effects), obstacle=np.concatenate(os_))


def _skew(r: np.ndarray) -> np.ndarray:
    """Cross-product matrices (k, 3, 3) of vectors r (k, 3)."""
    S = np.zeros(r.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -r[..., 2], r[..., 1]
    S[..., 1, 0], S[..., 1, 2] = r[..., 2], -r[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -r[..., 1], r[..., 0]
    return S


def _jacobian(solver, state, contacts: Contacts):
    """Contact-space operators of the flexible body: (Jac (3k, 6 + nm), JW (3k, 6 + nm), A (3k, 3k),
    V (6 + nm,), R, nm); see ``resolve_contacts``."""
    body = solver.body
    k = contacts.count
    R = state.rotation()
    Iw_inv = R @ body.inertia_inv @ R.T
    j = contacts.vertex
    phi = body.vertex_shapes(j)  # (k, 3, r) body axes
    r = (body.rest[j] + np.einsum("kcr,r->kc", phi, state.q)) @ R.T  # (k, 3) world, from the centre of mass
    modal = np.array([contacts.effects[e].modal for e in contacts.effect], dtype=bool)
    nm = body.mode_count if modal.any() else 0
    Jac = np.zeros((k, 3, 6 + nm))
    Jac[:, :, 0:3] = np.eye(3)
    Jac[:, :, 3:6] = -_skew(r)  # w x r = -[r]x w
    if nm:
        Jac[modal, :, 6:] = np.einsum("ab,kbr->kar", R, phi[modal])  # R Phi_j: modal velocity of the vertex
    Jac = Jac.reshape(3 * k, 6 + nm)
    JW = Jac.copy()  # J W with W = diag(I/m, Iw^-1, I_r)
    JW[:, 0:3] /= body.mass
    JW[:, 3:6] = Jac[:, 3:6] @ Iw_inv
    A = JW @ Jac.T  # (3k, 3k)
    V = np.concatenate([state.velocity, Iw_inv @ state.angular_momentum, state.qdot[:nm]])
    return Jac, JW, A, V, R, nm


def normal_velocities(solver, state, contacts: Contacts) -> np.ndarray:
    """Normal velocities (k,) [m/s] of the contact vertices (flexible: with the modal part where the
    contact's effect is ``modal``); negative = approaching the obstacle."""
    if contacts.count == 0:
        return np.zeros(0)
    Jac, _, _, V, _, _ = _jacobian(solver, state, contacts)
    return np.einsum("ka,ka->k", contacts.normal, (Jac @ V).reshape(-1, 3))


def resolve_contacts(solver, state, contacts: Contacts, dt: float, *, accel=None, sustained: bool = False) -> None:
    """Sequential impulses over all contacts (in place on ``state``); see the module docstring.

    Works in contact space. The generalised velocities are V = (v, w, qdot) [m/s, rad/s,
    sqrt(kg) m/s] with the kinetic energy 0.5 V^T W^-1 V, W = diag(I/m, Iw^-1, I_r) (mass-normalised
    modes). The world velocity of contact vertex j is ``u_j = v + w x r_j + R Phi_j qdot`` = J_j V
    (the modal column only for ``modal`` obstacles) and the response to contact impulses lambda
    (3k,) [N s] is u = u0 + A lambda with the Delassus matrix A = J W J^T (3k, 3k): the rigid
    compliance ``I/m - [r_i]x Iw^-1 [r_j]x`` plus the modal one ``R Phi_i Phi_j^T R^T`` per contact
    pair. The impulses change V by W J^T lambda, i.e. v, L and qdot consistently with the
    velocities the solve saw. The kinetic energy changes by ``lambda . u0 + 0.5 lambda . A lambda``;
    should an unconverged or frictional solve make that positive, lambda is scaled down to the
    largest multiple that does not add energy, so no contact solve adds energy.

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
    k = contacts.count
    contacts.impulses = np.zeros(k)
    contacts.tangential = np.zeros((k, 3))
    if k == 0:
        return
    body = solver.body
    Jac, JW, A, V, R, nm = _jacobian(solver, state, contacts)
    u = Jac @ V
    u_now = u.copy()  # the actual velocities: the energy check uses them
    n = np.ascontiguousarray(contacts.normal)
    u3 = u.reshape(k, 3)
    gap = contacts.gap
    effs = [contacts.effects[i] for i in contacts.effect]
    e = np.array([f.restitution for f in effs])
    mu = np.array([f.friction for f in effs])
    thr = np.array([f.bounce_threshold for f in effs])
    iters = max(f.iterations for f in effs)
    if sustained:
        a = np.zeros(3) if accel is None else np.asarray(accel, dtype=np.float64)
        u3 += 0.5 * dt * a  # predicted end-of-step velocities without contact (u3 is a view of u)
        an = n @ a
        target = 0.25 * dt * an - 2.0 * gap / dt
    else:
        vn0 = np.einsum("ka,ka->k", n, u3)
        target = np.where(gap > 0, -gap / dt, 0.0)
        bounce = (vn0 < -thr) & (e > 0)
        target = np.where(bounce, np.maximum(target, -e * vn0), target)
    u0 = u.copy()
    blocks = A.reshape(3 * k, k, 3)
    Akk = A.reshape(k, 3, k, 3)[np.arange(k), :, np.arange(k), :]  # (k, 3, 3) diagonal blocks
    Wn = np.einsum("ka,kab,kb->k", n, Akk, n)
    lam_n = np.zeros(k)
    lam = np.zeros((k, 3))  # total contact impulse per contact (world)
    jt = np.zeros((k, 3))
    for _ in range(iters):
        change = 0.0
        for i in range(k):
            ni = n[i]
            vn = ni @ u3[i]
            new = lam_n[i] + (target[i] - vn) / Wn[i]
            new = max(0.0, new)
            d = new - lam_n[i]
            delta = d * ni
            lam_n[i] = new
            if mu[i] > 0.0:
                ui = u3[i] + Akk[i] @ delta
                ut = ui - ni * (ni @ ui)
                speed = np.sqrt(ut @ ut)
                cand = jt[i]
                if speed > 0.0:  # impulse along -ut stopping the sliding (scalar effective mass)
                    t = ut / speed
                    cand = cand - (speed / (t @ Akk[i] @ t)) * t
                lim = mu[i] * new
                norm = np.sqrt(cand @ cand)
                if norm > lim:
                    cand *= lim / norm
                delta = delta + (cand - jt[i])
                jt[i] = cand
            if delta.any():
                lam[i] += delta
                u += blocks[:, i, :] @ delta
                change = max(change, float(np.abs(delta).max()))
        if change <= 1e-12 * float(np.abs(lam).max()):  # converged: a sweep changed nothing that matters
            break
    flat = lam.reshape(-1)
    work = float(flat @ u_now)  # lambda . u [J], u the actual velocities at this instant
    quad = float(flat @ (u - u0))  # lambda . A lambda [J] (u - u0 = A lambda)
    if work + 0.5 * quad > 1e-12 * quad:  # would add energy: keep the largest share that does not
        # lambda -> s lambda changes the energy by s work + 0.5 s^2 quad: zero at s = -2 work / quad
        scale = min(1.0, -2.0 * (1.0 - 1e-9) * work / quad) if work < 0.0 and quad > 0.0 else 0.0
        lam *= scale
        lam_n *= scale
        jt *= scale
        flat = lam.reshape(-1)
    dV = JW.T @ flat
    state.velocity += dV[0:3]
    state.angular_momentum += R @ (body.inertia @ (R.T @ dV[3:6]))
    if nm:  # the same impulses move the modes: qdot += sum_i phi_i^T R^T lambda_i
        state.qdot += dV[6:]
    contacts.impulses = lam_n
    contacts.tangential = jt


#: most sub-steps (impact events, friction stops) in one step; beyond, the rest of the step is one
#: sustained-contact sub-step (which never adds energy either)
MAX_EVENTS = 32


def _crossings(gap, vn, an, thr, horizon):
    """First downward zero crossings of the contacts' gaps ``gap + vn t + an t^2 / 2`` [m] in
    (0, horizon] [s]: ``(t_fast, j, t_slow)``, the earliest crossing faster than the contact's bounce
    threshold and its contact index ((None, -1) if none), and the earliest slower one (None if none).

    The roots are taken in the cancellation-free form q = -(b + sign(b) sqrt(D)) / 2, t = q / a and
    c / q (a = an / 2, b = vn, c = gap).
    """
    a, b, c = 0.5 * an, vn, gap
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    q = -0.5 * (b + np.where(b >= 0.0, sq, -sq))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = np.where(a != 0.0, q / a, np.where(b != 0.0, -c / b, np.inf))
        r2 = np.where(q != 0.0, c / q, np.inf)
    first = np.full(len(gap), np.inf)
    speed = np.zeros(len(gap))
    for r in (r1, r2):
        with np.errstate(invalid="ignore"):
            v = vn + an * r  # normal velocity at the crossing (r may be inf: masked below)
        down = ok & np.isfinite(r) & (r > 0.0) & (r <= horizon) & (v < 0.0) & (r < first)
        first = np.where(down, r, first)
        speed = np.where(down, v, speed)
    # touching or inside and not leaving faster than the threshold: a (slow) crossing now, for the
    # sustained solve (with a rounding-size gap < 0 the quadratic may have no root at all)
    below = (gap <= 0.0) & (vn <= thr)
    first = np.where(below, 0.0, first)
    speed = np.where(below, np.minimum(vn, 0.0), speed)
    fast = np.isfinite(first) & (speed < -thr)
    slow = np.isfinite(first) & ~fast
    t_fast, j = None, -1
    fast &= first > 0.0  # (a fast one at t = 0 is the impact solve's: not an event)
    if fast.any():
        j = int(np.flatnonzero(fast)[np.argmin(first[fast])])
        t_fast = float(first[j])
    t_slow = float(first[slow].min()) if slow.any() else None
    return t_fast, j, t_slow


def _gaps(effects, contacts: Contacts, x: np.ndarray):
    """Gaps (k,) [m] and normals (k, 3) of the contact vertices at positions x (nv, 3) [m] against the
    obstacle each contact belongs to."""
    gap = np.empty(contacts.count)
    nrm = np.empty((contacts.count, 3))
    for ei, eff in enumerate(effects):
        for oi, ob in enumerate(eff.obstacles):
            sel = np.flatnonzero((contacts.effect == ei) & (contacts.obstacle == oi))
            if sel.size:
                g, nn = ob.signed_distance(x[contacts.vertex[sel]])
                gap[sel] = g
                nrm[sel] = nn
    return gap, nrm


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
    record: dict = {}

    def keep(c: Contacts, gap) -> None:
        _accumulate(record, c, gap)

    t_left, events, forced, event_vertex = float(dt), 0, None, -1
    while t_left > 1e-12 * dt:
        c = find_contacts(solver, state, effects, t_left, accel=accel)
        if c.count == 0:
            solver.advance_free(state, loads, t_left)
            break
        slop = np.array([0.1 * effects[i].margin for i in c.effect])
        thr = np.array([effects[i].bounce_threshold for i in c.effect])
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
        t_hit, j, t_slow = _crossings(c.gap, vn, c.normal @ accel, thr, span)
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
        gap_mid, n_mid = _gaps(effects, c, _positions64(body, state))
        mid = Contacts(c.vertex, n_mid, gap_mid, c.effect, effects, obstacle=c.obstacle)
        resolve_contacts(solver, state, mid, span, accel=accel, sustained=True)
        stop = _stop_fraction(body, mid, v_start, state.velocity, accel, span)
        if stop is not None and events < MAX_EVENTS:  # the sliding ends inside: step to that instant
            restore(state, saved)
            forced = stop * span
            events += 1
            continue
        keep(mid, gap_mid)
        solver.advance_free(state, loads, 0.5 * span)
        t_left -= span
    _write_record(contacts, record)


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
        gap, _ = _gaps(c.effects, c, _positions64(solver.body, state))
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
    if mid.count == 0 or not np.any(mid.impulses > 0.0):
        return None
    mu = np.array([mid.effects[i].friction for i in mid.effect])
    cone = float(mu @ mid.impulses)
    if cone <= 0.0:
        return None
    n = mid.normal[int(np.argmax(mid.impulses))]
    vt0 = v_start - n * (n @ v_start)
    s0 = float(np.sqrt(vt0 @ vt0))
    if s0 == 0.0:
        return None
    d = vt0 / s0
    a_end = v_after + 0.5 * span * accel  # end-of-sub-step velocity of the centre of mass
    vt_end = a_end - n * (n @ a_end)
    if float(np.sqrt(vt_end @ vt_end)) > 1e-3 * s0:  # still sliding at the end: friction was saturated
        return None
    rate = cone / span - body.mass * float(accel @ d)  # [N]: deceleration force of saturated friction
    if rate <= 0.0:
        return None
    share = body.mass * s0 / (rate * span)
    if 1e-3 < share < 1.0 - 1e-6:
        return share
    return None


def push_out(solver, state, contacts: Contacts, passes: int = 4, *, accel=None) -> None:
    """Translate the body so that no surface vertex is inside an obstacle (in place).

    The contact solve works on velocities and the impact times are predicted without the rotation and
    the modes, so a vertex may end a step slightly inside. Lifting the body out by a shift d changes
    its potential energy in the load field by ``-m accel . d`` [J]; with ``accel`` (3,) [m/s^2] given,
    that gain is taken from the kinetic energy (all velocities scaled by one factor), so the
    correction creates no energy (if the kinetic energy is smaller than the gain, the body stops).
    """
    x = None
    total = np.zeros(3)
    for _ in range(passes):
        moved = False
        for eff in contacts.effects:
            for ob in eff.obstacles:
                if x is None:
                    x = _positions64(solver.body, state)
                gap, nrm = ob.signed_distance(x)
                i = int(np.argmin(gap))
                if gap[i] < 0.0:
                    shift = -gap[i] * np.asarray(nrm[i]) * (1.0 + 1e-9)
                    state.position += shift
                    total += shift
                    x += shift
                    moved = True
        if not moved:
            break
    if accel is None or not total.any():
        return
    body = solver.body
    gain = -body.mass * float(np.asarray(accel, dtype=np.float64) @ total)  # [J]
    if gain <= 0.0:
        return
    kinetic = body.kinetic_energy_rigid(state) + 0.5 * float(state.qdot @ state.qdot)
    scale = float(np.sqrt(max(0.0, 1.0 - gain / kinetic))) if kinetic > 0.0 else 0.0
    state.velocity *= scale
    state.angular_momentum *= scale
    state.qdot *= scale
