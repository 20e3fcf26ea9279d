"""Rayleigh-Ritz trial fields over the spatial coordinate, and their reduced matrices in UFL.

A Ritz field is a smooth displacement ``B_I(x) = w(x) m_a(xi) e_c`` [m per unit coordinate]: one
component ``e_c`` (c = x, y, z) times one monomial ``m_a`` of the scaled coordinate
``xi = (x - centre) / scale`` (centre and half the largest extent of the body's bounding box, so that
``|xi| <= 1``: well-conditioned products), times an optional clamp weight ``w = (x_k - x_clamp) /
scale`` that makes every field vanish on the plane ``x_k = x_clamp`` (a clamped end).

* ``affine``: monomials ``1, x, y, z``: 12 fields; they span the 6 rigid motions and all uniform
  strains.
* ``quadratic``: affine plus ``x^2, y^2, z^2, xy, yz, zx``: 30 fields.

Field ``I = n_monomials * c + a`` (component-major). The reduced stiffness ``K_r[I, J] = int
sigma(B_J) : eps(B_I) dx`` [N/m] and mass ``M_r[I, J] = int rho B_I . B_J dx`` [kg] come from the same
energy densities as the full-FEM forms (``elastic_energy_density`` and ``kinetic_density`` of
``modalfem.forms.ufl_elasticity`` / ``skfem_elasticity``), integrated exactly: the fields are
polynomials of degree ``p`` (1 or 2, plus 1 with a clamp) so quadrature of degree ``2 p`` (mass) and
``2 (p - 1)`` (stiffness) on affine tetrahedra is exact.

UFL path (``reduced_matrices_ufl``): all upper-triangle entries of ``K_r`` and ``M_r`` form one
vector-valued UFL expression evaluated at the quadrature points of every cell by a single compiled
``dolfinx.fem.Expression`` (one JIT compilation per basis kind, cached; material constants and the
frame enter as ``Constant``), then weighted and summed. The scikit-fem equivalent is
``modalfem.forms.skfem_ritz``. This module imports ufl/dolfinx only inside the UFL functions, so the
numpy part (``monomials``, ``RitzFrame``, ``evaluate_fields``) works in a pip-only environment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = [
    "KINDS",
    "RitzFrame",
    "evaluate_fields",
    "field_count",
    "field_degree",
    "frame_for",
    "monomials",
    "reduced_matrices_ufl",
    "rigid_coefficients",
    "ufl_fields",
]

_AFFINE = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1))
_QUADRATIC = _AFFINE + ((2, 0, 0), (0, 2, 0), (0, 0, 2), (1, 1, 0), (0, 1, 1), (1, 0, 1))
#: basis kind -> exponents (a, 3) of the monomials of xi
KINDS = {"affine": _AFFINE, "quadratic": _QUADRATIC}


def monomials(kind: str) -> tuple[tuple[int, int, int], ...]:
    """Exponents of the monomials of basis ``kind`` (``"affine"``: 4, ``"quadratic"``: 10).

    Raises:
        InputError: unknown kind.
    """
    if kind not in KINDS:
        raise InputError(f"unknown Ritz basis {kind!r}; choose one of: {', '.join(KINDS)}")
    return KINDS[kind]


def field_count(kind: str) -> int:
    """Number of Ritz fields: 3 components x monomials (12 affine, 30 quadratic)."""
    return 3 * len(monomials(kind))


@dataclass(frozen=True)
class RitzFrame:
    """Coordinate frame of the Ritz fields.

    Attributes:
        centre: centre of the body's bounding box (3,) [m].
        scale: half the largest bounding-box extent [m] (``xi = (x - centre) / scale``).
        clamp: None, or ``(axis, coordinate [m])``: fields are multiplied by
            ``(x[axis] - coordinate) / scale`` and vanish on that plane.
    """

    centre: tuple[float, float, float]
    scale: float
    clamp: tuple[int, float] | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise InputError(f"Ritz frame scale must be a positive length [m], got {self.scale!r}")
        if self.clamp is not None and (int(self.clamp[0]) not in (0, 1, 2) or not np.isfinite(self.clamp[1])):
            raise InputError(f"clamp must be (axis 0/1/2, coordinate [m]), got {self.clamp!r}")


def frame_for(points: np.ndarray, *, clamp: tuple[int, float] | None = None) -> RitzFrame:
    """The Ritz frame of a body from its points (n, 3) [m] (see ``RitzFrame``)."""
    p = np.asarray(points, dtype=np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    clamp = None if clamp is None else (int(clamp[0]), float(clamp[1]))
    return RitzFrame(tuple(float(c) for c in centre), float(0.5 * np.max(hi - lo)), clamp)


def field_degree(kind: str, frame: RitzFrame) -> int:
    """Polynomial degree of the fields (1 affine, 2 quadratic; +1 with a clamp weight)."""
    return max(sum(e) for e in monomials(kind)) + (0 if frame.clamp is None else 1)


def evaluate_fields(kind: str, frame: RitzFrame, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ritz fields and their gradients at points.

    Args:
        kind: ``"affine"`` or ``"quadratic"``.
        frame: the ``RitzFrame``.
        x: points (3, ...) [m] (coordinate first).

    Returns:
        ``(values, grads)``: values (F, 3, ...) [-] (field I, component c) and gradients
        (F, 3, 3, ...) [1/m] with ``grads[I, c, j] = d B_I,c / d x_j``.
    """
    x = np.asarray(x, dtype=np.float64)
    shape = x.shape[1:]
    c = np.asarray(frame.centre).reshape((3,) + (1,) * len(shape))
    s = frame.scale
    xi = (x - c) / s
    mono = monomials(kind)
    nm = len(mono)
    m = np.empty((nm,) + shape)
    dm = np.zeros((nm, 3) + shape)  # d m / d xi_j
    for a, e in enumerate(mono):
        m[a] = np.prod([xi[j] ** e[j] for j in range(3)], axis=0)
        for j in range(3):
            if e[j]:
                ej = list(e)
                ej[j] -= 1
                dm[a, j] = e[j] * np.prod([xi[i] ** ej[i] for i in range(3)], axis=0)
    dm /= s  # d / d x
    if frame.clamp is not None:
        k, x0 = frame.clamp
        w = (x[k] - x0) / s
        dm = dm * w
        dm[:, k] += m / s
        m = m * w
    values = np.zeros((3 * nm, 3) + shape)
    grads = np.zeros((3 * nm, 3, 3) + shape)
    for comp in range(3):
        values[comp * nm : (comp + 1) * nm, comp] = m
        grads[comp * nm : (comp + 1) * nm, comp] = dm
    return values, grads


def rigid_coefficients(kind: str, frame: RitzFrame) -> np.ndarray:
    """Coefficients (F, 6) of the rigid motions in the fields (free bodies only).

    Columns: translations along x, y, z (1 m), then infinitesimal rotations about x, y, z through the
    frame centre (``u = e_k x (x - centre)``, 1 rad). They are exact: the affine monomials ``1`` and
    ``xi_j`` are fields of every basis.

    Raises:
        InputError: the frame has a clamp (no rigid motion is admissible).
    """
    if frame.clamp is not None:
        raise InputError("a clamped Ritz frame admits no rigid motion")
    nm = len(monomials(kind))
    R = np.zeros((3 * nm, 6))
    for c in range(3):
        R[c * nm, c] = 1.0  # translation: monomial 1 of component c
    for k in range(3):  # rotation about axis k: u = s e_k x xi, monomial xi_j sits at index 1 + j
        for c in range(3):
            for j in range(3):
                eps = np.cross(np.eye(3)[k], np.eye(3)[j])[c]  # (e_k x e_j)_c
                if eps:
                    R[c * nm + 1 + j, 3 + k] = eps * frame.scale
    return R


# ------------------------------------------------------------------------------------------ UFL
def ufl_fields(kind: str, x, centre, scale, weight) -> list:
    """Ritz fields as UFL vector expressions of the spatial coordinate.

    Args:
        kind: ``"affine"`` or ``"quadratic"``.
        x: ``ufl.SpatialCoordinate`` of the domain [m].
        centre: UFL vector (3,) [m] (e.g. a dolfinx ``Constant``).
        scale: UFL scalar [m].
        weight: UFL scalar [-] multiplying every field: the clamp weight ``(x[k] - x_clamp) / scale``,
            or a domain ``Constant`` equal to 1 (UFL needs a domain to differentiate a constant).

    Returns:
        list of ``field_count(kind)`` UFL vector expressions, field ``I = n_monomials * c + a``.
    """
    import ufl

    xi = [(x[j] - centre[j]) / scale for j in range(3)]
    fields = []
    for comp in range(3):
        for e in monomials(kind):
            m = weight
            for j in range(3):
                for _ in range(e[j]):
                    m = m * xi[j]
            vec = [m if i == comp else ufl.zero() for i in range(3)]
            fields.append(ufl.as_vector(vec))
    return fields


_EXPRESSIONS: dict = {}
#: values per chunk of cells evaluated by the Expression
_EVAL_VALUES = 5_000_000


def _expression(kind: str, dmesh, clamp_axis: int | None, quad_degree: int):
    """Compiled dolfinx Expression of the upper triangles of K_r and M_r integrands (cached per mesh)."""
    import basix
    import dolfinx.fem
    import ufl
    from modalfem.forms.ufl_elasticity import elastic_energy_density, kinetic_density
    from petsc4py import PETSc

    key = (id(dmesh), kind, clamp_axis, quad_degree)
    if key in _EXPRESSIONS:
        return _EXPRESSIONS[key]
    consts = {
        "centre": dolfinx.fem.Constant(dmesh, np.zeros(3, dtype=PETSc.ScalarType)),
        "scale": dolfinx.fem.Constant(dmesh, PETSc.ScalarType(1.0)),
        "clamp": dolfinx.fem.Constant(dmesh, PETSc.ScalarType(0.0)),
        "mu": dolfinx.fem.Constant(dmesh, PETSc.ScalarType(1.0)),
        "lam": dolfinx.fem.Constant(dmesh, PETSc.ScalarType(1.0)),
        "rho": dolfinx.fem.Constant(dmesh, PETSc.ScalarType(1.0)),
        "one": dolfinx.fem.Constant(dmesh, PETSc.ScalarType(1.0)),
    }
    x = ufl.SpatialCoordinate(dmesh)
    if clamp_axis is None:
        weight = consts["one"]
    else:
        weight = (x[clamp_axis] - consts["clamp"]) / consts["scale"]
    B = ufl_fields(kind, x, consts["centre"], consts["scale"], weight)
    n = len(B)
    iu = np.triu_indices(n)
    detJ = abs(ufl.JacobianDeterminant(dmesh))
    entries = [elastic_energy_density(B[j], B[i], consts["mu"], consts["lam"]) * detJ for i, j in zip(*iu)]
    entries += [kinetic_density(B[i], B[j], consts["rho"]) * detJ for i, j in zip(*iu)]
    points, weights = basix.make_quadrature(basix.CellType.tetrahedron, quad_degree)
    expr = dolfinx.fem.Expression(ufl.as_vector(entries), points)
    _EXPRESSIONS.clear()  # keep one (the dolfinx mesh it refers to may be gone otherwise)
    _EXPRESSIONS[key] = (expr, consts, np.asarray(weights), iu)
    return _EXPRESSIONS[key]


def reduced_matrices_ufl(mesh, material, kind: str, *, frame: RitzFrame | None = None, dmesh=None):
    """Reduced stiffness and mass of the Ritz fields, integrated with dolfinx (UFL).

    Args:
        mesh: ``modalfem.mesh.Mesh`` of the body [m] (its volume is the integration domain).
        material: ``modalfem.Material`` (E [Pa], nu [-], rho [kg/m^3]).
        kind: ``"affine"`` or ``"quadratic"``.
        frame: the ``RitzFrame`` (default ``frame_for(mesh.points)``, no clamp).
        dmesh: optional dolfinx mesh of ``mesh`` to reuse (else one is created, serial).

    Returns:
        ``(K_r, M_r)``: dense symmetric (F, F) arrays, K_r [N/m], M_r [kg].

    Raises:
        InputError: unknown kind. ImportError: dolfinx is not installed.
    """
    from mpi4py import MPI

    frame = frame_for(mesh.points) if frame is None else frame
    p = field_degree(kind, frame)
    if dmesh is None:
        from modalfem.backends.fenicsx import create_function_space

        dmesh = create_function_space(mesh, degree=1, comm=MPI.COMM_SELF, shape=None)[0].mesh
    expr, consts, weights, iu = _expression(kind, dmesh, None if frame.clamp is None else frame.clamp[0], 2 * p)
    consts["centre"].value[:] = frame.centre
    consts["scale"].value = frame.scale
    consts["clamp"].value = 0.0 if frame.clamp is None else frame.clamp[1]
    consts["mu"].value = material.shear_modulus
    consts["lam"].value = material.lame_lambda
    consts["rho"].value = material.rho
    n_cells = dmesh.topology.index_map(3).size_local
    half = len(iu[0])
    step = max(1, _EVAL_VALUES // (2 * half * len(weights)))  # bounds the evaluated array to ~40 MB
    tot = np.zeros(2 * half)
    for start in range(0, n_cells, step):
        cells = np.arange(start, min(start + step, n_cells), dtype=np.int32)
        tot += np.einsum("cqe,q->e", expr.eval(cells).reshape(len(cells), len(weights), -1), weights)
    n = field_count(kind)
    K = np.zeros((n, n))
    M = np.zeros((n, n))
    K[iu] = tot[:half]
    M[iu] = tot[half:]
    K = K + np.triu(K, 1).T
    M = M + np.triu(M, 1).T
    return K, M
