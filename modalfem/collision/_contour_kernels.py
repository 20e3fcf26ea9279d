"""Compiled contour test of the self-collision culling (Volino and Magnenat-Thalmann): the boundary of a
BVH node (or of two adjacent nodes), projected on the plane normal to its normal cone's axis, must not
cross itself. Data layout as in :mod:`modalfem.collision._bvh_kernels`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["contour_ok"]


@numba.njit(cache=True)
def _argsort(keys: np.ndarray) -> np.ndarray:
    """Indices sorting ``keys`` (k,) ascending (heapsort: a small kernel that compiles quickly)."""
    k = len(keys)
    idx = np.arange(k)
    for start in range(k // 2 - 1, -1, -1):
        _sift(keys, idx, start, k)
    for end in range(k - 1, 0, -1):
        idx[0], idx[end] = idx[end], idx[0]
        _sift(keys, idx, 0, end)
    return idx


@numba.njit(cache=True)
def _sift(keys: np.ndarray, idx: np.ndarray, root: int, end: int) -> None:
    while True:
        child = 2 * root + 1
        if child >= end:
            return
        if child + 1 < end and keys[idx[child + 1]] > keys[idx[child]]:
            child += 1
        if keys[idx[root]] >= keys[idx[child]]:
            return
        idx[root], idx[child] = idx[child], idx[root]
        root = child


@numba.njit(cache=True)
def _crosses(E: np.ndarray, pu: np.ndarray, pw: np.ndarray) -> bool:
    """Two of the 2D segments ``(pu[k, 0], pw[k, 0]) - (pu[k, 1], pw[k, 1])`` (vertex pairs ``E`` (k, 2))
    that share no vertex cross, touch or overlap collinearly: sort and sweep along u over the boxes (u
    widened by 1e-9 of the extent), orientation tests on the overlapping pairs."""
    k = len(E)
    if k < 2:
        return False
    lo_u = np.minimum(pu[:, 0], pu[:, 1])
    hi_u = np.maximum(pu[:, 0], pu[:, 1])
    lo_w = np.minimum(pw[:, 0], pw[:, 1])
    hi_w = np.maximum(pw[:, 0], pw[:, 1])
    tol = 1e-9 * (hi_u.max() - lo_u.min() + 1.0)
    order = _argsort(lo_u)
    for ii in range(k):
        i = order[ii]
        end = hi_u[i] + tol
        for jj in range(ii + 1, k):
            j = order[jj]
            if lo_u[j] > end:
                break
            if lo_w[i] > hi_w[j] or lo_w[j] > hi_w[i]:
                continue
            if E[i, 0] == E[j, 0] or E[i, 0] == E[j, 1] or E[i, 1] == E[j, 0] or E[i, 1] == E[j, 1]:
                continue
            ax, ay, bx, by = pu[i, 0], pw[i, 0], pu[i, 1], pw[i, 1]
            cx, cy, dx, dy = pu[j, 0], pw[j, 0], pu[j, 1], pw[j, 1]
            o1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            o2 = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
            o3 = (dx - cx) * (ay - cy) - (dy - cy) * (ax - cx)
            o4 = (dx - cx) * (by - cy) - (dy - cy) * (bx - cx)
            if o1 * o2 <= 0 and o3 * o4 <= 0:
                return True
    return False


@numba.njit(cache=True)
def contour_ok(na: int, nb: int, axis: np.ndarray, bnd_start: np.ndarray, bnd_edge: np.ndarray,
               bnd_id: np.ndarray, limit: int, x0: np.ndarray, x1: np.ndarray, static: bool) -> bool:
    """The contour of node ``na`` (united with node ``nb`` if >= 0: edges listed by both are interior)
    projected on the plane normal to ``axis`` (3,) does not cross itself at the step's start, middle
    and end positions ``x0 + s (x1 - x0)`` ((n, 3) [m]; start only if ``static``); False for a contour
    longer than ``limit`` edges (not checked)."""
    n1 = bnd_start[na + 1] - bnd_start[na]
    n2 = bnd_start[nb + 1] - bnd_start[nb] if nb >= 0 else 0
    pos = np.empty(n1 + n2, dtype=np.int64)
    ids = np.empty(n1 + n2)
    for i in range(n1 + n2):
        pos[i] = bnd_start[na] + i if i < n1 else bnd_start[nb] + i - n1
        ids[i] = bnd_id[pos[i]]
    o = _argsort(ids)
    E = np.empty((n1 + n2, 2), dtype=np.int64)
    count = 0
    i = 0
    while i < len(o):
        j = i + 1
        while j < len(o) and ids[o[j]] == ids[o[i]]:
            j += 1
        if j == i + 1:  # listed once: a contour edge
            E[count, 0], E[count, 1] = bnd_edge[pos[o[i]], 0], bnd_edge[pos[o[i]], 1]
            count += 1
        i = j
    if count > limit:
        return False
    E = E[:count]
    # an orthonormal basis (u, w) of the plane
    if abs(axis[0]) < 0.9:
        h0, h1, h2 = 1.0, 0.0, 0.0
    else:
        h0, h1, h2 = 0.0, 1.0, 0.0
    u0, u1, u2 = axis[1] * h2 - axis[2] * h1, axis[2] * h0 - axis[0] * h2, axis[0] * h1 - axis[1] * h0
    un = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0, u1, u2 = u0 / un, u1 / un, u2 / un
    w0, w1, w2 = axis[1] * u2 - axis[2] * u1, axis[2] * u0 - axis[0] * u2, axis[0] * u1 - axis[1] * u0
    pu = np.empty((count, 2))
    pw = np.empty((count, 2))
    for si in range(1 if static else 3):
        s = 0.5 * si
        for e in range(count):
            for c in range(2):
                v = E[e, c]
                p0 = x0[v, 0] + s * (x1[v, 0] - x0[v, 0])
                p1 = x0[v, 1] + s * (x1[v, 1] - x0[v, 1])
                p2 = x0[v, 2] + s * (x1[v, 2] - x0[v, 2])
                pu[e, c] = p0 * u0 + p1 * u1 + p2 * u2
                pw[e, c] = p0 * w0 + p1 * w1 + p2 * w2
        if _crosses(E, pu, pw):
            return False
    return True
