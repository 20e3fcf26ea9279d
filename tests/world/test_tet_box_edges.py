"""A moving box's edges and corners against a tet body inside the tet step (issue 17): only the tet's vertices met a
box, so a box's edge crossing a tet cube's edge, or its corner pushed into a face between the cube's vertices, went
into the cube with no tet vertex inside the box (before: the edge 10 mm in at 10 ms steps, 18 mm at 50 ms). And a
stiffened retry of the tet step (a contact ended too deep) was refused when it ended with more energy than the
attempt it redid, although the moving box's harder push does more work on it: the too-deep attempt was kept.

Measured here independently of the contacts: the box's edges sampled every ~0.25 mm, a sample inside the cube's
surface (winding number) as deep as its distance to that surface (sampled on each triangle every 1/80 of its edges,
which over-estimates it by at most ~0.2 mm on these 2 cm triangles). Frictionless and without gravity, the box's
impulse on the cube is its momentum p and the box's work ``U a . p`` (its velocity U a constant): the cube's energy
(kinetic, elastic, stored in its contacts) may gain at most that, plus the implicit step's tolerance (Newton stops at
vertex updates below ``tol * size``) against the push's force scale ``m U / dt``, per step."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem import world as mw
from modalfem.effects import Contact
from modalfem.mesh import box

U = 1.0  # the box's speed [m/s]


@pytest.fixture(scope="module")
def cube():
    from modalfem import tet
    from modalfem.material import Material

    return tet.tet_model(box(size=(0.06, 0.06, 0.06), cells=(3, 3, 3)), Material(E=1e6, nu=0.3, rho=1000.0))


def _rotation(frm: np.ndarray, to: np.ndarray) -> np.ndarray:
    """The rotation taking unit vector ``frm`` to unit vector ``to`` (Rodrigues; not opposite vectors)."""
    v, c = np.cross(frm, to), float(frm @ to)
    K = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def _depth_inside(p: np.ndarray, X: np.ndarray, T: np.ndarray) -> float:
    """The largest distance [m] of points ``p`` inside the closed outward surface (X, T) to it (0: none inside)."""
    a, b, c = (X[T[:, k]][None] - p[:, None] for k in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=2) for v in (a, b, c))
    num = np.einsum("pkd,pkd->pk", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("pkd,pkd->pk", a, b) * lc + np.einsum("pkd,pkd->pk", b, c) * la
           + np.einsum("pkd,pkd->pk", c, a) * lb)
    inside = np.arctan2(num, den).sum(1) / (2.0 * np.pi) > 0.5  # (winding number: 1 inside, 0 outside)
    if not inside.any():
        return 0.0
    s = np.linspace(0.0, 1.0, 81)
    u, v = (g[np.add(*np.meshgrid(s, s)) <= 1.0 + 1e-12] for g in np.meshgrid(s, s))
    A, B, C = X[T[:, 0]], X[T[:, 1]], X[T[:, 2]]
    S = (A[:, None] + u[None, :, None] * (B - A)[:, None] + v[None, :, None] * (C - A)[:, None]).reshape(-1, 3)
    q = p[inside]
    return float(max(np.sqrt(((S - x) ** 2).sum(1)).min() for x in q))


@pytest.mark.parametrize("lead", ["edge", "corner"])
@pytest.mark.parametrize("dt", [1e-2, 2e-2, 5e-2])
def test_a_moving_box_edge_or_corner_stays_out_of_a_tet_cube(cube, lead, dt):
    contact = Contact(friction=0.0)
    h = 0.02
    if lead == "edge":  # its edge along (1, 0, 1) crosses the cube's edge along y (x = 0, z = 0.06) at y = 0.03
        a = np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0)
        y = np.array([0.0, 1.0, 0.0])
        R = np.column_stack([(a + y) / np.sqrt(2.0), (a - y) / np.sqrt(2.0), np.cross(a + y, a - y) / 2.0])
        half = np.array([h, h, 0.05])
        hit = np.array([0.0, 0.03, 0.06])
    else:  # its corner into the middle of the cube's x = 0 face (between the cube's vertices)
        a = np.array([1.0, 0.0, 0.0])
        R = _rotation(np.ones(3) / np.sqrt(3.0), a)
        half = np.array([h, h, h])
        hit = np.array([0.0, 0.03, 0.03])
    front = hit - 0.005 * a  # the leading edge's middle or corner, 5 mm from the cube at the start
    center = front - R @ (half * (1.0, 1.0, 0.0 if lead == "edge" else 1.0))
    moving = mw.Box(center, half, rotation=R, path=lambda t: U * t * a)
    w = mw.World(bodies=[mw.Tet(cube, name="cube")], obstacles=[moving], effects=[contact])
    s = w.state()
    sv, T = w._tet["cube"]["surface"], w._tet["cube"]["triangles"]
    m = float(cube.masses.sum())
    e0 = w.energy(s, "cube")["total"]
    steps = int(round(0.06 / dt))
    allow = (m * U / dt) * w._tet["cube"]["solver"].tol * cube.size
    corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(corners[i] != corners[j]) == 1]
    for i in range(steps):
        w.step(s, s, None, dt)
        X = s.bodies["cube"].x[sv]
        C = center + U * s.time * a + (corners * half) @ R.T
        pts = np.concatenate([C[p] + np.linspace(0.0, 1.0, 401)[:, None] * (C[q] - C[p]) for p, q in edges])
        pts = pts[np.all((pts >= X.min(0) - 1e-3) & (pts <= X.max(0) + 1e-3), axis=1)]
        depth = _depth_inside(pts, X, T) if len(pts) else 0.0
        assert depth <= contact.margin, f"step {i}: the box's {lead} {depth * 1e3:.2f} mm in the cube"
        assert w.penetrations(s, tolerance=contact.margin) == [], f"step {i}: a cube vertex in the box"
        work = U * float(a @ (cube.masses @ s.bodies["cube"].v))
        gain = w.energy(s, "cube")["total"] - e0
        assert gain <= work + (i + 1) * allow, (i, gain, work)
    assert float(a @ (cube.masses @ s.bodies["cube"].v)) > 0.5 * m * U  # (pushed ahead, not passed through)
