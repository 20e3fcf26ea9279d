"""Rigid impact zones (Provot 1997; Bridson, Fedkiw and Anderson 2002), stage (c).

Vertices that still collide after the CCD passes are merged into zones (union-find); each zone
then moves rigidly over the step. A free zone keeps its linear and angular momentum: with centre of
mass ``xc``, velocity ``Vc = P / M`` and ``omega = I^-1 L`` (inertia ``I`` and angular momentum ``L``
about ``xc`` at the step start), vertex i gets ``Vc + omega x (x_i - xc)``. The linearised rotation
``x0 + s dt (Vc + omega x r)`` is an affine map with singular values >= 1, so distances inside the
zone never shrink during the step: its internal pairs need no further test.

A zone holding kinematic members (pinned or scripted vertices, obstacle vertices, a plane or sphere,
given as nodes after the vertices) follows them instead, and is *consistent* when it can follow
them exactly:

- when the kinematic vertices' end positions ``x + tau v`` are one finite rigid motion ``R x + T`` of
  their start positions (a handle turning over the step: its chord velocities are not a rigid
  velocity field), every member moves by that motion (``follow_finite_motion``): the whole zone,
  kinematic members included, then moves by the affine maps ``(1 - sigma) I + sigma R`` (plus a
  translation), invertible for turns below pi, so no pair inside it can cross during the step;
- otherwise by the rigid velocity field that best fits those members' velocities (least squares,
  angular velocity regularised), consistent when that fit is exact.

An inconsistent zone (e.g. cloth caught between a pin and a turning handle) is reported so that the
caller tests its pairs again.
"""

from __future__ import annotations

import numpy as np

__all__ = ["UnionFind", "follow_finite_motion", "rigid_zone_velocities"]


class UnionFind:
    """Disjoint sets over ``count`` nodes (roots are the smallest member index; compiled merges,
    :mod:`modalfem.collision._zone_kernels`)."""

    def __init__(self, count: int) -> None:
        self.parent = np.arange(count, dtype=np.int64)

    def roots(self) -> np.ndarray:
        """(count,) root of every node (a copy)."""
        from modalfem.collision._zone_kernels import compress

        compress(self.parent)
        return self.parent.copy()

    def union(self, a: np.ndarray, b: np.ndarray) -> None:
        """Merge the sets of ``a[k]`` and ``b[k]`` for every k."""
        from modalfem.collision._zone_kernels import union_pairs

        a, b = np.asarray(a, dtype=np.int64).ravel(), np.asarray(b, dtype=np.int64).ravel()
        if a.shape != b.shape:
            raise ValueError(f"union of {a.shape} and {b.shape} nodes")
        union_pairs(self.parent, a, b)

    def union_quads(self, quads: np.ndarray) -> None:
        """Merge the four nodes of every row of ``quads`` (k, 4)."""
        from modalfem.collision._zone_kernels import union_quads

        union_quads(self.parent, np.ascontiguousarray(quads, dtype=np.int64))


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
        analytic: the A analytic obstacles (rigidly moving: ``rigid_motion(t)``).
        t: time [s] of the step start.

    Returns:
        ``(V_new, inconsistent)``: (N, 3) velocities [m/s] (kinematic vertices unchanged) and the roots
        of zones whose kinematic members do not move rigidly together (neither as a rigid velocity field
        nor by one finite rigid motion over the step).
    """
    from modalfem.collision._zone_kernels import free_zone_velocities, zone_members

    N = len(X0)
    V = np.array(V, dtype=float, order="C")
    invm = np.ascontiguousarray(invm, dtype=float)
    # the zones' members in one compiled pass: free zones (numbered in root order) and kinematic ones
    idx, zone, Z, kroots, kptr, kmembers = zone_members(np.ascontiguousarray(roots, dtype=np.int64), invm, N)
    # free zones: momentum-preserving rigid motion (compiled, one pass over the members per quantity)
    if len(idx):
        free_zone_velocities(np.ascontiguousarray(X0, dtype=float), V, invm, idx, zone, Z)
    # kinematic zones: a zone of pins or scripted vertices alone first tries their finite rigid motion (Python, rare);
    # the others, and those it cannot follow, get the best-fitting rigid velocity field (compiled, all zones in one
    # call; analytic obstacles move rigidly: ``rigid_motion``)
    fit = []
    obstacle_root = np.zeros(len(roots), dtype=bool)  # the zones holding an analytic obstacle
    obstacle_root[roots[N:]] = True
    no_obstacle = ~obstacle_root[kroots]
    for z in range(len(kroots)):
        members = kmembers[kptr[z]:kptr[z + 1]]
        if no_obstacle[z]:
            vel = follow_finite_motion(X0[members], V[members], invm[members])
            if vel is not None:
                dm = invm[members] > 0
                V[members[dm]] = vel[dm]
                continue
        fit.append(z)
    if not fit:
        return V, np.zeros(0, dtype=np.int64)
    from modalfem.collision._zone_kernels import kinematic_zone_velocities

    A = len(analytic)
    motion = np.zeros((3, A, 3))
    for k, ob in enumerate(analytic):
        motion[0, k], motion[1, k], motion[2, k] = ob.rigid_motion(t)
    where = np.full(N + A, -1, dtype=np.int64)
    where[kroots] = np.arange(len(kroots))
    obs_zone = where[roots[N:]] if A else np.zeros(0, dtype=np.int64)
    fit = np.array(fit, dtype=np.int64)
    bad = kinematic_zone_velocities(np.ascontiguousarray(X0, dtype=float), V, invm, fit, kptr, kmembers,
                                    np.ascontiguousarray(obs_zone), motion[0], motion[1], motion[2])
    return V, kroots[fit[bad]]


def follow_finite_motion(X: np.ndarray, V: np.ndarray, invm: np.ndarray) -> np.ndarray | None:
    """Velocities moving a zone with the finite rigid motion of its kinematic vertices, if they have one.

    Scripted vertices turning with a handle get the chord velocity ``(x(t + dt) - x(t)) / dt``: their
    end positions are a rotation of their start positions, but their velocities are not a rigid
    velocity field ``v + omega x r`` (the map ``(R - I) / dt`` has a symmetric part, of relative size
    half the angle), so the linearised rigid fit cannot follow them (the zone would be reported
    inconsistent and all its pairs tested again). Here ``tau > 0`` is the time over which
    ``X + tau V`` is a rigid image ``R X + T`` of the kinematic members: from the preserved Gram matrix
    ``|a + tau u|^2 = |a|^2`` (a: offsets from their centroid, u: velocity offsets),
    ``tau = -2 sum(a . u) / sum(|u|^2)`` (= dt for chords); ``R`` is the Kabsch fit (the rotation
    about the line of collinear kinematic members is fitted to the dynamic members' own motion, with a
    negligible weight). Every member then gets ``(R x + T - x) / tau``: the zone moves by
    ``x -> x + sigma ((R - I) x + T)`` (sigma = s dt / tau), an affine map whose eigenvalues ``1``
    and ``1 - sigma + sigma exp(+-i angle)`` never vanish for turns below pi, so no pair inside the
    zone can cross during the step (the kinematic members follow exactly).

    Args:
        X: (k, 3) member positions [m] at the step start.
        V: (k, 3) velocities [m/s].
        invm: (k,) inverse masses [1/kg] (0: kinematic; at least one).

    Returns:
        (k, 3) velocities [m/s] of every member, or None when the kinematic members do not move by
        one finite rigid motion (to 1e-9 of their extent and displacement) turning less than 0.9 pi,
        or when they all translate together or have a rigid velocity field (then the linearised fit
        of ``rigid_zone_velocities`` follows them exactly).
    """
    kin = invm == 0
    a = X - X[kin].mean(axis=0)
    u = V - V[kin].mean(axis=0)
    uu = float(np.sum(u[kin] ** 2))
    if uu == 0.0:
        return None  # one kinematic vertex, or all translating together: the linearised fit is exact
    tau = -2.0 * float(np.sum(a[kin] * u[kin])) / uu
    if not tau > 0.0:
        return None  # e.g. a rigid velocity field (tau = 0): the linearised fit is exact
    Y = X + tau * V
    dk = Y[kin].mean(axis=0)
    b = Y - dk
    m = np.where(kin, 0.0, 1.0 / np.where(kin, 1.0, invm))
    w = np.where(kin, 1.0, 1e-12 * m / max(m.max(), 1e-300))
    H = np.einsum("k,ki,kj->ij", w, a, b)
    U, _, Wt = np.linalg.svd(H)
    flip = 1.0 if np.linalg.det(Wt.T @ U.T) >= 0 else -1.0
    R = Wt.T @ np.diag([1.0, 1.0, flip]) @ U.T
    Xn = a @ R.T + dk
    scale = np.ptp(X[kin], axis=0).max() + tau * np.abs(V[kin]).max() + 1e-300
    if np.abs(Xn[kin] - Y[kin]).max() > 1e-9 * scale or np.trace(R) <= 1.0 + 2.0 * np.cos(0.9 * np.pi):
        return None
    return (Xn - X) / tau
