"""Partial re-walks of the coherent pair search (``_coherent_kernels.coherent_pairs``): once a pair's bodies have moved
more than the slack since its walk (but less than the guard band), only the vertices and edges that moved, in the
other body's axes, more than the slack left since their own last walk are walked again; the others keep their
candidates. Every call must still give exactly the contacts of the brute-force ``all_pairs``."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact
from modalfem.runtime.rotation import quat_from_axis_angle, quat_multiply
from modalfem.world import _coherent_kernels as CK


def _rotation(axis, angle):
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.mark.parametrize("seed", range(3))
def test_partial_rewalks_find_what_brute_force_finds_under_random_motion(bar_model, monkeypatch, seed):
    """Bar b (0.2 x 0.1 x 0.05 m) lies across bar a and wanders: each call it slides by up to 0.35 mm (pulled back
    towards its start so that it stays across a), turns by up to 2 mrad about a random axis through its centre, and
    its height follows a sine through the search radius (3 mm; up to 0.39 mm per call, plus up to 0.1 mm at
    random): its points move ~0.2-0.8 mm per call against a slack of 0.45 mm, and enter and leave reach. The contacts equal ``all_pairs``' at every call, and the partial path is taken (the pair's cache
    row marked 2) at many calls, with fewer full walks than calls."""
    from modalfem.world import _solid_kernels as SK

    rng = np.random.default_rng(seed)
    pb0 = np.array([0.07, 0.02, 0.05 - 1e-3])
    bodies = [mw.Modal(bar_model, name="a", position=(0, 0, 0)), mw.Modal(bar_model, name="b", position=pb0)]
    w = mw.World(bodies=bodies, effects=[Contact(margin=3e-3)])
    s = w.state()
    coherent = CK.coherent_pairs
    walks = []

    def checked(*a):
        out = coherent(*a)
        ref = SK.all_pairs(*a[:4], *a[5:11], *a[16:23], *a[37:])  # as in test_modal_contacts
        for x, y in zip(out[0] + out[1], ref[0] + ref[1]):
            assert x.shape == y.shape and np.array_equal(x, y)
        walks.append(out[2])
        return out

    monkeypatch.setattr(CK, "coherent_pairs", checked)
    fast = w._fast
    names = fast.names
    off = {n: 0 if i == 0 else 6 + w._modal[names[0]]["body"].mode_count for i, n in enumerate(names)}
    row = fast._meta[0 * len(names) + 1]
    partial = 0
    found = 0
    for k in range(150):
        p = s["b"].position
        step = np.append(rng.uniform(-3.5e-4, 3.5e-4, 2), 0.0) - 0.05 * (p - pb0)
        s["b"].position[:] = p + step
        # up and down through the search radius: b's lowest points from 3.5 mm into a to 1.5 mm above it
        s["b"].position[2] = pb0[2] + 2.5e-3 * np.sin(2 * np.pi * k / 40) + rng.uniform(-1e-4, 1e-4) - 1.5e-3
        turn = rng.uniform(0.0, 2e-3)
        s["b"].orientation[:] = quat_multiply(quat_from_axis_angle(rng.normal(size=3), turn), s["b"].orientation)
        data = fast.collect(s.bodies, off, {n: 0.0 for n in names}, 1e-5, {n: i for i, n in enumerate(names)}, None)
        found += 0 if data is None else len(data["gap"])
        partial += row[CK._VALID] == 2.0
    assert len(walks) == 150 and found > 1500
    assert partial >= 30
