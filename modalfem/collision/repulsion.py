"""Contact frames and impulses for primitive pairs; stage (a): repulsions with Coulomb friction.

A pair is four vertices with weights ``w`` such that ``sum_i w_i x_i`` is the separation vector from
the second primitive's closest point to the first's (point-triangle: ``w = (1, -b0, -b1, -b2)``;
edge-edge: ``w = (1 - s, s, -(1 - t), -t)``). A change ``dvn`` [m/s] of the relative normal velocity
needs the impulse ``j = dvn / sum_i w_i**2 / m_i`` and moves vertex i by ``w_i j / m_i`` along the
normal (pinned and obstacle vertices have ``1 / m = 0`` and do not move). The changes of many pairs
are summed per vertex and divided by the sum of that vertex's weights |w_i| over those pairs (when
above 1): k identical contacts give one push, not k, while an edge pair in which the vertex has a
small weight dilutes the others only by that weight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SWEEPS", "PairOrder", "apply_pair_impulses", "contact_frames", "pair_order", "repulsion_impulses",
           "repulsion_pairs", "sequential_pair_impulses"]

#: default number of sweeps of stage (a)'s pair-by-pair impulses (``CollisionConfig.repulsion_iterations``)
SWEEPS = 10


def contact_frames(X: np.ndarray, quads: np.ndarray, kind: str, Xref: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights, unit normals and distances of primitive pairs at positions ``X``.

    Args:
        X: (N, 3) positions [m] at which the closest points are taken.
        quads: (k, 4) vertex indices (``vf``: p, a, b, c; ``ee``: a0, a1, b0, b1).
        kind: ``"vf"`` or ``"ee"``.
        Xref: (N, 3) positions [m] (step start) that orient the normal when the primitives touch.

    Returns:
        ``(w, n, d)``: (k, 4) weights, (k, 3) unit normals from the second primitive to the first, (k,)
        distances [m].
    """
    from modalfem.collision._distance_kernels import contact_frames as frames

    return frames(kind == "vf", np.ascontiguousarray(X, dtype=float), np.ascontiguousarray(quads, dtype=np.int64),
                  np.ascontiguousarray(Xref, dtype=float))


def apply_pair_impulses(
    V: np.ndarray,
    invm: np.ndarray,
    quads: np.ndarray,
    w: np.ndarray,
    n: np.ndarray,
    target_vn: np.ndarray,
    *,
    friction: float = 0.0,
) -> tuple[np.ndarray, int]:
    """Raise the relative normal velocity of pairs to at least ``target_vn``, with Coulomb friction.

    Args:
        V: (N, 3) velocities [m/s] (not modified).
        invm: (N,) inverse masses [1/kg] (0: kinematic).
        quads, w, n: pairs, weights and unit normals as from :func:`contact_frames`.
        target_vn: (k,) wanted relative normal velocity [m/s].
        friction: Coulomb coefficient [-]: the tangential relative velocity drops by at most
            ``friction`` times the normal change.

    Returns:
        ``(dV, active)``: (N, 3) velocity change [m/s] (weight-averaged per vertex), number of pairs that
        acted.
    """
    from modalfem.collision._impulse_kernels import pair_impulses

    return pair_impulses(np.ascontiguousarray(V, dtype=float), np.ascontiguousarray(invm, dtype=float),
                         np.ascontiguousarray(quads, dtype=np.int64), np.ascontiguousarray(w, dtype=float),
                         np.ascontiguousarray(n, dtype=float), np.ascontiguousarray(target_vn, dtype=float),
                         float(friction))


def repulsion_pairs(
    X0: np.ndarray, vf: np.ndarray, ee: np.ndarray, *, thickness: float, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pairs of stage (a) at ``X0`` and what they want; they depend on the positions only.

    Args:
        X0: (N, 3) positions [m].
        vf, ee: (k, 4) candidate point-triangle and edge-edge pairs.
        thickness: ``h`` [m]; dt: step [s].

    Returns:
        ``(quads, w, n, target)``: the pairs closer than ``h`` ((p, 4) vertex indices), their (p, 4)
        weights and (p, 3) unit normals (:func:`contact_frames`) and (p,) wanted relative normal
        velocities ``0.1 (h - d) / dt`` [m/s].
    """
    from modalfem.collision._distance_kernels import close_frames

    quads, ws, ns, ts = [], [], [], []
    X0 = np.ascontiguousarray(X0, dtype=float)
    for kind, q in (("vf", vf), ("ee", ee)):
        if len(q) == 0:
            continue
        # the frames of the pairs closer than h only (one compiled pass: no masks over all candidates)
        q, w, n, d = close_frames(kind == "vf", X0, np.ascontiguousarray(q, dtype=np.int64), X0, float(thickness))
        quads.append(q)
        ws.append(w)
        ns.append(n)
        ts.append(0.1 * (thickness - d) / dt)
    if not quads:
        return np.zeros((0, 4), dtype=np.int64), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0)
    return tuple(np.concatenate(a) for a in (quads, ws, ns, ts))


@dataclass(frozen=True)
class PairOrder:
    """The order of :func:`sequential_pair_impulses`' sweeps over a list of pairs: groups of pairs, the groups of one
    colour sharing no vertex an impulse may move, so that they run in parallel (:func:`pair_order`).

    Attributes:
        perm: (k,) the pairs in sweep order (by colour, group, index); None: the pairs are in that order already
            (:meth:`arrange`).
        cptr: (colours + 1,) the groups of each colour.
        tptr: (groups + 1,) each group's span of the pairs in sweep order.
        writable: (N,) bool, the vertices the order lets impulses move (at least those with ``invm > 0``).
    """

    perm: np.ndarray | None
    cptr: np.ndarray
    tptr: np.ndarray
    writable: np.ndarray

    @property
    def colour_count(self) -> int:
        """Number of colours (a sweep goes colour by colour; the last colour of one and the first of the next in one
        parallel loop)."""
        return len(self.cptr) - 1

    @classmethod
    def serial(cls, k: int, N: int) -> PairOrder:
        """The given order, one group: ``k`` pairs over ``N`` vertices."""
        return cls(None, np.array([0, 1], np.int64), np.array([0, k], np.int64), np.ones(N, dtype=bool))

    def arrange(self, quads: np.ndarray, w: np.ndarray, n: np.ndarray, target: np.ndarray) -> tuple:
        """The pairs' arrays in sweep order and the order for them (``perm`` None): one gather, for arrays swept
        more than once (the sweeps then read them in memory order).

        Returns:
            ``(quads, w, n, target, order)``.
        """
        from modalfem.collision._impulse_kernels import arrange_pairs

        if self.perm is None:
            return quads, w, n, target, self
        arrays = arrange_pairs(self.perm, np.ascontiguousarray(quads, dtype=np.int64), np.ascontiguousarray(w, float),
                               np.ascontiguousarray(n, float), np.ascontiguousarray(target, float))
        return (*arrays, PairOrder(None, self.cptr, self.tptr, self.writable))


def pair_order(X: np.ndarray, writable: np.ndarray, quads: np.ndarray) -> PairOrder:
    """The parallel sweep order of the pairs ``quads`` at positions ``X``.

    The pairs are cut into slabs of about equal count along the widest axis of their first vertices
    (:func:`modalfem.collision._impulse_kernels.sweep_groups`: ``GROUP_PAIRS`` pairs or more per group, at most
    ``MAX_GROUPS`` groups), the groups' conflicts (a writable vertex in pairs of both) coloured greedily. The order
    depends on the pairs and positions only, never on the thread count.

    Args:
        X: (N, 3) positions [m] (the step start).
        writable: (N,) bool, the vertices impulses may move (every vertex with ``invm > 0`` in the sweeps).
        quads: (k, 4) vertex indices of the pairs.

    Returns:
        The :class:`PairOrder`.
    """
    from modalfem.collision._impulse_kernels import GROUP_PAIRS, MAX_GROUPS, pair_keys, sweep_groups

    quads = np.ascontiguousarray(quads, dtype=np.int64)
    writable = np.ascontiguousarray(writable, dtype=bool)
    groups = max(1, min(MAX_GROUPS, len(quads) // GROUP_PAIRS))
    key, reach = pair_keys(np.ascontiguousarray(X, dtype=float), writable, quads)
    perm, cptr, tptr = sweep_groups(key, reach, writable, quads, groups)
    return PairOrder(perm, cptr, tptr, writable)


def sequential_pair_impulses(
    V: np.ndarray,
    invm: np.ndarray,
    quads: np.ndarray,
    w: np.ndarray,
    n: np.ndarray,
    target_vn: np.ndarray,
    *,
    friction: float = 0.0,
    sweeps: int = SWEEPS,
    order: PairOrder | None = None,
) -> tuple[np.ndarray, int, int]:
    """Raise the relative normal velocity of pairs to at least ``target_vn``, pair by pair (Gauss-Seidel).

    Each pair in turn gets the impulse that brings its own relative normal velocity to its target, from
    the velocities the pairs before it left (Bridson et al.'s pair-wise application); sweeps alternate
    forwards and backwards and stop after ``sweeps`` or once no pair acts. A vertex between two layers
    so gets what both of its pairs need, where :func:`apply_pair_impulses` (all pairs against the same
    velocities, changes averaged per vertex) gives it a share and needs many more passes: on the 64x64
    pile at step 44 the largest remaining approach is 0.20 m/s after 20 averaged passes and 0.06 m/s
    after 10 sequential sweeps, which take a quarter of the time.

    Args:
        V: (N, 3) velocities [m/s] (not modified).
        invm: (N,) inverse masses [1/kg] (0: kinematic).
        quads, w, n: pairs, weights and unit normals as from :func:`contact_frames`.
        target_vn: (k,) wanted relative normal velocity [m/s].
        friction: Coulomb coefficient [-]: each impulse lowers the tangential relative velocity by at most
            ``friction`` times its normal change.
        sweeps: largest number of sweeps (>= 1).
        order: the sweep order (:func:`pair_order`: groups of pairs in parallel; the sweeps are then the
            sequential sweeps over ``quads[order.perm]``; :meth:`PairOrder.arrange` gathers the arrays into it once
            for repeated calls); None: the given order, serial.

    Returns:
        ``(V_new, done, active)``: (N, 3) velocities [m/s], the sweeps run, and the pairs that acted in the
        last sweep (0: all at or above their targets).

    Raises:
        ValueError: ``order`` is for another number of pairs or vertices, or leaves a movable vertex unmarked.
    """
    from modalfem.collision._impulse_kernels import sequential_impulses

    invm = np.ascontiguousarray(invm, dtype=float)
    if order is None:
        order = PairOrder.serial(len(quads), len(invm))
    elif order.tptr[-1] != len(quads) or len(order.writable) != len(invm) or (~order.writable & (invm > 0)).any():
        raise ValueError("pair order made for other pairs, or leaving a movable vertex unmarked")
    quads, w, n, target_vn, order = order.arrange(quads, w, n, target_vn)
    return sequential_impulses(np.ascontiguousarray(V, dtype=float), invm,
                               np.ascontiguousarray(quads, dtype=np.int64), np.ascontiguousarray(w, dtype=float),
                               np.ascontiguousarray(n, dtype=float), np.ascontiguousarray(target_vn, dtype=float),
                               float(friction), int(sweeps), order.cptr, order.tptr)


def repulsion_impulses(
    X0: np.ndarray,
    V: np.ndarray,
    invm: np.ndarray,
    vf: np.ndarray,
    ee: np.ndarray,
    *,
    thickness: float,
    dt: float,
    friction: float,
    sweeps: int = SWEEPS,
) -> tuple[np.ndarray, int]:
    """Stage (a): pairs closer than ``thickness`` at ``X0`` stop approaching and are pushed apart.

    The relative normal velocity of a pair at distance ``d < h`` is raised to ``0.1 (h - d) / dt``
    (an inelastic impulse plus a soft repulsion that restores a tenth of the missing thickness per
    step), with Coulomb friction on the tangential velocity, pair by pair
    (:func:`sequential_pair_impulses`, at most ``sweeps`` sweeps; the pipeline's stage (a)).

    Args:
        X0: (N, 3) positions [m]; V: (N, 3) velocities [m/s]; invm: (N,) inverse masses [1/kg].
        vf, ee: (k, 4) candidate point-triangle and edge-edge pairs.
        thickness: ``h`` [m]; dt: step [s]; friction: Coulomb coefficient [-]; sweeps: >= 1.

    Returns:
        ``(dV, count)``: (N, 3) velocity change [m/s] and the number of proximities (d < h).
    """
    quads, w, n, tv = repulsion_pairs(X0, vf, ee, thickness=thickness, dt=dt)
    if len(quads) == 0:
        return np.zeros_like(V), 0
    V_new, _, _ = sequential_pair_impulses(V, invm, quads, w, n, tv, friction=friction, sweeps=sweeps)
    return V_new - V, len(quads)
