"""The lift of the solid solve for every body at once (``_solid_stage.gravity_lifts``): the part of a body's velocity
change against gravity up to the step's load ``|g| dt`` acts at the step's middle, so the body moves ``-dt / 2`` of
it along ``up = -g / |g|`` (none without gravity or without such a part). Written out here per body; the two differ
by rounding only: a few eps of ``dt |g| dt`` (the largest lift) per component."""

from __future__ import annotations

import numpy as np

from modalfem.world._solid_stage import gravity_lift, gravity_lifts

EPS = np.finfo(float).eps


def test_gravity_lifts_are_each_bodys_lift():
    rng = np.random.default_rng(3)
    m = 400
    dt = 10.0 ** rng.uniform(-4, 0, size=1)[0]
    g = rng.normal(size=(m, 3)) * rng.choice([0.0, 1.0, 9.81], size=(m, 1))
    dv = rng.normal(size=(m, 3)) * np.linalg.norm(g, axis=1)[:, None] * dt * rng.uniform(0, 3, size=(m, 1))
    lifts, has = gravity_lifts(dv, g, dt)
    for i in range(m):
        gn = np.linalg.norm(g[i])
        if gn == 0.0:
            assert not has[i]
            continue
        up = -g[i] / gn
        c = min(max(float(np.dot(dv[i], up)), 0.0), gn * dt)
        assert has[i] == (c > 0.0)
        if has[i]:
            assert np.allclose(lifts[i], -0.5 * dt * c * up, rtol=0.0, atol=8 * EPS * dt * gn * dt)
            assert np.allclose(lifts[i], gravity_lift(dv[i], g[i], dt), rtol=0.0, atol=8 * EPS * dt * gn * dt)
    assert 50 < has.sum() < m - 50  # lifts and none, capped and not
    assert np.any(np.einsum("ij,ij->i", dv, -g) > np.einsum("ij,ij->i", g, g) * dt)
