"""Cloth energies: corotational in-plane membrane and dihedral-angle bending.

Membrane (per triangle, rest area ``A``, deformation gradient ``F = Ds Dm^-1`` (3, 2) from a 2D rest
frame, polar decomposition ``F = R S``):

    W = A * (mu |F - R|^2 + lam / 2 (tr S - 2)^2)

with 2D Lame coefficients [N/m] (plane stress times thickness). Gradient ``P = 2 mu (F - R) +
lam (tr S - 2) R``; the exact Hessian uses ``dR = R Omega + (I - R R^T) dF S^-1`` with ``Omega`` the
2x2 skew part ``(R^T dF - dF^T R) / tr S``. For the solve, each 6x6 F-space Hessian is projected to
positive semi-definite by clamping its eigenvalues at zero (in closed form: see
``Membrane.hessian_blocks``).

Bending (per interior edge ``e`` with rest length ``|e|``, rest areas ``A1 + A2`` of its two
triangles, dihedral angle ``theta`` between their normals, rest angle ``theta0``):

    W = (kb / 2) * |e|^2 / (A1 + A2) * (theta - theta0)^2

calibrated so that a grid bent into a cylinder of radius ``r`` across its grid lines stores
``kb / (2 r^2)`` per unit area (``kb`` [N m] the plate bending stiffness). The exact Hessian (tested
by finite differences) has the Gauss-Newton part ``c grad theta grad theta^T`` and a curvature part
``c (theta - theta0) Hess theta``; the solve uses the Gauss-Newton part alone, which is positive
semi-definite by construction and exact at the rest angle.

All functions take positions ``x`` (n, 3) [m] and return energy [J], gradient (n, 3) [N] (the negative
force), and per-element Hessian blocks with their DOF indices for sparse assembly. The per-element work
(polar decomposition, stresses, projected Hessians, dihedral angles and their gradients) runs in the
compiled loops of ``modalfem.cloth._energy_kernels``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from modalfem.cloth.mesh import ClothMesh

__all__ = ["Bending", "Membrane", "assemble_blocks", "dihedral_angles"]

_GRAD_REF = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])


def assemble_blocks(blocks: np.ndarray, verts: np.ndarray, n: int) -> sp.csr_matrix:
    """Sum per-element Hessian blocks into a sparse (3n, 3n) matrix.

    Args:
        blocks: (m, 3k, 3k) element matrices in local node-major order.
        verts: (m, k) vertex indices of each element.
        n: number of vertices.
    """
    k = verts.shape[1]
    dof = (3 * verts[:, :, None] + np.arange(3)).reshape(len(verts), 3 * k)
    rows = np.repeat(dof, 3 * k, axis=1).reshape(-1)
    cols = np.tile(dof, (1, 3 * k)).reshape(-1)
    return sp.csr_matrix((blocks.reshape(-1), (rows, cols)), shape=(3 * n, 3 * n))


@dataclass(frozen=True, eq=False)
class Membrane:
    """Corotational in-plane elasticity of a triangle mesh (see module docstring).

    Args:
        mesh: the cloth; its points are the rest shape.
        mu: 2D shear modulus [N/m] (= E h / (2 (1 + nu))).
        lam: 2D Lame modulus [N/m] (= E h nu / (1 - nu^2), plane stress).
    """

    mesh: ClothMesh
    mu: float
    lam: float

    def __post_init__(self) -> None:
        X = self.mesh.points[self.mesh.triangles]
        e1 = X[:, 1] - X[:, 0]
        e2 = X[:, 2] - X[:, 0]
        u = e1 / np.linalg.norm(e1, axis=1)[:, None]
        nrm = np.cross(e1, e2)
        v = np.cross(nrm / np.linalg.norm(nrm, axis=1)[:, None], u)
        Dm = np.zeros((len(u), 2, 2))
        Dm[:, 0, 0], Dm[:, 0, 1], Dm[:, 1, 1] = np.sum(e1 * u, 1), np.sum(e2 * u, 1), np.sum(e2 * v, 1)
        B = np.linalg.inv(Dm)
        object.__setattr__(self, "_G", _GRAD_REF @ B)  # (m, 3, 2): F = sum_a x_a G_a^T
        object.__setattr__(self, "_area", self.mesh.areas.copy())

    def _args(self, x: np.ndarray):
        return (np.ascontiguousarray(x, dtype=float), self.mesh.triangles, self._G, self._area, float(self.mu),
                float(self.lam))

    def energy(self, x: np.ndarray) -> float:
        """Membrane energy [J] at positions ``x`` (n, 3) [m]."""
        from modalfem.cloth import _energy_kernels as ek

        return float(ek.membrane_energy(*self._args(x)))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dW/dx (n, 3) [N] (the negative elastic force)."""
        from modalfem.cloth import _energy_kernels as ek

        out = np.zeros((len(x), 3))
        ek.membrane_gradient(*self._args(x), out)
        return out

    def hessian_blocks(self, x: np.ndarray, *, project: bool = True) -> np.ndarray:
        """Per-triangle 9x9 Hessians (m, 9, 9) [N/m], exact or projected to positive semi-definite.

        In F-space (``vec F`` row-major, 6 entries) the exact Hessian is
        ``2 mu I + lam r r^T + (lam (tr S - 2) - 2 mu) (q q^T / tr S + kron(I - R R^T, S^-1))`` with
        ``r = vec R``, ``q = vec(R J)``, ``J`` the 2x2 rotation by 90 degrees. Its spectrum is known in
        closed form: the only eigenvalues that can be negative are the twist ``2 mu + 2 c / tr S`` (vector
        ``q / sqrt 2``, ``c = lam (tr S - 2) - 2 mu``) and the out-of-plane ``2 mu + c / sigma_k`` (vectors
        ``vec(n v_k^T)``, ``n`` the unit normal, ``v_k`` the right singular vectors, ``sigma_k`` the
        singular values of F); the projection clamps them at zero. Compiled
        (``modalfem.cloth._energy_kernels.membrane_hessian``).

        Args:
            x: positions (n, 3) [m].
            project: clamp the negative eigenvalues of each F-space Hessian to zero.
        """
        from modalfem.cloth import _energy_kernels as ek

        out = np.empty((len(self.mesh.triangles), 9, 9))
        ek.membrane_hessian(*self._args(x), bool(project), out, np.zeros((0, 3, 3), np.int64))
        return out

    def add_hessian(self, x: np.ndarray, data: np.ndarray, maps: np.ndarray) -> None:
        """Add the projected Hessian [N/m] at ``x`` (n, 3) [m] straight into a 3x3-block matrix's ``data``
        (nnzb, 3, 3), the triangles' blocks at positions ``maps`` (m, 3, 3) (no per-triangle blocks formed)."""
        from modalfem.cloth import _energy_kernels as ek

        ek.membrane_hessian(*self._args(x), True, data, maps)

    def hessian(self, x: np.ndarray, *, project: bool = True) -> sp.csr_matrix:
        """Sparse (3n, 3n) Hessian [N/m] (see ``hessian_blocks``)."""
        return assemble_blocks(self.hessian_blocks(x, project=project), self.mesh.triangles, self.mesh.point_count)


def dihedral_angles(x: np.ndarray, hinges: np.ndarray):
    """Signed dihedral angles (h,) [rad] and their gradients (h, 4, 3) [rad/m] at ``hinges`` (h, 4).

    The angle is 0 for a flat hinge and positive when the hinge folds towards the normal of the
    first triangle ``(e0, e1, a)``. Gradient formulas: the opposite vertices move along their
    triangle's normal (``|e| n / (2 A)``); the edge vertices take the balancing combination.
    """
    from modalfem.cloth import _energy_kernels as ek

    hinges = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    theta = np.empty(len(hinges))
    g = np.empty((len(hinges), 4, 3))
    ek.dihedral(np.ascontiguousarray(x, dtype=float), hinges, theta, g)
    return theta, g


@dataclass(frozen=True, eq=False)
class Bending:
    """Dihedral-angle bending of a triangle mesh (see module docstring).

    Args:
        mesh: the cloth; its points give the rest angles (flat for a grid).
        kb: bending stiffness [N m] (= E h^3 / (12 (1 - nu^2))).
    """

    mesh: ClothMesh
    kb: float

    def __post_init__(self) -> None:
        h = self.mesh.hinges.vertices
        X = self.mesh.points
        theta0, _ = dihedral_angles(X, h) if len(h) else (np.zeros(0), None)
        le2 = np.sum((X[h[:, 1]] - X[h[:, 0]]) ** 2, axis=1)
        a1 = 0.5 * np.linalg.norm(np.cross(X[h[:, 1]] - X[h[:, 0]], X[h[:, 2]] - X[h[:, 0]]), axis=1)
        a2 = 0.5 * np.linalg.norm(np.cross(X[h[:, 1]] - X[h[:, 0]], X[h[:, 3]] - X[h[:, 0]]), axis=1)
        object.__setattr__(self, "_theta0", theta0)
        object.__setattr__(self, "_coef", self.kb * le2 / (a1 + a2))  # W = coef / 2 (theta - theta0)^2

    def _wrapped(self, theta: np.ndarray) -> np.ndarray:
        return (theta - self._theta0 + np.pi) % (2.0 * np.pi) - np.pi

    def energy(self, x: np.ndarray) -> float:
        """Bending energy [J] at positions ``x`` (n, 3) [m]."""
        h = self.mesh.hinges.vertices
        if not len(h):
            return 0.0
        theta, _ = dihedral_angles(x, h)
        return float(0.5 * np.sum(self._coef * self._wrapped(theta) ** 2))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dW/dx (n, 3) [N]."""
        h = self.mesh.hinges.vertices
        out = np.zeros((len(x), 3))
        if not len(h):
            return out
        from modalfem.cloth import _energy_kernels as ek

        theta, g = dihedral_angles(x, h)
        ek.scatter_rows(out, h, g, self._coef * self._wrapped(theta))
        return out

    def angle_factors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the gradient and the Gauss-Newton Hessian are made of, from one evaluation of the angles at
        ``x`` (n, 3) [m]: the gradient's hinge weights ``coef (theta - theta0)`` (h,) [J] (dW/dx = sum of
        weight x angle gradient), the Gauss-Newton weights ``coef`` (h,) [J] and the angle gradients (h, 4, 3)
        [rad/m]."""
        h = self.mesh.hinges.vertices
        if not len(h):
            return np.zeros(0), self._coef, np.zeros((0, 4, 3))
        theta, g = dihedral_angles(x, h)
        return self._coef * self._wrapped(theta), self._coef, g

    def gradient_and_factors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``gradient(x)`` and ``gauss_newton_factors(x)`` from one evaluation of the angles: (dW/dx (n, 3)
        [N], weights (h,) [J], angle gradients (h, 12) [rad/m])."""
        h = self.mesh.hinges.vertices
        out = np.zeros((len(x), 3))
        wg, coef, g = self.angle_factors(x)
        if len(h):
            from modalfem.cloth import _energy_kernels as ek

            ek.scatter_rows(out, h, g, wg)
        return out, coef, g.reshape(len(h), 12)

    def gauss_newton_factors(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The projected Hessian of each hinge as ``w g g^T``: weights ``w`` (h,) [J] and the angle
        gradients ``g`` (h, 12) [rad/m] at positions ``x`` (n, 3) [m] (for assembly without forming blocks)."""
        h = self.mesh.hinges.vertices
        _, g = dihedral_angles(x, h)
        return self._coef, g.reshape(len(h), 12)

    def hessian_blocks(self, x: np.ndarray, *, project: bool = True, step: float = 1e-6) -> np.ndarray:
        """Per-hinge 12x12 Hessians (h, 12, 12) [N/m].

        Args:
            x: positions (n, 3) [m].
            project: True (the solve): the Gauss-Newton part ``coef grad theta grad theta^T``, positive
                semi-definite. False: the exact Hessian, whose curvature part ``coef (theta - theta0)
                Hess theta`` is taken by central differences of the analytic angle gradient with
                relative step ``step`` (for checks and studies, not for the solve).
        """
        h = self.mesh.hinges.vertices
        w, g = self.gauss_newton_factors(x)
        H = w[:, None, None] * g[:, :, None] * g[:, None, :]
        if project:
            return H
        theta, _ = dihedral_angles(x, h)
        scale = step * np.sqrt(self._coef.size and np.max(np.sum((x[h[:, 1]] - x[h[:, 0]]) ** 2, axis=1)))
        Hth = np.empty((len(h), 12, 12))
        for k in range(12):
            xp = x[h].copy()
            xm = x[h].copy()
            xp[:, k // 3, k % 3] += scale
            xm[:, k // 3, k % 3] -= scale
            loc = np.arange(4 * len(h)).reshape(-1, 4)
            _, gp = dihedral_angles(xp.reshape(-1, 3), loc)
            _, gm = dihedral_angles(xm.reshape(-1, 3), loc)
            Hth[:, :, k] = (gp - gm).reshape(len(h), 12) / (2.0 * scale)
        Hth = 0.5 * (Hth + np.transpose(Hth, (0, 2, 1)))
        return H + (self._coef * self._wrapped(theta))[:, None, None] * Hth

    def hessian(self, x: np.ndarray, *, project: bool = True) -> sp.csr_matrix:
        """Sparse (3n, 3n) Hessian [N/m] (see ``hessian_blocks``)."""
        h = self.mesh.hinges.vertices
        return assemble_blocks(self.hessian_blocks(x, project=project), h, self.mesh.point_count)
