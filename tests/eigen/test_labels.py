"""Mode labels on synthetic analytic fields (Euler-Bernoulli, torsion, axial, plate), no FE solve.

Every field is built from beam / plate kinematics with an analytic profile along the axis, so the
expected label follows from theory, not from the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.eigen.labels import body_frame, label_modes, mode_fractions
from modalfem.errors import InputError
from modalfem.theory import euler_bernoulli_shape

L, A, B = 1.0, 0.02, 0.02


def grid(size=(L, A, B), n=(61, 5, 5), origin=None):
    o = -0.5 * np.asarray(size) if origin is None else np.asarray(origin)
    o[0] = 0.0 if origin is None else o[0]
    axes = [np.linspace(o[i], o[i] + size[i], n[i]) for i in range(3)]
    X = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([c.ravel() for c in X])


def d_dx(f, x, h=1e-6):
    lo, hi = np.clip(x - h, 0, L), np.clip(x + h, 0, L)
    return (f(hi) - f(lo)) / (hi - lo)


def bending(P, n, boundary, d):
    """Euler-Bernoulli kinematics: transverse w(x) along axis d, axial -r_d w'(x)."""
    f = lambda x: euler_bernoulli_shape(x, L, n, boundary)
    u = np.zeros_like(P)
    u[:, d] = f(P[:, 0])
    u[:, 0] = -P[:, d] * d_dx(f, P[:, 0])
    return u.ravel()


def wave(x, n, boundary):
    """Rod / shaft mode profile: clamped at x=0 and free at L, or free-free."""
    if boundary == "clamped-free":
        return np.sin((2 * n - 1) * np.pi * x / (2 * L))
    return np.cos(n * np.pi * x / L)


def torsion(P, n, boundary, warp=0.0):
    th = wave(P[:, 0], n, boundary)
    u = np.zeros_like(P)
    u[:, 1] = -th * P[:, 2]
    u[:, 2] = th * P[:, 1]
    u[:, 0] = warp * P[:, 1] * P[:, 2] * d_dx(lambda x: wave(x, n, boundary), P[:, 0])
    return u.ravel()


def axial(P, n, boundary, nu=0.3):
    f = lambda x: wave(x, n, boundary)
    eps = d_dx(f, P[:, 0])
    u = np.column_stack([f(P[:, 0]), -nu * eps * P[:, 1], -nu * eps * P[:, 2]])
    return u.ravel()


@pytest.fixture(scope="module")
def beam_points():
    return grid()


# ----------------------------------------------------------------------------- frame
def test_body_frame_kinds_and_names():
    f = body_frame(grid())
    assert f.kind == "beam" and f.names == ("x", "y", "z")
    f = body_frame(grid((0.4, 0.3, 0.004), (21, 17, 3)))
    assert f.kind == "plate" and f.names == ("x", "y", "z")
    f = body_frame(grid((0.1, 0.1, 0.1), (5, 5, 5)))
    assert f.kind == "solid"
    # a beam along z: the long axis is named z, the square section keeps x, y order
    P = grid()[:, [1, 2, 0]]
    f = body_frame(P)
    assert f.kind == "beam" and f.names == ("z", "x", "y")
    assert body_frame(grid(), kind="solid").kind == "solid"


# ----------------------------------------------------------------------------- beams
@pytest.mark.parametrize("boundary", ["clamped-free", "free-free", "clamped-clamped"])
def test_euler_bernoulli_bending_labels(beam_points, boundary):
    P = beam_points
    S = np.column_stack([bending(P, n, boundary, d) for n in (1, 2, 3, 4) for d in (1, 2)])
    expect = tuple(f"bending-{'yz'[d - 1]} {n}" for n in (1, 2, 3, 4) for d in (1, 2))
    assert label_modes(P, S) == expect
    # sign and normalisation do not matter
    assert label_modes(P, -3.7e-4 * S) == expect


def test_bending_fractions_are_pure(beam_points):
    P = beam_points
    S = np.column_stack([bending(P, 2, "clamped-free", 1), torsion(P, 1, "clamped-free"), axial(P, 1, "free-free")])
    f = mode_fractions(P, S)
    assert f[0]["bending-y"] > 0.999 and f[1]["torsion"] > 0.999 and f[2]["axial"] > 0.999
    for fi in f:
        assert all(0.0 <= v <= 1.0 + 1e-12 for v in fi.values())
        assert abs(sum(fi.values()) - 1.0) < 1e-9


@pytest.mark.parametrize("boundary", ["clamped-free", "free-free"])
def test_torsion_and_axial_labels(beam_points, boundary):
    P = beam_points
    S = np.column_stack([torsion(P, 1, boundary), torsion(P, 2, boundary, warp=0.5),
                         axial(P, 1, boundary), axial(P, 3, boundary)])
    assert label_modes(P, S) == ("torsion 1", "torsion 2", "axial 1", "axial 3")


def test_per_component_support_counts_as_held(beam_points):
    """Pinned-pinned: w = 0 at both ends but the ends rotate; sin(n pi x / L) has n - 1 interior nodes."""
    P = beam_points
    S = np.column_stack([bending(P, n, "pinned-pinned", 2) for n in (1, 2, 3)])
    assert label_modes(P, S) == ("bending-z 1", "bending-z 2", "bending-z 3")


@pytest.mark.parametrize("angle_deg", [0.0, 17.0, 45.0, 90.0, 133.0, 225.0])
@pytest.mark.parametrize("boundary,n", [("clamped-free", 1), ("free-free", 2)])
def test_degenerate_pair_any_mixing_angle(beam_points, angle_deg, boundary, n):
    """A square beam's pair mixed by any rotation still gets one bending-y n and one bending-z n."""
    P = beam_points
    pair = np.column_stack([bending(P, n, boundary, 1), bending(P, n, boundary, 2)])
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    mixed = pair @ np.array([[c, -s], [s, c]])
    labels = label_modes(P, mixed)
    assert sorted(labels) == [f"bending-y {n}", f"bending-z {n}"]
    # each mode gets the label of the pure mode it overlaps most (ties at exactly 45 deg either way)
    if abs(abs(c) - abs(s)) > 1e-6:
        assert labels[0] == (f"bending-y {n}" if abs(c) > abs(s) else f"bending-z {n}")


def test_pair_next_to_other_modes(beam_points):
    """A mixed pair inside a list of other modes: only the pair is rotated."""
    P = beam_points
    c, s = np.cos(0.8), np.sin(0.8)
    b1 = np.column_stack([bending(P, 1, "clamped-free", 1), bending(P, 1, "clamped-free", 2)]) @ [[c, -s], [s, c]]
    b2 = np.column_stack([bending(P, 2, "clamped-free", 1), bending(P, 2, "clamped-free", 2)]) @ [[s, c], [-c, s]]
    S = np.column_stack([b1, b2, torsion(P, 1, "clamped-free")])
    labels = label_modes(P, S)
    assert sorted(labels[:2]) == ["bending-y 1", "bending-z 1"]
    assert sorted(labels[2:4]) == ["bending-y 2", "bending-z 2"]
    assert labels[4] == "torsion 1"


def test_rectangular_section_in_rotated_frame():
    """A 30 x 20 mm beam rotated off the global axes: labels use local names a, t1 (wide), t2."""
    P0 = grid((L, 0.03, 0.02), (61, 7, 5))
    S0 = [bending(P0, 2, "clamped-free", 1), bending(P0, 1, "clamped-free", 2), torsion(P0, 1, "clamped-free"),
          axial(P0, 2, "free-free")]
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("xyz", [25, 40, -15], degrees=True).as_matrix()
    P = P0 @ R.T + np.array([0.3, -1.0, 2.0])
    S = np.column_stack([(s.reshape(-1, 3) @ R.T).ravel() for s in S0])
    assert body_frame(P).names == ("a", "t1", "t2")
    assert label_modes(P, S) == ("bending-t1 2", "bending-t2 1", "torsion 1", "axial 2")


def test_beam_along_z_uses_global_names():
    P0 = grid()
    perm = [1, 2, 0]  # old x -> new z, old y -> new x, old z -> new y
    P = P0[:, perm]
    S0 = [bending(P0, 1, "clamped-free", 1), bending(P0, 3, "clamped-free", 2)]
    S = np.column_stack([s.reshape(-1, 3)[:, perm].ravel() for s in S0])
    assert label_modes(P, S) == ("bending-x 1", "bending-y 3")


def test_noise_is_mixed(beam_points):
    rng = np.random.default_rng(0)
    S = rng.standard_normal((3 * len(beam_points), 3))
    assert label_modes(beam_points, S) == ("mixed",) * 3


# ----------------------------------------------------------------------------- plates
def plate_field(P, w, wx, wy):
    """Kirchhoff plate kinematics: u = (-z w_x, -z w_y, w)."""
    z = P[:, 2]
    return np.column_stack([-z * wx, -z * wy, w]).ravel()


def test_plate_labels_count_nodal_lines():
    a, b, t = 0.4, 0.3, 0.004
    P = grid((a, b, t), (41, 31, 3), origin=(0.0, 0.0, -t / 2))
    x, y = P[:, 0], P[:, 1]
    fields = []
    # twisting mode of a free plate: w = (x - a/2)(y - b/2), nodal lines on both centre lines -> (1,1)
    fields.append(plate_field(P, (x - a / 2) * (y - b / 2), y - b / 2, x - a / 2))
    # simply supported (m, n) half-waves -> (m - 1, n - 1) interior nodal lines
    for m, n in ((2, 1), (3, 2), (1, 3)):
        kx, ky = m * np.pi / a, n * np.pi / b
        w = np.sin(kx * x) * np.sin(ky * y)
        fields.append(plate_field(P, w, kx * np.cos(kx * x) * np.sin(ky * y), ky * np.sin(kx * x) * np.cos(ky * y)))
    # an in-plane (membrane) mode
    fields.append(np.column_stack([np.sin(np.pi * x / a), np.zeros_like(x), np.zeros_like(x)]).ravel())
    labels = label_modes(P, np.column_stack(fields))
    assert labels == ("plate (1,1)", "plate (1,0)", "plate (2,1)", "plate (0,2)", "in-plane")
    f = mode_fractions(P, np.column_stack(fields))
    assert f[1]["plate"] > 0.99 and f[4]["in-plane"] > 0.99


# ----------------------------------------------------------------------------- errors
def test_bad_input(beam_points):
    P = beam_points
    with pytest.raises(InputError):
        label_modes(P, np.zeros((3 * len(P) + 1, 2)))
    with pytest.raises(InputError):
        label_modes(P[:, :2], np.zeros((2 * len(P), 1)))
    with pytest.raises(InputError):
        label_modes(P, np.zeros((3 * len(P), 1)), kind="shell")
    with pytest.raises(InputError):
        label_modes(P, np.zeros((3 * len(P), 1)), threshold=0.3)
    with pytest.raises(InputError):
        label_modes(P, np.full((3 * len(P), 1), np.nan))


def test_zero_mode_is_mixed(beam_points):
    assert label_modes(beam_points, np.zeros((3 * len(beam_points), 1))) == ("mixed",)


# ----------------------------------------------------------------------------- end to end
def test_end_to_end_rectangular_cantilever_follows_theory_order():
    """30 x 20 mm cantilever: labels of the computed modes, in frequency order, are the order theory
    predicts (Euler-Bernoulli for y and z bending, St-Venant torsion)."""
    import math

    import modalfem
    from modalfem import STEEL, theory
    from modalfem.mesh import box

    res = modalfem.modes(box(size=(1.0, 0.03, 0.02), cells=(30, 3, 2)), STEEL, k=8, fixed="x0",
                         backend="skfem", solver="scipy")
    sec = theory.rectangle_section(0.03, 0.02)
    ref = [(w, f"bending-{d} {n}") for d in "yz"
           for n, w in enumerate(theory.euler_bernoulli_omegas(STEEL, 1.0, sec, direction=d, count=5), start=1)]
    ref.append((theory.torsion_omegas(STEEL, 1.0, sec, count=1)[0], "torsion 1"))
    expect = tuple(label for _, label in sorted(ref))[:8]
    assert res.labels == expect
    assert res.labels == label_modes(res.dof_points, res.shapes)
    assert math.isclose(res.frequencies_hz[1] / res.frequencies_hz[0], 1.5, rel_tol=0.01)  # I_yy / I_zz = 2.25


def test_end_to_end_free_plate():
    """Free 400 x 300 x 4 mm plate: the lowest mode is the twisting mode (nodal lines on both centre
    lines), and the first modes are all out-of-plane plate modes."""
    import modalfem
    from modalfem import STEEL
    from modalfem.mesh import box

    res = modalfem.modes(box(size=(0.4, 0.3, 0.004), cells=(16, 12, 1)), STEEL, k=4, backend="skfem", solver="scipy")
    assert res.labels[0] == "plate (1,1)"
    assert all(label.startswith("plate (") for label in res.labels)
    assert len(set(res.labels)) == len(res.labels)
