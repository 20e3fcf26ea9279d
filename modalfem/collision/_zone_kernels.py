"""Compiled union-find of the impact zones (numba ``njit``, cached on disk): the only implementation of
:class:`modalfem.collision.zones.UnionFind`'s merges.

Every parent pointer points to a smaller or equal index (a merge links the larger root under the smaller),
so each set's root is its smallest member, whatever the order of the merges, and one pass in index order
compresses every path.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["compress", "free_zone_velocities", "kinematic_zone_velocities", "union_pairs", "union_quads",
           "zone_members"]


@numba.njit(cache=True, inline="always")
def _find(parent: np.ndarray, i: int) -> int:
    """Root of node ``i`` (path halving: each visited node is pointed at its grandparent)."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@numba.njit(cache=True)
def union_pairs(parent: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """In place: merge the sets of ``a[k]`` and ``b[k]`` for every k (the larger root under the smaller)."""
    for k in range(len(a)):
        ra, rb = _find(parent, a[k]), _find(parent, b[k])
        if ra < rb:
            parent[rb] = ra
        elif rb < ra:
            parent[ra] = rb


@numba.njit(cache=True)
def union_quads(parent: np.ndarray, quads: np.ndarray) -> None:
    """In place: merge the four vertices of every row of ``quads`` (k, 4) into one set."""
    for k in range(len(quads)):
        r0 = _find(parent, quads[k, 0])
        for j in range(1, 4):
            r = _find(parent, quads[k, j])
            if r < r0:
                parent[r0] = r
                r0 = r
            elif r > r0:
                parent[r] = r0


@numba.njit(cache=True)
def compress(parent: np.ndarray) -> None:
    """In place: every node points at its root (in index order: a node's parent, smaller, is done first)."""
    for i in range(len(parent)):
        parent[i] = parent[parent[i]]


@numba.njit(cache=True)
def free_zone_velocities(X0: np.ndarray, V: np.ndarray, invm: np.ndarray, idx: np.ndarray, zone: np.ndarray,
                         Z: int) -> None:
    """In place: the members ``idx`` ((k,) vertex indices) of ``Z`` free zones (``zone`` (k,): each member's zone
    0..Z-1) get their zone's rigid velocity ``Vc + omega x (x - xc)``, which keeps the zone's linear momentum
    ``P = sum m v`` (``Vc = P / M``) and its angular momentum ``L`` about the centre of mass ``xc``
    (``omega = I^+ L``, the pseudo-inverse of the inertia ``I`` about ``xc`` dropping eigenvalues below 1e-12
    of the largest, as ``numpy.linalg.pinv(I, rcond=1e-12, hermitian=True)``), all at ``X0`` (N, 3) [m],
    from ``V`` (N, 3) [m/s] and the inverse masses ``invm`` (N,) [1/kg]."""
    M = np.zeros(Z)
    xc = np.zeros((Z, 3))
    vc = np.zeros((Z, 3))
    for j in range(len(idx)):
        i, z = idx[j], zone[j]
        m = 1.0 / invm[i]
        M[z] += m
        for c in range(3):
            xc[z, c] += m * X0[i, c]
            vc[z, c] += m * V[i, c]
    for z in range(Z):
        for c in range(3):
            xc[z, c] /= M[z]
            vc[z, c] /= M[z]
    L = np.zeros((Z, 3))
    inertia = np.zeros((Z, 3, 3))
    for j in range(len(idx)):
        i, z = idx[j], zone[j]
        m = 1.0 / invm[i]
        r0, r1, r2 = X0[i, 0] - xc[z, 0], X0[i, 1] - xc[z, 1], X0[i, 2] - xc[z, 2]
        v0, v1, v2 = V[i, 0], V[i, 1], V[i, 2]
        L[z, 0] += m * (r1 * v2 - r2 * v1)
        L[z, 1] += m * (r2 * v0 - r0 * v2)
        L[z, 2] += m * (r0 * v1 - r1 * v0)
        rr = r0 * r0 + r1 * r1 + r2 * r2
        r = (r0, r1, r2)
        for a in range(3):
            for b in range(3):
                inertia[z, a, b] -= m * r[a] * r[b]
            inertia[z, a, a] += m * rr
    omega = np.zeros((Z, 3))
    for z in range(Z):
        w, U = np.linalg.eigh(inertia[z])
        cut = 1e-12 * max(abs(w[0]), abs(w[1]), abs(w[2]))
        for k in range(3):
            if abs(w[k]) > cut:
                s = (U[0, k] * L[z, 0] + U[1, k] * L[z, 1] + U[2, k] * L[z, 2]) / w[k]
                for c in range(3):
                    omega[z, c] += s * U[c, k]
    for j in range(len(idx)):
        i, z = idx[j], zone[j]
        r0, r1, r2 = X0[i, 0] - xc[z, 0], X0[i, 1] - xc[z, 1], X0[i, 2] - xc[z, 2]
        o0, o1, o2 = omega[z, 0], omega[z, 1], omega[z, 2]
        V[i, 0] = vc[z, 0] + (o1 * r2 - o2 * r1)
        V[i, 1] = vc[z, 1] + (o2 * r0 - o0 * r2)
        V[i, 2] = vc[z, 2] + (o0 * r1 - o1 * r0)


@numba.njit(cache=True)
def zone_members(roots: np.ndarray, invm: np.ndarray, N: int):
    """The zones of ``roots`` ((N + A,) the zone root of every vertex and analytic obstacle node) in one pass.

    A zone (two or more nodes) is kinematic when it holds a vertex with ``invm == 0`` or an obstacle node, else
    free. Returns ``(idx, zone, Z, kroots, kptr, kmembers)``: the free zones' vertices ``idx`` (increasing) and
    their zone numbers ``zone`` (0..Z-1, in increasing root order, as ``numpy.unique``'s inverse), and the kinematic
    zones' roots ``kroots`` (increasing), each one's vertices ``kmembers[kptr[z]:kptr[z + 1]]`` (increasing)."""
    M = len(roots)
    size = np.zeros(M, np.int64)
    for i in range(M):
        size[roots[i]] += 1
    kin = np.zeros(M, np.bool_)
    for i in range(N):
        if invm[i] == 0.0 and size[roots[i]] > 1:
            kin[roots[i]] = True
    for a in range(N, M):
        kin[roots[a]] = True
    zid = np.full(M, -1, np.int64)
    Z = 0
    K = 0
    for r in range(M):
        if size[r] > 1 and roots[r] == r:
            if kin[r]:
                zid[r] = K
                K += 1
            else:
                zid[r] = Z
                Z += 1
    count = 0
    kptr = np.zeros(K + 1, np.int64)
    for i in range(N):
        r = roots[i]
        if size[r] > 1:
            if kin[r]:
                kptr[zid[r] + 1] += 1
            else:
                count += 1
    for z in range(K):
        kptr[z + 1] += kptr[z]
    idx = np.empty(count, np.int64)
    zone = np.empty(count, np.int64)
    kmembers = np.empty(kptr[K], np.int64)
    kroots = np.empty(K, np.int64)
    fill = kptr[:-1].copy()
    c = 0
    for i in range(N):
        r = roots[i]
        if size[r] > 1:
            if kin[r]:
                kmembers[fill[zid[r]]] = i
                fill[zid[r]] += 1
            else:
                idx[c] = i
                zone[c] = zid[r]
                c += 1
    for r in range(M):
        if size[r] > 1 and roots[r] == r and kin[r]:
            kroots[zid[r]] = r
    return idx, zone, Z, kroots, kptr, kmembers


@numba.njit(cache=True)
def kinematic_zone_velocities(X0: np.ndarray, V: np.ndarray, invm: np.ndarray, zones: np.ndarray, kptr: np.ndarray,
                              kmembers: np.ndarray, obs_zone: np.ndarray, origin: np.ndarray, lin: np.ndarray,
                              ang: np.ndarray) -> np.ndarray:
    """In place: the movable members of each kinematic zone in ``zones`` (indices into ``kptr``, the zones'
    vertices ``kmembers[kptr[z]:kptr[z + 1]]``) get the rigid velocity field ``v + omega x (x - xc)`` that best fits
    (least squares, ``omega`` regularised by ``1e-6`` of the zone's extent) the velocities of its kinematic vertices
    and of its obstacles (``obs_zone`` (A,): each analytic obstacle's zone in ``kptr`` numbering or -1; obstacle
    ``a`` moves rigidly with velocity ``lin[a]`` [m/s] and angular velocity ``ang[a]`` [rad/s] about ``origin[a]``
    [m], sampled at the centre ``xc`` of the members and at ``xc`` plus the extent along each axis), all at ``X0``
    (N, 3) [m]. Returns (len(zones),) bool: the fit is not exact (residual above ``1e-6`` of the fitted speeds): the
    kinematic members do not move rigidly together."""
    bad = np.zeros(len(zones), np.bool_)
    for q in range(len(zones)):
        z = zones[q]
        members = kmembers[kptr[z]:kptr[z + 1]]
        m = len(members)
        xc = np.zeros(3)
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        nkin = 0
        for i in members:
            for c in range(3):
                xc[c] += X0[i, c]
                lo[c] = min(lo[c], X0[i, c])
                hi[c] = max(hi[c], X0[i, c])
            if invm[i] == 0.0:
                nkin += 1
        for c in range(3):
            xc[c] /= m
        span = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) + 1e-12
        nobs = 0
        for a in range(len(obs_zone)):
            if obs_zone[a] == z:
                nobs += 1
        rows = nkin + 4 * nobs
        A = np.zeros((3 * rows + 3, 6))
        b = np.zeros(3 * rows + 3)
        pts = np.empty((rows, 3))
        vel = np.empty((rows, 3))
        k = 0
        for i in members:
            if invm[i] == 0.0:
                for c in range(3):
                    pts[k, c] = X0[i, c]
                    vel[k, c] = V[i, c]
                k += 1
        for a in range(len(obs_zone)):
            if obs_zone[a] != z:
                continue
            for j in range(4):
                for c in range(3):
                    pts[k, c] = xc[c] + (span if j == c + 1 else 0.0)
                r0, r1, r2 = pts[k, 0] - origin[a, 0], pts[k, 1] - origin[a, 1], pts[k, 2] - origin[a, 2]
                vel[k, 0] = lin[a, 0] + ang[a, 1] * r2 - ang[a, 2] * r1
                vel[k, 1] = lin[a, 1] + ang[a, 2] * r0 - ang[a, 0] * r2
                vel[k, 2] = lin[a, 2] + ang[a, 0] * r1 - ang[a, 1] * r0
                k += 1
        vmax = 0.0
        for k in range(rows):
            r0, r1, r2 = pts[k, 0] - xc[0], pts[k, 1] - xc[1], pts[k, 2] - xc[2]
            for c in range(3):
                A[3 * k + c, c] = 1.0
                b[3 * k + c] = vel[k, c]
                vmax = max(vmax, abs(vel[k, c]))
            # v + omega x r: the columns of -skew(r)
            A[3 * k, 4], A[3 * k, 5] = r2, -r1
            A[3 * k + 1, 3], A[3 * k + 1, 5] = -r2, r0
            A[3 * k + 2, 3], A[3 * k + 2, 4] = r1, -r0
        lam = 1e-6 * span
        for c in range(3):
            A[3 * rows + c, 3 + c] = lam
        sol = np.linalg.lstsq(A, b, rcond=np.finfo(np.float64).eps * len(b))[0]  # numpy's rcond=None
        res = 0.0
        for u in range(3 * rows):
            s = 0.0
            for c in range(6):
                s += A[u, c] * sol[c]
            res = max(res, abs(s - b[u]))
        bad[q] = res > 1e-6 * (vmax + 1e-9) + 1e-12
        for i in members:
            if invm[i] > 0.0:
                r0, r1, r2 = X0[i, 0] - xc[0], X0[i, 1] - xc[1], X0[i, 2] - xc[2]
                V[i, 0] = sol[0] + sol[4] * r2 - sol[5] * r1
                V[i, 1] = sol[1] + sol[5] * r0 - sol[3] * r2
                V[i, 2] = sol[2] + sol[3] * r1 - sol[4] * r0
    return bad
