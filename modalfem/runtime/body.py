"""``ModalBody``: the runtime's precomputed view of a ``ModalModel`` (numpy only).

It holds what every step and every reconstruction needs, laid out for speed:

* ``shapes_t`` (r, 3 nv), C-contiguous, modes-major (column ``3 i + c`` = component c of vertex i):
  the surface displacement in body axes is one vector-matrix product ``q @ shapes_t`` streaming the
  matrix once (``modalfem bench runtime`` compares the layouts);
* ``rest`` (nv, 3): rest vertices relative to the centre of mass, body (mesh) axes [m];
* principal axes and moments of the inertia tensor, its inverse, the modal damping.

World positions of the surface are ``x = c + R (X + Phi q)`` with c the centre of mass [m], R the
orientation (body -> world) and X the rest position relative to the centre of mass.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError, SimulationError

__all__ = ["ModalBody", "SurfacePoint", "load"]


@dataclass(frozen=True)
class SurfacePoint:
    """A point of the body surface: a triangle and barycentric coordinates on it.

    Attributes:
        triangle: triangle index into the model's ``triangles``.
        barycentric: (3,) weights of the triangle's vertices, >= 0, summing to 1.
    """

    triangle: int
    barycentric: tuple

    def __post_init__(self) -> None:
        try:
            b = np.asarray(self.barycentric, dtype=np.float64).reshape(3)
        except (TypeError, ValueError):
            raise SimulationError(f"surface point barycentric must be 3 numbers, got {self.barycentric!r}") from None
        if not np.all(np.isfinite(b)):
            raise SimulationError(f"surface point barycentric coordinates are not finite: {b.tolist()}")
        if np.any(b < -1e-9) or abs(b.sum() - 1.0) > 1e-9:
            raise SimulationError(
                f"point off the surface: barycentric {b.tolist()} must be >= 0 and sum to 1 on triangle {self.triangle}")
        object.__setattr__(self, "barycentric", tuple(float(x) for x in b))


class ModalBody:
    """Precomputed runtime data of one modal body.

    Args:
        model: a ``modalfem.model.ModalModel`` (or any object with its attributes).
        damping: Rayleigh coefficients (alpha [1/s], beta [s]) overriding ``model.damping``;
            mode i gets ``mu_i = alpha + beta * omega_i**2`` [1/s].
        dtype: floating type the mode shapes are stored in and the surface is reconstructed in.
            ``np.float32`` (default, what renderers consume) halves the memory traffic of
            ``positions``, the cost that dominates a real-time step, at ~6e-8 relative rounding of
            each shape and position; ``np.float64`` keeps the model's values (entries below 1e-15 of their
            mode's largest are zeroed either way, see ``_flush_tiny``). The modal and
            rigid state are float64 either way; distributed loads are projected in this type.

    Attributes:
        model: the model.
        omega (r,) [rad/s]; mu (r,) [1/s]; mass [kg]; inertia (3, 3) [kg m^2] body axes about the
        centre of mass; inertia_inv (3, 3) [1/(kg m^2)]; principal_axes (3, 3) (columns, body axes,
        right-handed); principal_moments (3,) [kg m^2]; shapes_t (r, 3 nv) [m/sqrt(kg)] (``shapes``
        is its (3 nv, r) transpose);
        rest (nv, 3) [m] rest vertices minus the centre of mass; triangles (nt, 3); radius [m]
        the largest |rest|; coupling: the ``RotationCoupling`` from the model's ``rotation_T`` /
        ``rotation_S`` (used by ``PseudoForces()``), or None when the model has none.
    """

    def __init__(self, model, *, damping=None, dtype=np.float32) -> None:
        self.model = model
        self.omega = np.asarray(model.omega, dtype=np.float64)
        alpha, beta = (model.damping if damping is None else damping)
        alpha, beta = float(alpha), float(beta)
        if not (np.isfinite(alpha) and np.isfinite(beta)) or alpha < 0 or beta < 0:
            raise InputError(f"Rayleigh damping (alpha, beta) must be finite and >= 0, got {(alpha, beta)}")
        self.damping = (alpha, beta)
        self.mu = alpha + beta * self.omega**2
        self.mass = float(model.mass)
        self.inertia = np.asarray(model.inertia, dtype=np.float64)
        self.inertia_inv = np.linalg.inv(self.inertia)
        moments, axes = np.linalg.eigh(self.inertia)
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1.0
        self.principal_moments, self.principal_axes = moments, axes
        self.center_of_mass = np.asarray(model.center_of_mass, dtype=np.float64)
        self.rest = np.ascontiguousarray(np.asarray(model.vertices, dtype=np.float64) - self.center_of_mass)
        self.triangles = np.ascontiguousarray(model.triangles, dtype=np.int64)
        self.radius = float(np.sqrt(np.max(np.einsum("ij,ij->i", self.rest, self.rest))))
        # modes-major (r, 3 nv): u = q @ shapes_t streams each mode's row once (measured 2-3x faster
        # than the (3 nv, r) C layout with OpenBLAS: long contiguous rows instead of r-long dots)
        # The rest shape is one more row, so positions() is a single streaming pass: [q, 1] @ basis.
        dtype = np.dtype(dtype)
        if dtype not in (np.float32, np.float64):
            raise InputError(f"ModalBody dtype must be float32 or float64, got {dtype}")
        r = len(self.omega)
        self._basis = np.empty((r + 1, 3 * len(self.rest)), dtype=dtype)
        self._basis[:r] = np.asarray(model.shapes).T
        self._basis[r] = self.rest.reshape(-1)
        self._row_scale = _flush_tiny(self._basis)
        self.shapes_t = self._basis[:r]  # (r, 3 nv) C-contiguous view
        self._modes3 = self.shapes_t.reshape(r, -1, 3)  # (r, nv, 3) view
        # triangle corners sorted by vertex: vertex normals are one gather + one segmented sum
        corners = self.triangles.reshape(-1)
        order = np.argsort(corners, kind="stable")
        counts = np.bincount(corners, minlength=len(self.rest))
        self._corner_triangle = order // 3
        self._corner_starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self._every_vertex_used = bool(np.all(counts > 0))
        rot_T, rot_S = getattr(model, "rotation_T", None), getattr(model, "rotation_S", None)
        self.coupling = None
        self._normal_basis = None  # built by the first modal_normals call
        self._local = threading.local()  # per-thread scratch of positions()
        if rot_T is not None and rot_S is not None:
            from modalfem.runtime.effects import RotationCoupling

            self.coupling = RotationCoupling(rot_T, rot_S)

    @property
    def shapes(self) -> np.ndarray:
        """Mode shapes (3 nv, r) [m/sqrt(kg)] (a transposed view of ``shapes_t``)."""
        return self.shapes_t.T

    def vertex_shapes(self, vertices) -> np.ndarray:
        """Mode shapes at vertices (k, 3, r) [m/sqrt(kg)], float64, body axes."""
        return np.moveaxis(self._modes3[:, vertices, :], 0, -1).astype(np.float64, copy=False)

    # ------------------------------------------------------------------ sizes
    @property
    def mode_count(self) -> int:
        """r, the number of deformation modes."""
        return len(self.omega)

    @property
    def vertex_count(self) -> int:
        """nv, the number of surface vertices."""
        return len(self.rest)

    # ------------------------------------------------------------------ surface points
    def surface_point(self, triangle: int, barycentric=(1 / 3, 1 / 3, 1 / 3)) -> SurfacePoint:
        """A validated ``SurfacePoint`` (raises ``SimulationError`` for a point off the surface)."""
        if not isinstance(triangle, (int, np.integer)) or not 0 <= int(triangle) < len(self.triangles):
            raise SimulationError(
                f"point off the surface: triangle {triangle!r} not in [0, {len(self.triangles)})")
        return SurfacePoint(int(triangle), tuple(barycentric))

    def _check_point(self, point) -> SurfacePoint:
        if isinstance(point, (int, np.integer)):  # a vertex index
            if not 0 <= int(point) < self.vertex_count:
                raise SimulationError(f"point off the surface: vertex {point} not in [0, {self.vertex_count})")
            return point
        if not isinstance(point, SurfacePoint):
            raise SimulationError(f"a surface point must be a SurfacePoint or a vertex index, got {point!r}")
        if not 0 <= point.triangle < len(self.triangles):
            raise SimulationError(
                f"point off the surface: triangle {point.triangle} not in [0, {len(self.triangles)})")
        return point

    def point_shapes(self, point) -> np.ndarray:
        """Mode shapes at a surface point, (3, r) [m/sqrt(kg)] in body axes (phi_i(p) per column)."""
        p = self._check_point(point)
        if isinstance(p, SurfacePoint):
            tri = self.triangles[p.triangle]
            return np.einsum("k,kcr->cr", np.asarray(p.barycentric), self.vertex_shapes(tri))
        return self.vertex_shapes(int(p))

    def point_rest(self, point) -> np.ndarray:
        """Rest position of a surface point relative to the centre of mass (3,) [m], body axes."""
        p = self._check_point(point)
        if isinstance(p, SurfacePoint):
            return np.asarray(p.barycentric) @ self.rest[self.triangles[p.triangle]]
        return self.rest[int(p)]

    def point_local(self, point, q: np.ndarray) -> np.ndarray:
        """Deformed position of a surface point relative to the centre of mass (3,) [m], body axes."""
        return self.point_rest(point) + self.point_shapes(point) @ q

    def locate(self, state, point, *, tolerance: float = 1e-6) -> SurfacePoint:
        """The surface point of the deformed body closest to a world point (e.g. a picked hit point).

        Args:
            state: current ``State``.
            point: (3,) [m], world.
            tolerance: largest accepted distance from the surface [m].

        Returns:
            ``SurfacePoint`` (triangle, barycentric) of the closest point.

        Raises:
            SimulationError: the point is not finite or farther than ``tolerance`` from the surface.
        """
        p = np.asarray(point, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise SimulationError(f"point must be a finite 3-vector [m], got {point!r}")
        x = self.positions(state).astype(np.float64, copy=False)
        t = self.triangles
        a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
        cands = []
        for s0, s1 in ((a, b), (b, c), (c, a)):  # closest points on the three edges
            e = s1 - s0
            ee = np.einsum("ij,ij->i", e, e)
            tt = np.clip(np.einsum("ij,ij->i", p - s0, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
            cands.append(s0 + tt[:, None] * e)
        n = np.cross(b - a, c - a)  # projection on the plane when it falls inside the triangle
        nn = np.einsum("ij,ij->i", n, n)
        proj = p - (np.einsum("ij,ij->i", p - a, n) / np.where(nn > 0, nn, 1.0))[:, None] * n
        inside = np.ones(len(t), dtype=bool)
        for s0, s1 in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("ij,ij->i", np.cross(s1 - s0, proj - s0), n) >= 0
        cands.append(np.where(inside[:, None], proj, np.inf))
        d2 = np.stack([np.einsum("ij,ij->i", q - p, q - p) for q in cands])  # (4, nt)
        k, i = np.unravel_index(int(np.argmin(d2)), d2.shape)
        dist = float(np.sqrt(d2[k, i]))
        if dist > tolerance:
            raise SimulationError(f"point off the surface: {p.tolist()} is {dist:.3g} m from it "
                                  f"(tolerance {tolerance:g} m)")
        q = cands[k][i]
        # barycentric coordinates of q in triangle i (least squares on the two edge vectors)
        E = np.stack([b[i] - a[i], c[i] - a[i]], axis=1)
        l12, *_ = np.linalg.lstsq(E, q - a[i], rcond=None)
        bary = np.clip(np.array([1.0 - l12.sum(), l12[0], l12[1]]), 0.0, None)
        return SurfacePoint(int(i), tuple(bary / bary.sum()))

    # ------------------------------------------------------------------ reconstruction
    def positions(self, state, out: np.ndarray | None = None, *, precise: bool = False,
                  frame: str = "world") -> np.ndarray:
        """Positions of all surface vertices (nv, 3) [m]: world ``c + R (X + Phi q)``, or body axes.

        Cost: one (3 nv x r) matrix-vector product, plus O(nv) for the rigid motion in the world
        frame. ``out`` (nv, 3) may be given to avoid allocation.

        Args:
            state: current ``State``.
            out: (nv, 3) array of the body's dtype to write into.
            precise: return float64 with the rest shape, rotation and translation in float64, so
                only the small deformation ``Phi q`` carries the storage rounding (what contact
                uses: ~1e-7 of the deformation instead of ~1e-7 of the position).
            frame: ``"world"``, or ``"body"`` for ``X + Phi q`` in body axes about the centre of
                mass: the matrix-vector product alone, for a renderer that applies
                ``model_matrix(state)`` itself (a GPU vertex shader does so for free). At 50k
                vertices x 30 modes this saves the rigid-motion pass, ~0.2 ms of ~1.1 ms.

        Raises:
            InputError: unknown ``frame``, or an ``out`` of the wrong shape or type.
        """
        if frame not in _FRAMES:
            raise InputError(f"frame must be one of {', '.join(_FRAMES)}, got {frame!r}")
        if precise:
            # float64 rest shape (and rigid motion); the same subnormal-free mode weights as below
            coef = _coefficients(state.q, self._basis.dtype, self._row_scale)[:-1]
            x = np.dot(coef, self.shapes_t).reshape(-1, 3) + self.rest
            if frame == "world":
                x = x @ state.rotation().T
                x += state.position
            return x
        if frame == "body":
            out = self._output(out, "positions")
            np.dot(_coefficients(state.q, self._basis.dtype, self._row_scale), self._basis, out=out.reshape(-1))
            return out
        dtype = self._basis.dtype
        out = self._output(out, "positions")
        u = self._scratch()
        np.dot(_coefficients(state.q, dtype, self._row_scale), self._basis, out=u)  # X + Phi q, (3 nv,), one pass over the basis
        _rotate_translate(u, state.rotation().T.astype(dtype), state.position.astype(dtype), out)
        return out

    @staticmethod
    def model_matrix(state) -> np.ndarray:
        """The rigid motion as a 4 x 4 homogeneous matrix (float64, row-major; translation [m] in
        the last column): ``world = M @ [x_body, 1]`` for ``x_body`` from ``positions(frame="body")``.
        Its upper-left 3 x 3 block is also the normal matrix (a rotation)."""
        M = np.eye(4)
        M[:3, :3] = state.rotation()
        M[:3, 3] = state.position
        return M

    def _scratch(self) -> np.ndarray:
        """A (3 nv,) work vector of the body's dtype, one per thread (reused: a fresh 3 nv vector per
        call costs ~0.07 ms of page mapping at 50k vertices, 7 % of a step)."""
        u = getattr(self._local, "u", None)
        if u is None:
            u = self._local.u = np.empty(3 * self.vertex_count, dtype=self._basis.dtype)
        return u

    def _output(self, out: np.ndarray | None, what: str) -> np.ndarray:
        """A (nv, 3) C-contiguous output array of the body's dtype: ``out`` checked, or a new one."""
        nv, dtype = self.vertex_count, self._basis.dtype
        if out is None:
            return np.empty((nv, 3), dtype=dtype)
        if out.shape != (nv, 3) or out.dtype != dtype or not out.flags.c_contiguous:
            raise InputError(f"{what} out must be a C-contiguous ({nv}, 3) {dtype} array, got {out.shape} {out.dtype}")
        return out

    def local_positions(self, q: np.ndarray) -> np.ndarray:
        """Deformed vertices relative to the centre of mass in body axes ``X + Phi q`` (nv, 3) [m]."""
        return np.dot(np.asarray(q, dtype=np.float64), self.shapes_t).reshape(-1, 3) + self.rest

    def normals(self, positions: np.ndarray) -> np.ndarray:
        """Unit vertex normals (nv, 3) from the triangles of ``positions`` (area-weighted average).

        Args:
            positions: deformed vertex positions (nv, 3) [m] (world or body axes; the normals are
                in the same axes).
        """
        p = positions
        t = self.triangles
        a = p[t[:, 0]]
        n_face = np.cross(p[t[:, 1]] - a, p[t[:, 2]] - a)  # length = 2 x area
        if self._every_vertex_used:
            out = np.add.reduceat(n_face[self._corner_triangle], self._corner_starts, axis=0)
        else:  # vertices outside every triangle keep a zero normal
            nv = len(p)
            out = np.empty((nv, 3), dtype=p.dtype)
            for c in range(3):
                out[:, c] = np.bincount(t.reshape(-1), weights=np.repeat(n_face[:, c], 3), minlength=nv)
        norm = np.sqrt(np.einsum("ij,ij->i", out, out))
        out /= np.where(norm > 0, norm, 1.0)[:, None]
        return out

    def modal_normals(self, state, out: np.ndarray | None = None, *, frame: str = "world") -> np.ndarray:
        """Unit world vertex normals (nv, 3) by the modes, at the cost of one more streaming pass.

        The area-weighted vertex normal ``N(x) = sum_t (x_b - x_a) x (x_c - x_a)`` is linearised in
        the modal coordinates, ``N(X + Phi q) = N0 + sum_i q_i dN_i + O(q^2)`` with ``dN_i`` its
        derivative along mode i (built on the first call, one (r, 3 nv) matrix in the body's dtype),
        then normalised and rotated: exact at rest, second-order accurate in the deformation (the
        order of the modal model itself) and ~15x cheaper than ``normals(positions)`` from the
        triangles (``modalfem bench runtime``).

        Args:
            state: current ``State``.
            out: (nv, 3) C-contiguous array of the body's dtype to write into.
            frame: ``"world"``, or ``"body"`` (body axes: rotate by ``model_matrix(state)[:3, :3]``).

        Raises:
            InputError: unknown ``frame``, or an ``out`` of the wrong shape or type.
        """
        if frame not in _FRAMES:
            raise InputError(f"frame must be one of {', '.join(_FRAMES)}, got {frame!r}")
        if self._normal_basis is None:
            self._normal_basis = self._build_normal_basis()
            self._normal_scale = _flush_tiny(self._normal_basis)
        dtype = self._normal_basis.dtype
        out = self._output(out, "modal_normals")
        n = out.reshape(-1) if frame == "body" else self._scratch()
        np.dot(_coefficients(state.q, dtype, self._normal_scale), self._normal_basis, out=n)  # unnormalised, body axes
        sq = n * n  # |n|^2 by strided sums: an inner axis of 3 is slow in numpy reductions
        inv = sq[0::3] + sq[1::3]
        inv += sq[2::3]
        np.sqrt(inv, out=inv)
        inv[inv == 0] = 1.0
        np.divide(1.0, inv, out=inv)
        n3 = n.reshape(-1, 3)
        for k in range(3):
            n3[:, k] *= inv
        if frame == "world":
            _rotate_translate(n, state.rotation().T.astype(dtype), None, out)
        return out

    def _build_normal_basis(self) -> np.ndarray:
        """(r + 1, 3 nv): rows dN_i (derivatives of the unnormalised vertex normals along the modes)
        and N0 (the rest normals), both in body axes."""
        t = self.triangles
        X = self.rest
        eb, ec = X[t[:, 1]] - X[t[:, 0]], X[t[:, 2]] - X[t[:, 0]]
        r, nv = self.mode_count, self.vertex_count
        basis = np.zeros((r + 1, 3 * nv), dtype=self._basis.dtype)

        def gather(face: np.ndarray) -> np.ndarray:  # (nt, 3) per-face vectors summed to vertices
            acc = np.zeros((nv, 3))
            for k in range(3):
                np.add.at(acc, t[:, k], face)
            return acc.reshape(-1)

        basis[r] = gather(np.cross(eb, ec))
        U = self._modes3.astype(np.float64)  # (r, nv, 3)
        for i in range(r):
            ua, ub, uc = U[i][t[:, 0]], U[i][t[:, 1]], U[i][t[:, 2]]
            basis[i] = gather(np.cross(ub - ua, ec) + np.cross(eb, uc - ua))
        return basis

    def modal_energy(self, state) -> float:
        """Deformation energy 0.5 sum (qdot^2 + omega^2 q^2) [J]."""
        return float(0.5 * (state.qdot @ state.qdot + (self.omega**2) @ (state.q**2)))

    def kinetic_energy_rigid(self, state) -> float:
        """Rigid kinetic energy 0.5 m |v|^2 + 0.5 L . omega [J]."""
        return float(0.5 * self.mass * state.velocity @ state.velocity
                     + 0.5 * state.angular_momentum @ self.angular_velocity(state))

    def angular_velocity(self, state) -> np.ndarray:
        """World angular velocity ``R I^-1 R^T L`` (3,) [rad/s]."""
        R = state.rotation()
        return R @ (self.inertia_inv @ (R.T @ state.angular_momentum))

    def inertia_world_inv(self, state) -> np.ndarray:
        """Inverse world inertia ``R I^-1 R^T`` (3, 3) [1/(kg m^2)]."""
        R = state.rotation()
        return R @ self.inertia_inv @ R.T


#: a mode whose largest contribution |q_i| max|row_i| is below this [m] is left out of a product
NEGLIGIBLE = 1e-20
#: basis entries below this fraction of their row's largest are set to zero
FLUSH = 1e-15


_FRAMES = ("world", "body")


def _flush_tiny(basis: np.ndarray) -> np.ndarray:
    """Zero the entries of each row below ``FLUSH`` x its largest (in place); return the row maxima.

    With ``NEGLIGIBLE`` this keeps every product q_i * basis_ij of a reconstruction either zero or
    above 1e-35: a decayed mode (q ~ 1e-40 after a few seconds of damping) would otherwise make them
    subnormal, and subnormal arithmetic made a float32 reconstruction 3x slower (measured).
    """
    scale = np.abs(basis).max(axis=1).astype(np.float64)
    basis[np.abs(basis) < (FLUSH * scale)[:, None]] = 0.0
    return scale


def _coefficients(q: np.ndarray, dtype, scale: np.ndarray) -> np.ndarray:
    """[q, 1] in ``dtype``, the weights of a basis whose last row is the rest term, with the modes whose
    contribution is below ``NEGLIGIBLE`` [m] set to zero (see ``_flush_tiny``)."""
    coef = np.empty(len(q) + 1, dtype=dtype)
    coef[:-1] = np.where(np.abs(q) * scale[:-1] < NEGLIGIBLE, 0.0, q)
    coef[-1] = 1.0
    return coef


_PAIR = 2  # vertices per row of the block-diagonal rotation product
_TILE = 256  # vertices per row of the translation add


def _rotate_translate(u: np.ndarray, Rt: np.ndarray, c: np.ndarray | None, out: np.ndarray) -> None:
    """``out = u.reshape(-1, 3) @ Rt + c`` for (nv, 3) points (no translation when c is None), at
    streaming speed.

    A (nv, 3) @ (3, 3) product and a broadcast add of a 3-vector both run an inner loop of length 3
    (measured 0.25-0.45 ms at 50k vertices, a third of a step); two vertices per row against the
    block-diagonal ``diag(Rt, Rt)`` and the translation tiled over 256 vertices per row take
    ~0.1 ms and ~0.03 ms.
    """
    nv = len(out)
    h = nv - nv % _PAIR
    if h:
        K = np.zeros((3 * _PAIR, 3 * _PAIR), dtype=Rt.dtype)
        for k in range(_PAIR):
            K[3 * k:3 * k + 3, 3 * k:3 * k + 3] = Rt
        np.dot(u[:3 * h].reshape(-1, 3 * _PAIR), K, out=out[:h].reshape(-1, 3 * _PAIR))
    if h < nv:
        np.dot(u[3 * h:].reshape(-1, 3), Rt, out=out[h:])
    if c is None:
        return
    flat = out.reshape(-1)
    m = len(flat) - len(flat) % (3 * _TILE)
    if m:
        rows = flat[:m].reshape(-1, 3 * _TILE)
        np.add(rows, np.tile(c, _TILE), out=rows)
    if m < len(flat):
        tail = flat[m:].reshape(-1, 3)
        np.add(tail, c, out=tail)


def load(path, **kwargs) -> ModalBody:
    """Load a model file (``ModalModel.load``) and return its ``ModalBody``.

    Args:
        path: ``.npz`` model file written by ``ModalModel.save``.
        **kwargs: keyword options of ``ModalBody`` (``damping``, ``dtype``).

    Raises:
        ModelFileError: unreadable, edited or truncated file, or a newer schema.
    """
    from modalfem.model import ModalModel

    return ModalBody(ModalModel.load(path), **kwargs)
