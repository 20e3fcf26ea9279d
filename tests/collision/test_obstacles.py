"""Signed distances of the analytic cloth obstacles against their definitions."""

from __future__ import annotations

import numpy as np

from modalfem.collision.obstacles import Plane, Sphere


def test_moving_tilted_plane_signed_distance():
    rng = np.random.default_rng(3)
    normal = np.array([1.0, -2.0, 2.0])
    plane = Plane(point=(0.3, -0.1, 0.2), normal=normal, velocity=(0.5, 0.0, -1.0))
    x = rng.uniform(-1, 1, (50, 3))
    for t in (0.0, 0.7):
        origin = np.array([0.3, -0.1, 0.2]) + t * np.array([0.5, 0.0, -1.0])
        expected = [float(np.dot(p - origin, normal / 3.0)) for p in x]  # |normal| = 3
        np.testing.assert_allclose(plane.signed_distance(x, t), expected, atol=1e-14)
    # a point moved along the normal by d is at distance d; on the plane at 0
    assert abs(plane.signed_distance(np.array([[0.3, -0.1, 0.2]]), 0.0)[0]) < 1e-15
    np.testing.assert_allclose(plane.signed_distance((0.3, -0.1, 0.2) + 0.25 * normal / 3.0, 0.0), 0.25, atol=1e-15)


def test_sphere_signed_distance():
    sphere = Sphere(center=(0.0, 0.0, 1.0), radius=0.5, velocity=(0.0, 1.0, 0.0))
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 1.0, 1.0], [0.3, 0.0, 1.0]])
    np.testing.assert_allclose(sphere.signed_distance(pts, 0.0), [0.5, 0.5, -0.2], atol=1e-15)
    np.testing.assert_allclose(sphere.signed_distance(pts, 1.0), [np.sqrt(2) - 0.5, -0.5, np.sqrt(1.09) - 0.5],
                               atol=1e-15)
