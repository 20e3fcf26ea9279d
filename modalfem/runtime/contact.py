"""Contact of the surface vertices with static obstacles: plane (ground), sphere, box.

``Obstacles([...])`` is an opt-in effect; ``ModalSolver.collide`` turns it into ``Contacts`` (the
vertices within a margin of an obstacle, with gap [m] and obstacle normal), and the step resolves
them by sequential impulses (projected Gauss-Seidel over all simultaneous contacts):

* the velocity of a contact vertex is that of the flexible body, ``v + w x r + R Phi_j qdot``
  (the modal part only with ``modal=True``), and its response to contact impulses is the flexible
  one: the Delassus matrix of a contact pair (i, j) is the rigid ``I / m - [r_i]x Iw^-1 [r_j]x``
  plus, with ``modal=True``, the modal ``R Phi_i Phi_j^T R^T`` (mass-normalised modes: unit modal
  masses). The impulses then change v, L and qdot consistently with what the solve saw, so hits
  make the body ring with energy taken from the impact, never from nowhere;
* no contact solve adds kinetic energy: a Gauss-Seidel update towards a target <= 0 only removes
  energy (frictionless PGS descends the kinetic energy), a bounce target is ``-e`` times the
  approach, and a solve that would still add some (restitution near 1 with mixed bouncing and
  resting contacts, truncated sweeps, friction) is scaled back to the largest multiple of its
  impulses that does not (``resolve_contacts``; in random drops of a block only at e = 1, in 12
  of ~600 solves);
* normal: accumulated impulse >= 0 reaching the target normal velocity: ``-e vn0`` for an impact
  within this step faster than ``bounce_threshold`` (restitution e); otherwise 0 when touching and,
  for a vertex still ``gap`` away, an approach of up to ``gap / dt`` (speculative contact: no
  sticking in mid air, no tunnelling);
* friction: the tangential impulse along the sliding velocity that stops it, accumulated per contact
  and clamped to the Coulomb disc ``|jt| <= friction * jn`` (sliding friction opposes sliding).

After the step, vertices left inside an obstacle (the contact solve is velocity-level) are pushed
out by translating the body along the obstacle normal, so no vertex ends inside (e.g. below the
ground).

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

__all__ = [
    "Box",
    "Contacts",
    "Ground",
    "Obstacles",
    "Plane",
    "Sphere",
    "find_contacts",
    "push_out",
    "resolve_contacts",
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
        impulses: (k,) normal impulses [N s] applied by the last resolve (for sound and logging).
    """

    vertex: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    effect: np.ndarray
    effects: list
    impulses: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.vertex)


def _positions64(body, state) -> np.ndarray:
    return body.positions(state, precise=True)


def find_contacts(solver, state, effects, dt=None) -> Contacts:
    """Surface vertices within the margin of an obstacle (see ``ModalSolver.collide``)."""
    body = solver.body
    x = _positions64(body, state)
    speed = float(np.linalg.norm(state.velocity) + np.linalg.norm(body.angular_velocity(state)) * body.radius)
    vs, ns, gs, es = [], [], [], []
    for ei, eff in enumerate(effects):
        margin = eff.margin + (2.0 * speed * float(dt) if dt is not None else 0.0)
        for ob in eff.obstacles:
            gap, n = ob.signed_distance(x)
            sel = np.flatnonzero(gap < margin)
            vs.append(sel)
            ns.append(np.asarray(n)[sel])
            gs.append(gap[sel])
            es.append(np.full(len(sel), ei))
    return Contacts(np.concatenate(vs), np.concatenate(ns).reshape(-1, 3), np.concatenate(gs),
                    np.concatenate(es), list(effects))


def _skew(r: np.ndarray) -> np.ndarray:
    """Cross-product matrices (k, 3, 3) of vectors r (k, 3)."""
    S = np.zeros(r.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -r[..., 2], r[..., 1]
    S[..., 1, 0], S[..., 1, 2] = r[..., 2], -r[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -r[..., 1], r[..., 0]
    return S


def resolve_contacts(solver, state, contacts: Contacts, dt: float) -> None:
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
    """
    k = contacts.count
    contacts.impulses = np.zeros(k)
    if k == 0:
        return
    body = solver.body
    R = state.rotation()
    Iw_inv = R @ body.inertia_inv @ R.T
    j = contacts.vertex
    phi = body.vertex_shapes(j)  # (k, 3, r) body axes
    r = (body.rest[j] + np.einsum("kcr,r->kc", phi, state.q)) @ R.T  # (k, 3) world, from the centre of mass
    modal = np.array([contacts.effects[e].modal for e in contacts.effect])
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
    u = Jac @ V
    u0 = u.copy()
    n = np.ascontiguousarray(contacts.normal)
    effs = [contacts.effects[i] for i in contacts.effect]
    e = np.array([f.restitution for f in effs])
    mu = np.array([f.friction for f in effs])
    thr = np.array([f.bounce_threshold for f in effs])
    slop = np.array([0.1 * f.margin for f in effs])
    iters = max(f.iterations for f in effs)
    blocks = A.reshape(3 * k, k, 3)
    Akk = A.reshape(k, 3, k, 3)[np.arange(k), :, np.arange(k), :]  # (k, 3, 3) diagonal blocks
    Wn = np.einsum("ka,kab,kb->k", n, Akk, n)
    u3 = u.reshape(k, 3)
    vn0 = np.einsum("ka,ka->k", n, u3)
    gap = contacts.gap
    target = np.where(gap > 0, -gap / dt, 0.0)
    bounce = (vn0 < -thr) & (gap + vn0 * dt <= slop) & (e > 0)  # an impact within this step
    target = np.where(bounce, np.maximum(target, -e * vn0), target)
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
    work = float(flat @ u0)  # lambda . u0 [J]
    quad = float(flat @ (u - u0))  # lambda . A lambda [J] (u - u0 = A lambda)
    if work + 0.5 * quad > 1e-12 * quad:  # would add energy: keep the largest share that does not
        # lambda -> s lambda changes the energy by s work + 0.5 s^2 quad: zero at s = -2 work / quad
        scale = min(1.0, -2.0 * (1.0 - 1e-9) * work / quad) if work < 0.0 and quad > 0.0 else 0.0
        lam *= scale
        lam_n *= scale
        flat = lam.reshape(-1)
    dV = JW.T @ flat
    state.velocity += dV[0:3]
    state.angular_momentum += R @ (body.inertia @ (R.T @ dV[3:6]))
    if nm:  # the same impulses move the modes: qdot += sum_i phi_i^T R^T lambda_i
        state.qdot += dV[6:]
    contacts.impulses = lam_n


def push_out(solver, state, contacts: Contacts, passes: int = 4) -> None:
    """Translate the body so that no surface vertex is inside an obstacle (in place)."""
    x = None
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
                    x += shift
                    moved = True
        if not moved:
            return
