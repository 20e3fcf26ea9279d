"""The public ``modes``: rigid counts found with no user shift, certificate, shapes, validation."""

import warnings

import numpy as np
import pytest
import scipy.linalg
from _eigen_bounds import dense_bounds, residual_bounds

import modalfem
from modalfem.constraints import Fix
from modalfem.errors import ConstraintError, InputError, SolverError
from modalfem.mesh.core import Mesh
from modalfem.modes import modes

PLATE_Z = [Fix(t, components="z") for t in ("x0", "x1", "y0", "y1")]


@pytest.mark.parametrize(
    "mesh_name, fixed, rigid",
    [("beam", None, 6), ("beam", "x0", 0), ("plate", PLATE_Z, 3), ("two_cubes", None, 12)],
)
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("solver", ["scipy", "block"])
def test_rigid_counts_found_and_certified(request, mesh_name, fixed, rigid, degree, solver, steel, assemble_km):
    mesh = request.getfixturevalue(mesh_name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no rigid-count mismatch warning
        res = modes(mesh, steel, k=5, degree=degree, fixed=fixed, backend="skfem", solver=solver)
    assert res.solver == solver
    assert res.rigid_mode_count == rigid == res.info["rigid_expected"]
    assert res.rigid_shapes.shape == (3 * mesh.node_count(degree), rigid)
    assert res.certificate.passed, res.certificate.to_dict()
    assert res.info["shift"] < 0
    assert len(res.omega) == 5 and np.all(np.diff(res.omega) >= 0) and res.omega[0] > 0
    assert len(res.labels) == 5
    # shapes over all DOFs: zero on fixed DOFs, mass-normalised with the rigid modes
    assert np.all(res.shapes[res.fixed_dofs] == 0)
    K, M = assemble_km(mesh, steel, degree=degree)
    Phi = np.hstack([res.rigid_shapes, res.shapes])
    np.testing.assert_allclose(Phi.T @ (M @ Phi), np.eye(rigid + 5), atol=1e-9)
    np.testing.assert_allclose(np.einsum("ij,ij->j", res.shapes, K @ res.shapes), res.eigenvalues, rtol=1e-9)


def test_square_beam_pairs_and_public_entry(beam, steel):
    calls = []
    res = modalfem.modes(beam, steel, k=4, fixed="x0", backend="skfem", solver="scipy", progress=calls.append)
    assert modalfem.modes(beam, steel, k=1, fixed="x0", backend="skfem", solver="scipy").certificate.passed
    assert res.certificate.pairs == ((0, 1), (2, 3))
    stages = [c.split(" ")[0] for c in calls]
    assert stages[:3] == ["constraints", "assembly", "shift"] and "eigen" in stages
    assert stages.index("eigen") <= 3
    # the progress line states the shift in rad^2/s^2, not in the solver's scaled units
    shown = float(next(c for c in calls if c.startswith("eigen")).split("shift=")[1].split()[0])
    assert shown == pytest.approx(res.info["shift"], rel=1e-3)
    assert calls[-1].startswith("done")
    for key in ("assembly", "constraints", "eigen", "certificate", "labels", "total"):
        assert res.timings[key] >= 0
    assert {"numpy", "scipy"} <= set(res.info["versions"]) and res.info["n_free"] == int((~res.fixed_dofs).sum())


@pytest.mark.parametrize("solver", ["scipy", "block", "slepc"])
def test_one_rule_for_k_on_tiny_problems(cube, steel, solver, assemble_km):
    """A free body has n_free - 6 deformation modes: every k up to that is solved and certified (the
    last ones by an inertia shift above the whole spectrum), one more is refused with the same limit."""
    if solver == "slepc":
        pytest.importorskip("slepc4py")
    n_free = 3 * cube.node_count(1)
    K, M = assemble_km(cube, steel, degree=1)
    ref = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True)[6:]
    for k in (1, 2, 3, n_free - 7, n_free - 6):
        res = modes(cube, steel, k=k, degree=1, backend="skfem", solver=solver)
        assert res.certificate.passed and res.rigid_mode_count == 6
        # within both results' own error bounds (tests/eigen/_eigen_bounds.py), not a tolerance from one CPU
        bound = residual_bounds(K, M, res.shapes, res.eigenvalues) + dense_bounds(K, M, ref[:k])
        assert np.all(np.abs(res.eigenvalues - ref[:k]) <= bound), (k, res.eigenvalues - ref[:k], bound)
    with pytest.raises(SolverError, match=rf"k={n_free - 5} exceeds the {n_free - 6} deformation modes.*at most {n_free - 6}"):
        modes(cube, steel, k=n_free - 5, degree=1, backend="skfem", solver=solver)


@pytest.mark.parametrize(
    "kwargs, err, match",
    [
        (dict(k=0), InputError, "k must be"),
        (dict(k=2.0), InputError, "k must be"),
        (dict(k=True), InputError, "k must be"),
        (dict(k=2, degree=3), InputError, "degree"),
        (dict(k=2, solver="arpack"), InputError, "unknown solver"),
        (dict(k=2, backend="ansys"), InputError, "unknown backend"),
        (dict(k=2, tol=0.0), InputError, "tol"),
        (dict(k=2, fixed="left"), ConstraintError, "unknown tag"),
        (dict(k=2, fixed=lambda p: p[:, 0] < -1), ConstraintError, "selects no nodes"),
    ],
)
def test_invalid_arguments(cube, steel, kwargs, err, match):
    kwargs = {"backend": "skfem", "solver": "scipy", **kwargs}
    with pytest.raises(err, match=match):
        modes(cube, steel, **kwargs)


def test_wrong_types(cube, steel):
    with pytest.raises(InputError, match="Material"):
        modes(cube, {"E": 1}, k=2)
    with pytest.raises(InputError, match="Mesh"):
        modes("cube.msh", steel, k=2)


@pytest.mark.parametrize("solver", ["scipy", "block"])
@pytest.mark.parametrize("hinge, origin, extra, where", [
    ("vertex", (0.1, 0.1, 0.1), 3, r"at vertex \d+ \(0\.1, 0\.1, 0\.1\)"),
    ("edge", (0.1, 0.1, 0.0), 1, r"at a line of edges \(an edge hinge\) through 2 vertices"),
])
def test_mechanism_is_reported_where_it_hinges(make_box, steel, hinge, origin, extra, where, solver):
    """Two cubes touching at one vertex (or along one edge) are one piece (6 rigid modes) with a hinge:
    3 (or 1) more zero-energy motions. Found from the structure, named, and the certificate fails."""
    a = make_box((0.1, 0.1, 0.1), (1, 1, 1))
    b = make_box((0.1, 0.1, 0.1), (1, 1, 1), origin=origin)
    pts = np.vstack([a.points, b.points])
    _, first, inv = np.unique(np.round(pts, 12), axis=0, return_index=True, return_inverse=True)
    mesh = Mesh(pts[first], inv.ravel()[np.vstack([a.cells, b.cells + a.point_count])])
    assert mesh.piece_count == 1
    with pytest.warns(RuntimeWarning, match=rf"mechanism: piece 0 is 2 parts joined only {where}.* "
                                            rf"hinge with {extra} free motion.*{6 + extra} zero-frequency modes where 6"):
        res = modes(mesh, steel, k=2, degree=1, backend="skfem", solver=solver)
    assert not res.certificate.passed and res.rigid_mode_count == 6 + extra
    assert res.info["rigid_expected"] == 6 and len(res.info["mechanisms"]) == 1
    # the elastic modes are still right: both cubes' deformation modes (K restricted off the hinge motions)
    K, M = _assemble(mesh, steel)
    ref = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    np.testing.assert_allclose(res.eigenvalues, ref[6 + extra : 8 + extra], rtol=1e-8)


@pytest.mark.fenicsx
def test_modalfem_warning_is_a_python_warning_after_a_fenicsx_solve(make_box, steel):
    """FFCx's JIT switches Python warnings to logging; after a FEniCSx solve modalfem's own warning (here
    the mechanism of two cubes sharing a vertex) must still be a warning pytest.warns sees."""
    pytest.importorskip("dolfinx")
    modes(make_box((0.1, 0.1, 0.1), (1, 1, 1)), steel, k=1, degree=2, backend="fenicsx")  # JIT first
    a = make_box((0.1, 0.1, 0.1), (1, 1, 1))
    b = make_box((0.1, 0.1, 0.1), (1, 1, 1), origin=(0.1, 0.1, 0.1))
    pts = np.vstack([a.points, b.points])
    _, first, inv = np.unique(np.round(pts, 12), axis=0, return_index=True, return_inverse=True)
    mesh = Mesh(pts[first], inv.ravel()[np.vstack([a.cells, b.cells + a.point_count])])
    with pytest.warns(RuntimeWarning, match="mechanism: piece 0"):
        modes(mesh, steel, k=2, degree=2, backend="fenicsx")


def _assemble(mesh, material, degree=1):
    from modalfem.backends.skfem import assemble

    return assemble(mesh, material, degree=degree)


@pytest.mark.fenicsx
def test_fenicsx_slepc_agrees_with_skfem_scipy(beam, steel):
    pytest.importorskip("dolfinx")
    pytest.importorskip("modalfem.eigen.slepc")
    a = modes(beam, steel, k=4, fixed="x0", backend="fenicsx", solver="slepc")
    b = modes(beam, steel, k=4, fixed="x0", backend="skfem", solver="scipy")
    assert a.certificate.passed and b.certificate.passed
    np.testing.assert_allclose(a.omega, b.omega, rtol=1e-6)


@pytest.mark.fenicsx
def test_slepc_finds_twelve_rigid_modes_of_two_pieces(two_cubes, steel):
    pytest.importorskip("dolfinx")
    pytest.importorskip("modalfem.eigen.slepc")
    res = modes(two_cubes, steel, k=3, degree=2, backend="fenicsx", solver="slepc")
    assert res.rigid_mode_count == 12 and res.certificate.passed


def test_restrict_equals_fancy_indexing():
    import scipy.sparse as sp

    from modalfem.modes import restrict

    rng = np.random.default_rng(5)
    A = sp.random(60, 60, density=0.2, random_state=5, format="csr")
    A = A + A.T
    keep = rng.random(60) > 0.3
    B = restrict(A, keep)
    ref = A[keep][:, keep].tocsr()
    assert B.shape == ref.shape and B.has_sorted_indices
    np.testing.assert_array_equal(B.toarray(), ref.toarray())
    assert restrict(A, np.zeros(60, bool)).shape == (0, 0)


def test_auto_solver_is_block_on_pardiso_in_one_process_and_slepc_under_mpi(monkeypatch):
    import sys

    mod = sys.modules["modalfem.modes"]  # the module (``modalfem.modes`` the attribute is the function)
    monkeypatch.setattr(mod, "_have_pardiso", lambda: True)
    monkeypatch.setattr("modalfem.backends.have_slepc", lambda: True)
    monkeypatch.setattr(mod, "_world_size", lambda: 1)
    assert mod._pick_solver("auto") == "block"
    monkeypatch.setattr(mod, "_world_size", lambda: 2)
    assert mod._pick_solver("auto") == "slepc"
    monkeypatch.setattr(mod, "_have_pardiso", lambda: False)
    monkeypatch.setattr(mod, "_world_size", lambda: 1)
    assert mod._pick_solver("auto") == "slepc"  # MUMPS
    monkeypatch.setattr("modalfem.backends.have_slepc", lambda: False)
    assert mod._pick_solver("auto") == "scipy"
    assert mod._pick_solver("block") == "block"
    with pytest.raises(InputError, match="unknown solver"):
        mod._pick_solver("lanczos")
