"""``ModalSolver``: advances the ``State`` of one modal body (rigid motion + modal deformation).

Step contract (as in NVIDIA Warp / Newton): ``solver.step(state_in, state_out, control, contacts, dt)``.
Order inside a step of length h [s]:

0. the inputs are validated whole (dt, every control entry, the contacts) before anything changes;
   a step that still fails restores ``state_out`` (all-or-nothing);
1. ``control.impulses`` are applied at once (rigid velocity, angular momentum, modal velocities);
2. loads held constant over the step are summed: ``control.forces``, ``control.body_force`` and the
   ``loads`` of every load effect (gravity, ...);
3. free motion (``advance_free``): the centre of mass exactly for a constant force; angular momentum
   by half kicks of the torque around the symplectic free-rotation splitting
   (``rotation.free_rotation_step``); the modes by their exact solution (``ModalIntegrator``), with
   state-dependent effects (pseudo-forces) re-evaluated at the end and the step corrected with the
   mean load (Heun on top of the exact integrator: second order in the coupling);
4. with contacts (``contacts`` from ``solver.collide``, not None), 3. is split at the events of
   ``contact.step_with_contacts``: impacts at their predicted time, sustained contact with the
   step's load, friction stops; vertices still inside an obstacle at the end are pushed out by
   translating the body, the potential energy this adds being taken from the kinetic energy.

Only what is asked for runs: with no effects, an empty control and ``contacts=None`` a step costs
the modal update plus the free rigid update (nothing else is called; tested by counting calls).
The rigid body is not influenced by the deformation (modes are mass-orthogonal to the rigid
motions, so they carry no linear momentum and, to first order, no angular momentum).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from modalfem.errors import SimulationError
from modalfem.runtime.integrator import ModalIntegrator, check_dt
from modalfem.runtime.rotation import free_rotation_step
from modalfem.runtime.state import Control, State, restore, snapshot

__all__ = ["TINY", "Loads", "ModalSolver"]

#: modal amplitudes below this are flushed to zero after each step (far above the subnormal range
#: 2.2e-308, far below any physical amplitude in sqrt(kg) m)
TINY = 1e-150


def _finite3(name: str, value, unit: str) -> np.ndarray:
    """``value`` as a finite float64 3-vector, or ``SimulationError`` saying what is wrong with it."""
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise SimulationError(f"{name} must be 3 numbers [{unit}], got {value!r}") from None
    if a.shape != (3,):
        raise SimulationError(f"{name} must have 3 components [{unit}], got {a.size}")
    if not np.all(np.isfinite(a)):
        raise SimulationError(f"{name} is not finite: {a.tolist()} [{unit}]")
    return a


#: a contact step that ends with more mechanical energy than ENERGY_RTOL x (its energy scale) above where it
#: started is redone as two half steps, at most SPLIT_DEPTH times deep (a 1 s step -> ~1 ms sub-steps)
ENERGY_RTOL = 1e-10
SPLIT_DEPTH = 10


class Loads:
    """Loads held constant over one step, accumulated by effects.

    Attributes:
        force: total force on the body (3,) [N], world.
        torque: total torque about the centre of mass (3,) [N m], world.
        modal: generalised modal force (r,) [sqrt(kg) m/s^2] (``phi_i(p) . F_body`` summed).
    """

    __slots__ = ("force", "modal", "torque")

    def __init__(self, r: int) -> None:
        self.force = np.zeros(3)
        self.torque = np.zeros(3)
        self.modal = np.zeros(r)


@functools.cache
def _settle():
    """``_contact_step_kernels.settle`` (imported on first use: that module imports this one)."""
    from modalfem.runtime._contact_step_kernels import settle

    return settle


class ModalSolver:
    """Time stepper of one ``ModalBody`` with opt-in effects.

    Args:
        body: the ``ModalBody``.
        effects: effects composed into the simulation, e.g. ``Gravity()``, ``PseudoForces(...)``,
            ``Obstacles([Ground()])``. An effect may define any of:
            ``loads(solver, state, dt, loads)`` (add forces; if ``state_dependent`` is True it is
            called again at the predicted end state), and ``obstacles`` (a list of obstacles, which
            makes ``collide`` produce contacts).
    """

    def __init__(self, body, *, effects=()) -> None:
        from modalfem.effects import for_modal

        self.body = body
        self.effects = [for_modal(e) for e in effects]  # modalfem.effects classes are taken too
        self.integrator = ModalIntegrator(body.omega, body.mu)
        self._load_effects = [e for e in self.effects if hasattr(e, "loads")]
        self._dependent = [e for e in self._load_effects if getattr(e, "state_dependent", False)]
        self._contact_effects = [e for e in self.effects if hasattr(e, "obstacles")]
        self._axes = tuple(tuple(a) for a in body.principal_axes.T.tolist())
        self._moments = tuple(body.principal_moments.tolist())

    # ------------------------------------------------------------------ states
    def state(self, **kwargs) -> State:
        """``State.rest(body, **kwargs)``: a body at rest, optionally placed and moving."""
        return State.rest(self.body, **kwargs)

    # ------------------------------------------------------------------ impulses and forces
    def _point_terms(self, state: State, point, R: np.ndarray):
        phi = self.body.point_shapes(point)  # (3, r) body axes
        r_world = R @ (self.body.point_rest(point) + phi @ state.q)
        return phi, r_world

    def apply_impulse(self, state: State, point, J) -> None:
        """Apply a point impulse J (3,) [N s] (world) at a surface point, in place.

        Changes v by J / m, L by r x J (r from the centre of mass to the deformed point) and each
        modal velocity by ``phi_i(p) . R^T J``.

        Raises:
            SimulationError: J not finite, or the point is off the surface.
        """
        J = np.asarray(J, dtype=np.float64)
        if J.shape != (3,) or not np.all(np.isfinite(J)):
            raise SimulationError(f"impulse must be a finite 3-vector [N s], got {J.tolist()}")
        R = state.rotation()
        phi, r_world = self._point_terms(state, point, R)
        state.velocity += J / self.body.mass
        state.angular_momentum += np.cross(r_world, J)
        state.qdot += phi.T @ (R.T @ J)

    def add_point_force(self, state: State, point, F, loads: Loads) -> None:
        """Add a force F (3,) [N] (world) at a surface point to ``loads`` (force, torque, modal)."""
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (3,) or not np.all(np.isfinite(F)):
            raise SimulationError(f"force must be a finite 3-vector [N], got {F.tolist()}")
        R = state.rotation()
        phi, r_world = self._point_terms(state, point, R)
        loads.force += F
        loads.torque += np.cross(r_world, F)
        loads.modal += phi.T @ (R.T @ F)

    # ------------------------------------------------------------------ contacts
    def collide(self, state: State, dt: float | None = None):
        """Contacts of the surface vertices with the obstacles of the contact effects, or None.

        Args:
            state: current state.
            dt: the coming step [s]; widens the search margin to what the body can travel.

        Returns:
            ``Contacts`` or None when no contact effect is configured.
        """
        if not self._contact_effects:
            return None
        from modalfem.runtime.contact import find_contacts

        accel = None
        gravities = [np.asarray(e.g, dtype=np.float64) for e in self._load_effects if hasattr(e, "g")]
        if gravities:
            accel = gravities[0].copy() if len(gravities) == 1 else np.sum(gravities, axis=0)
        return find_contacts(self, state, self._contact_effects, dt, accel=accel)

    # ------------------------------------------------------------------ step
    def check_control(self, control: Control | None) -> tuple[list, list, np.ndarray | None]:
        """Validate a whole ``Control`` without changing anything.

        Every impulse and force entry (its point on this body's surface, its vector finite with 3
        components) and the body force are checked before a step touches the state, so a bad entry
        anywhere in the control leaves the state as it was.

        Args:
            control: a ``Control`` or None.

        Returns:
            ``(impulses, forces, body_force)``: lists of (point, (3,) float64 vector) and the body
            force (3,) [N] or None.

        Raises:
            SimulationError: not a ``Control``; an entry that is not a (point, vector) pair; a point off
                the surface; a vector that is not 3 finite numbers. The message names the entry.
        """
        if control is None:
            return [], [], None
        if not isinstance(control, Control):
            raise SimulationError(f"control must be a modalfem.runtime.Control or None, got {type(control).__name__}")
        out = []
        for kind, unit, entries in (("impulse", "N s", control.impulses), ("force", "N", control.forces)):
            try:
                entries = list(entries)
            except TypeError:
                raise SimulationError(f"control {kind}s must be a list of (point, vector) pairs, "
                                      f"got {type(entries).__name__}") from None
            checked = []
            for i, entry in enumerate(entries):
                where = f"control {kind} {i} (of {len(entries)})"
                try:
                    point, vec = entry
                except (TypeError, ValueError):
                    raise SimulationError(f"{where} must be a (point, vector) pair, got {entry!r}") from None
                if isinstance(point, (bool, np.bool_)):
                    raise SimulationError(f"{where}: a surface point must be a SurfacePoint or a vertex index, "
                                          f"got {point!r}")
                try:
                    self.body._check_point(point)
                except SimulationError as exc:
                    raise SimulationError(f"{where}: {exc}") from None
                checked.append((point, _finite3(f"{where}: {kind}", vec, unit)))
            out.append(checked)
        body_force = None
        if control.body_force is not None:
            body_force = _finite3("control body force", control.body_force, "N")
        return out[0], out[1], body_force

    def step(self, state_in: State, state_out: State, control: Control | None, contacts, dt: float) -> State:
        """Advance ``state_in`` by dt into ``state_out`` (may be the same object).

        All-or-nothing: the inputs (dt, the whole control, the contacts) are validated before anything
        changes, and should the step still fail (an effect raising, a state that became non-finite)
        ``state_out`` is restored to its values before the call.

        Args:
            state_in: state at time t.
            state_out: receives the state at t + dt.
            control: impulses and forces of this step, or None.
            contacts: ``Contacts`` from ``collide(state_in, dt)``, or None (no contact handling). The
                step re-detects the contacts as it advances (the body may move far in a large step)
                and writes the vertices it touched and their normal impulses [N s] back into it.
            dt: step [s], finite and > 0 (any size: the modal update is exact).

        Returns:
            ``state_out``.

        Raises:
            SimulationError: dt <= 0 or not finite, a bad control entry (non-finite impulse or force,
                a point off the surface), contacts that are not ``Contacts``, or a state that became
                non-finite.
        """
        h = check_dt(dt)
        impulses, forces, body_force = self.check_control(control)
        if contacts is not None:
            from modalfem.runtime.contact import Contacts

            if not isinstance(contacts, Contacts):
                raise SimulationError(f"contacts must be the Contacts of solver.collide or None, "
                                      f"got {type(contacts).__name__}")
        s = state_out
        saved = snapshot(s)
        try:
            self._step(state_in, s, impulses, forces, body_force, contacts, h)
        except BaseException:
            restore(s, saved)
            raise
        return s

    def _step(self, state_in: State, s: State, impulses, forces, body_force, contacts, h: float) -> None:
        if s is not state_in:
            s.assign(state_in)
        body = self.body
        for point, J in impulses:
            self.apply_impulse(s, point, J)
        loads = None
        if self._load_effects or forces or body_force is not None:
            loads = Loads(body.mode_count)
            for point, F in forces:
                self.add_point_force(s, point, F, loads)
            if body_force is not None:
                loads.force += body_force
            for e in self._load_effects:
                if not getattr(e, "state_dependent", False):
                    e.loads(self, s, h, loads)
        if contacts is None:
            self.advance_free(s, loads, h)
        else:
            from modalfem.runtime.contact import push_out, step_with_contacts

            if self._conservative(loads, forces):
                self._contact_step_without_gain(s, contacts, loads, h, SPLIT_DEPTH)
            else:
                step_with_contacts(self, s, contacts, loads, h)
                push_out(self, s, contacts, accel=None if loads is None else loads.force / body.mass)
        # modes that decayed below any physical amplitude are set to 0: subnormal numbers would make
        # every later step and reconstruction ~100x slower (a body at rest rings down to them); then the
        # finiteness check (one compiled call: the two were ~12 us of numpy calls, 7 % of a resting bar's step)
        s.time = state_in.time + h
        if not _settle()(s.q, s.qdot, s.position, s.velocity, s.angular_momentum, TINY):
            raise SimulationError("state became non-finite during the step")

    def _conservative(self, loads: Loads | None, forces) -> bool:
        """True when the step's loads are a constant force through the centre of mass (gravity): then
        kinetic + modal + its potential energy is what contact may only remove."""
        if loads is None:
            return True
        return not (forces or self._dependent or loads.torque.any() or loads.modal.any())

    def _mechanical_energy(self, s: State, loads: Loads | None) -> float:
        """Rigid kinetic + modal energy + potential of the constant load force [J]."""
        e = self.energy(s)
        return e if loads is None else e - float(loads.force @ s.position)

    def _contact_step_without_gain(self, s: State, contacts, loads: Loads | None, h: float, depth: int) -> None:
        """``step_with_contacts`` + ``push_out`` that never adds energy: if the step ends with more
        mechanical energy than it started with (beyond rounding), it is redone as two half steps, down to
        ``depth`` halvings. Impact times are predicted without the rotation and the modes, and a push-out
        of a body too slow to pay for its lift would add energy: both shrink with the step (a tumbling
        steel block with e = 1 gained ~0.2 of its energy in one 1 s step before)."""
        from modalfem.runtime.contact import guard_energy, merge_contacts, push_out, step_with_contacts, sustained_step

        # the commonest case (one sustained sub-step, no impact, no stop, no gain) in one compiled call
        if loads is not None and sustained_step(self, s, contacts, loads, h):
            return
        own0, e0 = guard_energy(self, s, loads)  # (energy, _mechanical_energy), compiled as the fused step's
        saved = snapshot(s)
        accel = None if loads is None else loads.force / self.body.mass
        step_with_contacts(self, s, contacts, loads, h)
        push_out(self, s, contacts, accel=accel)
        own1, e1 = guard_energy(self, s, loads)
        scale = own1 + own0
        if loads is not None:  # (3-vector norms as the fused step forms them)
            (f0, f1, f2), (d0, d1, d2) = loads.force.tolist(), (s.position - saved[2]).tolist()
            scale += math.sqrt(f0 * f0 + f1 * f1 + f2 * f2) * (math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                                                              + self.body.radius)
        if e1 <= e0 + ENERGY_RTOL * scale or depth <= 0:
            return
        restore(s, saved)
        first = contacts.copy()
        self._contact_step_without_gain(s, first, loads, 0.5 * h, depth - 1)
        self._contact_step_without_gain(s, contacts, loads, 0.5 * h, depth - 1)
        merge_contacts(contacts, first)

    def advance_free(self, s: State, loads: Loads | None, h: float) -> None:
        """Advance ``s`` in place by h [s] under loads held constant (no contacts, no control).

        The centre of mass moves exactly for the constant force, the angular momentum gets half kicks
        of the torque around the free rotation, the modes their exact solution; state-dependent
        effects are evaluated at the start and at the end (Heun correction of the modal load).
        """
        body = self.body
        dep = None
        modal = None if loads is None else loads.modal
        if self._dependent:
            dep = Loads(body.mode_count)
            for e in self._dependent:
                e.loads(self, s, h, dep)
            modal = dep.modal if modal is None else modal + dep.modal
        # rigid body: exact centre of mass for a constant force; torque half kicks around the free rotation
        if loads is not None:
            a = loads.force / body.mass
            s.position += h * s.velocity + 0.5 * h * h * a
            s.velocity += h * a
            s.angular_momentum += 0.5 * h * loads.torque
        else:
            s.position += h * s.velocity
        if np.any(s.angular_momentum != 0.0):
            s.orientation[...] = free_rotation_step(s.orientation, s.angular_momentum, self._axes, self._moments, h)
        if loads is not None:
            s.angular_momentum += 0.5 * h * loads.torque
        # modes: exact update; Heun correction for state-dependent loads (re-evaluated at the end)
        self.integrator.step(s.q, s.qdot, modal, h, s.q, s.qdot)
        if dep is not None:
            end = Loads(body.mode_count)
            for e in self._dependent:
                e.loads(self, s, h, end)
            _, _, _, _, b1, b2 = self.integrator.coefficients(h)
            df = 0.5 * (end.modal - dep.modal)
            s.q += b1 * df
            s.qdot += b2 * df

    def advance(self, state: State, dt: float, control: Control | None = None) -> State:
        """Convenience: ``collide`` then ``step`` in place (single buffer). Returns ``state``."""
        contacts = self.collide(state, dt) if self._contact_effects else None
        return self.step(state, state, control, contacts, dt)

    # ------------------------------------------------------------------ diagnostics
    def momentum(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """Linear momentum m v (3,) [kg m/s] and angular momentum about the origin c x m v + L
        (3,) [kg m^2/s], world."""
        p = self.body.mass * state.velocity
        return p, np.cross(state.position, p) + state.angular_momentum

    def energy(self, state: State) -> float:
        """Rigid kinetic + modal (kinetic + elastic) energy [J] (no potential of effects)."""
        return self.body.kinetic_energy_rigid(state) + self.body.modal_energy(state)
