"""Restitution between two tet bodies stepped together (a ``tetgroup`` group): ``Contact(restitution=e)``.

The joint implicit step (``tetgroup.JointTetSolver``) lets two tet bodies bounce only through their own
elasticity, damped by backward Euler. Here, as ``World._tet_restitution`` does between a tet and a modal body, the
pair's relative motion is given the requested restitution (Poisson, on the bodies' centres of mass):

- an impact between members ``a`` and ``b`` starts at the first step their contacts push; its record (kept in the
  world state's contacts under ``(reaction key, a, "pair impact", b)``) holds the relative velocity ``v0`` [m/s] of
  their centres of mass at the step start, their internal energy then (elastic + kinetic about the centres of
  mass, [J]) and their relative kinetic energy, and the normal impulse ``J_c`` [N s] a has received from b so far;
- when they stop approaching along ``J_c`` they take ``e |J_c|`` more, equal and opposite through their centres of
  mass (all of a body's vertices alike: no strain), capped below;
- when the contacts let go, the relative normal velocity of the centres of mass is set to what the cap allows
  (topped up, or trimmed down when the bodies' elasticity threw them apart faster than ``e v0``: trimming only
  takes energy out).

The cap: ``mu vn^2 / 2 + (U - U0) <= e^2 mu v0n^2 / 2``, ``mu`` the pair's reduced mass [kg], ``vn`` the normal
relative velocity after the impulse, ``U`` the internal energy (both bodies' elastic and vibration kinetic energy and
their contacts' penalty energy) and ``U0`` at the start: the energy the implicit step's damping took is given back,
never more, and what the bodies keep as vibration is not available to the rebound (this is what limits the
rebound of ``e = 1``). A second cap keeps the pair's total (relative kinetic + internal) at or below its value at the
impact's start, so restitution never adds energy. The impulses are equal and opposite: the pair's momentum is
unchanged; each is reported in ``StepReport.exchanged`` (receiver, source, impulse, its moment about the origin).
"""

from __future__ import annotations

import math

import numpy as np

from modalfem.world import _tet_kernels
from modalfem.world.tetgroup import between, pair_owners

__all__ = ["pair_restitution"]


def pair_restitution(world, ctx, t: dict, s, out, key0: str) -> None:
    """Apply ``Contact(restitution)`` between the members of tet group ``t`` (``World._tet_group``'s entry) that
    touch each other in this step: end velocities ``out.v`` (n, 3) [m/s] changed in place (stacked members),
    ``s`` the group's start state. ``key0``: the world's reaction key (records in ``ctx.contacts``)."""
    e = float(t["contact"].restitution)
    pen = t["penalty"]
    members = t["members"]
    solver = t["solver"]
    offs = solver.offsets
    n_obstacle, modal = t.get("modal_contacts", (0, []))
    start = n_obstacle + len(modal)
    names = [n for n, _ in members]
    rows = np.arange(start, pen.count)
    f = pen.forces(out.x)[rows] if len(rows) else np.zeros(0)
    psi = _tet_kernels.penalty(pen.depths(out.x), pen.k, pen.eps)[0][rows] if len(rows) else np.zeros(0)
    if len(rows):
        owner, first, other = pair_owners(solver, pen, rows)
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            key = (key0, names[a], "pair impact", names[b])
            rec = ctx.state_in.contacts.get(key)
            sel = between(first, other, a, b) if len(rows) else np.zeros(0, dtype=np.int64)
            if len(sel):  # a's share of each contact's normal impulse (its vertices' signed weights)
                wa = np.where(owner[sel] == a, pen.w[rows[sel]], 0.0).sum(1)
                J = ((wa * f[sel] * ctx.dt)[:, None] * pen.nrm[rows[sel]]).sum(0)
            else:
                J = np.zeros(3)
            if not np.any(J) and rec is None:
                continue
            sa, sb = slice(offs[a], offs[a + 1]), slice(offs[b], offs[b + 1])
            ma, mb = t["masses"][sa], t["masses"][sb]
            if not (np.all(np.isfinite(ma)) and np.all(np.isfinite(mb))):
                continue
            Ma, Mb = float(ma.sum()), float(mb.sum())
            mu = Ma * Mb / (Ma + Mb)
            if rec is None:  # the impact starts: relative velocity, internal and relative energy before it
                v_start = ma @ s.v[sa] / Ma - mb @ s.v[sb] / Mb
                rec = (v_start, _internal(world, names, (a, b), (sa, sb), s, 0.0), 0.5 * mu * float(v_start @ v_start),
                       np.zeros(3), False)
            v_start, u0, k0, Jc, done = rec
            Jc = Jc + J
            ended = not np.any(J)
            if not ended:
                ctx.contacts[key] = (v_start, u0, k0, Jc, done)
            nJ = float(np.linalg.norm(Jc))
            if (done and not ended) or nJ == 0:
                continue
            nh = Jc / nJ  # on a, out of b
            Va, Vb = ma @ out.v[sa] / Ma, mb @ out.v[sb] / Mb
            vrel = Va - Vb
            vn = float(vrel @ nh)
            if vn < 0:  # still approaching
                continue
            pair_psi = float(psi[sel].sum()) if len(sel) else 0.0
            u = _internal(world, names, (a, b), (sa, sb), out, pair_psi)
            v0 = max(-float(v_start @ nh), 0.0)
            target = e * e * v0 * v0 - 2.0 * max(u - u0, 0.0) / mu  # the restitution's share, vibration taken off
            budget = vn * vn + 2.0 * (k0 + u0 - 0.5 * mu * float(vrel @ vrel) - u) / mu  # never above the start
            vmax = math.sqrt(max(min(target, budget), 0.0))
            if ended:
                lam = mu * (vmax - vn)  # may be negative: only ever takes energy out then (vmax < vn)
            else:
                lam = max(0.0, min(e * nJ, mu * (vmax - vn)))
                ctx.contacts[key] = (v_start, u0, k0, Jc, True)
            if lam == 0:
                continue
            out.v[sa] += lam * nh / Ma
            out.v[sb] -= lam * nh / Mb
            Ja = lam * nh
            ca, cb = ma @ out.x[sa] / Ma, mb @ out.x[sb] / Mb
            ctx.report.exchanged.append((names[a], names[b], Ja, np.cross(ca, Ja)))
            ctx.report.exchanged.append((names[b], names[a], -Ja, np.cross(cb, -Ja)))


def _internal(world, names: list, pair: tuple, slices: tuple, st, contact: float) -> float:
    """The energy [J] of two members not in their centres of mass' motion: elastic, kinetic about their centres of
    mass, plus ``contact`` (their contacts' penalty energy)."""
    from modalfem.tet import TetState

    u = contact
    for i, sl in zip(pair, slices):
        m = world._tet[names[i]]["masses"]
        part = TetState(st.x[sl], st.v[sl], st.t)
        en = world._tet[names[i]]["solver"].energies(part)
        P = m @ st.v[sl]
        u += en["elastic"] + en["kinetic"] - 0.5 * float(P @ P) / float(m.sum())
    return u
