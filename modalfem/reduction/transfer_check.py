"""Accuracy of a coarse-to-fine transfer against a finer solve: ``check_transfer``, ``refine_mesh``.

The reference is a given finer tet mesh of the body (e.g. a mesh of the fine surface, which also
sees the coarse mesh's geometry error) or the coarse mesh refined once (each tetrahedron split into
8 at its edge midpoints: same geometry, half the element size; its P1/P2 space contains the coarse
one, so no reference frequency lies above the coarse one). Frequencies are compared after matching
modes by MAC; the MAC is taken on the fine surface vertices, weighted by vertex area (a third of the
adjacent triangles' areas, per component), between the transferred coarse modes and the reference
modes carried to the same vertices; each coarse mode is matched one to one to a reference mode (the
reference solve has a few more modes, so a mode that changed place in the order is still found).
Nearly degenerate modes (reference frequencies within ``cluster_tol`` of each other) rotate freely
within their pair, so the MAC is the subspace MAC: the W-norm share of the coarse mode inside the
span of its reference cluster (the plain MAC for a single mode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.reduction.render_surface import RenderSurface
from modalfem.reduction.transfer import TransferReport, transfer_modes

__all__ = ["TransferCheck", "check_transfer", "refine_mesh", "surface_mac"]


def refine_mesh(mesh):
    """``mesh`` with every tetrahedron split into 8 at its edge midpoints (tags split into 4 likewise).

    The points are ``mesh.dof_points(2)`` (vertices, then edge midpoints); the geometry is unchanged,
    the element size halves.

    Args:
        mesh: a ``Mesh`` [m].

    Returns:
        The refined ``Mesh``, all cells positively oriented.
    """
    from modalfem.mesh.core import Mesh

    n = mesh.point_count
    c = mesh.cell_nodes(2)  # 0..3 vertices, 4..9 midpoints of edges 01 02 03 12 13 23
    v0, v1, v2, v3, m01, m02, m03, m12, m13, m23 = c.T
    children = [
        (v0, m01, m02, m03), (m01, v1, m12, m13), (m02, m12, v2, m23), (m03, m13, m23, v3),
        (m02, m13, m01, m03), (m02, m13, m03, m23), (m02, m13, m23, m12), (m02, m13, m12, m01),
    ]
    cells = np.vstack([np.column_stack(ch) for ch in children])
    pts = mesh.dof_points(2)
    d = pts[cells]
    vol = np.einsum("ij,ij->i", d[:, 1] - d[:, 0], np.cross(d[:, 2] - d[:, 0], d[:, 3] - d[:, 0]))
    neg = vol < 0
    cells[neg] = cells[neg][:, [0, 2, 1, 3]]
    ekeys = mesh.edges[:, 0].astype(np.int64) * n + mesh.edges[:, 1]

    def mid(a, b):
        lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
        return n + np.searchsorted(ekeys, lo * n + hi)

    tags = {}
    for name, f in mesh.tags.items():
        if len(f) == 0:
            tags[name] = f
            continue
        a, b, cc = f.T
        ab, bc, ca = mid(a, b), mid(b, cc), mid(cc, a)
        tags[name] = np.vstack([np.column_stack(t) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, cc), (ab, bc, ca))])
    return Mesh(pts, cells, tags)


@dataclass(frozen=True)
class TransferCheck:
    """Transferred coarse modes against a finer solve, on the fine surface.

    Attributes:
        reference: ``"refined coarse mesh"`` or the reference mesh's description.
        reference_dof_count: DOFs of the reference solve.
        frequencies_hz: coarse frequencies (k,) [Hz].
        reference_frequencies_hz: frequencies of the matched reference modes (k,) [Hz].
        frequency_error: (coarse - reference) / reference (k,) [-].
        mac: area-weighted MAC on the fine surface vertices (k,) [-] (subspace MAC inside clusters).
        matched: index of the reference mode matched to each coarse mode (k,) (the reference solve
            computes k + max(2, k // 2) modes, so a coarse mode whose place in the order changed is found).
        reference_spectrum_hz: all frequencies of the reference solve (k_r,) [Hz].
        clusters: groups of reference mode indices treated as one (nearly) degenerate subspace.
        report: the ``TransferReport`` of the coarse transfer.
        seconds: wall time of the reference solve [s].
    """

    reference: str
    reference_dof_count: int
    frequencies_hz: np.ndarray
    reference_frequencies_hz: np.ndarray
    frequency_error: np.ndarray
    mac: np.ndarray
    matched: np.ndarray
    reference_spectrum_hz: np.ndarray
    clusters: tuple
    report: TransferReport
    seconds: float

    @property
    def max_frequency_error(self) -> float:
        """Largest |relative frequency error| [-]."""
        return float(np.max(np.abs(self.frequency_error)))

    @property
    def min_mac(self) -> float:
        """Smallest MAC [-]."""
        return float(np.min(self.mac))

    def as_dict(self) -> dict:
        """JSON-ready dict (frequencies in Hz)."""
        return {
            "reference": self.reference, "reference_dof_count": int(self.reference_dof_count),
            "frequencies_hz": [float(x) for x in self.frequencies_hz],
            "reference_frequencies_hz": [float(x) for x in self.reference_frequencies_hz],
            "frequency_error": [float(x) for x in self.frequency_error],
            "mac": [float(x) for x in self.mac], "matched": [int(x) for x in self.matched],
            "reference_spectrum_hz": [float(x) for x in self.reference_spectrum_hz], "clusters": [list(map(int, c)) for c in self.clusters],
            "max_frequency_error": self.max_frequency_error, "min_mac": self.min_mac,
            "mac_weighting": "fine-surface vertex areas; subspace MAC within clusters", "seconds": float(self.seconds),
        }


def _clusters(f: np.ndarray, tol: float) -> list[list[int]]:
    out: list[list[int]] = [[0]]
    for i in range(1, len(f)):
        if f[i] - f[i - 1] <= tol * f[i]:
            out[-1].append(i)
        else:
            out.append([i])
    return out


def surface_mac(approx: np.ndarray, ref: np.ndarray, weights: np.ndarray, f_ref: np.ndarray, *,
                cluster_tol: float = 0.01):
    """Match each approximate mode to a reference mode and measure its MAC on surface DOFs.

    Args:
        approx: approximate shapes (3 n, k).
        ref: reference shapes (3 n, k_r), k_r >= k, on the same vertices.
        weights: per-vertex weights (n,) (e.g. areas [m^2]).
        f_ref: reference frequencies (k_r,) [Hz], ascending.
        cluster_tol: reference modes whose frequencies differ by at most this fraction form one cluster.

    Returns:
        ``(matched, mac, clusters)``: the reference mode matched to each approximate mode (k,) (one to
        one, maximising the summed MAC; inside a cluster in frequency order), the MAC of each (k,):
        the W-norm share of the approximate mode inside the span of its reference cluster, and the
        clusters (lists of reference indices).
    """
    from modalfem.reduction.compare import mac_matrix, match_modes

    w = np.repeat(np.asarray(weights, dtype=np.float64), 3)
    s = np.sqrt(w)[:, None]
    A, B = approx * s, ref * s  # W-weighted shapes: plain products are W inner products
    matched = match_modes(mac_matrix(B, A))  # for each approximate mode, its reference mode
    clusters = _clusters(np.asarray(f_ref, dtype=np.float64), cluster_tol)
    cluster_of = np.empty(len(f_ref), dtype=np.int64)
    for c, members in enumerate(clusters):
        cluster_of[members] = c
    mac = np.empty(A.shape[1])
    for i in range(A.shape[1]):
        Q, _ = np.linalg.qr(B[:, clusters[cluster_of[matched[i]]]])
        a = A[:, i]
        mac[i] = min(1.0, float(np.sum((Q.T @ a) ** 2) / (a @ a)))
    for c in np.unique(cluster_of[matched]):  # inside a cluster the shapes may rotate: pair by frequency order
        idx = np.flatnonzero(cluster_of[matched] == c)
        matched[idx] = np.sort(matched[idx])
    return matched, mac, clusters


def check_transfer(result, mesh, material, surface: RenderSurface, *, reference_mesh=None, fixed=None,
                   backend: str = "auto", solver: str = "auto", lumped: bool = False,
                   max_distance: float | None = None, cluster_tol: float = 0.01, progress=None) -> TransferCheck:
    """Frequency error and MAC of the transferred coarse modes against a finer solve.

    Args:
        result: ``ModalResult`` on the coarse ``mesh``.
        mesh: the coarse ``Mesh`` [m].
        material: the ``Material`` of ``result``.
        surface: the fine ``RenderSurface`` [m].
        reference_mesh: a finer ``Mesh`` of the body (e.g. a tet mesh of the fine surface); None for
            ``refine_mesh(mesh)`` (same geometry, half the element size).
        fixed: the constraints ``result`` was computed with (tag names must exist on the reference).
        backend, solver, lumped: as for ``modalfem.modes`` (the reference uses the result's degree).
        max_distance: see ``transfer_modes`` [m].
        cluster_tol: relative frequency spacing below which reference modes form one cluster [-].
        progress: optional callable(str) for stage lines (passed to the reference solve).

    Returns:
        ``TransferCheck``.
    """
    import time

    import modalfem
    from modalfem.reduction.compare import frequency_errors
    from modalfem.reduction.embed import embed_points

    say = progress if callable(progress) else (lambda msg: None)
    shapes, report = transfer_modes(result, mesh, surface.vertices, max_distance=max_distance)
    if reference_mesh is None:
        say("check transfer: refining the coarse mesh (each tetrahedron into 8)")
        ref_mesh, what = refine_mesh(mesh), "refined coarse mesh"
    else:
        ref_mesh, what = reference_mesh, f"reference mesh ({reference_mesh.cell_count} tetrahedra)"
    k = len(result.omega)
    t0 = time.perf_counter()  # a few more reference modes, so that reordered coarse modes find their partner
    ref = modalfem.modes(ref_mesh, material, k=k + max(2, k // 2), degree=int(result.degree), fixed=fixed, backend=backend,
                         solver=solver, lumped=lumped, progress=progress)
    seconds = time.perf_counter() - t0
    say("check transfer: comparing on the fine surface")
    ref_shapes = embed_points(ref_mesh, surface.vertices).transfer(ref.shapes, degree=int(ref.degree))
    f_ref = np.asarray(ref.frequencies_hz)
    matched, mac, clusters = surface_mac(shapes, ref_shapes, surface.vertex_areas(), f_ref, cluster_tol=cluster_tol)
    f = np.asarray(result.frequencies_hz)
    return TransferCheck(reference=what, reference_dof_count=int(ref.shapes.shape[0]), frequencies_hz=f,
                         reference_frequencies_hz=f_ref[matched], frequency_error=frequency_errors(f, f_ref[matched]),
                         mac=mac, matched=matched, reference_spectrum_hz=f_ref,
                         clusters=tuple(tuple(c) for c in clusters), report=report, seconds=seconds)
