"""Rotations for the rigid part: unit quaternions and a symplectic free-rigid-body step.

Quaternions are ``(w, x, y, z)`` arrays (4,), unit length, mapping body (mesh) axes to world axes.

``free_rotation_step`` advances the orientation of a torque-free rigid body by the splitting of
Dullweber, Reich and Touma (J. Chem. Phys. 107, 1997): the kinetic energy
``T = sum_k Lb_k^2 / (2 I_k)`` (body angular momentum Lb in principal axes) is split into three
parts, each an exact rotation about one principal axis, composed symmetrically:
x(h/2) y(h/2) z(h) y(h/2) x(h/2). The scheme is symplectic, time-reversible and
second order; the world angular momentum is not changed at all by the step (it is the caller's
state), so it is conserved to rounding; energy errors stay bounded (no drift).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "free_rotation_step",
    "quat_from_axis_angle",
    "quat_from_matrix",
    "quat_multiply",
    "quat_normalize",
    "quat_to_matrix",
]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a b of quaternions (4,) (rotation b first, then a)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ])


def quat_from_axis_angle(axis, angle: float) -> np.ndarray:
    """Quaternion of a rotation by ``angle`` [rad] about the unit ``axis`` (3,)."""
    axis = np.asarray(axis, dtype=np.float64)
    return np.concatenate([[np.cos(0.5 * angle)], np.sin(0.5 * angle) * axis])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """``q / |q|`` with a positive scalar part (one representative per rotation)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.sqrt(q @ q)
    return -q if q[0] < 0 else q


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion of a rotation matrix (3, 3) (Shepperd's method, stable for all angles)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    diag = np.diag(R)
    k = int(np.argmax([tr, *diag]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    return quat_normalize(np.array(q))


#: symmetric composition of the three axis flows: (principal axis, fraction of the step)
_SPLIT = ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5))


def free_rotation_step(quat: np.ndarray, L_world: np.ndarray, axes, moments, h: float) -> np.ndarray:
    """Orientation after a torque-free step h [s] (symplectic splitting; plain floats for speed).

    Args:
        quat: orientation (4,), body (mesh) axes -> world.
        L_world: angular momentum about the centre of mass (3,) [kg m^2/s], world (not changed).
        axes: the 3 principal axes of the inertia tensor in body axes, unit, right-handed
            (sequence of 3 triples).
        moments: principal moments of inertia (3,) [kg m^2].
        h: step [s].

    Returns:
        The new unit quaternion (4,) with a non-negative scalar part.

    Composition x(h/2) y(h/2) z(h) y(h/2) x(h/2): each part is the exact flow of
    ``Lb_k^2 / (2 I_k)``, a rotation of the body about principal axis k by ``h_k Lb_k / I_k``; the
    body components of the (fixed) world angular momentum rotate back by the same angle.
    """
    w, x, y, z = quat.tolist()
    vx, vy, vz = L_world.tolist()
    # Lb = R^T L: rotate by the conjugate quaternion (v + 2 w' (u x v) + 2 u x (u x v), u = -(x, y, z))
    ux, uy, uz = -x, -y, -z
    tx, ty, tz = 2 * (uy * vz - uz * vy), 2 * (uz * vx - ux * vz), 2 * (ux * vy - uy * vx)
    lx = vx + w * tx + (uy * tz - uz * ty)
    ly = vy + w * ty + (uz * tx - ux * tz)
    lz = vz + w * tz + (ux * ty - uy * tx)
    for k, frac in _SPLIT:
        ax, ay, az = axes[k]
        angle = frac * h * (ax * lx + ay * ly + az * lz) / moments[k]
        c, s = math.cos(0.5 * angle), math.sin(0.5 * angle)
        bx, by, bz = s * ax, s * ay, s * az
        w, x, y, z = (w * c - x * bx - y * by - z * bz, w * bx + x * c + y * bz - z * by,
                      w * by - x * bz + y * c + z * bx, w * bz + x * by - y * bx + z * c)
        # rotate Lb about the axis by -angle (Rodrigues)
        ca, sa = math.cos(angle), -math.sin(angle)
        d = (ax * lx + ay * ly + az * lz) * (1.0 - ca)
        cx, cy, cz = ay * lz - az * ly, az * lx - ax * lz, ax * ly - ay * lx
        lx, ly, lz = lx * ca + cx * sa + ax * d, ly * ca + cy * sa + ay * d, lz * ca + cz * sa + az * d
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0:
        n = -n
    return np.array([w / n, x / n, y / n, z / n])
