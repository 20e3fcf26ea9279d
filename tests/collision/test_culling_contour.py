"""The second culling condition (the projected contour must not cross itself): a ramp winding more than
one turn about a vertical axis has all its normals within a few degrees of +z, yet its layers overlap;
the normal cone alone would cull the pairs between them."""

from __future__ import annotations

import numpy as np

from modalfem.collision.bvh import BroadPhaseBVH


def _ramp(turns: float, *, nu: int = 60, nv: int = 3, pitch: float = 0.003):
    """A ribbon r in [0.3, 0.5] m, angle in [0, 2 pi turns], rising ``pitch`` [m] per turn."""
    u = np.linspace(0.0, 2 * np.pi * turns, nu + 1)
    r = np.linspace(0.3, 0.5, nv + 1)
    U, R = np.meshgrid(u, r, indexing="ij")
    pts = np.stack([R * np.cos(U), R * np.sin(U), pitch * U / (2 * np.pi)], axis=-1).reshape(-1, 3)
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])  # normals up (+z)
    # the rest shape, unrolled flat: a long strip, so the tree's nodes are runs along the ribbon
    flat = np.stack([U * 0.4, R, np.zeros_like(U)], axis=-1).reshape(-1, 3)
    return pts, tri, flat, U.reshape(-1)


def _pairs(bvh, x, *, culling):
    bvh.refit(x, x, margin=0.002)
    pairs, tests = bvh.self_pairs(culling=culling)
    return {tuple(sorted(map(int, p))) for p in pairs}, tests


def _normal_cone_deg(x, tri):
    n = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.degrees(np.arccos(n[:, 2].min()))


def test_overlapping_ramp_layers_are_not_culled():
    x, tri, flat, angle = _ramp(1.3)
    assert _normal_cone_deg(x, tri) < 5.0  # the cone condition alone holds for the whole ribbon
    bvh = BroadPhaseBVH(tri, flat, leaf_size=4)
    full, _ = _pairs(bvh, x, culling=False)
    turn = angle[tri].mean(axis=1)
    layers = {p for p in full if abs(turn[p[0]] - turn[p[1]]) > np.pi}  # one turn apart, stacked 3 mm
    assert layers  # the overlap exists and the boxes see it
    culled, tests_on = _pairs(bvh, x, culling=True)
    assert layers <= culled  # none of them culled
    assert culled <= full and tests_on > 0
    bvh.boundary_check = False  # the normal cone alone: the whole ribbon is one flat patch
    cone_only, tests_cone = _pairs(bvh, x, culling=True)
    assert not (layers & cone_only) and tests_cone < tests_on


def test_contour_check_keeps_culling_a_ramp_less_than_one_turn():
    x, tri, flat, _ = _ramp(0.8)
    bvh = BroadPhaseBVH(tri, flat, leaf_size=4)
    culled, tests = _pairs(bvh, x, culling=True)
    assert tests == 0 and not culled  # contour does not cross itself: the whole ribbon is culled
    assert _pairs(bvh, x, culling=False)[1] > 0
