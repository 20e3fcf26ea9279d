"""Isotropic elastic energy densities of tetrahedra, as functions of the signed singular values of F.

Every term here is an energy density ``psi(sigma)`` [J/m^3 = Pa] per unit rest volume, where
``sigma`` are the rotation-variant singular values of F (``modalfem.tet.kinematics.svd_rv``; an
inverted element has ``sigma[2] < 0``). An element's energy is ``V0 psi`` [J]. Each term returns
``SigmaDerivs``: psi, d psi / d sigma, d^2 psi / d sigma^2, and the eigenvalues of the two 2x2 blocks
that couple ``F``-hat entries (i, j) and (j, i) (Teran et al. 2005, Stomakhin et al. 2012):

* ``twist`` (antisymmetric, a rotation in the i-j plane) ``(psi_i + psi_j) / (sigma_i + sigma_j)``,
* ``flip`` (symmetric) ``(psi_i - psi_j) / (sigma_i - sigma_j)``,

written in closed forms without the removable 0/0. With those, ``d^2 Psi / d F^2`` has the 9 known
eigenvectors and projection to positive semi-definite is a clamp of eigenvalues (exact, cheap).

Terms:
  * ``Corotated``: linear elasticity in the rotated frame, ``mu |S - I|^2 + lam/2 tr(S - I)^2`` with
    ``F = R S`` (polar); its tangent at ``F = I`` is the linear elasticity tensor (stiffness warping).
  * ``StableCorotated``: ``mu |S - I|^2 + lam/2 (J - 1)^2`` (Stomakhin et al. 2012, "fixed
    corotated"): robust to inversion and to nu -> 0.5.
  * ``VolumeSpringDensity``: ``k/2 (J - 1)^2`` = element energy ``K/2 (V - V0)^2`` with ``K = k / V0``.
  * ``VolumeBarrierDensity``: ``k (J - 1 - log J)``, infinite for ``J <= 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "PAIRS",
    "TRIU",
    "Corotated",
    "SigmaDerivs",
    "StableCorotated",
    "VolumeBarrierDensity",
    "VolumeSpringDensity",
    "element_forces_and_hessians",
    "element_hessians",
    "first_piola",
]

#: pair k couples singular values (i, j) = PAIRS[k]; k is the third index
PAIRS = ((1, 2), (0, 2), (0, 1))
_I = np.array([p[0] for p in PAIRS])
_J = np.array([p[1] for p in PAIRS])
_EPS = 1e-12
#: (rows, columns) of the upper triangle of a 12x12 element Hessian: the order of ``upper=True`` values
TRIU = np.triu_indices(12)


@dataclass
class SigmaDerivs:
    """Derivatives of an isotropic density w.r.t. signed singular values, per element.

    Attributes:
        psi: energy density (m,) [Pa] (``inf`` outside the domain, e.g. a barrier at J <= 0).
        d1: d psi / d sigma (m, 3) [Pa].
        d2: d^2 psi / d sigma^2 (m, 3, 3) [Pa] (None when not requested).
        twist: eigenvalue of the antisymmetric mode of pair k (m, 3) [Pa].
        flip: eigenvalue of the symmetric mode of pair k (m, 3) [Pa].
    """

    psi: np.ndarray
    d1: np.ndarray | None = None
    d2: np.ndarray | None = None
    twist: np.ndarray | None = None
    flip: np.ndarray | None = None

    def __add__(self, other: SigmaDerivs) -> SigmaDerivs:
        def add(a, b):
            return None if a is None or b is None else a + b

        return SigmaDerivs(self.psi + other.psi, add(self.d1, other.d1), add(self.d2, other.d2),
                           add(self.twist, other.twist), add(self.flip, other.flip))


def _pair_sum(s: np.ndarray) -> np.ndarray:
    """sigma_i + sigma_j per pair (m, 3), kept >= _EPS (it is >= 0 for the rotation-variant SVD)."""
    return np.maximum(s[:, _I] + s[:, _J], _EPS)


def _arap(s: np.ndarray, mu, order: int) -> SigmaDerivs:
    """``mu sum (sigma - 1)^2`` = ``mu |F - R|^2``."""
    mu = np.asarray(mu, dtype=float).reshape(-1, 1) if np.ndim(mu) else float(mu)
    e = s - 1.0
    out = SigmaDerivs(np.sum(mu * e * e, axis=1))
    if order >= 1:
        out.d1 = 2.0 * mu * e
    if order >= 2:
        m = len(s)
        out.d2 = np.broadcast_to(2.0 * np.asarray(mu).reshape(-1, 1, 1) * np.eye(3), (m, 3, 3)).copy()
        out.flip = np.broadcast_to(2.0 * mu, (m, 3)).astype(float)
        out.twist = 2.0 * mu - 4.0 * mu / _pair_sum(s)
    return out


def _trace(s: np.ndarray, lam, order: int) -> SigmaDerivs:
    """``lam/2 (sum sigma - 3)^2`` = ``lam/2 tr(S - I)^2``."""
    lam = np.asarray(lam, dtype=float).reshape(-1) if np.ndim(lam) else float(lam)
    t = s.sum(axis=1) - 3.0
    out = SigmaDerivs(0.5 * lam * t * t)
    if order >= 1:
        out.d1 = np.repeat((lam * t)[:, None], 3, axis=1)
    if order >= 2:
        m = len(s)
        out.d2 = np.broadcast_to(np.asarray(lam).reshape(-1, 1, 1) * np.ones((1, 3, 3)), (m, 3, 3)).copy()
        out.flip = np.zeros((m, 3))
        out.twist = 2.0 * (lam * t)[:, None] / _pair_sum(s)
    return out


def _volumetric(s: np.ndarray, e0, e1, e2, order: int) -> SigmaDerivs:
    """A density ``e(J)``, ``J = s0 s1 s2``, from its values ``e0, e1 = e', e2 = e''`` (m,)."""
    out = SigmaDerivs(e0)
    if order >= 1:
        dJ = np.stack([s[:, 1] * s[:, 2], s[:, 0] * s[:, 2], s[:, 0] * s[:, 1]], axis=1)
        out.d1 = e1[:, None] * dJ
    if order >= 2:
        HJ = np.zeros((len(s), 3, 3))
        for k, (i, j) in enumerate(PAIRS):
            HJ[:, i, j] = HJ[:, j, i] = s[:, k]
        out.d2 = e2[:, None, None] * dJ[:, :, None] * dJ[:, None, :] + e1[:, None, None] * HJ
        out.twist = e1[:, None] * s
        out.flip = -e1[:, None] * s
    return out


def _det(s: np.ndarray) -> np.ndarray:
    return s[:, 0] * s[:, 1] * s[:, 2]


@dataclass(frozen=True)
class Corotated:
    """Corotational linear elasticity ``mu |S - I|^2 + lam/2 tr(S - I)^2`` [Pa].

    Args:
        mu: shear modulus [Pa] (scalar or per element (m,)).
        lam: first Lame parameter [Pa] (scalar or per element (m,)).
    """

    mu: float
    lam: float

    def derivs(self, s: np.ndarray, order: int = 2) -> SigmaDerivs:
        """psi and derivatives at signed singular values ``s`` (m, 3); ``order`` 0, 1 or 2."""
        return _arap(s, self.mu, order) + _trace(s, self.lam, order)


@dataclass(frozen=True)
class StableCorotated:
    """Inversion-robust corotated model ``mu |S - I|^2 + lam/2 (J - 1)^2`` [Pa].

    Args:
        mu: shear modulus [Pa].
        lam: first Lame parameter [Pa].
    """

    mu: float
    lam: float

    def derivs(self, s: np.ndarray, order: int = 2) -> SigmaDerivs:
        """psi and derivatives at signed singular values ``s`` (m, 3); ``order`` 0, 1 or 2."""
        if np.ndim(self.mu) == 0 and np.ndim(self.lam) == 0:
            # scalar moduli: one compiled pass, elements in parallel (the sums of _arap and _volumetric)
            from modalfem.tet import _kernels

            s = np.ascontiguousarray(s, dtype=float)
            m = len(s)
            psi = np.empty(m)
            if order == 0:  # the line search's energies: psi only
                e = np.empty((0, 0))
                _kernels.stable_corotated(s, float(self.mu), float(self.lam), 0, psi, e, np.empty((0, 0, 0)), e, e)
                return SigmaDerivs(psi)
            d1 = np.empty((3, m))
            if order == 1:  # forces only (an iteration reusing the previous matrix)
                e = np.empty((0, 0))
                _kernels.stable_corotated(s, float(self.mu), float(self.lam), 1, psi, d1, np.empty((0, 0, 0)), e, e)
                return SigmaDerivs(psi, d1.T)
            d2, twist, flip = np.empty((3, 3, m)), np.empty((3, m)), np.empty((3, m))
            _kernels.stable_corotated(s, float(self.mu), float(self.lam), 2, psi, d1, d2, twist, flip)
            # stored with the element index last (what the Hessians read), returned as (m, ...) views
            return SigmaDerivs(psi, d1.T, np.moveaxis(d2, -1, 0), twist.T, flip.T)
        d = _det(s) - 1.0
        lam = np.asarray(self.lam, dtype=float)
        e2 = np.broadcast_to(lam, d.shape).astype(float)
        return _arap(s, self.mu, order) + _volumetric(s, 0.5 * lam * d * d, lam * d, e2, order)


@dataclass(frozen=True)
class VolumeSpringDensity:
    """Volume spring density ``k/2 (J - 1)^2`` [Pa]: element energy ``K/2 (V - V0)^2``, ``K = k / V0``.

    Args:
        k: volumetric stiffness [Pa] (scalar or per element).
    """

    k: float

    def derivs(self, s: np.ndarray, order: int = 2) -> SigmaDerivs:
        """psi and derivatives at signed singular values ``s`` (m, 3); ``order`` 0, 1 or 2."""
        d = _det(s) - 1.0
        k = np.asarray(self.k, dtype=float)
        return _volumetric(s, 0.5 * k * d * d, k * d, np.broadcast_to(k, d.shape).astype(float), order)


@dataclass(frozen=True)
class VolumeBarrierDensity:
    """Volume barrier density ``k (J - 1 - log J)`` [Pa]: zero at rest volume, infinite as V -> 0.

    Args:
        k: stiffness [Pa] (its second derivative at J = 1 is ``k``, like a volume spring's).
    """

    k: float

    def derivs(self, s: np.ndarray, order: int = 2) -> SigmaDerivs:
        """psi and derivatives at signed singular values ``s`` (m, 3); ``order`` 0, 1 or 2.

        Elements with ``J <= 0`` get ``psi = inf`` and zero derivatives (a line search rejects them).
        """
        J = _det(s)
        ok = J > 0
        Js = np.where(ok, J, 1.0)
        k = np.asarray(self.k, dtype=float)
        e0 = np.where(ok, k * (Js - 1.0 - np.log(Js)), np.inf)
        e1 = np.where(ok, k * (1.0 - 1.0 / Js), 0.0)
        e2 = np.where(ok, k / (Js * Js), 0.0)
        return _volumetric(s, e0, e1, e2, order)


def first_piola(U: np.ndarray, V: np.ndarray, d1: np.ndarray) -> np.ndarray:
    """First Piola-Kirchhoff stress ``P = U diag(d psi/d sigma) V^T`` (m, 3, 3) [Pa]."""
    return np.matmul(U * d1[:, None, :], np.swapaxes(V, 1, 2))


def _psd3(A: np.ndarray) -> np.ndarray:
    """Mask (m,) of symmetric 3x3 matrices that are positive semi-definite (principal-minor test)."""
    a, b, c = A[:, 0, 0], A[:, 1, 1], A[:, 2, 2]
    d, e, f = A[:, 0, 1], A[:, 1, 2], A[:, 0, 2]
    tol = -1e-12 * (np.abs(a) + np.abs(b) + np.abs(c)) ** 2
    minors2 = np.minimum(np.minimum(a * b - d * d, b * c - e * e), a * c - f * f)
    det = a * (b * c - e * e) - d * (d * c - e * f) + f * (d * e - b * f)
    return (np.minimum(np.minimum(a, b), c) >= 0) & (minors2 >= tol) & (det >= tol * np.abs(a + b + c))


def _project_d2(d2: np.ndarray) -> np.ndarray:
    """``d2`` (m, 3, 3) with its positive part where it is not positive semi-definite (a copy if changed)."""
    bad = ~_psd3(d2)
    if bad.any():
        w, W = np.linalg.eigh(d2[bad])
        d2 = d2.copy()
        d2[bad] = np.einsum("mik,mk,mjk->mij", W, np.maximum(w, 0.0), W)
    return d2


def element_hessians(U: np.ndarray, V: np.ndarray, d: SigmaDerivs, grad: np.ndarray, vol: np.ndarray, *,
                     project: bool = True, upper: bool = False) -> np.ndarray:
    """Element Hessians ``V0 B^T (d^2 psi / d F^2) B`` (m, 12, 12) [N/m] from the analytic eigensystem.

    ``d^2 psi / d F^2 = sum_pq (d2)_pq D_p D_q^T + sum_pairs twist T T^T + flip L L^T`` with
    ``D_p = vec(u_p v_p^T)``, ``T, L = vec(u_i v_j^T -+ u_j v_i^T) / sqrt 2``; projection clamps twist and
    flip at 0 and replaces the 3x3 block ``d2`` by its positive part (an eigen-decomposition only for
    the elements where ``d2`` is not already positive semi-definite).

    Computed per element by a compiled kernel, elements in parallel (``_hessians_upper``).

    Args:
        U, V: rotations of the rotation-variant SVD (m, 3, 3).
        d: ``SigmaDerivs`` of order 2.
        grad: shape-function gradients (m, 4, 3) [1/m].
        vol: rest volumes (m,) [m^3].
        project: make every element Hessian positive semi-definite.
        upper: return only the upper triangles, (78, m) in the order of ``np.triu_indices(12)`` (what
            ``HessianPattern.assemble(..., upper=True)`` takes), instead of (m, 12, 12).

    Returns:
        Hessians (m, 12, 12) (or (78, m)), local DOF order ``3 a + k`` (vertex a, component k).
    """
    m = len(U)
    d2 = d.d2
    if project:
        d2 = _project_d2(d2)
    H = _hessians_upper(np.moveaxis(U, 0, -1), np.moveaxis(V, 0, -1), d2, d, np.moveaxis(grad, 0, -1), vol,
                        project=bool(project))
    if upper:
        return H
    full = np.empty((12, 12, m))
    full[TRIU] = H
    full[TRIU[::-1]] = H
    return np.ascontiguousarray(np.moveaxis(full, -1, 0))


def element_forces_and_hessians(U: np.ndarray, V: np.ndarray, d: SigmaDerivs, grad: np.ndarray,
                                vol: np.ndarray, *, element_last: bool = False,
                                project: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Element forces and (projected) Hessians in one pass (what an implicit step needs), element index last.

    Args:
        U, V: rotations of the rotation-variant SVD (m, 3, 3), or (3, 3, m) with ``element_last``
            (``svd_rv_t``).
        d: ``SigmaDerivs`` of order 2.
        grad: shape-function gradients (m, 4, 3) [1/m], or (4, 3, m) with ``element_last``.
        vol: rest volumes (m,) [m^3].
        element_last: the layout of ``U``, ``V`` and ``grad`` (saves their transposes).
        project: project each element Hessian to positive semi-definite (twist and flip eigenvalues
            clamped at 0, the 3x3 block ``d2`` replaced by its positive part); False: the exact Hessians,
            which are indefinite where an element's geometric stiffness is negative (compression).

    Returns:
        ``(f, H)``: ``f`` (4, 3, m) [N] with ``f[a, :, e] = V0 P grad_a`` (the energy gradient w.r.t. vertex
        a of element e; ``P = U diag(d psi / d sigma) V^T``), and ``H`` (78, m) [N/m] the upper triangles
        of the element Hessians as ``element_hessians(..., project=project, upper=True)``.
    """
    if not element_last:
        U, V, grad = np.moveaxis(U, 0, -1), np.moveaxis(V, 0, -1), np.moveaxis(grad, 0, -1)
    m = U.shape[-1]
    d2 = _project_d2(d.d2) if project else d.d2
    f = np.empty((4, 3, m))
    H = _hessians_upper(U, V, d2, d, grad, vol, f, project=bool(project))
    return f, H


def _hessians_upper(Ut, Vt, d2, d, gt, vol, f=None, *, project: bool = True) -> np.ndarray:
    """Upper triangles (78, m) of the element Hessians from the (projected) eigensystem (``d2`` (m, 3, 3)
    and the twist and flip eigenvalues of ``d``); with ``f`` also the element forces (from ``d.d1``) into
    ``f`` (4, 3, m). The result is the transposed view of an (m, 78) array (each element's values
    together, as the kernel writes them; ``HessianPattern.assemble`` reads that layout without a copy).

    Element index last: ``Ut``, ``Vt`` (3, 3, m) are U and V, ``gt`` (4, 3, m) the shape gradients.
    Per element (:func:`modalfem.tet._kernels.hessians_upper`, compiled, elements in parallel): the 9
    eigen-modes of d^2 psi / d F^2 as 9-vectors over vertices 1..3 (U e_p e_q^T V^T through the
    gradients), weighted by V0 d2 (the 3x3 block mixing the first three) and V0 lambda / 2 (twist and
    flip, the 1/sqrt 2 of their modes squared); only the 9x9 block of vertices 1..3 is formed (its upper
    triangle, 45 dot products over the modes); the rows of vertex 0 follow from translation invariance
    (``grad_0 = -(grad_1 + grad_2 + grad_3)``, so ``H 1 = 0``).
    """
    from modalfem.tet import _kernels

    m = Ut.shape[-1]
    H = np.empty((m, 78))
    forces = f is not None
    # the densities' columns element index last (``StableCorotated`` stores them so: views, no copies)
    lam = np.concatenate([np.asarray(d.twist, dtype=float).T, np.asarray(d.flip, dtype=float).T], axis=0)
    c = np.ascontiguousarray
    _kernels.hessians_upper(c(Ut, dtype=float), c(Vt, dtype=float), c(np.moveaxis(d2, 0, -1), dtype=float), lam,
                            c(gt, dtype=float), c(vol, dtype=float),
                            c(np.asarray(d.d1, dtype=float).T) if forces else np.zeros((3, 0)), H,
                            f if forces else np.zeros((4, 3, 0)), forces, project)
    return H.T
