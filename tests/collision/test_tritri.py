"""The independent triangle-triangle check against hand-made cases and a third formulation."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.collision.tritri import intersecting_pairs
from modalfem.errors import InputError


def _pair(t1, t2):
    x = np.vstack([t1, t2]).astype(float)
    return intersecting_pairs(x, np.array([[0, 1, 2], [3, 4, 5]]))


def test_hand_made_cases():
    base = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert len(_pair(base, [[0.2, 0.2, -1], [0.2, 0.2, 1], [2, 2, 0.5]])) == 1  # pierces
    assert len(_pair(base, [[0.2, 0.2, 0.1], [0.5, 0.2, 1], [0.2, 0.5, 1]])) == 0  # above
    assert len(_pair(base, [[2, 2, -1], [2, 2, 1], [3, 2, 0]])) == 0  # beside


def test_shared_vertex_and_shared_edge():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0], [0.3, 0.3, -1], [0.3, 0.3, 1]])
    # triangles sharing vertex 0: the second pierces the first
    assert len(intersecting_pairs(x, np.array([[0, 1, 2], [0, 4, 5]]))) == 1
    # sharing an edge, folded: never reported
    assert len(intersecting_pairs(x, np.array([[0, 1, 2], [1, 2, 3]]))) == 0
    # sharing vertex 0 but apart
    x2 = x.copy()
    x2[4:] = [[-0.5, 0.0, 1], [0.0, -0.5, 1]]
    assert len(intersecting_pairs(x2, np.array([[0, 1, 2], [0, 4, 5]]))) == 0


def _reference(P, Q):
    """Edge crossings by line-plane parameter + barycentric inside test (a different formulation)."""
    def crosses(T, U):
        n = np.cross(T[1] - T[0], T[2] - T[0])
        for e in range(3):
            a, b = U[e], U[(e + 1) % 3]
            den = n @ (b - a)
            if den == 0:
                continue
            s = n @ (T[0] - a) / den
            if not 0 <= s <= 1:
                continue
            y = a + s * (b - a)
            m = np.array([T[1] - T[0], T[2] - T[0]]).T
            uv = np.linalg.lstsq(m, y - T[0], rcond=None)[0]
            if uv.min() >= 0 and uv.sum() <= 1:
                return True
        return False
    return crosses(P, Q) or crosses(Q, P)


def test_random_pairs_agree_with_reference_and_other_mesh_mode():
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 1, size=(3 * 120, 3))
    tri = np.arange(len(x)).reshape(-1, 3)
    found = {tuple(p) for p in intersecting_pairs(x, tri)}
    ref = {(i, j) for i in range(len(tri)) for j in range(i + 1, len(tri)) if _reference(x[tri[i]], x[tri[j]])}
    assert len(ref) > 100 and found == ref
    # the same as two meshes
    a, b = tri[:60], tri[60:] - 180
    cross = {(i, j + 60) for i, j in intersecting_pairs(x, a, other_points=x[180:], other_triangles=b)}
    assert cross == {p for p in ref if p[0] < 60 <= p[1]}


def test_bad_input():
    with pytest.raises(InputError):
        intersecting_pairs(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(InputError):
        intersecting_pairs(np.zeros((3, 3)), np.array([[0, 1, 2]]), other_points=np.zeros((3, 3)))
