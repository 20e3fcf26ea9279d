"""The solid solve's no-gain factor per island (``_solid_kernels.no_gain_scales``, compiled; was a numpy bisection in
``_solid_stage._no_gain_scale``) against the energy balance written out here: per body the kinetic energy
``0.5 u^T M u`` with M built as a dense block (mass, the world inertia ``R I R^T``, unit modal masses) and ``u = V0
- g dt (linear part) + s dV``, less the lift's potential energy ``m |g dt| / 2 min(max(s a, 0), |g dt|)``, evaluated
on a dense grid of s and refined by bisection (80 halvings) inside the grid cell where it turns positive; the
islands found here by a breadth-first search of the body-body contacts.

Tolerances: the factor is the largest s in [0, 1] with f(s) <= 0; the kernel solves f's quadratic pieces, this
test bisects, both evaluate f in float64 from different but equivalent sums, so the two roots agree to the rounding
of f near its root over its slope there: ``64 eps (|work| + quad + sum m |g dt|^2) / f'(s)`` (f' > 0 at a root where
f turns positive), and 1e-15 for the bisection's own resolution. f at the kernel's factor is <= that rounding of f.
"""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.world._solid_kernels import island_labels, no_gain_scales

EPS = np.finfo(float).eps


def _instance(rng, m):
    nm = rng.integers(0, 4, size=m)
    size = 6 + nm
    off = np.concatenate([[0], np.cumsum(size)[:-1]]).astype(np.int64)
    n = int(size.sum())
    mass = rng.uniform(0.05, 3.0, size=m)
    R = np.array([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(m)])
    inertia = []
    for _ in range(m):
        A = rng.normal(size=(3, 3))
        inertia.append(1e-4 * (A @ A.T + 0.1 * np.eye(3)))
    inertia = np.array(inertia)
    dt = 10.0 ** rng.uniform(-3, 0)
    g = np.array([0.0, 0.0, -9.81]) if rng.random() < 0.8 else rng.normal(size=3)
    shift = np.tile(g * dt, (m, 1))
    shift[rng.random(m) < 0.1] = 0.0  # a body without gravity
    gn = np.linalg.norm(shift, axis=1)
    V0 = rng.normal(size=n) * rng.choice([1e-3, 0.1, 1.0])
    dV = rng.normal(size=n) * rng.choice([1e-3, 0.1, 1.0])
    for i in range(m):  # the velocity change against gravity often beyond the cap |g dt| (lift breaks in (0, 1))
        if gn[i] > 0 and rng.random() < 0.7:
            dV[off[i]:off[i] + 3] += -shift[i] / gn[i] * gn[i] * rng.uniform(0.0, 4.0)
        V0[off[i]:off[i] + 3] += shift[i]  # the solve's velocities hold g dt
    k = int(rng.integers(1, 3 * m))
    body = rng.integers(0, m, size=k)
    other = np.where(rng.random(k) < 0.4, rng.integers(0, m, size=k), -1)
    other[other == body] = -1
    lifted = rng.random(m) < 0.8
    exempt = rng.random(m) < 0.1
    return dict(dV=dV, V0=V0, body=body.astype(np.int64), other=other.astype(np.int64), off=off,
                size=size.astype(np.int64), mass=mass, R=R, inertia=inertia, shift=shift, lifted=lifted, exempt=exempt)


def _components(body, other, m):
    adj = [set() for _ in range(m)]
    touched = set(body.tolist()) | set(other[other >= 0].tolist())
    for a, b in zip(body.tolist(), other.tolist()):
        if b >= 0:
            adj[a].add(b)
            adj[b].add(a)
    seen, out = set(), []
    for i in sorted(touched):
        if i in seen:
            continue
        comp, todo = [], [i]
        seen.add(i)
        while todo:
            j = todo.pop()
            comp.append(j)
            for nb in adj[j]:
                if nb not in seen:
                    seen.add(nb)
                    todo.append(nb)
        out.append(sorted(comp))
    return out


def _energy(inst, ids):
    """f(s) (vectorised over s) of the bodies ``ids`` and its scale (for the rounding bound)."""
    terms = []
    for i in ids:
        o, sz = inst["off"][i], inst["size"][i]
        M = np.eye(sz)
        M[0:3, 0:3] *= inst["mass"][i]
        M[3:6, 3:6] = inst["R"][i] @ inst["inertia"][i] @ inst["R"][i].T
        u0 = inst["V0"][o:o + sz].copy()
        u0[0:3] -= inst["shift"][i]
        d = inst["dV"][o:o + sz]
        gn = np.linalg.norm(inst["shift"][i])
        a = float(-d[0:3] @ inst["shift"][i] / gn) if gn > 0 else 0.0
        c = 0.5 * inst["mass"][i] * gn if inst["lifted"][i] else 0.0
        terms.append((M, u0, d, a, c, gn))

    def f(s):
        s = np.atleast_1d(np.asarray(s, dtype=float))
        out = np.zeros_like(s)
        for M, u0, d, a, c, gn in terms:  # 0.5 (u0 + s d)^T M (u0 + s d) - 0.5 u0^T M u0, less the lift
            out += s * (d @ M @ u0) + 0.5 * s * s * (d @ M @ d)
            out -= c * np.minimum(np.maximum(s * a, 0.0), gn)
        return out

    work = sum(abs(d @ M @ u0) for M, u0, d, *_ in terms)
    quad = sum(d @ M @ d for M, u0, d, *_ in terms)
    size = work + quad + sum(2 * c * gn for *_, c, gn in terms) + sum(0.5 * u0 @ M @ u0 for M, u0, *_ in terms)
    return f, quad, size


@pytest.mark.parametrize("seed", range(40))
def test_no_gain_factor_is_the_largest_scale_without_gain(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 9))
    inst = _instance(rng, m)
    scale = no_gain_scales(inst["dV"], inst["V0"], inst["body"], inst["other"], inst["off"], inst["size"],
                           inst["mass"], inst["R"], inst["inertia"], inst["shift"], inst["lifted"], inst["exempt"])
    comps = _components(inst["body"], inst["other"], m)
    label = island_labels(inst["body"], inst["other"], m)
    assert sorted(sorted(np.flatnonzero(label == r).tolist()) for r in set(label[label >= 0].tolist())) == comps
    covered = {i for c in comps for i in c}
    assert all(scale[i] == 1.0 for i in range(m) if i not in covered)
    grid = np.linspace(0.0, 1.0, 20001)
    for ids in comps:
        assert len(set(scale[ids].tolist())) == 1
        s = float(scale[ids[0]])
        if inst["exempt"][ids].any():
            assert s == 1.0
            continue
        f, quad, size = _energy(inst, ids)
        tol = 64 * EPS * size
        if f(1.0)[0] <= 1e-12 * quad - tol:  # clearly no gain at full impulse
            assert s == 1.0
            continue
        if s == 1.0:  # the kernel's f(1) within rounding of the threshold
            assert f(1.0)[0] <= 1e-12 * quad + tol
            continue
        fg = f(grid)
        assert fg[0] == 0.0
        j = int(np.flatnonzero(fg <= 0.0)[-1])  # f convex: {f <= 0} is [0, s*]
        lo, hi = grid[j], grid[min(j + 1, len(grid) - 1)]
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if f(mid)[0] <= 0.0:
                lo = mid
            else:
                hi = mid
        slope = (f(min(lo + 1e-6, 1.0))[0] - f(max(lo - 1e-6, 0.0))[0]) / (min(lo + 1e-6, 1.0) - max(lo - 1e-6, 0.0))
        assert f(s)[0] <= tol
        if slope > 0:
            assert abs(s - lo) <= tol / slope + 1e-15, (s, lo, slope)
        else:  # f flat at 0 to the root: any s with f(s) <= 0 near it
            assert s <= lo + 1e-12
