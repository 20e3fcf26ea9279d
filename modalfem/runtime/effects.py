"""Opt-in load effects: ``Gravity``, ``Wind`` and ``PseudoForces`` (Coriolis, centripetal, Euler).

An effect is composed into a ``ModalSolver(body, effects=[...])`` and is called only when present.
Load effects implement ``loads(solver, state, dt, loads)`` and add to ``loads.force`` [N],
``loads.torque`` [N m] (world) and ``loads.modal`` (r,) [sqrt(kg) m/s^2].

Pseudo-forces. The deformation u = Phi q lives in the body frame, which rotates with angular
velocity w (body axes) and angular acceleration w'. Projected on the mass-normalised modes, the
body-frame equations of motion gain (M the mass matrix, X the rest positions relative to the
centre of mass; the frame's linear acceleration projects to zero on deformation modes)::

    q'' + mu q' + Lam q = f - 2 G(w) q'  - G(w') q - s(w')            (Coriolis, Euler)
                            - (C(w) - |w|^2 I) q - (h(w) - |w|^2 h0)    (centripetal, centrifugal)

with G(w) = Phi^T M [w]x Phi = sum eps_cde w_d T[c, e], C(w) = sum w_c w_e T[c, e],
s(w') = sum eps_cde w'_d S[c, e], h(w) = sum w_c w_e S[c, e], h0 = sum_c S[c, c], where
T[a, b] = int rho phi_a phi_b dV = Phi_a^T m Phi_b (r, r) and S[a, b] = int rho phi_a X_b dV =
Phi_a^T m X_b (r,), with Phi_a (n, r) the component-a rows of the modes and m the scalar (per
component) mass matrix, M = m (x) I3. These need the volume mass matrix, so they are computed
offline (``RotationCoupling.from_matrices``, which ``ModalModel.from_modes`` calls and stores in
the model file as ``rotation_T`` / ``rotation_S``). ``PseudoForces()`` uses the body's stored
coupling; an explicit ``RotationCoupling`` may be given instead. The rigid motion is not affected
(one-way coupling).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = ["Gravity", "PseudoForces", "RotationCoupling", "Wind"]

#: Levi-Civita symbol eps[c, d, e]
_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0


class Gravity:
    """Uniform gravity: a force m g at the centre of mass (no torque, no deformation of a free body).

    Args:
        g: acceleration (3,) [m/s^2], world (default (0, 0, -9.81)).
    """

    def __init__(self, g=(0.0, 0.0, -9.81)) -> None:
        self.g = np.asarray(g, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(self.g)):
            raise InputError(f"gravity must be finite, got {self.g.tolist()}")

    def loads(self, solver, state, dt, loads) -> None:
        """Add m g to ``loads.force``."""
        loads.force += solver.body.mass * self.g


def windward_pressure(cr: np.ndarray, w_rel: np.ndarray, density: float, drag: float) -> np.ndarray:
    """Wind forces (m, 3) [N] on the faces the air meets: ``0.5 rho C A s^2 (-n)`` with ``s = max(0, -(w - u) . n)``.

    Args:
        cr: (m, 3) ``2 A n`` of each face (the cross product of two edges; n outward) [m^2].
        w_rel: (m, 3) air velocity relative to each face's centroid [m/s].
        density: rho [kg/m^3]; drag: the pressure coefficient C [-].
    """
    area2 = np.sqrt(np.einsum("ij,ij->i", cr, cr))
    n = cr / np.where(area2 > 0, area2, 1.0)[:, None]
    s = np.maximum(0.0, -np.einsum("ij,ij->i", w_rel, n))
    return (-0.25 * density * drag * area2 * s * s)[:, None] * n  # 0.5 rho C A s^2 (-n), A = area2 / 2


class Wind:
    """Wind pressure on the windward triangles: p = 0.5 rho C ((w - u) . (-n))_+^2 along -n.

    Each triangle t (area A_t, outward normal n_t, centroid velocity u_t of the rigid motion)
    receives F_t = 0.5 rho C A_t max(0, -(w - u_t) . n_t)^2 (-n_t), shared equally by its three
    vertices; the vertex forces project on the rigid body (force, torque) and on the modes
    (``Phi^T R^T F``) like any point force. Costs a reconstruction and a transposed product per
    step, so it is opt-in like every effect.

    Args:
        velocity: wind velocity w (3,) [m/s], world.
        density: air density rho [kg/m^3] (default 1.2).
        drag: pressure coefficient C [-] (default 1.0).
    """

    def __init__(self, velocity, *, density: float = 1.2, drag: float = 1.0) -> None:
        self.velocity = np.asarray(velocity, dtype=np.float64).reshape(3)
        self.density, self.drag = float(density), float(drag)
        if not (np.all(np.isfinite(self.velocity)) and self.density >= 0 and self.drag >= 0):
            raise InputError("wind velocity must be finite, density and drag >= 0")

    def loads(self, solver, state, dt, loads) -> None:
        """Add the wind forces at ``state`` to ``loads``."""
        body = solver.body
        x = body.positions(state).astype(np.float64, copy=False)
        t = body.triangles
        a = x[t[:, 0]]
        cr = np.cross(x[t[:, 1]] - a, x[t[:, 2]] - a)  # 2 A_t n_t
        rc = (a + x[t[:, 1]] + x[t[:, 2]]) / 3.0 - state.position  # centroids from the centre of mass
        w_rel = self.velocity - (state.velocity + np.cross(body.angular_velocity(state), rc))
        F = windward_pressure(cr, w_rel, self.density, self.drag)
        loads.force += F.sum(axis=0)
        loads.torque += np.cross(rc, F).sum(axis=0)
        Fv = np.zeros_like(x)
        for c in range(3):
            np.add.at(Fv, t[:, c], F / 3.0)
        R = state.rotation()
        loads.modal += body.shapes_t @ (Fv @ R).reshape(-1).astype(body.shapes_t.dtype)


@dataclass(frozen=True)
class RotationCoupling:
    """Inertial coupling tensors of the modes with the frame rotation (see module docstring).

    Attributes:
        T: (3, 3, r, r) [-], ``T[a, b] = Phi_a^T m Phi_b`` (``T[b, a] = T[a, b]^T``);
            sum_a T[a, a] = I for mass-normalised modes.
        S: (3, 3, r) [sqrt(kg) m], ``S[a, b] = Phi_a^T m X_b``.
    """

    T: np.ndarray
    S: np.ndarray

    def __post_init__(self) -> None:
        T = np.asarray(self.T, dtype=np.float64)
        S = np.asarray(self.S, dtype=np.float64)
        if T.ndim != 4 or T.shape[:2] != (3, 3) or T.shape[2] != T.shape[3] or S.shape != (3, 3, T.shape[2]):
            raise InputError(f"RotationCoupling needs T (3, 3, r, r) and S (3, 3, r), got {T.shape}, {S.shape}")
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(S))):
            raise InputError("RotationCoupling tensors must be finite")
        object.__setattr__(self, "T", T)
        object.__setattr__(self, "S", S)

    @property
    def mode_count(self) -> int:
        return self.T.shape[2]

    @classmethod
    def from_matrices(cls, shapes: np.ndarray, M, points: np.ndarray, center_of_mass) -> RotationCoupling:
        """Compute T and S from full-mesh modes and the mass matrix (offline side; numpy only here).

        The mass matrix of an isotropic density (consistent or lumped) is component-diagonal,
        M = m (x) I3 in the node-major DOF order: it couples component a of one node only with
        component a of another. T[a, b] with a != b pairs component a of one mode with component
        b of another, so it is formed with the scalar block m (read as ``(M @ F)[0::3]`` for a
        field F whose component 0 carries the values): ``T[a, b] = Phi_a^T m Phi_b``.

        Args:
            shapes: mass-normalised deformation modes over all DOFs (3 n, r), node-major
                (``ModalResult.shapes``).
            M: mass matrix (3 n, 3 n) [kg], component-diagonal ``m (x) I3``, any object
                supporting ``M @ dense`` (scipy.sparse works).
            points: DOF points (n, 3) [m] (``ModalResult.dof_points``).
            center_of_mass: (3,) [m].

        Returns:
            The ``RotationCoupling``.

        Raises:
            InputError: sizes do not match.
        """
        Phi = np.asarray(shapes, dtype=np.float64)
        n3, r = Phi.shape
        X = np.asarray(points, dtype=np.float64) - np.asarray(center_of_mass, dtype=np.float64).reshape(1, 3)
        if n3 % 3 or X.shape != (n3 // 3, 3):
            raise InputError(f"RotationCoupling.from_matrices needs shapes (3 n, r) and points (n, 3), "
                             f"got {Phi.shape} and {X.shape}")
        comps = [Phi[a::3] for a in range(3)]  # (n, r) component-a rows
        F = np.zeros((n3, r + 3))
        T = np.empty((3, 3, r, r))
        S = np.empty((3, 3, r))
        for b in range(3):
            F[0::3, :r] = comps[b]  # component 0 of the field carries Phi_b (and X_b below)
            F[0::3, r + b] = X[:, b]
            mF = np.asarray(M @ F).reshape(n3, r + 3)[0::3]  # m [Phi_b, ..., X_b, ...]
            F[0::3, r + b] = 0.0
            for a in range(3):
                T[a, b] = comps[a].T @ mF[:, :r]
                S[a, b] = comps[a].T @ mF[:, r + b]
        T = 0.5 * (T + np.transpose(T, (1, 0, 3, 2)))  # exact symmetry T[b, a] = T[a, b]^T (M symmetric)
        return cls(T, S)


class PseudoForces:
    """Coriolis, centripetal/centrifugal and Euler pseudo-forces on the modes in the rotating body frame.

    Args:
        coupling: a ``RotationCoupling`` (r modes, same order as the model), or None (default) for
            the body's own coupling, stored in its model file (``ModalBody.coupling``).
        coriolis: include -2 G(w) q'.
        centripetal: include -(C(w) - |w|^2 I) q and the centrifugal load on the rest shape.
        euler: include the Euler terms from the torque-free angular acceleration w' = -I^-1 (w x I w).

    With the body not rotating every term is zero (tested: the trajectory is unchanged).

    Raises:
        InputError: (at the first step) no coupling given and the body's model has none, or a
            coupling whose mode count differs from the body's.
    """

    state_dependent = True

    def __init__(self, coupling: RotationCoupling | None = None, *, coriolis: bool = True,
                 centripetal: bool = True, euler: bool = True) -> None:
        if coupling is not None and not isinstance(coupling, RotationCoupling):
            raise InputError(f"PseudoForces needs a RotationCoupling or None, got {type(coupling).__name__}")
        self.coupling = coupling
        self.coriolis, self.centripetal, self.euler = bool(coriolis), bool(centripetal), bool(euler)
        self._cache = None  # (coupling, G, s, h0) of the coupling in use
        if coupling is not None:
            self._tensors(coupling)

    def _tensors(self, coupling: RotationCoupling):
        if self._cache is None or self._cache[0] is not coupling:
            T, S = coupling.T, coupling.S
            # G_d = sum_{c,e} eps_cde T[c, e] (r, r) for each axis d; s_d likewise (r,)
            self._cache = (coupling, np.einsum("cde,ceij->dij", _EPS, T), np.einsum("cde,cei->di", _EPS, S),
                           np.einsum("cci->i", S))
        return self._cache

    def loads(self, solver, state, dt, loads) -> None:
        """Add the pseudo-forces at ``state`` to ``loads.modal``."""
        body = solver.body
        coupling = self.coupling if self.coupling is not None else getattr(body, "coupling", None)
        if coupling is None:
            raise InputError("PseudoForces() needs the body's rotation coupling, but its model has no rotation_T/"
                             "rotation_S (rebuild it with ModalModel.from_modes) and no RotationCoupling was given")
        if coupling.mode_count != body.mode_count:
            raise InputError(f"RotationCoupling has {coupling.mode_count} modes, the body {body.mode_count}")
        _, G, s_eps, h0 = self._tensors(coupling)
        R = state.rotation()
        Lb = R.T @ state.angular_momentum
        w = body.inertia_inv @ Lb  # body-frame angular velocity [rad/s]
        if not np.any(w):
            return
        f = loads.modal
        if self.coriolis:
            f -= 2.0 * np.einsum("d,dij,j->i", w, G, state.qdot)
        if self.centripetal:
            W = np.outer(w, w)
            f -= np.einsum("ce,ceij,j->i", W, coupling.T, state.q) - (w @ w) * state.q
            f -= np.einsum("ce,cei->i", W, coupling.S) - (w @ w) * h0
        if self.euler:
            wdot = -body.inertia_inv @ np.cross(w, body.inertia @ w)
            if np.any(wdot):
                f -= np.einsum("d,dij,j->i", wdot, G, state.q) + wdot @ s_eps
