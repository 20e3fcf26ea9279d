"""Pair impulses: the per-vertex averaging of many pairs' changes against a plain loop over the pairs."""

from __future__ import annotations

import numpy as np

from modalfem.collision.repulsion import apply_pair_impulses


def _reference(V, invm, quads, w, n, target, friction):
    """One pair at a time: the change each pair wants, summed per vertex and divided by the vertex's
    summed weights |w| (when above 1)."""
    dV = np.zeros_like(V)
    cnt = np.zeros(len(V))
    active = 0
    for q, wk, nk, tk in zip(quads, w, n, target):
        vr = wk @ V[q]
        vn = vr @ nk
        dvn = max(tk - vn, 0.0)
        den = np.sum(wk * wk * invm[q])
        if not (dvn > 0 and den > 0):
            continue
        active += 1
        dv_rel = dvn * nk
        vt = vr - vn * nk
        tn = np.linalg.norm(vt)
        if friction > 0:
            dv_rel = dv_rel - min(friction * dvn / (tn if tn > 0 else 1.0), 1.0) * vt
        for j in range(4):
            dV[q[j]] += wk[j] * invm[q[j]] / den * dv_rel
            cnt[q[j]] += abs(wk[j]) * (invm[q[j]] > 0)
    return dV / np.maximum(cnt, 1.0)[:, None], active


def test_pair_impulses_match_a_loop_over_the_pairs():
    rng = np.random.default_rng(2)
    N, k = 40, 300  # many pairs per vertex
    V = rng.standard_normal((N, 3))
    invm = rng.uniform(0.5, 2.0, N)
    invm[:5] = 0.0  # kinematic vertices
    quads = np.array([rng.choice(N, 4, replace=False) for _ in range(k)])
    w = rng.standard_normal((k, 4))
    n = rng.standard_normal((k, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    target = rng.uniform(-0.5, 1.0, k)
    for friction in (0.0, 0.4):
        dV, active = apply_pair_impulses(V, invm, quads, w, n, target, friction=friction)
        ref, ref_active = _reference(V, invm, quads, w, n, target, friction)
        assert active == ref_active > 0
        assert np.allclose(dV, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
        assert not dV[:5].any()  # kinematic vertices never move
