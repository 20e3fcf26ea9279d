"""Rigid impact zones (Provot 1997; Bridson, Fedkiw and Anderson 2002), stage (c).

Vertices that still collide after the CCD passes are merged into zones (union-find); each zone
then moves rigidly over the step. A free zone keeps its linear and angular momentum: with centre of
mass ``xc``, velocity ``Vc = P / M`` and ``omega = I^-1 L`` (inertia ``I`` and angular momentum ``L``
about ``xc`` at the step start), vertex i gets ``Vc + omega x (x_i - xc)``. A zone holding kinematic
members (pinned vertices, obstacle vertices, a plane or sphere, given as nodes after the vertices)
instead follows the rigid motion that best fits those members' velocities (least squares, angular
velocity regularised); the zone is *consistent* when that fit is exact, i.e. the kinematic members
move rigidly together. The linearised rotation ``x0 + s dt (Vc + omega x r)`` is an affine map with
singular values >= 1, so distances inside a consistent zone never shrink during the step: its
internal pairs need no further test.
"""

from __future__ import annotations

import numpy as np

from modalfem.collision.distance import cross

__all__ = ["UnionFind", "rigid_zone_velocities"]


class UnionFind:
    """Disjoint sets over ``count`` nodes, vectorised (roots are the smallest member index)."""

    def __init__(self, count: int) -> None:
        self.parent = np.arange(count)

    def roots(self) -> np.ndarray:
        """(count,) root of every node."""
        p = self.parent
        while True:
            q = p[p]
            if np.array_equal(q, p):
                break
            p = q
        self.parent = p
        return p

    def union(self, a: np.ndarray, b: np.ndarray) -> None:
        """Merge the sets of ``a[k]`` and ``b[k]`` for every k."""
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        while True:
            r = self.roots()
            ra, rb = r[a], r[b]
            diff = ra != rb
            if not diff.any():
                return
            np.minimum.at(self.parent, np.maximum(ra[diff], rb[diff]), np.minimum(ra[diff], rb[diff]))


def _skew(r: np.ndarray) -> np.ndarray:
    z = np.zeros(len(r))
    return np.stack(
        [np.stack([z, -r[:, 2], r[:, 1]], 1), np.stack([r[:, 2], z, -r[:, 0]], 1), np.stack([-r[:, 1], r[:, 0], z], 1)], 1
    )


def rigid_zone_velocities(
    X0: np.ndarray,
    V: np.ndarray,
    invm: np.ndarray,
    roots: np.ndarray,
    analytic: list,
    t: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Velocities of every zone's members moving rigidly.

    Args:
        X0: (N, 3) vertex positions [m] at the step start.
        V: (N, 3) velocities [m/s].
        invm: (N,) inverse masses [1/kg] (0: kinematic).
        roots: (N + A,) zone root of every vertex and of the A analytic obstacles (nodes N..N+A-1).
        analytic: the A analytic obstacles (``velocity_at(x, t)``).
        t: time [s] of the step start.

    Returns:
        ``(V_new, inconsistent)``: (N, 3) velocities [m/s] (kinematic vertices unchanged) and the roots
        of zones whose kinematic members do not move rigidly together.
    """
    N = len(X0)
    V = V.copy()
    size = np.bincount(roots, minlength=len(roots))
    vz = roots[:N]
    in_zone = size[vz] > 1
    kin_root = np.zeros(len(roots), dtype=bool)
    kin_root[vz[in_zone & (invm == 0)]] = True
    kin_root[roots[N:]] = True
    dyn = in_zone & (invm > 0) & ~kin_root[vz]
    # free zones: momentum-preserving rigid motion, vectorised over zones
    if dyn.any():
        idx = np.nonzero(dyn)[0]
        zr, zi = np.unique(vz[idx], return_inverse=True)
        m = 1.0 / invm[idx]
        x, v = X0[idx], V[idx]
        Z = len(zr)
        M = np.bincount(zi, m, minlength=Z)
        xc = np.stack([np.bincount(zi, m * x[:, c], minlength=Z) for c in range(3)], 1) / M[:, None]
        Vc = np.stack([np.bincount(zi, m * v[:, c], minlength=Z) for c in range(3)], 1) / M[:, None]
        r = x - xc[zi]
        mrv = m[:, None] * cross(r, v)
        Lz = np.stack([np.bincount(zi, mrv[:, c], minlength=Z) for c in range(3)], 1)
        rr = np.einsum("k,ki,kj->kij", m, r, r)
        Iz = np.zeros((Z, 3, 3))
        np.add.at(Iz, zi, -rr)
        tr = np.bincount(zi, m * np.einsum("ki,ki->k", r, r), minlength=Z)
        Iz += tr[:, None, None] * np.eye(3)
        omega = np.einsum("zij,zj->zi", np.linalg.pinv(Iz, rcond=1e-12, hermitian=True), Lz)
        V[idx] = Vc[zi] + cross(omega[zi], r)
    inconsistent = []
    for root in np.nonzero(kin_root & (size > 1))[0]:
        members = np.nonzero(vz == root)[0]
        obs = [analytic[k] for k in np.nonzero(roots[N:] == root)[0]]
        xc = X0[members].mean(axis=0)
        span = np.ptp(X0[members], axis=0).max() + 1e-12
        kin = members[invm[members] == 0]
        pts, vel = [X0[kin]], [V[kin]]
        probe = xc + span * np.vstack([np.zeros(3), np.eye(3)])
        for ob in obs:
            pts.append(probe)
            vel.append(ob.velocity_at(probe, t))
        pts, vel = np.concatenate(pts), np.concatenate(vel)
        r = pts - xc
        A = np.concatenate([np.tile(np.eye(3), (len(r), 1, 1)), -_skew(r)], axis=2).reshape(-1, 6)
        lam = 1e-6 * span
        A = np.vstack([A, np.hstack([np.zeros((3, 3)), lam * np.eye(3)])])
        b = np.concatenate([vel.ravel(), np.zeros(3)])
        sol = np.linalg.lstsq(A, b, rcond=None)[0]
        res = np.abs(A[:-3] @ sol - b[:-3]).max() if len(b) > 3 else 0.0
        if res > 1e-6 * (np.abs(vel).max() + 1e-9) + 1e-12:
            inconsistent.append(root)
        dm = members[invm[members] > 0]
        V[dm] = sol[:3] + cross(sol[3:], X0[dm] - xc)
    return V, np.array(inconsistent, dtype=np.int64)
