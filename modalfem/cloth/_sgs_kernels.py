"""Filtered conjugate gradients preconditioned by symmetric block Gauss-Seidel (SGS), with Eisenstat's trick
(numba, compiled on first call, cached). Same matrices, constraints and stopping rule as
:func:`modalfem.cloth._kernels.pcg` (see that module's docstring).

With the constrained system ``A' = S A S`` on range(S) split into its block parts ``A' = L + D + L^T`` (``D`` the
projected 3x3 diagonal blocks, ``L`` the blocks below the diagonal in vertex order), the SGS preconditioner is
``M = (D + L) D^-1 (D + L^T)``. CG preconditioned by ``M`` is CG on ``Abar = (D + L)^-1 A' (D + L^T)^-1`` (symmetric)
preconditioned by ``D``, and Eisenstat's trick makes its product cost one matrix pass instead of two
(``A' = (D + L) + (D + L^T) - D``): ``Abar c = t + (D + L)^-1 (c - D t)`` with ``t = (D + L^T)^-1 c`` (a backward
sweep over the blocks above the diagonal, then a forward sweep over those below). The solve works on the
correction ``e`` of the start ``y``: ``rbar = (D + L)^-1 S (b - A y)``, ``e = (D + L^T)^-1 xbar``.

The transformed residual ``rbar`` is not the residual ``S (b - A y)`` of the stopping rule (that is
``(D + L) rbar``, another half pass per iteration): its norm times the ratio of the two norms seen so far
predicts the true one, and the true residual is computed (one backward sweep and one product) only when the
prediction says converged; the solve stops when the true residual does. So the stopping rule is
``_kernels.pcg``'s exactly.

Why: block SGS propagates a correction across the whole sheet in one sweep, which block Jacobi plus the additive
aggregation levels cannot: on the 64x64 pile's step-60 systems CG takes 31 iterations instead of 51 (implicit step,
1e-4) and 18 instead of 28 (smoothing, 0.1), for about the cost of one matrix product per iteration as before, and
without the levels' setup (their Galerkin matrices and coarse inverse, twice per step). The sweeps are serial
(a sweep split into independent chunks lost the gain: 44-48 iterations with 4-16 chunks), so a solve gives the
same bits on any thread count; the residual checks use ``_kernels``' chunked parallel kernels.
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem.cloth._kernels import _preconditioner, _project, _residual

__all__ = ["pcg_sgs"]

#: floating-point freedoms of the sweeps: reassociation and fused multiply-adds (no assumptions about NaN or
#: infinity); they let LLVM vectorise the 3x3 block products: a sweep over the 64x64 pile's ~20k blocks on one
#: side of the diagonal 141 -> 100 us
_FAST = {"reassoc", "contract"}


@numba.njit(cache=True, fastmath=_FAST)
def _backward(indptr, indices, data, diag, P, rhs, t, z, beta, direction):
    """``t = (D + L^T)^-1 rhs`` (``rhs`` in range(S)): vertices from last to first, the blocks right of the
    diagonal; ``P`` the projected inverses of the diagonal blocks (``_kernels._preconditioner``). With
    ``direction``, ``rhs`` is first updated to ``z + beta rhs`` row by row (CG's new search direction)."""
    n = len(diag)
    for i in range(n - 1, -1, -1):
        if direction:
            for a in range(3):
                rhs[i, a] = z[i, a] + beta * rhs[i, a]
        s0 = rhs[i, 0]
        s1 = rhs[i, 1]
        s2 = rhs[i, 2]
        for p in range(diag[i] + 1, indptr[i + 1]):
            j = indices[p]
            x0, x1, x2 = t[j, 0], t[j, 1], t[j, 2]
            s0 -= data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
            s1 -= data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
            s2 -= data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
        for a in range(3):
            t[i, a] = P[i, a, 0] * s0 + P[i, a, 1] * s1 + P[i, a, 2] * s2


@numba.njit(cache=True, fastmath=_FAST)
def _forward(indptr, indices, data, diag, P, rhs, t, u, q, with_t):
    """``u = (D + L)^-1 rhs`` (``with_t`` False), or (True: ``Abar rhs`` given ``t = (D + L^T)^-1 rhs``)
    ``u = (D + L)^-1 (rhs - D t)`` and ``q = t + u``, returning ``rhs . q``; vertices from first to last, the
    blocks left of the diagonal."""
    n = len(diag)
    cq = 0.0
    for i in range(n):
        s0 = rhs[i, 0]
        s1 = rhs[i, 1]
        s2 = rhs[i, 2]
        for p in range(indptr[i], diag[i]):
            j = indices[p]
            x0, x1, x2 = u[j, 0], u[j, 1], u[j, 2]
            s0 -= data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
            s1 -= data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
            s2 -= data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
        if with_t:
            d = diag[i]
            x0, x1, x2 = t[i, 0], t[i, 1], t[i, 2]
            s0 -= data[d, 0, 0] * x0 + data[d, 0, 1] * x1 + data[d, 0, 2] * x2
            s1 -= data[d, 1, 0] * x0 + data[d, 1, 1] * x1 + data[d, 1, 2] * x2
            s2 -= data[d, 2, 0] * x0 + data[d, 2, 1] * x1 + data[d, 2, 2] * x2
        for a in range(3):
            u[i, a] = P[i, a, 0] * s0 + P[i, a, 1] * s1 + P[i, a, 2] * s2
        if with_t:
            for a in range(3):
                q[i, a] = t[i, a] + u[i, a]
                cq += rhs[i, a] * q[i, a]
    return cq


@numba.njit(cache=True)
def _diagonal(data, diag, kind, normal, r, s, alpha, c, q, x):
    """``x += alpha c`` and ``r -= alpha q`` (CG's update; alpha 0: none), then ``s = D r`` (the projected diagonal
    blocks, ``r`` in range(S)); returns ``(r . s, |r|^2)``."""
    n = len(diag)
    rs = 0.0
    rr = 0.0
    for i in range(n):
        if alpha != 0.0:
            for a in range(3):
                x[i, a] += alpha * c[i, a]
                r[i, a] -= alpha * q[i, a]
        d = diag[i]
        x0, x1, x2 = r[i, 0], r[i, 1], r[i, 2]
        a0 = data[d, 0, 0] * x0 + data[d, 0, 1] * x1 + data[d, 0, 2] * x2
        a1 = data[d, 1, 0] * x0 + data[d, 1, 1] * x1 + data[d, 1, 2] * x2
        a2 = data[d, 2, 0] * x0 + data[d, 2, 1] * x1 + data[d, 2, 2] * x2
        a0, a1, a2 = _project(kind, normal, i, a0, a1, a2)
        s[i, 0] = a0
        s[i, 1] = a1
        s[i, 2] = a2
        rs += x0 * a0 + x1 * a1 + x2 * a2
        rr += x0 * x0 + x1 * x1 + x2 * x2
    return rs, rr


@numba.njit(cache=True)
def _handles2(kind, z):
    """The squared norm of the handles' prescribed values (part of ``|b'|^2``)."""
    s = 0.0
    for i in range(len(kind)):
        if kind[i] == 2:
            s += z[i, 0] ** 2 + z[i, 1] ** 2 + z[i, 2] ** 2
    return s


@numba.njit(cache=True)
def pcg_sgs(indptr, indices, data, diag, kind, normal, b, y, rtol, maxiter):
    """Solve ``A y = b`` on the free components (filtered PCG, SGS preconditioner; module docstring).

    Args and returns as :func:`modalfem.cloth._kernels.pcg` without the levels: ``y`` (n, 3) updated in place
    (on entry the start, whose constrained components are kept); returns (iterations, relative residual
    reached), iterations = -1 if ``maxiter`` was not enough. ``|S (b - A y)| <= rtol |b'|`` holds on return
    (it is computed, not predicted).
    """
    n = len(diag)
    r = np.empty((n, 3))
    z = np.empty((n, 3))
    for i in range(n):  # z: the constrained part of the start
        u0, u1, u2 = _project(kind, normal, i, y[i, 0], y[i, 1], y[i, 2])
        z[i, 0] = y[i, 0] - u0
        z[i, 1] = y[i, 1] - u1
        z[i, 2] = y[i, 2] - u2
    rz2 = _residual(indptr, indices, data, kind, normal, b, z, r)  # r: the residual of the start z
    nb = np.sqrt(rz2 + _handles2(kind, z))  # the prescribed values of the handles count in |b'|
    if nb == 0.0:
        for i in range(n):
            for a in range(3):
                y[i, a] = z[i, a]
        return 0, 0.0
    w = np.empty((n, 3))
    rn = np.sqrt(_residual(indptr, indices, data, kind, normal, b, y, w))
    if rn > np.sqrt(rz2):  # a start worse than none (e.g. a warm start against a right-hand side near 0):
        rn = np.sqrt(rz2)  # start from the prescribed part
        for i in range(n):
            for a in range(3):
                y[i, a] = z[i, a]
    else:
        for i in range(n):
            for a in range(3):
                r[i, a] = w[i, a]
    goal = rtol * nb
    if rn <= goal:
        return 0, rn / nb
    P = _preconditioner(data, diag, kind, normal)
    rb = np.empty((n, 3))
    xb = np.zeros((n, 3))
    s = np.empty((n, 3))
    c = np.empty((n, 3))
    t = np.empty((n, 3))
    q = np.empty((n, 3))
    _forward(indptr, indices, data, diag, P, r, t, rb, q, False)  # rbar = (D + L)^-1 r
    rho, rb2 = _diagonal(data, diag, kind, normal, rb, s, 0.0, c, q, xb)
    if not rb2 > 0.0:
        return -1, rn / nb
    ratio = rn / np.sqrt(rb2)  # |true residual| / |rbar|, updated at every check
    for i in range(n):
        for a in range(3):
            c[i, a] = s[i, a]
    beta = 0.0
    for k in range(1, maxiter + 1):
        _backward(indptr, indices, data, diag, P, c, t, s, beta, k > 1)  # c = s + beta c on the way
        cq = _forward(indptr, indices, data, diag, P, c, t, w, q, True)  # q = Abar c (w: scratch)
        if not cq > 0.0:
            return -1, rn / nb
        alpha = rho / cq
        rho_new, rb2 = _diagonal(data, diag, kind, normal, rb, s, alpha, c, q, xb)
        if np.sqrt(rb2) * ratio <= goal or k == maxiter:  # predicted converged: compute the true residual
            _backward(indptr, indices, data, diag, P, xb, t, s, 0.0, False)  # e = (D + L^T)^-1 xbar
            for i in range(n):
                for a in range(3):
                    w[i, a] = y[i, a] + t[i, a]
            rn = np.sqrt(_residual(indptr, indices, data, kind, normal, b, w, r))
            if rn <= goal:
                for i in range(n):
                    for a in range(3):
                        y[i, a] = w[i, a]
                return k, rn / nb
            if not rb2 > 0.0:
                return -1, rn / nb
            ratio = rn / np.sqrt(rb2)
        beta = rho_new / rho
        rho = rho_new
    return -1, rn / nb
