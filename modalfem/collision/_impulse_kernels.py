"""Compiled pair impulses (numba ``njit``, cached on disk): the per-vertex weight-averaged velocity changes
of :func:`modalfem.collision.repulsion.apply_pair_impulses`, its only implementation (one pass over the
pairs instead of a dozen numpy passes over (k, 4, 3) temporaries).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["pair_impulses"]


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
        if not (dvn > 0.0 and den > 0.0):
            continue
        active += 1
        d0, d1, d2 = dvn * n[p, 0], dvn * n[p, 1], dvn * n[p, 2]
        if friction > 0.0:
            t0, t1, t2 = vr0 - vn * n[p, 0], vr1 - vn * n[p, 1], vr2 - vn * n[p, 2]
            tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
            k = min(friction * dvn / (tn if tn > 0.0 else 1.0), 1.0)
            d0, d1, d2 = d0 - k * t0, d1 - k * t1, d2 - k * t2
        for j in range(4):
            i = quads[p, j]
            if invm[i] > 0.0:
                c = w[p, j] * invm[i] / den
                dV[i, 0] += c * d0
                dV[i, 1] += c * d1
                dV[i, 2] += c * d2
                cnt[i] += abs(w[p, j])
    for i in range(N):
        if cnt[i] > 1.0:
            dV[i, 0] /= cnt[i]
            dV[i, 1] /= cnt[i]
            dV[i, 2] /= cnt[i]
    return dV, active
