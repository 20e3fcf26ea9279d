"""Hard bodies: several free pieces of unequal sizes, very thin free plates, slivers, nearly incompressible
material. Rigid modes come from the mesh's structure (``modalfem.eigen.rigid``), so none of these may
turn an elastic mode into a "rigid" one or lose one.

References are independent of the code under test: dense ``scipy.linalg.eigh`` on each piece's own
matrices, Kirchhoff plate theory (Leissa 1969) and the nu -> 0.5 limit. Tolerances come from the
computation: a dense generalised eigensolver is backward stable, so its eigenvalue error is about
eps * lambda_max (the largest eigenvalue of the same pencil), relative to lambda_j that is
eps * lambda_max / lambda_j; the tests allow 100x that.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg

from modalfem.backends.skfem import assemble as skfem_assemble
from modalfem.material import STEEL, Material
from modalfem.mesh import box
from modalfem.mesh.core import TET_FACES, Mesh
from modalfem.modes import modes

EPS = np.finfo(float).eps


def box_mesh(size, cells, *, origin=(0.0, 0.0, 0.0)) -> Mesh:
    return box(size=size, cells=cells, origin=origin)


def merge_meshes(*meshes: Mesh) -> Mesh:
    """Disjoint union: one Mesh with several pieces."""
    offsets = np.cumsum([0] + [m.point_count for m in meshes[:-1]])
    return Mesh(np.vstack([m.points for m in meshes]), np.vstack([m.cells + o for m, o in zip(meshes, offsets)]))


def _dense_tol(ref: np.ndarray, lam_max: float) -> np.ndarray:
    """Relative error allowed against a dense eigh reference: 100 eps lambda_max / lambda_j (+1e-11)."""
    return 100 * EPS * lam_max / np.abs(ref) + 1e-11


# ---------------------------------------------------------------- several pieces of unequal sizes
PIECES = {
    2: [((0.4, 0.1, 0.1), (8, 2, 2), (0, 0, 0)), ((0.15, 0.15, 0.05), (3, 3, 1), (1, 0, 0))],
    3: [((0.15, 0.15, 0.05), (3, 3, 1), (1, 0, 0)), ((0.05, 0.05, 0.05), (1, 1, 1), (0, 0.5, 0)),
        ((0.4, 0.1, 0.1), (8, 2, 2), (0, 0, 0))],
    10: [((0.05 * (1 + 0.37 * i), 0.05 * (1 + 0.11 * i), 0.04), (2, 2, 1 + i % 2), (0.5 * i, 0, 0)) for i in range(10)],
}
_REF: dict = {}


def _pieces_reference(count: int, degree: int) -> tuple[np.ndarray, float]:
    """Sorted deformation eigenvalues of the union of pieces, each piece solved alone (dense), and the
    largest eigenvalue of them all."""
    if (count, degree) not in _REF:
        lam, top = [], 0.0
        for size, cells, origin in PIECES[count]:
            K, M = skfem_assemble(box_mesh(size, cells, origin=origin), STEEL, degree=degree)
            ev = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True)
            lam.append(ev[6:])
            top = max(top, float(ev[-1]))
        _REF[count, degree] = (np.sort(np.concatenate(lam)), top)
    return _REF[count, degree]


def _solvers():
    out = ["block", "scipy"]
    try:
        import slepc4py  # noqa: F401

        out.append("slepc")
    except ImportError:
        pass
    return out


def _backends():
    return [pytest.param("skfem"), pytest.param("fenicsx", marks=pytest.mark.fenicsx)]


@pytest.mark.parametrize("backend", _backends())
@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("count", [2, 3, 10])
def test_unequal_free_pieces_every_solver_k_1_to_20(count, degree, backend):
    """Each piece has its own 6 rigid modes (6 x count in all), whatever the order of the pieces, the
    solver or k; the deformation modes are the union of the pieces' own."""
    if backend == "fenicsx":
        pytest.importorskip("dolfinx")
    ref, top = _pieces_reference(count, degree)
    meshes = [box_mesh(s, c, origin=o) for s, c, o in PIECES[count]]
    for order in (meshes, meshes[::-1]):
        mesh = merge_meshes(*order)
        assert mesh.piece_count == count
        for solver in _solvers():
            for k in (1, 2, 5, 12, 20):
                with warnings.catch_warnings():
                    warnings.simplefilter("error")  # no "mechanism" or certificate warning
                    res = modes(mesh, STEEL, k=k, degree=degree, backend=backend, solver=solver)
                assert res.rigid_mode_count == 6 * count, (solver, k)
                assert res.certificate.passed, (solver, k, res.certificate)
                assert res.certificate.rigid_coupling <= 1e-8
                err = np.abs(res.eigenvalues / ref[:k] - 1)
                assert np.all(err <= _dense_tol(ref[:k], top)), (solver, k, err)


# ---------------------------------------------------------------- very thin free plates
#: Leissa (1969), free square plate, nu = 0.3: omega a^2 sqrt(rho t / D) of the first five modes
LEISSA_FREE_SQUARE = np.array([13.468, 19.596, 24.270, 34.801, 34.801])


@pytest.mark.parametrize("solver", ["block", "scipy"])
def test_thin_free_plates_keep_their_first_modes(solver):
    """A free 10 m square steel plate at a/t = 200, 1000 and 2000: exactly 6 rigid modes, the certificate
    passes, and the Kirchhoff frequency parameters are the same at every thickness (the thin limit) and
    within the 8 x 8 P2 mesh's discretisation error (measured +1.0 to +4.5 %) of Leissa's values."""
    a = 10.0
    params = []
    for ratio in (200, 1000, 2000):
        t = a / ratio
        mesh = box_mesh((a, a, t), (8, 8, 1))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            res = modes(mesh, STEEL, k=5, degree=2, backend="skfem", solver=solver)
        assert res.rigid_mode_count == 6 and res.certificate.passed, (ratio, res.certificate)
        D = STEEL.E * t**3 / (12 * (1 - STEEL.nu**2))
        params.append(res.omega * a * a * np.sqrt(STEEL.rho * t / D))
    params = np.array(params)
    np.testing.assert_allclose(params[1:], params[[0, 0]], rtol=5e-3)  # the thin limit: no drift with 1/t
    rel = params / LEISSA_FREE_SQUARE - 1
    assert np.all(rel > 0) and np.all(rel < 0.05), rel  # P2 tets are stiff, never below the continuum


# ---------------------------------------------------------------- slivers
def _quality(points, cells) -> np.ndarray:
    """6 sqrt(2) V / l_rms^3 per tet: 1 for a regular tetrahedron, -> 0 for a sliver."""
    p = points[cells]
    v = np.abs(np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])) / 6
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    l2 = sum(((p[:, i] - p[:, j]) ** 2).sum(axis=1) for i, j in pairs) / 6
    return 6 * np.sqrt(2) * v / l2**1.5


def _sliver_box(offset: float) -> Mesh:
    """A 0.2 x 0.1 x 0.1 m box whose Kuhn tets are kept except one face flip (2 tets -> 3 around the
    segment joining their apexes). That segment passes through the midpoint of an edge of the shared
    face; moving one apex by ``offset`` (relative) makes the tet holding that edge a sliver of volume
    ~ offset. An ordinary body, meshed with one sliver."""
    m = box_mesh((0.2, 0.1, 0.1), (4, 2, 2))
    P, C = m.points.copy(), m.cells
    faces = np.sort(C[:, TET_FACES].reshape(-1, 3), axis=1)
    keys, inv, counts = np.unique(faces, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    for f in np.flatnonzero(counts == 2):
        ca, cb = np.flatnonzero(inv == f) // 4
        face = keys[f]
        da = int(np.setdiff1d(C[ca], face)[0])
        db = int(np.setdiff1d(C[cb], face)[0])
        A, B, Cc = P[face]
        n = np.cross(B - A, Cc - A)
        s = np.dot(A - P[da], n) / np.dot(P[db] - P[da], n)
        x = P[da] + s * (P[db] - P[da])
        bc = np.linalg.solve(np.column_stack([B - A, Cc - A, n]), x - A)
        bary = np.array([1 - bc[0] - bc[1], bc[0], bc[1]])
        if np.sum(np.abs(bary) < 1e-12) == 1 and np.all(bary > -1e-12):
            break
    else:  # pragma: no cover - the box generator always has such faces
        raise AssertionError("no face to flip")
    tip = face[np.abs(bary) < 1e-12][0]
    rest = face[np.abs(bary) >= 1e-12]
    P[db] += offset * (P[tip] - 0.5 * (P[rest[0]] + P[rest[1]]))
    keep = np.ones(len(C), dtype=bool)
    keep[[ca, cb]] = False
    new = np.array([[face[i], face[(i + 1) % 3], da, db] for i in range(3)])
    cells = np.vstack([C[keep], new])
    p = P[cells]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])
    cells[vol < 0] = cells[vol < 0][:, [0, 2, 1, 3]]
    return Mesh(P, cells)


@pytest.mark.parametrize("offset", [1e-4, 1e-8])
@pytest.mark.parametrize("solver", _solvers())
def test_sliver_does_not_turn_elastic_modes_rigid(solver, offset):
    """Worst quality ~offset. At 1e-8, K_ii / M_ii reaches ~4e19, so the old shift floor (1e-9 of it) sat
    20x above the first elastic eigenvalue and the modes below it were counted as rigid. Now: 6 rigid
    modes and the 10 lowest elastic ones, matching a dense solve of the same pencil."""
    mesh = _sliver_box(offset)
    q = _quality(mesh.points, mesh.cells)
    assert q.min() < 1e-4
    K, M = skfem_assemble(mesh, STEEL, degree=2)
    ref = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    if offset < 1e-6:
        assert 1e-9 * np.max(K.diagonal() / M.diagonal()) > 10 * ref[6]  # as hard as the CAD part
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = modes(mesh, STEEL, k=10, degree=2, backend="skfem", solver=solver)
    assert res.rigid_mode_count == 6 and res.certificate.passed
    np.testing.assert_array_less(np.abs(res.eigenvalues / ref[6:16] - 1), _dense_tol(ref[6:16], ref[-1]))


# ---------------------------------------------------------------- nearly incompressible
def test_nearly_incompressible_cube_has_six_rigid_modes_and_a_limit():
    """nu up to 0.4999999999 (lambda / mu ~ 5e9): 6 rigid modes, never a "mechanism", a passed
    certificate, and frequencies that converge as nu -> 0.5 (the discrete problem's limit: they change
    like 1 / lambda, so 0.4999999 and 0.4999999999 agree to ~1e-6)."""
    mesh = box_mesh((0.1, 0.1, 0.1), (3, 3, 3))
    f = {}
    for nu in (0.49, 0.4999, 0.4999999, 0.4999999999):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            res = modes(mesh, Material(E=200e9, nu=nu, rho=7850.0), k=6, degree=2, backend="skfem")
        assert res.rigid_mode_count == 6 and res.certificate.passed, (nu, res.certificate)
        f[nu] = res.frequencies_hz
    np.testing.assert_allclose(f[0.4999999999], f[0.4999999], rtol=1e-5)
    assert np.all(np.abs(f[0.4999] / f[0.4999999] - 1) < 1e-2)


# ---------------------------------------------------------------- tiny or huge matrix entries
@pytest.mark.parametrize("solver", ["block", "scipy"])
def test_pencil_scale_does_not_matter(solver):
    """A 0.1 mm cantilever with E from 1e-14 to 1e-7 Pa (stiffness entries ~1e-19..1e-12): the pencil is
    solved in units where its largest diagonal entries are 1, so omega scales exactly as sqrt(E / rho)
    (before, PARDISO's absolute pivot thresholds made E = 1e-12..1e-10 Pa 4-10x off)."""
    mesh = box_mesh((1e-4, 2e-5, 2e-5), (6, 2, 2))
    ref = modes(mesh, Material(E=1.0, nu=0.3, rho=1.0), k=3, fixed="x0", backend="skfem", solver=solver)
    for E in (1e-14, 1e-12, 1e-10, 1e-7, 1e7):
        res = modes(mesh, Material(E=E, nu=0.3, rho=1.0), k=3, fixed="x0", backend="skfem", solver=solver)
        assert res.certificate.passed, E
        np.testing.assert_allclose(res.omega, ref.omega * np.sqrt(E), rtol=1e-9)
