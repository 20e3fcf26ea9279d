"""The World's modal bodies stepped in one compiled call (numba, cached on disk): what ``ModalSolver.step`` does for
a body whose only load is gravity, with no static obstacles, control or strikes (the solid solve's impulses taken
at the step start; the part holding the step's load at the middle: ``ctx.lift``), for all such bodies at once on
packed arrays. The same arithmetic in the same order as ``ModalSolver.advance_free``,
``runtime.rotation.free_rotation_step`` and ``ModalIntegrator.step``; a body that needs anything else goes through
its solver.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from modalfem.runtime._contact_step_kernels import _free_rotation
from modalfem.world._shared import packed_states
from modalfem.world._solid_stage import apply_lift

@numba.njit(cache=True)
def free_steps(pos, vel, L, quat, q, qdot, qoff, nm, dV, dvoff, kick, inertia, mass, g, axes, moments, coef, h,
               tiny):
    """Every body's step in place on packed arrays; returns False if any value became non-finite.

    Args:
        pos, vel, L: (nb, 3) centres of mass [m], velocities [m/s], world angular momenta [kg m^2/s]; quat: (nb, 4)
            orientations. q, qdot: the modal coordinates, body i's ``nm[i]`` from ``qoff[i]``.
        dV: the solid solve's velocity changes ``(dv, dw, dqdot)`` (6 + r), body i's from ``dvoff[i]`` when
            ``kick[i]``, taken at the step start (``dw`` as the angular momentum ``R I R^T dw``).
        inertia: (nb, 3, 3) inertias in body axes [kg m^2]; mass: (nb,) [kg]; g: (nb, 3) gravity [m/s^2];
            axes: (nb, 3, 3) principal axes (rows, body axes); moments: (nb, 3) [kg m^2]. coef: the integrator's
            ``(a11, a12, a21, a22, b1, b2)`` for step h, per mode, body i's (6, nm[i]) flattened from ``6 qoff[i]``.
        h: step [s]. tiny: modal values below this are set to 0 (``runtime.solver.TINY``).
    """
    nb = pos.shape[0]
    ok = True
    R = np.empty((3, 3))
    for b in range(nb):
        r = nm[b]
        o = qoff[b]
        if kick[b]:
            d = dvoff[b]
            for c in range(3):
                vel[b, c] += dV[d + c]
            w, x, y, z = quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3]
            R[0, 0], R[0, 1], R[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
            R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
            R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
            t0 = R[0, 0] * dV[d + 3] + R[1, 0] * dV[d + 4] + R[2, 0] * dV[d + 5]  # R^T dw
            t1 = R[0, 1] * dV[d + 3] + R[1, 1] * dV[d + 4] + R[2, 1] * dV[d + 5]
            t2 = R[0, 2] * dV[d + 3] + R[1, 2] * dV[d + 4] + R[2, 2] * dV[d + 5]
            u0 = inertia[b, 0, 0] * t0 + inertia[b, 0, 1] * t1 + inertia[b, 0, 2] * t2
            u1 = inertia[b, 1, 0] * t0 + inertia[b, 1, 1] * t1 + inertia[b, 1, 2] * t2
            u2 = inertia[b, 2, 0] * t0 + inertia[b, 2, 1] * t1 + inertia[b, 2, 2] * t2
            for c in range(3):
                L[b, c] += R[c, 0] * u0 + R[c, 1] * u1 + R[c, 2] * u2
            for m in range(r):
                qdot[o + m] += dV[d + 6 + m]
        # the centre of mass exactly under the constant force m g (advance_free's order of operations)
        hh = 0.5 * h * h
        for c in range(3):
            a = (mass[b] * g[b, c]) / mass[b]
            pos[b, c] += h * vel[b, c] + hh * a
            vel[b, c] += h * a
        if L[b, 0] != 0.0 or L[b, 1] != 0.0 or L[b, 2] != 0.0:
            _free_rotation(quat[b], L[b], axes[b], moments[b], h)
        k = 6 * o
        for m in range(r):
            a11, a12, a21, a22 = coef[k + m], coef[k + r + m], coef[k + 2 * r + m], coef[k + 3 * r + m]
            q1 = a11 * q[o + m] + a12 * qdot[o + m]
            v1 = a21 * q[o + m] + a22 * qdot[o + m]
            q[o + m] = 0.0 if abs(q1) < tiny else q1
            qdot[o + m] = 0.0 if abs(v1) < tiny else v1
        s = 0.0
        for m in range(r):
            s += q[o + m] + qdot[o + m]
        for c in range(3):
            s += pos[b, c] + vel[b, c] + L[b, c]
        if not math.isfinite(s):
            ok = False
    return ok


def _kicks(ctx, names: list, position: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the solid stage left for the modal bodies ``names`` stepped together: each body's lift (position change
    [m] from ``gravity_lift``) added to its row of the start ``position`` (m, 3) [m] in place; and its velocity
    change ``ctx.dV[name]`` (6 + r) packed as ``(dv, dvoff, kick)``: the changes one after another, (m,) offsets
    into them, (m,) bool: the body has one."""
    kick = np.zeros(len(names), dtype=np.bool_)
    dvoff = np.zeros(len(names), dtype=np.int64)
    parts, o = [np.zeros(0)], 0
    for i, n in enumerate(names):
        apply_lift(ctx.lift, n, position[i])
        d = ctx.dV.get(n)
        if d is not None:
            kick[i], dvoff[i] = True, o
            parts.append(d)
            o += len(d)
    return np.concatenate(parts), dvoff, kick


class ModalBatch:
    """The modal bodies of a World that ``free_steps`` can step: each body's only effect in its solver is one
    gravity (``runtime.effects.Gravity``; modal damping is in its integrator), with no static obstacles of its own.

    Args:
        modal: the World's ``{name: {"body", "solver", "static", "scratch", ...}}`` of modal bodies.
    """

    def __init__(self, modal: dict) -> None:
        from modalfem.runtime.effects import Gravity

        self.names = [n for n, m in modal.items() if not m["static"] and len(m["solver"].effects) <= 1
                      and all(type(e) is Gravity for e in m["solver"].effects)]
        bodies = [modal[n]["body"] for n in self.names]
        self.solvers = [modal[n]["solver"] for n in self.names]
        self.outs = [modal[n]["scratch"] for n in self.names]
        self.nm = np.array([b.mode_count for b in bodies], dtype=np.int64)
        self.qoff = np.concatenate([[0], np.cumsum(self.nm)[:-1]]).astype(np.int64) if bodies else self.nm
        self.inertia = np.array([b.inertia for b in bodies], dtype=np.float64).reshape(-1, 3, 3)
        self.mass = np.array([b.mass for b in bodies], dtype=np.float64)
        self.g = np.array([s.effects[0].g if s.effects else np.zeros(3) for s in self.solvers],
                          dtype=np.float64).reshape(-1, 3)
        self.axes = np.array([b.principal_axes.T for b in bodies], dtype=np.float64).reshape(-1, 3, 3)
        self.moments = np.array([b.principal_moments for b in bodies], dtype=np.float64).reshape(-1, 3)
        self._coef = {}
        # the packed arrays ``free_steps`` steps in place and, per body, its rows of them: a stepped body's scratch
        # state holds these views (bound at every step), so the step's results need no copying out (was 6 array
        # copies per body and step)
        nb, o = len(bodies), np.concatenate([self.qoff, [int(self.nm.sum())]]).astype(np.int64)
        self._packed = (np.zeros((nb, 3)), np.zeros((nb, 3)), np.zeros((nb, 3)), np.zeros((nb, 4)),
                        np.zeros(int(o[-1])), np.zeros(int(o[-1])))
        P, V, L, Q, q, qd = self._packed
        self._views = [(P[i], V[i], L[i], Q[i], q[o[i]:o[i + 1]], qd[o[i]:o[i + 1]]) for i in range(nb)]

    def _coefficients(self, h: float) -> np.ndarray:
        c = self._coef.get(h)
        if c is None:
            c = np.concatenate([np.zeros(0)] + [np.concatenate([np.broadcast_to(a, (r,)) for a in
                                                                s.integrator.coefficients(h)])
                                                for s, r in zip(self.solvers, self.nm)]).astype(np.float64)
            self._coef = {h: c}
        return c

    def step(self, ctx, skip: set) -> list:
        """Step every body of the batch not in ``skip`` from ``ctx.state_in`` (with the solve's ``ctx.dV``) into
        its scratch state, put it in ``ctx.out`` and ``ctx.done``; returns the names stepped.

        Raises:
            SimulationError: a body's state became non-finite (named).
        """
        from modalfem.runtime.solver import TINY

        h = float(ctx.dt)
        names = [n for n in self.names if n not in skip]
        if not names:
            return []
        coef = self._coefficients(h)
        if not skip:  # every body: stepped in the packed arrays its scratch state views
            packed = self._packed
            for a, b in zip(packed, packed_states(ctx, self.names)):  # (shared with the contact stage: copied)
                a[...] = b
            dv, dvoff, kick = _kicks(ctx, names, packed[0])
            ok = free_steps(*packed, self.qoff, self.nm, dv, dvoff, kick, self.inertia, self.mass,
                            self.g, self.axes, self.moments, coef, h, TINY)
            for n, out, v in zip(names, self.outs, self._views):
                out.position, out.velocity, out.angular_momentum, out.orientation, out.q, out.qdot = v
                out.time = ctx.state_in.bodies[n].time + h
            ctx.out.bodies.update(zip(names, self.outs))
            ctx.done.update(names)
            if not ok:
                self._raise_non_finite(names, self.outs)
            return names
        sel = [i for i, n in enumerate(self.names) if n not in skip]
        idx = sel
        sts = [ctx.state_in.bodies[n] for n in names]
        pos = np.array([s.position for s in sts], dtype=np.float64)
        vel = np.array([s.velocity for s in sts], dtype=np.float64)
        L = np.array([s.angular_momentum for s in sts], dtype=np.float64)
        quat = np.array([s.orientation for s in sts], dtype=np.float64)
        q = np.concatenate([np.zeros(0)] + [s.q for s in sts])
        qdot = np.concatenate([np.zeros(0)] + [s.qdot for s in sts])
        nm = self.nm[idx]
        qoff = np.concatenate([[0], np.cumsum(nm)[:-1]]).astype(np.int64)
        dv, dvoff, kick = _kicks(ctx, names, pos)
        # the coefficients of the bodies stepped here
        full = np.concatenate([[0], np.cumsum(self.nm)])
        coef = np.concatenate([np.zeros(0)] + [coef[6 * full[i]:6 * full[i + 1]] for i in sel])
        ok = free_steps(pos, vel, L, quat, q, qdot, qoff, nm, dv, dvoff, kick,
                        self.inertia[idx], self.mass[idx], self.g[idx], self.axes[idx], self.moments[idx], coef, h,
                        TINY)
        for i, (n, s) in enumerate(zip(names, sts)):
            out = self.outs[sel[i]]
            out.position[...] = pos[i]
            out.velocity[...] = vel[i]
            out.angular_momentum[...] = L[i]
            out.orientation[...] = quat[i]
            out.q[...] = q[qoff[i]:qoff[i] + nm[i]]
            out.qdot[...] = qdot[qoff[i]:qoff[i] + nm[i]]
            out.time = s.time + h
            ctx.out.bodies[n] = out
            ctx.done.add(n)
        if not ok:
            self._raise_non_finite(names, [self.outs[i] for i in sel])
        return names

    @staticmethod
    def _raise_non_finite(names: list, outs: list) -> None:
        """Raise ``SimulationError`` naming the first of the bodies ``names`` (new states ``outs``) whose state is
        not finite."""
        from modalfem.errors import SimulationError

        for n, out in zip(names, outs):
            if not all(np.all(np.isfinite(a)) for a in (out.q, out.qdot, out.position, out.velocity,
                                                         out.angular_momentum)):
                raise SimulationError(f"modal body {n!r}: state became non-finite during the step")
