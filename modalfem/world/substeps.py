"""Sub-division of a ``World`` step in which a modal body near a tet body, or two tet bodies, would travel far
against a tet's surface (``World.step``).

The tet stage meets a modal body's surface at its predicted free step end, its contacts with the tet linearised
at the closest features found there (``_tet_contacts``): when the body travels more than about the tet surface's
smallest edge within the step, the features it passes are not the ones found at its end (a steel bar travelling
2.5 cm and turning ~10 degrees per 20 ms step over soft foam: two foam edges 1.1 and 3.6 mm in front of its edge
at the step start were 20 mm behind it at its predicted end, their pairs dropped as ill-signed, and the bar's edge
cut through the foam; tests/world/test_tet_squeeze.py). So a step in which a modal body with contact, within reach
of a tet body with contact, would move more than ``TRAVEL_SHARE`` of that tet's smallest rest surface edge is
taken as ``n`` equal sub-steps, each a whole world step (every stage, in order), ``n`` the smallest with the
body's travel per sub-step below that length.

Two tet bodies with contact closing on each other are divided by the same rule: their contacts with each other are
found and linearised at the step start (``_tet_contacts._tet_pair_contacts``), so a stiff tet cube falling 12.3 mm
onto soft tet foam in one 50 ms step crossed it (tests/world/test_tet_stack_substeps.py). Their relative travel is
bounded by ``(vmax_a + vmax_b) dt + max(|g_a|, |g_b|) dt^2 / 2`` (each body's fastest vertex; one may be held
while the other falls), against ``TRAVEL_SHARE`` of the smaller of their smallest rest surface edges, for pairs
whose surfaces' boxes, each grown by its own travel and margin, overlap.

The travel is bounded from the start state, for the body as a rigid sphere: ``(|v| + |omega| r) dt + |g| dt^2 /
2`` (``r`` its bounding radius [m] about the centre of mass; its modes' small deformation is not counted). A
step with scripted tet vertices is not divided (their targets are for the step's end).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["TRAVEL_SHARE", "extents", "substep_count", "taken_count", "merged_report"]

#: a modal body may travel at most this part of a nearby tet body's smallest rest surface edge per (sub-)step [-]
TRAVEL_SHARE = 0.5


def _smallest_edge(world, name: str) -> float:
    """The smallest rest surface edge [m] of tet body ``name`` (kept in its build entry)."""
    t = world._tet[name]
    if "smallest_edge" not in t:
        x = world.by_name[name].model.rest_points[t["surface"]]
        T = t["triangles"]
        e = np.concatenate([x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 1]], x[T[:, 0]] - x[T[:, 2]]])
        t["smallest_edge"] = float(np.sqrt(np.einsum("ij,ij->i", e, e)).min())
    return t["smallest_edge"]


def substep_count(world, state, dt: float, ext: dict | None = None) -> int:
    """How many equal sub-steps a step of ``dt`` [s] from ``state`` takes (1: not divided; see the module
    docstring). ``ext``: ``extents(world, state)`` (computed here when not given)."""
    ext = extents(world, state) if ext is None else ext
    count = _tet_pairs_count(world, state, dt, ext)
    return max(count, _modal_count(world, state, dt, ext, None))


def taken_count(world, state, bodies_out: dict, dt: float, ext: dict | None = None) -> int:
    """The sub-steps a step of ``dt`` [s] from ``state`` needed by the travel its modal bodies took in it
    (``bodies_out``: their states at its end, as a single pass left them): the rule of ``substep_count`` with each
    body's travel measured, ``|p_1 - p_0| + theta r`` (``theta`` [rad] the turn between the two orientations,
    ``r`` its bounding radius), instead of bounded from its start velocities. A body at rest at the step start can
    be set moving in the step by a moving obstacle or a strike (a box ridge rising at 1 m/s under the end of a bar
    lying across a soft tet cube turned the bar 0.14 rad in one 20 ms step, and the linearised contacts of the tet
    step left cube vertices 0.8 mm inside it: tests/world/test_tet_modal_moving_ridge.py); ``World.step`` then
    takes that step again in this many sub-steps (1: the pass stands). ``ext``: ``extents(world, state)``, the one
    ``substep_count`` used (computed here when not given)."""
    tets = [n for n in world._tet if world._tet_modal.get(n)]
    if not tets:
        return 1

    def travel(m, body, st):
        end = bodies_out.get(m)
        if end is None:
            return 0.0
        c = min(1.0, abs(float(np.dot(st.orientation, end.orientation))))
        return float(np.linalg.norm(end.position - st.position)) + 2.0 * math.acos(c) * body.radius

    return _modal_count(world, state, dt, extents(world, state) if ext is None else ext, travel)


def _modal_count(world, state, dt: float, ext: dict, travel) -> int:
    """The sub-steps of the modal bodies with contact near a tet body with contact (``substep_count``): ``travel(m,
    body, st)`` [m] a body's travel in the step, None: bounded from its start velocities."""
    count = 1
    tets = [n for n in world._tet if world._tet_modal.get(n)]  # (not the groups' keys)
    if not tets:
        return count
    g = max((float(np.linalg.norm(world._modal[m]["g"])) for m in world._modal_contact), default=0.0)
    boxes = {}
    for n in tets:
        lo, hi, vmax = ext[n]
        r = vmax * dt + 0.5 * g * dt * dt + world._tet[n]["contact"].margin
        boxes[n] = (lo - r, hi + r)
    for m in world._modal_contact:
        body, st = world._modal[m]["body"], state.bodies[m]
        if travel is None:
            gm = float(np.linalg.norm(world._modal[m]["g"]))
            d = (float(np.linalg.norm(st.velocity)) + float(np.linalg.norm(body.angular_velocity(st))) * body.radius
                 ) * dt + 0.5 * gm * dt * dt
        else:
            d = travel(m, body, st)
        lo, hi = st.position - body.radius - d, st.position + body.radius + d
        for n in tets:
            if m not in world._tet_modal[n]:
                continue
            blo, bhi = boxes[n]
            if np.all(lo <= bhi) and np.all(blo <= hi):
                count = max(count, math.ceil(d / (TRAVEL_SHARE * _smallest_edge(world, n))))
    return count


def _gravity(world, name: str) -> float:
    """|g| [m/s^2] acting on body ``name`` (0 without ``Gravity``)."""
    from modalfem.effects import Gravity

    e = world._one(name, Gravity)
    return 0.0 if e is None else float(np.linalg.norm(e.g))


def extents(world, state) -> dict:
    """Per tet body with contact: its surface's bounding box ``(lo, hi)`` (3,) [m] and its fastest vertex's speed
    [m/s] at ``state``, computed once per step for the counts (``substep_count``, ``_tet_pairs_count``,
    ``taken_count``)."""
    out = {}
    for n, t in world._tet.items():
        if t["contact"] is None:
            continue
        st = state.bodies[n]
        xs = st.x[t["surface"]]
        vmax = float(np.sqrt(np.einsum("ij,ij->i", st.v, st.v)).max()) if len(st.v) else 0.0
        out[n] = (xs.min(0), xs.max(0), vmax)
    return out


def _tet_pairs_count(world, state, dt: float, ext: dict | None = None) -> int:
    """The sub-steps two tet bodies with contact closing on each other need: for each pair whose surfaces' boxes,
    each grown by its own travel bound and margin, overlap, their relative travel ``(vmax_a + vmax_b) dt + max(|g_a|,
    |g_b|) dt^2 / 2`` (the faster vertex of each; one body may be held while the other falls) against
    ``TRAVEL_SHARE`` of the smaller of their smallest rest surface edges. ``ext``: ``extents(world, state)``
    (computed here when not given)."""
    tets = [n for n, t in world._tet.items() if t["contact"] is not None]
    if len(tets) < 2:
        return 1
    ext = extents(world, state) if ext is None else ext
    info = {}
    for n in tets:
        lo, hi, vmax = ext[n]
        g = _gravity(world, n)
        r = vmax * dt + 0.5 * g * dt * dt + world._tet[n]["contact"].margin
        info[n] = (lo - r, hi + r, vmax, g)
    count = 1
    for i, a in enumerate(tets):
        alo, ahi, va, ga = info[a]
        for b in tets[i + 1:]:
            blo, bhi, vb, gb = info[b]
            if np.all(alo <= bhi) and np.all(blo <= ahi):
                travel = (va + vb) * dt + 0.5 * max(ga, gb) * dt * dt
                edge = min(_smallest_edge(world, a), _smallest_edge(world, b))
                count = max(count, math.ceil(travel / (TRAVEL_SHARE * edge)))
    return count


def merged_report(reports: list):
    """One ``StepReport`` of a step's sub-steps: wall times and solve sweeps summed, the contacts by kind the most
    any sub-step had, and what each body received from each other one summed per ordered pair (one entry each, in
    the order first seen), ``substeps`` their number."""
    out = type(reports[0])()
    exchanged = {}
    for r in reports:
        for k, v in r.seconds.items():
            out.seconds[k] = out.seconds.get(k, 0.0) + v
        for k, v in r.contacts.items():
            out.contacts[k] = max(out.contacts.get(k, 0), v)
        out.sweeps += r.sweeps
        for a, b, J, L in r.exchanged:
            if (a, b) in exchanged:
                J0, L0 = exchanged[(a, b)]
                exchanged[(a, b)] = (J0 + J, L0 + L)
            else:
                exchanged[(a, b)] = (np.asarray(J, dtype=np.float64), np.asarray(L, dtype=np.float64))
    out.exchanged = [(a, b, J, L) for (a, b), (J, L) in exchanged.items()]
    out.substeps = len(reports)
    return out
