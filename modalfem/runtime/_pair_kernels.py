"""Compiled body-body contact search of ``runtime.pairs.ContactGroup`` (numba ``njit(cache=True)``).

``pair_contacts`` does in one call what took a dozen numpy calls and a BVH query per pair of bodies: the
vertices of body a inside body b's box grown by the search radius, a box query of each against b's tree
(``collision._bvh_kernels._query_range``, the serial walk of ``BroadPhaseBVH.query``: the same pairs in the
same order), the closest of the candidate triangles (``_contact_kernels.closest_triangles``) and the selection
of the vertices within the radius.
"""

from __future__ import annotations

import numba
import numpy as np

from modalfem.collision._bvh_kernels import _query_range
from modalfem.runtime._contact_kernels import closest_triangles

__all__ = ["pair_contacts"]


@numba.njit(cache=True)
def pair_contacts(xa, box_lo, box_hi, r, P, lo, hi, nonempty, slot_tri, slo, shi, Xb, Tb, tie_rel):
    """Vertices of a near the deformed surface of b.

    Args:
        xa: (na, 3) world vertices of body a [m].
        box_lo, box_hi: (3,) world box of body b [m]; r: search radius [m].
        P, lo, hi, nonempty, slot_tri, slo, shi: b's tree (``BroadPhaseBVH`` arrays, refitted to ``Xb``).
        Xb: (nb, 3) world vertices of b [m]; Tb: (mb, 3) its outward triangles; tie_rel: as
            ``closest_triangles``.

    Returns:
        ``(vertex, triangle, bary, normal, gap, point)`` of the vertices whose closest triangle of b is within
        (-r, r): (k,) vertex of a, (k,) triangle of b, (k, 3) barycentric weights, (k, 3) normal out of b,
        (k,) gap [m], (k, 3) the vertex [m]. Every triangle within r of a vertex is a candidate, so a closest
        distance below r is the true one; a vertex whose candidates are all farther is not judged.
    """
    na = xa.shape[0]
    near = np.empty(na, dtype=np.int64)
    m = 0
    for j in range(na):
        if (box_lo[0] - r <= xa[j, 0] <= box_hi[0] + r and box_lo[1] - r <= xa[j, 1] <= box_hi[1] + r
                and box_lo[2] - r <= xa[j, 2] <= box_hi[2] + r):
            near[m] = j
            m += 1
    p = np.empty((m, 3))
    qlo = np.empty((m, 3))
    qhi = np.empty((m, 3))
    for i in range(m):
        for c in range(3):
            x = xa[near[i], c]
            p[i, c] = x
            qlo[i, c] = x - r
            qhi[i, c] = x + r
    pairs = _query_range(qlo, qhi, 0, m, P, lo, hi, nonempty, slot_tri, slo, shi)
    best, w, gap, nrm = closest_triangles(p, pairs[:, 0].copy(), pairs[:, 1].copy(), Xb, Tb, tie_rel)
    k = 0
    for i in range(m):
        if best[i] >= 0 and gap[i] < r and gap[i] > -r:
            k += 1
    vertex = np.empty(k, dtype=np.int64)
    tri = np.empty(k, dtype=np.int64)
    bary = np.empty((k, 3))
    normal = np.empty((k, 3))
    g = np.empty(k)
    point = np.empty((k, 3))
    k = 0
    for i in range(m):
        if best[i] >= 0 and gap[i] < r and gap[i] > -r:
            vertex[k] = near[i]
            tri[k] = best[i]
            g[k] = gap[i]
            for c in range(3):
                bary[k, c] = w[i, c]
                normal[k, c] = nrm[i, c]
                point[k, c] = p[i, c]
            k += 1
    return vertex, tri, bary, normal, g, point
