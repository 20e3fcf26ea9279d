"""Compiled per-element kernels of the cloth energies (numba, compiled on first call, cached).

The formulas are those of ``modalfem.cloth.energies`` (its module docstring and ``Membrane.hessian_blocks``);
one loop over the elements, no temporaries per element beyond a few small arrays.
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem._threads import chunk_bounds, chunk_count

__all__ = ["dihedral", "gather_rows", "membrane_energy", "membrane_gradient", "membrane_hessian",
           "membrane_hessian_and_gradient", "scatter_outer", "scatter_rows"]

_SQRT_EPS = 1e-12


@numba.njit(cache=True)
def _deformation(x, tri, G, e, F):
    """F (3, 2) = sum_a x_a G_a^T of triangle ``e``."""
    for i in range(3):
        for j in range(2):
            s = 0.0
            for a in range(3):
                s += x[tri[e, a], i] * G[e, a, j]
            F[i, j] = s


@numba.njit(cache=True)
def _polar(F, R, Sinv):
    """Fills R (3, 2) and S^-1 (2, 2) of ``F = R S`` (S SPD, closed form); returns tr S."""
    c00 = F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0]
    c11 = F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1]
    c01 = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
    sd = np.sqrt(max(c00 * c11 - c01 * c01, _SQRT_EPS))
    tr_s = np.sqrt(c00 + c11 + 2.0 * sd)
    s00 = (c00 + sd) / tr_s
    s11 = (c11 + sd) / tr_s
    s01 = c01 / tr_s
    det_s = s00 * s11 - s01 * s01
    Sinv[0, 0] = s11 / det_s
    Sinv[1, 1] = s00 / det_s
    Sinv[0, 1] = -s01 / det_s
    Sinv[1, 0] = -s01 / det_s
    for i in range(3):
        for k in range(2):
            R[i, k] = F[i, 0] * Sinv[0, k] + F[i, 1] * Sinv[1, k]
    return tr_s


@numba.njit(cache=True)
def membrane_energy(x, tri, G, area, mu, lam):
    """Membrane energy [J] (``Membrane.energy``)."""
    F = np.empty((3, 2))
    R = np.empty((3, 2))
    Sinv = np.empty((2, 2))
    total = 0.0
    for e in range(tri.shape[0]):
        _deformation(x, tri, G, e, F)
        tr_s = _polar(F, R, Sinv)
        d = 0.0
        for i in range(3):
            for j in range(2):
                d += (F[i, j] - R[i, j]) ** 2
        total += area[e] * (mu * d + 0.5 * lam * (tr_s - 2.0) ** 2)
    return total


@numba.njit(cache=True)
def membrane_gradient(x, tri, G, area, mu, lam, out):
    """``out += dW/dx`` (n, 3) [N] (``Membrane.gradient``)."""
    F = np.empty((3, 2))
    R = np.empty((3, 2))
    Sinv = np.empty((2, 2))
    P = np.empty((3, 2))
    for e in range(tri.shape[0]):
        _deformation(x, tri, G, e, F)
        tr_s = _polar(F, R, Sinv)
        t = lam * (tr_s - 2.0)
        for i in range(3):
            for j in range(2):
                P[i, j] = area[e] * (2.0 * mu * (F[i, j] - R[i, j]) + t * R[i, j])
        for a in range(3):
            v = tri[e, a]
            for i in range(3):
                out[v, i] += P[i, 0] * G[e, a, 0] + P[i, 1] * G[e, a, 1]


@numba.njit(cache=True, parallel=True)
def membrane_hessian(x, tri, G, area, mu, lam, project, out, maps):
    """Per-triangle 9x9 Hessians [N/m] (``Membrane.hessian_blocks``): into ``out`` (m, 9, 9) if ``maps`` is
    empty, else added into the block matrix data ``out`` (nnzb, 3, 3) at the triangles' block positions
    ``maps`` (m, 3, 3). The blocks are computed in parallel chunks of triangles; the additions into
    ``out`` follow in triangle order (one thread), so every thread count gives the same sums."""
    m = tri.shape[0]
    scatter = maps.shape[0] > 0
    blocks = np.empty((m, 9, 9)) if scatter else out
    chunks = chunk_count(m, 256)
    none = np.empty((0, 3, 3))
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        _membrane_blocks(x, tri, G, area, mu, lam, project, blocks, start, stop, none)
    if scatter:
        for e in range(m):
            for a in range(3):
                for b in range(3):
                    p = maps[e, a, b]
                    for i in range(3):
                        for k in range(3):
                            out[p, i, k] += blocks[e, 3 * a + i, 3 * b + k]


@numba.njit(cache=True, parallel=True)
def membrane_hessian_and_gradient(x, tri, G, area, mu, lam, project, blocks, grads):
    """Per-triangle 9x9 Hessians [N/m] into ``blocks`` (m, 9, 9) and each triangle's gradient terms [N] into
    ``grads`` (m, 3, 3) (``grads[e, a]``: the term of its corner ``a``, as ``membrane_gradient`` adds it), in
    one pass over the triangles (parallel chunks)."""
    m = tri.shape[0]
    chunks = chunk_count(m, 256)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(m, chunks, ch)
        _membrane_blocks(x, tri, G, area, mu, lam, project, blocks, start, stop, grads)


@numba.njit(cache=True, parallel=True)
def gather_rows(ptr, src, values, w, k, out):
    """``out[v] = sum_q w[src[q] // k] * values[src[q]]`` over ``q`` in ``ptr[v]:ptr[v+1]`` for element vertex
    vectors ``values`` (m k, 3) and element weights ``w`` (m,): a serial ``out[verts[e, a]] += w[e] *
    values[e, a]`` from zeros in element order, the same bits, with the vertices in parallel chunks."""
    n = len(ptr) - 1
    chunks = chunk_count(n, 256)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(n, chunks, ch)
        for v in range(start, stop):
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for q in range(ptr[v], ptr[v + 1]):
                s = src[q]
                we = w[s // k]
                a0 += we * values[s, 0]
                a1 += we * values[s, 1]
                a2 += we * values[s, 2]
            out[v, 0] = a0
            out[v, 1] = a1
            out[v, 2] = a2


@numba.njit(cache=True)
def _membrane_blocks(x, tri, G, area, mu, lam, project, out, start, stop, grads):
    """The 9x9 Hessians of triangles ``start..stop-1`` into ``out`` (m, 9, 9), and, if ``grads`` is not
    empty, their gradient terms into ``grads`` (m, 3, 3)."""
    F = np.empty((3, 2))
    R = np.empty((3, 2))
    Sinv = np.empty((2, 2))
    H = np.empty((6, 6))
    r = np.empty(6)
    q = np.empty(6)
    w = np.empty(6)
    nrm = np.empty(3)
    V = np.empty((2, 2))
    T = np.empty((3, 3, 3, 2))
    for e in range(start, stop):
        _deformation(x, tri, G, e, F)
        tr_s = _polar(F, R, Sinv)
        if grads.shape[0] > 0:  # membrane_gradient's terms
            t = lam * (tr_s - 2.0)
            for i in range(3):
                p0 = area[e] * (2.0 * mu * (F[i, 0] - R[i, 0]) + t * R[i, 0])
                p1 = area[e] * (2.0 * mu * (F[i, 1] - R[i, 1]) + t * R[i, 1])
                for a in range(3):
                    grads[e, a, i] = p0 * G[e, a, 0] + p1 * G[e, a, 1]
        c = lam * (tr_s - 2.0) - 2.0 * mu
        for i in range(3):
            r[2 * i] = R[i, 0]
            r[2 * i + 1] = R[i, 1]
            q[2 * i] = R[i, 1]  # vec(R J)
            q[2 * i + 1] = -R[i, 0]
        for i in range(3):
            for k in range(3):
                pn = (1.0 if i == k else 0.0) - R[i, 0] * R[k, 0] - R[i, 1] * R[k, 1]
                for j in range(2):
                    for l in range(2):
                        H[2 * i + j, 2 * k + l] = c * (q[2 * i + j] * q[2 * k + l] / tr_s + pn * Sinv[j, l]) \
                            + lam * r[2 * i + j] * r[2 * k + l]
        for d in range(6):
            H[d, d] += 2.0 * mu
        if project:
            # the only eigenvalues that can be negative: the twist 2 mu + 2 c / tr S (vector q / sqrt 2)
            # and the out-of-plane 2 mu + c / sigma_k (vectors vec(n v_k^T)); clamp them at zero
            lam_l = 2.0 * mu + 2.0 * c / tr_s
            if lam_l < 0.0:
                for d in range(6):
                    for f in range(6):
                        H[d, f] -= lam_l * 0.5 * q[d] * q[f]
            c00 = F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0]
            c11 = F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1]
            c01 = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
            mean = 0.5 * (c00 + c11)
            rad = np.sqrt(0.25 * (c00 - c11) ** 2 + c01 * c01)
            # unit eigenvector of the larger eigenvalue, the other one orthogonal to it
            va0, va1 = c01, mean + rad - c00
            vb0, vb1 = mean + rad - c11, c01
            if va0 * va0 + va1 * va1 >= vb0 * vb0 + vb1 * vb1:
                u0, u1 = va0, va1
            else:
                u0, u1 = vb0, vb1
            un = np.sqrt(u0 * u0 + u1 * u1)
            if un > 0.0:
                u0 /= un
                u1 /= un
            else:
                u0, u1 = 1.0, 0.0
            V[0, 1], V[1, 1] = u0, u1
            V[0, 0], V[1, 0] = -u1, u0
            n0 = F[1, 0] * F[2, 1] - F[2, 0] * F[1, 1]
            n1 = F[2, 0] * F[0, 1] - F[0, 0] * F[2, 1]
            n2 = F[0, 0] * F[1, 1] - F[1, 0] * F[0, 1]
            nn = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-300)
            nrm[0], nrm[1], nrm[2] = n0 / nn, n1 / nn, n2 / nn
            for k in range(2):
                sig2 = mean - rad if k == 0 else mean + rad
                lam_n = 2.0 * mu + c / np.sqrt(max(sig2, _SQRT_EPS))
                if lam_n < 0.0:
                    for i in range(3):
                        for j in range(2):
                            w[2 * i + j] = nrm[i] * V[j, k]
                    for d in range(6):
                        for f in range(6):
                            H[d, f] -= lam_n * w[d] * w[f]
        # K[(a i), (b k)] = area * sum_jl G_aj H_(ij)(kl) G_bl, over j first: T[a, i, k, l]
        for a in range(3):
            for i in range(3):
                for k in range(3):
                    for l in range(2):
                        T[a, i, k, l] = G[e, a, 0] * H[2 * i, 2 * k + l] + G[e, a, 1] * H[2 * i + 1, 2 * k + l]
        for a in range(3):
            for b in range(3):
                for i in range(3):
                    for k in range(3):
                        out[e, 3 * a + i, 3 * b + k] = area[e] * (T[a, i, k, 0] * G[e, b, 0]
                                                                  + T[a, i, k, 1] * G[e, b, 1])


@numba.njit(cache=True)
def scatter_outer(data, maps, w, g):
    """``data[maps[e, a, b]] += w[e] g_a g_b^T`` for element vectors ``g`` (m, 3k) and weights ``w`` (m,):
    the Gauss-Newton Hessian blocks, assembled without forming them."""
    m, k = maps.shape[0], maps.shape[1]
    for e in range(m):
        for a in range(k):
            for b in range(k):
                p = maps[e, a, b]
                for r in range(3):
                    t = w[e] * g[e, 3 * a + r]
                    for c in range(3):
                        data[p, r, c] += t * g[e, 3 * b + c]


@numba.njit(cache=True, parallel=True)
def dihedral(x, hinges, theta, g):
    """Signed dihedral angles ``theta`` (h,) [rad] and their gradients ``g`` (h, 4, 3) [rad/m] at the
    hinges (h, 4) (``modalfem.cloth.energies.dihedral_angles``), filled in place; chunks of hinges in
    parallel (each hinge alone)."""
    count = hinges.shape[0]
    chunks = chunk_count(count, 256)
    for ch in numba.prange(chunks):
        start, stop = chunk_bounds(count, chunks, ch)
        _dihedral_range(x, hinges, theta, g, start, stop)


@numba.njit(cache=True)
def _dihedral_range(x, hinges, theta, g, start, stop):
    e = np.empty(3)
    da = np.empty(3)
    db = np.empty(3)
    n1 = np.empty(3)
    n2 = np.empty(3)
    for h in range(start, stop):
        i0, i1, ia, ib = hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3]
        for k in range(3):
            e[k] = x[i1, k] - x[i0, k]
            da[k] = x[ia, k] - x[i0, k]
            db[k] = x[ib, k] - x[i0, k]
        _cross(e, da, n1)  # normal of triangle (e0, e1, a), |n1| = 2 A1
        _cross(db, e, n2)  # normal of triangle (e1, e0, b), |n2| = 2 A2
        le2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
        le = np.sqrt(le2)
        s = ((n1[1] * n2[2] - n1[2] * n2[1]) * e[0] + (n1[2] * n2[0] - n1[0] * n2[2]) * e[1]
             + (n1[0] * n2[1] - n1[1] * n2[0]) * e[2]) / le
        c = n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2]
        theta[h] = np.arctan2(s, c)
        q1 = n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]
        q2 = n2[0] * n2[0] + n2[1] * n2[1] + n2[2] * n2[2]
        ta = (da[0] * e[0] + da[1] * e[1] + da[2] * e[2]) / le2  # a's foot along the edge (0 at e0)
        tb = (db[0] * e[0] + db[1] * e[1] + db[2] * e[2]) / le2
        for k in range(3):
            ga = -le / q1 * n1[k]
            gb = -le / q2 * n2[k]
            g[h, 0, k] = -(1.0 - ta) * ga - (1.0 - tb) * gb
            g[h, 1, k] = -ta * ga - tb * gb
            g[h, 2, k] = ga
            g[h, 3, k] = gb


@numba.njit(cache=True)
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@numba.njit(cache=True)
def scatter_rows(out, verts, values, w):
    """``out[verts[e, a]] += w[e] * values[e, a]`` for element vertex vectors ``values`` (m, k, 3)."""
    for e in range(verts.shape[0]):
        for a in range(verts.shape[1]):
            for c in range(3):
                out[verts[e, a], c] += w[e] * values[e, a, c]
