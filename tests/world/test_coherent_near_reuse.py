"""The coherent pair search's tighter reuse test (``_coherent_kernels.coherent_pairs``): a pair's distances can only
have dropped by the motion, since the walk, of the points that can now be within reach: those in the overlap of the
two bodies' world boxes grown by the search radius (``_near_ball``: a ball about that region, in a body's axes), and
the drop may be measured in either body's axes (the smaller kept). ``_drift_at`` must bound the move of every point
of that ball (else a walk would be reused when features came within reach); ``_near_ball`` must hold the whole
region; and a bar turning about its own centre across another one (most of its lever far from the crossing) reuses
its walk more than the whole-body bound allows, while its contacts stay exactly those of a fresh walk."""

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


@pytest.mark.parametrize("seed", range(4))
def test_drift_at_bounds_the_move_of_every_point_of_the_ball(seed):
    rng = np.random.default_rng(seed)
    for _ in range(300):
        M0 = _rotation(rng.normal(size=3), rng.uniform(0, np.pi))
        M = M0 @ _rotation(rng.normal(size=3), 10.0 ** rng.uniform(-7, 0))
        t0, t = rng.normal(size=3), rng.normal(size=3) * 10.0 ** rng.uniform(-6, 0)
        c = rng.normal(size=3) * rng.uniform(0, 1)
        size = rng.uniform(0.0, 0.5)
        got = CK._drift_at(M.reshape(-1), t, M0.reshape(-1), t0, c, size)
        A = M - M0
        # the triangle-inequality bound it implements (any point c + u, |u| <= size)
        assert got >= (np.linalg.norm(A @ c + t - t0) + np.linalg.norm(A, 2) * size) * (1 - 1e-12)
        u = rng.normal(size=(200, 3))
        u *= size / np.linalg.norm(u, axis=1)[:, None]
        x = c + u
        moves = np.linalg.norm(x @ A.T + (t - t0), axis=1)
        assert np.all(moves <= got)
        # and it is the move about c (the turn's lever is the ball's radius, not |c| + size): at most the Frobenius
        # bound about c
        assert got <= (np.linalg.norm(A @ c + t - t0) + np.linalg.norm(A) * size) * (1 + 1e-12) + 1e-11


@pytest.mark.parametrize("seed", range(4))
def test_near_ball_holds_the_whole_overlap_of_the_grown_boxes(seed):
    rng = np.random.default_rng(seed)
    for _ in range(300):
        lo = rng.normal(size=(2, 3))
        hi = lo + rng.uniform(0.01, 1.0, size=(2, 3))
        grow = rng.uniform(0, 0.1)
        Ra = _rotation(rng.normal(size=3), rng.uniform(0, np.pi))
        pa = rng.normal(size=3)
        c = np.empty(3)
        rad = CK._near_ball(Ra, pa, lo, hi, 0, 1, grow, c)
        olo = np.maximum(lo[0], lo[1]) - grow
        ohi = np.minimum(hi[0], hi[1]) + grow
        if np.any(ohi < olo):
            continue  # boxes apart: no point can be in reach, any ball will do
        corners = np.array([[(olo, ohi)[(j >> d) & 1][d] for d in range(3)] for j in range(8)])
        inside = olo + rng.uniform(size=(100, 3)) * (ohi - olo)
        for p in np.vstack([corners, inside]):
            local = Ra.T @ (p - pa)  # in a's axes
            assert np.linalg.norm(local - c) <= rad


def test_a_bar_rocking_on_the_end_of_another_reuses_walks_and_finds_what_a_fresh_walk_finds(bar_model, monkeypatch):
    """Bar b (0.2 x 0.1 x 0.05 m) lies on the end of bar a (their ends overlap 3 cm along x, 2 mm deep) and rocks
    about a horizontal axis through the middle of that overlap, by up to 4 mrad (its far end moves ~0.7 mm): the
    contacts stay exactly those of a fresh walk at every call, and the first walk is reused for (nearly) every
    call at the World's slack (0.45 mm here): the points that can be in reach (within ~5 cm of the pivot) move
    less than that, while the bars' ends move ~0.7 mm (the whole-body bound, in either body's axes, walked 14
    times in these 200 calls)."""
    from modalfem.world import _solid_kernels as SK

    pb0 = np.array([0.17, 0.0, 0.05 - 2e-3])
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
    q0 = s["b"].orientation.copy()
    pivot = np.array([0.085, 0.0, 0.024])
    found = 0
    for k in range(200):
        theta = 4e-3 * np.sin(0.1 * k)
        s["b"].orientation[:] = quat_multiply(quat_from_axis_angle([0.0, 1.0, 0.0], theta), q0)
        s["b"].position[:] = pivot + _rotation([0.0, 1.0, 0.0], theta) @ (pb0 - pivot)
        data = fast.collect(s.bodies, off, {n: 0.0 for n in names}, 1e-5, {n: i for i, n in enumerate(names)}, None)
        found += 0 if data is None else len(data["gap"])
    assert len(walks) == 200 and found > 200
    assert 1 <= sum(walks) <= 4
