"""Compiled pair impulses (numba ``njit``, cached on disk), the only implementation of
:func:`modalfem.collision.repulsion.apply_pair_impulses` (all pairs against the same velocities, changes
weight-averaged per vertex: the CCD passes) and :func:`modalfem.collision.repulsion.sequential_pair_impulses`
(pair by pair, each against the velocities its predecessors left: stage (a)'s repulsion sweeps).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ROUNDING", "pair_impulses", "sequential_impulses"]

#: relative size [-] below which a pair's normal velocity deficit counts as met
ROUNDING = 1e-12


@numba.njit(cache=True, inline="always")
def _pair_change(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                 target: np.ndarray, friction: float, p: int) -> tuple:
    """The relative velocity change pair ``p`` wants, ``(d0, d1, d2, den)`` with ``den = sum w^2 / m``;
    ``den = 0`` when the pair does not act (its normal velocity is at or above its target, to
    ``ROUNDING`` of the velocities, or all its vertices are kinematic)."""
    vr0 = vr1 = vr2 = 0.0
    den = 0.0
    for j in range(4):
        i = quads[p, j]
        vr0 += w[p, j] * V[i, 0]
        vr1 += w[p, j] * V[i, 1]
        vr2 += w[p, j] * V[i, 2]
        den += w[p, j] * w[p, j] * invm[i]
    vn = vr0 * n[p, 0] + vr1 * n[p, 1] + vr2 * n[p, 2]
    dvn = max(target[p] - vn, 0.0)
    # a deficit at the rounding level of the velocities is none (a pair just brought to its target)
    if not (dvn > ROUNDING * (abs(target[p]) + abs(vn)) and den > 0.0):
        return 0.0, 0.0, 0.0, 0.0
    d0, d1, d2 = dvn * n[p, 0], dvn * n[p, 1], dvn * n[p, 2]
    if friction > 0.0:
        t0, t1, t2 = vr0 - vn * n[p, 0], vr1 - vn * n[p, 1], vr2 - vn * n[p, 2]
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        k = min(friction * dvn / (tn if tn > 0.0 else 1.0), 1.0)
        d0, d1, d2 = d0 - k * t0, d1 - k * t1, d2 - k * t2
    return d0, d1, d2, den


@numba.njit(cache=True, inline="always")
def _scatter(out: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, p: int, d0: float, d1: float,
             d2: float, den: float) -> None:
    """Add pair ``p``'s change ``(d0, d1, d2)`` to ``out`` (N, 3) at its movable vertices, each its share
    ``w_j / m_j / den`` (the impulse that changes the pair's relative velocity by exactly that)."""
    for j in range(4):
        i = quads[p, j]
        if invm[i] > 0.0:
            c = w[p, j] * invm[i] / den
            out[i, 0] += c * d0
            out[i, 1] += c * d1
            out[i, 2] += c * d2


@numba.njit(cache=True)
def pair_impulses(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                  target: np.ndarray, friction: float):
    """Velocity change (N, 3) [m/s] raising each pair's relative normal velocity ``w . V[quads] . n`` to at
    least ``target`` [m/s] (with Coulomb ``friction`` on the tangential part), summed per vertex and
    divided by the vertex's summed weights |w| over the acting pairs when above 1; and the number of
    acting pairs. See :func:`modalfem.collision.repulsion.apply_pair_impulses`."""
    N = len(V)
    dV = np.zeros((N, 3))
    cnt = np.zeros(N)
    active = 0
    for p in range(len(quads)):
        d0, d1, d2, den = _pair_change(V, invm, quads, w, n, target, friction, p)
        if den == 0.0:
            continue
        active += 1
        _scatter(dV, invm, quads, w, p, d0, d1, d2, den)
        for j in range(4):
            if invm[quads[p, j]] > 0.0:
                cnt[quads[p, j]] += abs(w[p, j])
    for i in range(N):
        if cnt[i] > 1.0:
            dV[i, 0] /= cnt[i]
            dV[i, 1] /= cnt[i]
            dV[i, 2] /= cnt[i]
    return dV, active


@numba.njit(cache=True)
def sequential_impulses(V: np.ndarray, invm: np.ndarray, quads: np.ndarray, w: np.ndarray, n: np.ndarray,
                        target: np.ndarray, friction: float, sweeps: int):
    """Velocities (N, 3) [m/s] after up to ``sweeps`` sweeps over the pairs (forwards, then backwards, in
    turn), each pair's whole change applied at once to a copy of ``V``; the sweeps run; and the pairs
    that acted in the last one (0: every pair at or above its target). See
    :func:`modalfem.collision.repulsion.sequential_pair_impulses`."""
    V = V.copy()
    k = len(quads)
    active = 0
    done = 0
    for s in range(sweeps):
        active = 0
        done = s + 1
        for r in range(k):
            p = r if s % 2 == 0 else k - 1 - r
            d0, d1, d2, den = _pair_change(V, invm, quads, w, n, target, friction, p)
            if den == 0.0:
                continue
            active += 1
            _scatter(V, invm, quads, w, p, d0, d1, d2, den)
        if active == 0:
            break
    return V, done, active
