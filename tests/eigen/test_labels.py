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


# ----------------------------------------------------------------------------- beam-/plate-likeness
BEAM_FAMILY = ("bending-", "torsion ", "axial ", "plate (", "in-plane", "mixed")


def _no_family_labels(labels):
    """No beam or plate label (also after a 'piece p: ' prefix)."""
    return not any(lab.split(": ")[-1].startswith(BEAM_FAMILY) for lab in labels)


def test_kind_needs_a_filled_single_prismatic_body():
    """Slender or flat extents alone are not enough: the body must fill its box, be one piece and (beams)
    keep its section width along the axis."""
    bar = grid((1.0, 0.05, 0.05), (21, 2, 2))
    two_bars = np.vstack([bar, bar + [0.0, 0.3, 0.0]])  # flat extents (1 x 0.35 x 0.05): was a "plate"
    f = body_frame(two_bars)
    assert f.kind == "solid" and f.pieces == 2
    # the same cloud with its pieces given
    assert body_frame(two_bars, pieces=np.repeat([0, 1], len(bar))).kind == "solid"
    # one bar, one piece label: still a beam
    assert body_frame(bar, pieces=np.zeros(len(bar), dtype=int)).kind == "beam"
    # an L of two bars in a plane: flat extents, but fills ~1/4 of its box
    arm = grid((0.1, 1.0, 0.1), (3, 21, 3), origin=(0.9, 0.1, 0.0))
    L_shape = np.vstack([grid((1.0, 0.1, 0.1), (21, 3, 3), origin=(0.0, 0.0, 0.0)), arm])
    f = body_frame(L_shape)
    assert f.kind == "solid" and f.fill < 0.5
    # a fork: 20 mm stem then two 4 mm prongs 8 mm apart: slender, but the stem is 1/4 of the width
    stem = grid((0.04, 0.004, 0.004), (21, 3, 3), origin=(0.0, 0.006, 0.0))
    prongs = [grid((0.08, 0.004, 0.004), (41, 3, 3), origin=(0.04, y, 0.0)) for y in (0.0, 0.012)]
    f = body_frame(np.vstack([stem, *prongs]))
    assert f.kind == "solid" and f.slice_width <= 0.5
    # a round rod (unstructured-like rings): fills pi/4 of its box, a beam
    t = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    rings = [np.column_stack([np.full(len(t) + 1, x), r * np.append(np.cos(t), 0.0), r * np.append(np.sin(t), 0.0)])
             for x in np.linspace(0.0, 1.0, 51) for r in (0.02, 0.04)]
    assert body_frame(np.unique(np.vstack(rings), axis=0)).kind == "beam"
    with pytest.raises(InputError):
        body_frame(bar, pieces=np.zeros(len(bar) - 1, dtype=int))
    with pytest.raises(InputError):
        body_frame(bar, pieces=np.full(len(bar), 0.5))


# ----------------------------------------------------------------------------- neutral labels
@pytest.fixture(scope="module")
def cube_points():
    return grid((0.2, 0.2, 0.2), (9, 9, 9), origin=(-0.1, -0.1, 0.0))


def test_neutral_labels_read_the_motion(cube_points):
    """A cube is neither beam nor plate: analytic fields get the label of their kinematics, no number."""
    P = cube_points
    x, y, z = P[:, 0], P[:, 1], P[:, 2] - 0.1  # about the centroid
    o = np.zeros_like(x)
    fields = {
        "breathing": (x, y, z),
        "stretch along x": (x, -0.3 * y, -0.3 * z),  # uniaxial with Poisson contraction
        "shear in x-y": (y, x, o),
        "shear in x-z": (x, o, -z),  # pure shear along the principal strains
        "twist about z": (-z * y, z * x, o),
        "bending about z": (-x * y, 0.5 * x**2, o),  # Euler-Bernoulli: deflection along y growing along x
        "bending about x": (o, 0.5 * z**2, -y * z),  # deflection along y growing along z
        "sway along x": (P[:, 2], o, -x),  # rotation about the base line (y axis at z = 0)
        "rocking about y": (z, o, -x),  # rigid rotation
        "stretch along z": (o, o, P[:, 2]),  # clamped base, stretching from it
    }
    S = np.column_stack([np.column_stack(c).ravel() for c in fields.values()])
    assert label_modes(P, S) == tuple(fields)
    assert label_modes(P, -2.5 * S) == tuple(fields)  # sign and scale do not matter


def test_neutral_axis_named_only_near_a_global_axis(cube_points):
    """Sway along the x = y diagonal (rotation about a base line at 45 degrees): no axis letter; at
    20 degrees from x (cos^2 = 0.88 >= 0.8): named x."""
    P = cube_points
    x, y, z = P[:, 0], P[:, 1], P[:, 2]

    def sway(deg):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        # rotation about the base line along (-s, c, 0) through the origin: u = omega x r
        return np.cross(np.array([-s, c, 0.0]), np.column_stack([x, y, z])).ravel()

    assert label_modes(P, np.column_stack([sway(45.0), sway(20.0)])) == ("sway", "sway along x")


def test_neutral_noise_and_zero_are_mode_numbers(cube_points):
    rng = np.random.default_rng(1)
    n = 3 * len(cube_points)
    S = np.column_stack([rng.standard_normal(n), rng.standard_normal(n), np.zeros(n)])
    assert label_modes(cube_points, S) == ("mode 1", "mode 2", "mode 3")
    assert label_modes(cube_points, S, kind="solid") == ("mode 1", "mode 2", "mode 3")


def test_numbered_labels_are_unique(beam_points):
    """Two modes reading the same beam label: the first keeps it, the second gets its neutral label."""
    P = beam_points
    b1 = bending(P, 1, "free-free", 1)  # deflection along y, mean 0: a rotation about z growing along x
    S = np.column_stack([b1, bending(P, 1, "free-free", 2), 2.0 * b1, torsion(P, 1, "free-free")])
    assert label_modes(P, S) == ("bending-y 1", "bending-z 1", "bending about z", "torsion 1")


# ----------------------------------------------------------------------------- real non-beam bodies
def _solve(mesh, **kw):
    import modalfem
    from modalfem import STEEL

    return modalfem.modes(mesh, STEEL, backend="skfem", solver="scipy", **kw)


def test_bell_gets_neutral_labels():
    """A bell is neither beam nor plate. Its lowest pair is the (2,0) 'ovalling' pair: the rim squeezed
    along one diameter and pushed out along the other, a pure shear in the plane of the rim (x-y)."""
    from modalfem.mesh import bell

    res = _solve(bell(h=0.012), k=8, degree=1)
    labels = label_modes(res.dof_points, res.shapes)
    assert body_frame(res.dof_points).kind == "solid"
    assert _no_family_labels(labels), labels
    assert labels[:2] == ("shear in x-y", "shear in x-y")


def test_tuning_fork_gets_no_beam_labels():
    """The fork is slender (127 x 16 x 6 mm) but a stem and two prongs: no beam-theory family."""
    from modalfem.mesh import tuning_fork

    res = _solve(tuning_fork(h=0.003), k=6, degree=1)
    labels = label_modes(res.dof_points, res.shapes)
    assert body_frame(res.dof_points).kind == "solid"
    assert _no_family_labels(labels), labels


def test_clamped_block_sways_twists_and_stretches():
    """A cube clamped on its base (z = 0): the lowest pair sways sideways (x and y, mixed by the solver),
    then it twists about the vertical axis, then it stretches vertically (shear waves are slower than
    the compression wave, and torsion stiffness sits between the shear-sway and the axial one)."""
    from modalfem.mesh import box

    res = _solve(box((0.1, 0.1, 0.1), (4, 4, 4)), k=4, degree=1, fixed="z0")
    labels = label_modes(res.dof_points, res.shapes)
    assert [lab.split(" along")[0] for lab in labels[:2]] == ["sway", "sway"]
    assert labels[2:] == ("twist about z", "stretch along z")


# ----------------------------------------------------------------------------- pieces
def _two_bars(second_length, gap=0.25, cells=(20, 2, 2)):
    from modalfem.mesh import box
    from modalfem.mesh.core import Mesh

    a = box((1.0, 0.05, 0.04), cells)
    b = box((second_length, 0.05, 0.04), (max(2, round(cells[0] * second_length)), *cells[1:]), origin=(0.0, gap, 0.0))
    return Mesh(np.vstack([a.points, b.points]), np.vstack([a.cells, b.cells + a.point_count]))


def test_two_bars_labelled_per_piece_in_theory_order():
    """Two free-free bars (1.0 m and 0.7 m, 50 x 40 mm): every mode lives in one bar and carries that bar's
    beam label; the order is the Euler-Bernoulli order of both bars together."""
    from modalfem import STEEL, theory
    from modalfem.eigen.rigid import node_pieces

    mesh = _two_bars(0.7)
    res = _solve(mesh, k=6, degree=2)
    labels = label_modes(res.dof_points, res.shapes, pieces=node_pieces(mesh, 2))
    sec = theory.rectangle_section(0.05, 0.04)
    ref = [(w, f"piece {p}: bending-{d} {n}") for p, length in ((0, 1.0), (1, 0.7)) for d in "yz"
           for n, w in enumerate(theory.euler_bernoulli_omegas(STEEL, length, sec, direction=d, boundary="free-free",
                                                                count=3), start=1)]
    assert labels == tuple(lab for _, lab in sorted(ref))[:6]
    # without the piece labels the two bars are never read as one plate or one beam
    plain = label_modes(res.dof_points, res.shapes)
    assert _no_family_labels(plain), plain


def test_identical_bars_mixed_by_the_solver_are_unmixed():
    """Two identical bars: each frequency is double, the solver returns any mix of the two bars' modes.
    The run of shared modes is rotated to one-bar vectors, so the labels still name one bar each."""
    from modalfem.eigen.rigid import node_pieces

    mesh = _two_bars(1.0, cells=(16, 2, 2))
    res = _solve(mesh, k=4, degree=2)
    pieces = node_pieces(mesh, 2)
    c, s = np.cos(0.6), np.sin(0.6)
    mixed = res.shapes.copy()
    mixed[:, :2] = res.shapes[:, :2] @ np.array([[c, -s], [s, c]])  # a 34 degree mix of the first pair
    for S in (res.shapes, mixed):
        labels = label_modes(res.dof_points, S, pieces=pieces)
        assert sorted(labels[:2]) == ["piece 0: bending-z 1", "piece 1: bending-z 1"], labels
        assert sorted(labels[2:]) == ["piece 0: bending-y 1", "piece 1: bending-y 1"], labels
    # an equal mix of both bars that is not part of a splittable run: neutral label of the whole body
    shared = (res.shapes[:, 0] + res.shapes[:, 1])[:, None]
    (lab,) = label_modes(res.dof_points, shared / np.linalg.norm(shared), pieces=pieces)
    assert not lab.startswith("piece") and _no_family_labels([lab])


def test_bad_pieces(beam_points):
    P = beam_points
    with pytest.raises(InputError):
        label_modes(P, np.zeros((3 * len(P), 1)), pieces=np.zeros(len(P) + 1, dtype=int))
