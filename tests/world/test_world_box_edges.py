"""Box edges in the World's solid solve: a modal body lying across a box's edge in a ``World`` (the box in the one
solid solve, as whenever two solid bodies have contact) is held by the edge under its faces (box-edge contacts: the
runtime's ``_contact_edge_kernels``), not by its vertices alone.

Before them (vertex contacts only; these tests on 65219fb): the thin plate across the narrow box rocked about its one
supported row of vertices and tipped, the box's edge passing through its bottom faces by 6.1 mm within 0.3 s at
dt = 0.1 ms, 107 mm at 1 ms, 99 mm at 10 ms; the bar over the box's end went over its edge by 0.5, 99.5 and 12.4 mm. The sinking is measured here directly: where a box edge passes under a bottom face of
the body, the clipped edge segment's end points (exact geometry, computed below independently of the kernels) must
not be inside the body beyond half its thickness. At dt = 0.1 s the plate fell through the box's top (49 mm, g dt^2 / 2
within a step) until the solve's translation acted at the step's middle (tests/world/test_world_resting_dt.py)."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem
from modalfem import world as mw
from modalfem.effects import Contact, Gravity
from modalfem.mesh import box

G = 9.81  # [m/s^2]
SETTLE = 0.1  # [s] the landing from 0.1 mm


@pytest.fixture(scope="module")
def thin_plate():
    """A steel plate 0.2 x 0.1 x 0.01 m (P1, 4 x 2 x 1 hexahedra, 8 undamped modes)."""
    from modalfem.model import ModalModel

    mesh = box(size=(0.2, 0.1, 0.01), cells=(4, 2, 1))
    res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 0.0))


def _edge_depth(x, tri, edges) -> float:
    """The least signed distance [m] of the box edges ``edges`` [(P0, P1), ...] from the body's downward faces (world
    surface ``x``, triangles ``tri`` outward): over each face, the edge segment clipped to where its projection
    along the face normal is inside the face; the distance of its two ends (it is linear along the segment) along
    the face's outward normal, negative when the edge is inside the body. +inf when no edge passes under a face."""
    worst = np.inf
    for t in tri:
        a, b, c = x[t]
        f = np.cross(b - a, c - a)
        f /= np.linalg.norm(f)
        if f[2] > -0.5:  # not a bottom face
            continue
        M = np.column_stack([b - a, c - a, f])
        for P0, P1 in edges:
            s0, s1 = np.linalg.solve(M, P0 - a), np.linalg.solve(M, P1 - a)
            w0 = np.array([1.0 - s0[0] - s0[1], s0[0], s0[1]])
            w1 = np.array([1.0 - s1[0] - s1[1], s1[0], s1[1]])
            lo, hi = 0.0, 1.0
            for u0, u1 in zip(w0, w1):
                d = u1 - u0
                if d > 0.0:
                    lo = max(lo, -u0 / d)
                elif d < 0.0:
                    hi = min(hi, -u0 / d)
                elif u0 < 0.0:
                    hi = -1.0
            if lo > hi:
                continue
            for tt in (lo, hi):
                worst = min(worst, float((P0 + tt * (P1 - P0) - a) @ f))
    return worst


def _across(model, dt, duration, *, centre, half, start, drop=1e-4):
    """Step body ``model`` lying on a box (top at z = 0, centre (x, y) ``centre`` [m], half extents ``half`` (x, y)
    [m]) from (x, y) ``start`` [m], ``drop`` [m] above it, with a second body of the model floating 1 m away (no
    gravity, touching nothing) so the box is in the one solid solve. Returns per step the total energy [J] and the
    edge depth (``_edge_depth``) of the box's top edges, the world, its state and the body's mass [kg]."""
    bx = mw.Box((centre[0], centre[1], -0.05), (*half, 0.05))
    body = mw.Modal(model, name="body")
    w0 = mw.World(bodies=[body], effects=[])
    s0 = w0.state()
    zmin = w0.surface(s0, "body")[0][:, 2].min() - s0.bodies["body"].position[2]
    w = mw.World(bodies=[mw.Modal(model, name="body", position=(*start, drop - zmin)),
                         mw.Modal(model, name="far", position=(0.0, 1.0, 1.0))],
                 obstacles=[bx], effects=[Gravity(bodies=["body"]), Contact(friction=0.5)])
    assert w._world_obstacles["body"] == [bx]  # the box in the solid solve
    hx, hy = half
    cx, cy = centre
    top = [(np.array([cx - hx, cy + sy * hy, 0.0]), np.array([cx + hx, cy + sy * hy, 0.0])) for sy in (-1, 1)]
    top += [(np.array([cx + sx * hx, cy - hy, 0.0]), np.array([cx + sx * hx, cy + hy, 0.0])) for sx in (-1, 1)]
    s = w.state()
    energy, depth = [], []
    for _ in range(int(round(duration / dt))):
        w.step(s, s, None, dt)
        energy.append(w.energy(s, "body")["total"] + w.energy(s, "far")["total"])
        depth.append(_edge_depth(*w.surface(s, "body"), top))
    return np.array(energy), np.array(depth), w, s, w._modal["body"]["body"].mass


def _energy_tol(mass, radius):
    """The solve's no-gain rule admits 1e-12 of the impulses' quadratic energy term and the free step's rotation
    keeps the energy to ~1e-9 of itself per step (tests/world/test_modal_contacts.py): 1e-9 of the body's
    m g (2 radius) scale [J]."""
    return 1e-9 * mass * G * 2.0 * radius


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2])
def test_a_thin_plate_across_a_narrow_box_in_a_world_rests_on_its_edges(thin_plate, dt):
    """The plate (0.2 x 0.1 x 0.01 m) across a box 0.1 x 0.06 m: only its middle row of bottom vertices (y = 0) is
    over the box; the box's edges y = +-0.03 m pass under its bottom faces and must keep it from rocking about that
    row. It settles where it was put, the energy never rises and no face sinks over an edge."""
    energy, depth, w, s, mass = _across(thin_plate, dt, 0.3 if dt < 1e-3 else 1.0, centre=(0.0, 0.0),
                                        half=(0.05, 0.03), start=(3e-7, 2e-7))
    radius = w._modal["body"]["body"].radius
    gains = np.diff(energy)
    assert gains.max() <= _energy_tol(mass, radius), f"energy rose by {gains.max():.3g} J in one step"
    sink = 0.5 * G * dt * dt  # the World's resting sink (module docstring)
    assert depth.min() >= -sink, f"a box edge went {-depth.min():.3g} m into the plate (allowed {sink:.3g} m)"
    st = s.bodies["body"]
    assert np.hypot(*st.position[:2]) < 1e-4  # did not slide or tip
    settled = int(round(SETTLE / dt))
    assert np.ptp(energy[settled:]) < 1e-3 * mass * G * 0.01  # settled: no rocking (1e-3 of m g thickness)


def test_a_thin_plate_across_a_narrow_box_in_a_world_at_a_tenth_of_a_second(thin_plate):
    energy, depth, w, s, mass = _across(thin_plate, 0.1, 1.0, centre=(0.0, 0.0), half=(0.05, 0.03),
                                        start=(3e-7, 2e-7))
    assert depth.min() >= -0.005  # half the plate's thickness
    assert np.hypot(*s.bodies["body"].position[:2]) < 1e-3


@pytest.mark.parametrize("dt", [1e-4, 1e-3, 1e-2])
def test_a_bar_with_its_centre_of_mass_over_the_last_supported_row_stays_on_the_box(bar_model, dt):
    """The steel bar (0.2 x 0.1 x 0.05 m) on a box wider than it in y that ends at x = 0.025 m, its centre of mass at
    x = -1 mm right over its last supported row of vertices (x = -1 mm; the next, x = 49 mm, is beyond the edge): the
    edge under its bottom faces holds it level, the energy never rises, no face sinks over the edge."""
    energy, depth, w, s, mass = _across(bar_model, dt, 0.3 if dt < 1e-3 else 1.0, centre=(0.025 - 0.15, 0.0),
                                        half=(0.15, 0.1), start=(-1e-3, 0.0))
    radius = w._modal["body"]["body"].radius
    gains = np.diff(energy)
    assert gains.max() <= _energy_tol(mass, radius), f"energy rose by {gains.max():.3g} J in one step"
    sink = 0.5 * G * dt * dt
    assert depth.min() >= -sink, f"the box edge went {-depth.min():.3g} m into the bar (allowed {sink:.3g} m)"
    st = s.bodies["body"]
    assert abs(st.position[0] + 1e-3) < 1e-4 and abs(st.position[1]) < 1e-4
    settled = int(round(SETTLE / dt))
    assert np.ptp(energy[settled:]) < 1e-3 * mass * G * 0.05
