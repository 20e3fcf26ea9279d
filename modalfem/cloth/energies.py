"""Cloth energies: corotational in-plane membrane and dihedral-angle bending, vectorised.

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
force), and per-element Hessian blocks with their DOF indices for sparse assembly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from modalfem.cloth.mesh import ClothMesh

__all__ = ["Bending", "Membrane", "assemble_blocks", "dihedral_angles", "scatter"]

_GRAD_REF = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
_SQRT_EPS = 1e-12


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


def scatter(verts: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum per-element vertex vectors ``values`` (m, k, 3) into (n, 3) over ``verts`` (m, k)."""
    idx = verts.reshape(-1)
    v = values.reshape(-1, 3)
    return np.stack([np.bincount(idx, weights=v[:, c], minlength=n) for c in range(3)], axis=1)


def _polar(F: np.ndarray):
    """R (m, 3, 2), S (m, 2, 2), S^-1, tr S of F (m, 3, 2) with ``F = R S``, S SPD (2x2 closed form)."""
    C = np.einsum("mki,mkj->mij", F, F)
    det = np.maximum(C[:, 0, 0] * C[:, 1, 1] - C[:, 0, 1] ** 2, _SQRT_EPS)
    sd = np.sqrt(det)
    tr_s = np.sqrt(C[:, 0, 0] + C[:, 1, 1] + 2.0 * sd)
    S = (C + sd[:, None, None] * np.eye(2)) / tr_s[:, None, None]
    det_s = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] ** 2
    Sinv = np.empty_like(S)
    Sinv[:, 0, 0], Sinv[:, 1, 1] = S[:, 1, 1], S[:, 0, 0]
    Sinv[:, 0, 1] = Sinv[:, 1, 0] = -S[:, 0, 1]
    Sinv /= det_s[:, None, None]
    R = F[:, :, 0, None] * Sinv[:, None, 0, :] + F[:, :, 1, None] * Sinv[:, None, 1, :]
    return R, S, Sinv, tr_s


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

    def _F(self, x: np.ndarray) -> np.ndarray:
        q = x[self.mesh.triangles]  # (m, a, i)
        G = self._G  # (m, a, j)
        return sum(q[:, a, :, None] * G[:, a, None, :] for a in range(3))

    def energy(self, x: np.ndarray) -> float:
        """Membrane energy [J] at positions ``x`` (n, 3) [m]."""
        F = self._F(x)
        R, _S, _, tr_s = _polar(F)
        psi = self.mu * np.sum((F - R) ** 2, axis=(1, 2)) + 0.5 * self.lam * (tr_s - 2.0) ** 2
        return float(np.sum(self._area * psi))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        """dW/dx (n, 3) [N] (the negative elastic force)."""
        F = self._F(x)
        R, _, _, tr_s = _polar(F)
        P = 2.0 * self.mu * (F - R) + (self.lam * (tr_s - 2.0))[:, None, None] * R
        g = (self._G @ np.transpose(P, (0, 2, 1))) * self._area[:, None, None]
        return scatter(self.mesh.triangles, g, len(x))

    def hessian_blocks(self, x: np.ndarray, *, project: bool = True) -> np.ndarray:
        """Per-triangle 9x9 Hessians (m, 9, 9) [N/m], exact or projected to positive semi-definite.

        In F-space (``vec F`` row-major, 6 entries) the exact Hessian is
        ``2 mu I + lam r r^T + (lam (tr S - 2) - 2 mu) (q q^T / tr S + kron(I - R R^T, S^-1))`` with
        ``r = vec R``, ``q = vec(R J)``, ``J`` the 2x2 rotation by 90 degrees.

        Args:
            x: positions (n, 3) [m].
            project: clamp the negative eigenvalues of each F-space Hessian to zero.
        """
        F = self._F(x)
        R, _, Sinv, tr_s = _polar(F)
        m = len(F)
        r = R.reshape(m, 6)
        q = np.stack([R[:, :, 1], -R[:, :, 0]], axis=2).reshape(m, 6)  # vec(R J)
        Pn = np.eye(3) - np.einsum("mij,mkj->mik", R, R)
        kron = (Pn[:, :, None, :, None] * Sinv[:, None, :, None, :]).reshape(m, 6, 6)
        c = self.lam * (tr_s - 2.0) - 2.0 * self.mu
        H = c[:, None, None] * (q[:, :, None] * q[:, None, :] / tr_s[:, None, None] + kron)
        H += self.lam * r[:, :, None] * r[:, None, :]
        H[:, np.arange(6), np.arange(6)] += 2.0 * self.mu
        if project:
            # closed-form spectrum: the only eigenvalues that can be negative are the twist
            # 2 mu + 2 c / tr S (vector q / sqrt 2) and the out-of-plane 2 mu + c / sigma_k (vectors
            # vec(n v_k^T), n the unit normal, v_k the right singular vectors); clamp them at zero.
            lam_l = 2.0 * self.mu + 2.0 * c / tr_s
            H += np.maximum(-lam_l, 0.0)[:, None, None] * 0.5 * q[:, :, None] * q[:, None, :]
            sig2, V = np.linalg.eigh(np.transpose(F, (0, 2, 1)) @ F)
            nrm = np.cross(F[:, :, 0], F[:, :, 1])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
            for k in range(2):
                lam_n = 2.0 * self.mu + c / np.sqrt(np.maximum(sig2[:, k], _SQRT_EPS))
                w = (nrm[:, :, None] * V[:, None, :, k]).reshape(m, 6)
                H += np.maximum(-lam_n, 0.0)[:, None, None] * w[:, :, None] * w[:, None, :]
        G = self._G * np.sqrt(self._area)[:, None, None]
        # (m, a, i, b, k) = sum_jl G_aj H_ijkl G_bl as two batched products: over j, then over l
        Ht = H.reshape(m, 3, 2, 3, 2).transpose(0, 2, 1, 3, 4).reshape(m, 2, 18)  # (m, j, (i k l))
        T = (G @ Ht).reshape(m, 27, 2)  # (m, (a i k), l)
        K = (T @ np.transpose(G, (0, 2, 1))).reshape(m, 3, 3, 3, 3)  # (m, a, i, k, b)
        return np.ascontiguousarray(K.transpose(0, 1, 2, 4, 3)).reshape(m, 9, 9)

    def hessian(self, x: np.ndarray, *, project: bool = True) -> sp.csr_matrix:
        """Sparse (3n, 3n) Hessian [N/m] (see ``hessian_blocks``)."""
        return assemble_blocks(self.hessian_blocks(x, project=project), self.mesh.triangles, self.mesh.point_count)


def dihedral_angles(x: np.ndarray, hinges: np.ndarray):
    """Signed dihedral angles (h,) [rad] and their gradients (h, 4, 3) [rad/m] at ``hinges`` (h, 4).

    The angle is 0 for a flat hinge and positive when the hinge folds towards the normal of the
    first triangle ``(e0, e1, a)``. Gradient formulas: the opposite vertices move along their
    triangle's normal (``|e| n / (2 A)``); the edge vertices take the balancing combination.
    """
    x0, x1, xa, xb = (x[hinges[:, k]] for k in range(4))
    e = x1 - x0
    n1 = np.cross(e, xa - x0)  # normal of triangle (e0, e1, a), |n1| = 2 A1
    n2 = np.cross(xb - x0, e)  # normal of triangle (e1, e0, b), |n2| = 2 A2
    le = np.linalg.norm(e, axis=1)
    ehat = e / le[:, None]
    s = np.einsum("hi,hi->h", np.cross(n1, n2), ehat)
    c = np.einsum("hi,hi->h", n1, n2)
    theta = np.arctan2(s, c)
    q1 = np.einsum("hi,hi->h", n1, n1)
    q2 = np.einsum("hi,hi->h", n2, n2)
    ga = -(le / q1)[:, None] * n1
    gb = -(le / q2)[:, None] * n2
    ta = np.einsum("hi,hi->h", xa - x0, ehat) / le  # position of a's foot along the edge (0 at e0)
    tb = np.einsum("hi,hi->h", xb - x0, ehat) / le
    g0 = -(1.0 - ta)[:, None] * ga - (1.0 - tb)[:, None] * gb
    g1 = -ta[:, None] * ga - tb[:, None] * gb
    return theta, np.stack([g0, g1, ga, gb], axis=1)


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
        out = np.zeros_like(x, dtype=float)
        if not len(h):
            return out
        theta, g = dihedral_angles(x, h)
        return scatter(h, (self._coef * self._wrapped(theta))[:, None, None] * g, len(x))

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
        theta, g = dihedral_angles(x, h)
        g = g.reshape(len(h), 12)
        H = self._coef[:, None, None] * g[:, :, None] * g[:, None, :]
        if project:
            return H
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
