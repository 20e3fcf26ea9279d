"""Mode labels read from the mode shapes: ``"bending-y 1"``, ``"torsion 1"``, ``"plate (2,1)"`` on beams
and plates; neutral labels (``"bending about x"``, ``"breathing"``, ``"mode 7"``) on every other body.

Convention (what a label means):

* **Body frame.** The node cloud's principal axes (PCA about the node centroid) give a local frame
  ``e1, e2, e3`` ordered by decreasing spread. When the covariance is diagonal in the global axes (an
  axis-aligned body) or a principal axis is within 1 degree of a global axis, the axis is snapped to
  that global axis and *named* after it (``"x"``, ``"y"``, ``"z"``); otherwise the axes are named
  ``"a"`` (the long axis) and ``"t1"``, ``"t2"`` (the transverse axes, ``t1`` the wider one), or for
  plates ``"p1"``, ``"p2"`` in-plane and ``"n"`` normal. If the two transverse spreads are within 5 % of
  each other (a square or round section) and the long axis is a global axis, the other two global axes
  are used.
* **Kind** (beam- and plate-likeness, decided from the geometry of the points alone). The extents
  ``L1 >= L2 >= L3`` are the ranges of the points along ``e1, e2, e3``. The points are binned into an
  occupancy grid aligned with the frame whose cell edge along each axis is the node spacing along it
  (median over the nodes of the largest offset along that axis among the 12 nearest neighbours, so
  anisotropic structured meshes are measured per axis); **fill** = occupied cells / all cells of the
  oriented bounding box, and the occupied cells' 26-connected components count the **pieces** (or the
  ``pieces`` labels decide, when given). The body is

  - ``"beam"`` when ``L1 >= 3 L2`` (slender), fill >= 0.6, one piece, and the section is
    roughly prismatic: every slice of the grid along ``e1`` spans at least half of the largest slice
    width along ``e2`` and along ``e3`` (a tuning fork's stem is a third of its prongs' width; a
    hammer's handle a fraction of its head);
  - ``"plate"`` when ``L3 <= 0.2 L2`` (flat), fill >= 0.6 and one piece;
  - ``"solid"`` otherwise (two bars side by side, an L bracket, a bell, a bunny, a CAD part).

  Why 0.6: a filled round section already reads ~0.8 (pi / 4 plus the cells its boundary cuts), a
  rectangle or a structured box mesh reads 1.0, while bodies made of separated arms (an L or U of
  bars, a fork, two bars) leave most of their box empty and read ~0.2-0.5. Hollow sections (tubes)
  also fill their box poorly and are treated as solids. The 3x and 0.2x extent ratios are the
  usual slenderness / thinness limits of beam and plate theory (a beam 3x longer than wide still has
  well separated bending, torsion and axial families; a plate 5x wider than thick bends out of plane).
* **Beam decomposition.** The displacement is fitted (least squares over all nodes, piecewise-linear
  functions of the axial coordinate s) by rigid section motions plus two section modes:
  ``u = t(s) + theta(s) x r + eps(s) (eta e2 + zeta e3) + w(s) eta zeta e1 + residual``
  (r = (0, eta, zeta) the position in the section). The energy-like fractions are squared-displacement
  norms of the parts over the nodes divided by ``sum |u|^2``:
  ``axial`` = t1 and the Poisson breathing eps; ``bending-<e2>`` = t2 and the section rotation theta3
  (displacement along e2); ``bending-<e3>`` = t3 and theta2; ``torsion`` = theta1 and the warping w;
  the rest is ``residual``. A component with fraction >= ``threshold`` (default 0.6) names the mode,
  provided its rigid-section part alone (t1, t2, t3 or theta1) holds >= 50 % (so a motion that is
  mostly "breathing" or "warping" is ``"mixed"``).
* **Order** counts sign changes (with 10 % hysteresis) along the axis of the dominant function
  (t2/t3 projected on the bending direction, t1 for axial, theta1 for torsion). An end is *held* when
  the displacement of that component at the end face is below 1e-6 of the mode's maximum (clamped,
  pinned or a per-component fix). Bending ``n`` = changes + 1 when an end is held, changes - 1 for
  a free-free beam (its first flexible mode, with two nodes, is ``bending 1``); axial and torsion
  ``n`` = changes + 1 when held, else changes (free-free ``axial 1`` has one node).
* **Degenerate pairs.** Two consecutive modes that are both bending of the same order (a square or
  round section: the pair may come out of the solver rotated by any angle in its 2D subspace) are
  rotated inside their subspace to the basis that maximises / minimises the ``bending-<e2>`` energy
  (2x2 eigenproblem); the rotated modes are labelled, and each original mode takes the label of the
  rotated mode it overlaps most. Labels of a pair are therefore always one ``bending-<e2> n`` and one
  ``bending-<e3> n``, whatever the mixing angle.
* **Plates.** ``"plate (m,n)"`` when the out-of-plane (along the normal) fraction is >= ``threshold``;
  ``m`` / ``n`` are the numbers of nodal lines crossed moving along in-plane axis 1 / axis 2 (median
  over grid lines, 10 % hysteresis), so a twisting mode is ``plate (1,1)`` and
  ``sin(2 pi x / a) sin(pi y / b)`` is ``plate (1,0)``. Mostly in-plane modes are ``"in-plane"``.
  Beam or plate modes that fit no family are ``"mixed"``.
* **Neutral labels** (solids, and any mode of a beam or plate whose numbered label is already taken).
  The motion is projected (least squares over the nodes, coordinates about the centroid) on a few
  global low-order fields, and the field family holding >= ``threshold`` of ``sum |u|^2`` names it:
  ``"sway along x"`` (uniform translation, e.g. a clamped body swaying), ``"rocking about x"`` (rigid
  rotation), the uniform strain read from its principal strains ``"stretch along x"`` (one principal
  strain holds >= ``threshold`` of the strain field), ``"breathing"`` (all three of one sign),
  ``"stretch in x-y"`` / ``"shear in x-y"`` (two principal strains of equal / opposite sign, named by
  their plane), ``"twist about z"`` (rotation about z growing along z) and ``"bending about z"`` (rotation
  about z growing along x or y, Euler-Bernoulli kinematics). An axis or plane is named only when the
  motion's axis lies within ~27 degrees of a global axis (80 % of its square on it), else it is left
  out (``"bending"``). A motion no family explains is ``"mode <i>"`` (i = its 1-based column). These
  labels carry no order number: a solid has no beam-theory ordering to number.
* **Pieces.** With ``pieces`` (a piece label per point, e.g. ``modalfem.eigen.rigid.node_pieces``),
  a mode whose squared displacement lies >= 90 % in one piece is labelled on that piece alone, with
  that piece's own kind, as ``"piece <p>: <label>"`` (p = the given piece label). A run of consecutive
  modes none of which is dominated is first rotated inside its span to piece-local vectors when the span
  is a sum of such vectors (degenerate modes of identical pieces come out of the solver mixed); the
  rotated modes are labelled and each original takes the label of the rotated mode it overlaps most.
  Modes still shared by several pieces get a neutral label of the whole body: never a beam or plate
  label across pieces.
* **Uniqueness.** A numbered label (beam or plate family) appears at most once per call: a later mode
  that reads the same label gets its neutral label instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalfem.errors import InputError

__all__ = ["KINDS", "BodyFrame", "body_frame", "label_modes", "mode_fractions"]

KINDS = ("beam", "plate", "solid")
_HELD_RTOL = 1e-6
_HYSTERESIS = 0.1
_SNAP_COS = np.cos(np.radians(1.0))
#: kind thresholds (module doc): slenderness, thinness, fill of the oriented box, slice width ratio
BEAM_RATIO = 3.0
PLATE_RATIO = 0.2
FILL_MIN = 0.6
SLICE_MIN = 0.5
#: share of sum |u|^2 in one piece for that piece to name the mode
PIECE_SHARE = 0.9
_AXIS_SHARE = 0.8  # a direction is named after a global axis when >= 80 % of its square lies on it
_GRID_MAX = 64  # occupancy cells per axis at most
_NEIGHBOURS = 12


@dataclass(frozen=True)
class BodyFrame:
    """Principal frame of a node cloud.

    Attributes:
        center: node centroid (3,) [m].
        axes: rows e1, e2, e3 (3, 3), orthonormal, decreasing spread (e3 = plate normal).
        extents: ranges of the nodes along e1, e2, e3 (3,) [m].
        names: axis names used in labels, global letters where aligned (see module doc).
        kind: ``"beam"``, ``"plate"`` or ``"solid"``.
        fill: occupied fraction of the oriented bounding box (see module doc), in (0, 1].
        pieces: connected pieces (given, or seen in the occupancy grid).
        slice_width: smallest slice width over the largest, along ``e1`` (worst of e2, e3), in [0, 1].
    """

    center: np.ndarray
    axes: np.ndarray
    extents: np.ndarray
    names: tuple[str, str, str]
    kind: str
    fill: float = 1.0
    pieces: int = 1
    slice_width: float = 1.0


def _check_points(points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4:
        raise InputError(f"points must have shape (n, 3) with n >= 4, got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError("points must be finite")
    return p


def _check_pieces(pieces, n: int) -> np.ndarray | None:
    if pieces is None:
        return None
    a = np.asarray(pieces)
    if a.shape != (n,):
        raise InputError(f"pieces must have shape ({n},) (one label per point), got {a.shape}")
    if a.dtype.kind not in "iub":
        if a.dtype.kind != "f" or not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise InputError("pieces must be integer labels")
    return a.astype(np.int64)


def _occupancy(q: np.ndarray, ext: np.ndarray) -> tuple[float, int, float]:
    """Fill of the oriented box, 26-connected pieces and slice-width ratio of local points q (N, 3)."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    n = len(q)
    k = min(_NEIGHBOURS + 1, n)
    sample = q[:: max(1, n // 2000)]
    _, idx = cKDTree(q).query(sample, k=k)
    h = np.median(np.abs(q[idx[:, 1:]] - sample[:, None, :]).max(axis=1), axis=0)
    # one cell per node level: ext / h + 1 cells, nodes rounded to the nearest cell centre
    bins = np.where(h > 1e-12 * max(float(ext.max()), 1e-300),
                    np.floor(ext / np.maximum(h, 1e-300)) + 1, 1).astype(np.int64)
    bins = np.clip(bins, 1, _GRID_MAX)
    t = (q - q.min(axis=0)) / np.maximum(ext, 1e-300)
    ij = np.clip(np.rint(t * (bins - 1)).astype(np.int64), 0, bins - 1)
    occ = np.zeros(tuple(bins), dtype=bool)
    occ[ij[:, 0], ij[:, 1], ij[:, 2]] = True
    pieces = int(ndimage.label(occ, structure=np.ones((3, 3, 3), dtype=bool))[1])
    lo = np.full((bins[0], 2), np.inf)
    hi = np.full((bins[0], 2), -np.inf)
    for a in (1, 2):
        np.minimum.at(lo[:, a - 1], ij[:, 0], q[:, a])
        np.maximum.at(hi[:, a - 1], ij[:, 0], q[:, a])
    filled = np.isfinite(lo[:, 0])
    width = np.where(filled[:, None], hi - lo, 0.0)
    big = width.max(axis=0)
    ratio = float(np.min(np.where(big > 0, width / np.where(big > 0, big, 1.0), 1.0)))
    return float(occ.mean()), pieces, ratio


def body_frame(points, *, kind: str | None = None, pieces=None) -> BodyFrame:
    """Principal axes, extents, axis names and kind of a node cloud (see module doc).

    Args:
        points: node coordinates (N, 3) [m].
        kind: force ``"beam"``, ``"plate"`` or ``"solid"``; None detects it from the extents, the fill
            of the oriented bounding box, the slice widths and the pieces.
        pieces: optional piece label per point (N,); more than one piece makes the body a ``"solid"``.

    Raises:
        InputError: bad points, kind or pieces.
    """
    p = _check_points(points)
    given = _check_pieces(pieces, len(p))
    if kind is not None and kind not in KINDS:
        raise InputError(f"kind must be one of {', '.join(KINDS)} or None, got {kind!r}")
    center = p.mean(axis=0)
    X = p - center
    C = X.T @ X / len(X)
    d = np.sqrt(np.maximum(np.diag(C), 1e-300))
    corr = np.abs(C / np.outer(d, d) - np.eye(3)).max()
    names = ["", "", ""]
    if corr < 1e-2:  # axis-aligned: use the global axes ordered by spread
        v = np.diag(C)
        order = list(np.argsort(-v, kind="stable"))
        for j in (0, 1, 0):  # nearly equal spreads (within 5 %): keep x, y, z order
            a, b = order[j], order[j + 1]
            if abs(v[a] - v[b]) <= 0.05 * max(v[a], v[b]) and b < a:
                order[j], order[j + 1] = b, a
        axes = np.eye(3)[order]
        names = ["xyz"[i] for i in order]
    else:
        vals, vecs = np.linalg.eigh(C)
        order = np.argsort(-vals, kind="stable")
        vals, axes = vals[order], vecs[:, order].T.copy()
        for i in range(3):
            g = int(np.argmax(np.abs(axes[i])))
            if abs(axes[i, g]) >= _SNAP_COS:
                axes[i] = np.eye(3)[g]
                names[i] = "xyz"[g]
        if names[0] and abs(vals[1] - vals[2]) <= 0.05 * vals[1]:
            g0 = "xyz".index(names[0])
            rest = [g for g in range(3) if g != g0]
            axes = np.eye(3)[[g0, *rest]]
            names = [names[0], "xyz"[rest[0]], "xyz"[rest[1]]]
        # re-orthonormalise after snapping (keep e1 exact)
        q, _ = np.linalg.qr(axes.T)
        q = q * np.sign(np.sum(q * axes.T, axis=0))
        axes = q.T
    q = X @ axes.T
    ext = np.ptp(q, axis=0)
    fill, seen, slice_width = _occupancy(q, ext)
    n_pieces = len(np.unique(given)) if given is not None else seen
    if kind is None:
        whole = fill >= FILL_MIN and n_pieces == 1
        if ext[0] >= BEAM_RATIO * ext[1]:
            kind = "beam" if whole and slice_width >= SLICE_MIN else "solid"
        elif ext[2] <= PLATE_RATIO * ext[1]:
            kind = "plate" if whole else "solid"
        else:
            kind = "solid"
    default = ("p1", "p2", "n") if kind == "plate" else ("a", "t1", "t2")
    names = tuple(n if n else default[i] for i, n in enumerate(names))
    return BodyFrame(center=center, axes=axes, extents=ext, names=names, kind=kind, fill=fill, pieces=n_pieces,
                     slice_width=slice_width)


# ----------------------------------------------------------------------------- helpers
def _sign_changes(f: np.ndarray, scale: float | None = None) -> int:
    """Sign changes of samples ``f`` ignoring values within 10 % of ``scale`` (default max |f|) of 0."""
    f = np.asarray(f, dtype=float)
    a = float(np.max(np.abs(f))) if scale is None else scale
    if a == 0.0 or len(f) == 0:
        return 0
    s = np.sign(f) * (np.abs(f) > _HYSTERESIS * a)
    s = s[s != 0]
    return int(np.count_nonzero(s[1:] != s[:-1]))


def _hats(t: np.ndarray, knots: int):
    """Piecewise-linear hat functions on [0, 1] at t: sparse (N, knots)."""
    import scipy.sparse as sp

    x = np.clip(t, 0.0, 1.0) * (knots - 1)
    i = np.minimum(np.floor(x).astype(np.int64), knots - 2)
    w = x - i
    rows = np.arange(len(t))
    return sp.csr_matrix((np.concatenate([1.0 - w, w]), (np.concatenate([rows, rows]), np.concatenate([i, i + 1]))),
                         shape=(len(t), knots))


def _check_shapes(shapes, n: int) -> np.ndarray:
    S = np.asarray(shapes, dtype=np.float64)
    if S.ndim == 1:
        S = S[:, None]
    if S.ndim != 2 or S.shape[0] != 3 * n:
        raise InputError(f"shapes must have shape (3 N, k) = ({3 * n}, k) for N = {n} points, got {S.shape}")
    if not np.all(np.isfinite(S)):
        raise InputError("shapes must be finite")
    return S


@dataclass
class _BeamFit:
    """Least-squares section-motion fit of k modes (all linear in the modes, so pairs rotate by R)."""

    K: int  # knots
    G1: np.ndarray  # Gram of the axial-displacement basis (4K, 4K): t1, eta-theta3, zeta-theta2, warping
    G23: np.ndarray  # Gram of the transverse basis (4K, 4K): t2, t3, theta1, breathing
    c1: np.ndarray  # coefficients (4K, k)
    c23: np.ndarray  # coefficients (4K, k)
    total: np.ndarray  # sum |u|^2 per mode (k,)

    def block(self, which: str, j: int) -> np.ndarray:
        c = self.c1 if which == "1" else self.c23
        return c[j * self.K:(j + 1) * self.K]

    def energy(self, which: str, j: int) -> np.ndarray:
        G = self.G1 if which == "1" else self.G23
        sl = slice(j * self.K, (j + 1) * self.K)
        c = self.block(which, j)
        return np.einsum("ak,ab,bk->k", c, G[sl, sl], c)

    def bend2_gram(self) -> np.ndarray:
        """(k, k) inner products of the bending-e2 parts (translation t2 + rotation theta3)."""
        K = self.K
        a, b = self.c1[K:2 * K], self.c23[:K]
        return a.T @ self.G1[K:2 * K, K:2 * K] @ a + b.T @ self.G23[:K, :K] @ b

    def rotated(self, cols, R: np.ndarray) -> _BeamFit:
        c1, c23 = self.c1[:, cols] @ R, self.c23[:, cols] @ R
        return _BeamFit(self.K, self.G1, self.G23, c1, c23, total=np.zeros(R.shape[1]))

    @property
    def axial(self) -> np.ndarray:
        return self.block("1", 0)

    @property
    def trans(self) -> np.ndarray:
        return np.stack([self.block("23", 0), self.block("23", 1)], axis=1)

    @property
    def twist(self) -> np.ndarray:
        return self.block("23", 2)

    def core(self) -> np.ndarray:
        """(4, k) fractions of the rigid-section parts alone: t1, t2, t3, theta1 (no section modes)."""
        total = np.where(self.total > 0, self.total, np.inf)
        return np.array([self.energy("1", 0), self.energy("23", 0), self.energy("23", 1), self.energy("23", 2)]) / total

    def fractions(self, names: tuple[str, str, str]) -> list[dict[str, float]]:
        parts = {
            "axial": self.energy("1", 0) + self.energy("23", 3),  # t1 + Poisson breathing
            f"bending-{names[1]}": self.energy("1", 1) + self.energy("23", 0),  # theta3 + t2
            f"bending-{names[2]}": self.energy("1", 2) + self.energy("23", 1),  # theta2 + t3
            "torsion": self.energy("23", 2) + self.energy("1", 3),  # theta1 + warping
        }
        total = np.where(self.total > 0, self.total, np.inf)
        out = []
        for i in range(len(total)):
            f = {key: float(min(1.0, max(0.0, v[i] / total[i]))) for key, v in parts.items()}
            f["residual"] = max(0.0, 1.0 - sum(f.values()))
            out.append(f)
        return out


def _beam_fit(p: np.ndarray, U: np.ndarray) -> _BeamFit:
    """Fit ``u = t(s) + theta(s) x r + eps(s) (0, eta, zeta) + w(s) eta zeta e1`` (local frame).

    p (N, 3) local coordinates, U (N, 3, k) local displacements. Normal equations of a sparse
    piecewise-linear basis in s (a few dozen knots); the section weights are scaled to O(1).
    """
    import scipy.sparse as sp

    N = U.shape[0]
    s = p[:, 0]
    L = max(float(np.ptp(s)), 1e-300)
    t = (s - s.min()) / L
    planes = len(np.unique(np.round(t, 6)))
    K = int(min(64, max(4, planes // 2)))
    H = _hats(t, K)
    rs = max(float(np.sqrt(np.mean(p[:, 1] ** 2 + p[:, 2] ** 2))), 1e-300)
    eta, zeta = p[:, 1] / rs, p[:, 2] / rs
    ez = eta * zeta
    ez = ez / max(float(np.sqrt(np.mean(ez**2))), 1e-300)
    D = sp.diags
    B1 = sp.hstack([H, D(eta) @ H, D(zeta) @ H, D(ez) @ H]).tocsr()
    Z = sp.csr_matrix((N, K))
    B23 = sp.vstack([
        sp.hstack([H, Z, D(-zeta) @ H, D(eta) @ H]),
        sp.hstack([Z, H, D(eta) @ H, D(zeta) @ H]),
    ]).tocsr()

    def solve(B, rhs):
        G = (B.T @ B).toarray()
        # = lstsq(G, B^T rhs, rcond=1e-12): G is symmetric, so its SVD is its eigendecomposition (up to
        # signs) and the pseudo-inverse keeps the eigenvalues with |w| > 1e-12 max |w| (eigh: ~2x faster)
        w, V = np.linalg.eigh(0.5 * (G + G.T))
        keep = np.abs(w) > 1e-12 * np.abs(w).max()
        Vk = V[:, keep]
        return G, Vk @ ((Vk.T @ (B.T @ rhs)) / w[keep][:, None])

    G1, c1 = solve(B1, U[:, 0, :])
    G23, c23 = solve(B23, np.vstack([U[:, 1, :], U[:, 2, :]]))
    return _BeamFit(K, G1, G23, c1, c23, total=np.einsum("nck,nck->k", U, U))


def _local(frame: BodyFrame, points: np.ndarray, S: np.ndarray):
    """Local coordinates (N, 3) and local displacements (N, 3, k)."""
    p = (points - frame.center) @ frame.axes.T
    U = np.einsum("ij,njk->nik", frame.axes, S.reshape(len(points), 3, -1))
    return p, U


def _end_held(p: np.ndarray, U: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(k,) bool: the displacement along ``direction`` (3,) (local) vanishes at an end face."""
    s = p[:, 0]
    tol = 1e-6 * max(float(np.ptp(s)), 1e-300)
    scale = np.sqrt(np.einsum("nck,nck->nk", U, U)).max(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    comp = np.abs(np.einsum("c,nck->nk", direction, U))
    held = np.zeros(U.shape[2], dtype=bool)
    for end in (s <= s.min() + tol, s >= s.max() - tol):
        held |= comp[end].max(axis=0) <= _HELD_RTOL * scale
    return held


# ----------------------------------------------------------------------------- public API
def mode_fractions(points, shapes, *, kind: str | None = None) -> list[dict[str, float]]:
    """Energy-like fractions of each mode (see module doc).

    Args:
        points: node coordinates (N, 3) [m].
        shapes: mode shapes (3 N, k) in node-major order (DOF ``3 a + c``); any units/normalisation.
        kind: ``"beam"``, ``"plate"``, ``"solid"`` or None (detect).

    Returns:
        Per mode a dict: beams/solids ``axial``, ``bending-<e2 name>``, ``bending-<e3 name>``,
        ``torsion``, ``residual``; plates ``plate`` (out-of-plane) and ``in-plane``. Values in [0, 1].
    """
    p_all = _check_points(points)
    S = _check_shapes(shapes, len(p_all))
    frame = body_frame(p_all, kind=kind)
    p, U = _local(frame, p_all, S)
    if frame.kind == "plate":
        return [_plate_fraction(U[:, :, i]) for i in range(U.shape[2])]
    return _beam_fit(p, U).fractions(frame.names)


def _plate_fraction(u: np.ndarray) -> dict[str, float]:
    tot = float(np.sum(u**2)) or 1.0
    w = float(np.sum(u[:, 2] ** 2)) / tot
    return {"plate": w, "in-plane": 1.0 - w}


def _plate_label(p: np.ndarray, u: np.ndarray, threshold: float) -> str:
    f = _plate_fraction(u)
    if f["plate"] < threshold:
        return "in-plane" if f["in-plane"] >= threshold else "mixed"
    w = u[:, 2]
    lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
    counts = []
    for a in (0, 1):
        uniq = len(np.unique(np.round((p[:, a] - lo[a]) / max(hi[a] - lo[a], 1e-300), 6)))
        counts.append(int(min(40, max(2, uniq))))
    idx = [np.minimum(((p[:, a] - lo[a]) / max(hi[a] - lo[a], 1e-300) * counts[a]).astype(int), counts[a] - 1)
           for a in (0, 1)]
    sums = np.zeros(counts)
    nums = np.zeros(counts)
    np.add.at(sums, (idx[0], idx[1]), w)
    np.add.at(nums, (idx[0], idx[1]), 1.0)
    grid = np.where(nums > 0, sums / np.maximum(nums, 1), np.nan)
    scale = float(np.nanmax(np.abs(grid))) or 1.0
    mn = []
    for a in (0, 1):
        lines = grid if a == 0 else grid.T  # a == 0: walk along axis 1 (rows = positions along axis 2)
        lines = lines.T  # each row: samples along axis a
        c = []
        for row in lines:
            row = row[~np.isnan(row)]
            if len(row) >= 2 and np.max(np.abs(row)) > _HYSTERESIS * scale:
                c.append(_sign_changes(row, scale))
        mn.append(round(float(np.median(c))) if c else 0)
    return f"plate ({mn[0]},{mn[1]})"


def _beam_labels(frame: BodyFrame, p: np.ndarray, U: np.ndarray, fit: _BeamFit, threshold: float) -> list[str]:
    n2, n3 = frame.names[1], frame.names[2]
    labels = []
    core = fit.core()
    for i, f in enumerate(fit.fractions(frame.names)):
        comps = {"axial": f["axial"], "b2": f[f"bending-{n2}"], "b3": f[f"bending-{n3}"], "torsion": f["torsion"]}
        best = max(comps, key=comps.get)
        # the section motion itself (t1, t2, t3 or theta1) must carry half the energy: a body that is
        # not a prism (tuning fork prongs, ...) can put its energy in the breathing / warping fields
        core_i = core[["axial", "b2", "b3", "torsion"].index(best), i]
        if comps[best] < threshold or core_i < 0.5:
            labels.append("mixed")
            continue
        if best in ("b2", "b3"):
            d = np.array([0.0, 1.0, 0.0]) if best == "b2" else np.array([0.0, 0.0, 1.0])
            curve = fit.trans[:, 0 if best == "b2" else 1, i]
            held = _end_held(p, U[:, :, i:i + 1], d)[0]
            nc = _sign_changes(curve)
            n = nc + 1 if held else nc - 1
            labels.append(f"bending-{n2 if best == 'b2' else n3} {max(n, 1)}")
        elif best == "axial":
            held = _end_held(p, U[:, :, i:i + 1], np.array([1.0, 0.0, 0.0]))[0]
            nc = _sign_changes(fit.axial[:, i])
            labels.append(f"axial {max(nc + 1 if held else nc, 1)}")
        else:
            held = bool(_end_held(p, U[:, :, i:i + 1], np.array([0.0, 1.0, 0.0]))[0]
                        and _end_held(p, U[:, :, i:i + 1], np.array([0.0, 0.0, 1.0]))[0])
            nc = _sign_changes(fit.twist[:, i])
            labels.append(f"torsion {max(nc + 1 if held else nc, 1)}")
    return labels


def _bending_order(fit: _BeamFit, i: int) -> int:
    """Sign changes of the transverse translation projected on its principal direction."""
    v = fit.trans[:, :, i]
    _, _, vt = np.linalg.svd(v, full_matrices=False)
    return _sign_changes(v @ vt[0])


# ----------------------------------------------------------------------------- neutral labels
_EYE = np.eye(3)


def _axis_name(v: np.ndarray) -> str:
    """Global axis letter of direction v (3,) when >= _AXIS_SHARE of |v|^2 lies on it, else ''."""
    s = np.asarray(v, dtype=float) ** 2
    tot = float(s.sum())
    if tot <= 0.0:
        return ""
    g = int(np.argmax(s))
    return "xyz"[g] if s[g] >= _AXIS_SHARE * tot else ""


def _plane_name(normal: np.ndarray) -> str:
    g = _axis_name(normal)
    return {"x": "y-z", "y": "x-z", "z": "x-y"}.get(g, "")


def _named(word: str, joiner: str, where: str) -> str:
    return f"{word} {joiner} {where}" if where else word


class _Neutral:
    """Projections of modes on global low-order field families over one set of points (module doc)."""

    def __init__(self, points: np.ndarray):
        d = points - points.mean(axis=0)
        x = d / (float(np.sqrt((d**2).sum(axis=1).mean())) or 1.0)
        n = len(x)
        self.C = x.T @ x / n  # second moments of the scaled coordinates

        def vec_field(vec):  # a constant direction per node (n, 3) from (3,) or per-node weights
            return np.broadcast_to(vec, (n, 3))

        T = [vec_field(_EYE[j]) for j in range(3)]  # translations
        R = [np.cross(_EYE[j], x) for j in range(3)]  # rotations about the centroid
        E = [x[:, i:i + 1] * _EYE[i] for i in range(3)]  # u_i = x_i
        E += [x[:, j:j + 1] * _EYE[i] + x[:, i:i + 1] * _EYE[j] for i, j in ((1, 2), (0, 2), (0, 1))]
        W = [x[:, j:j + 1] * np.cross(_EYE[j], x) for j in range(3)]  # rotation about e_j growing along e_j
        B, bend_axis = [], []
        for j in range(3):  # rotation about e_j growing along e_i: deflection x_i^2 / 2 along e_j x e_i,
            for i in range(3):  # plane sections normal to the axis (Euler-Bernoulli kinematics)
                if i != j:
                    dvec = np.cross(_EYE[j], _EYE[i])
                    B.append(0.5 * x[:, i:i + 1] ** 2 * dvec - (x @ dvec)[:, None] * x[:, i:i + 1] * _EYE[i])
                    bend_axis.append(j)
        # twist and bending fields minus their mean, so a sway never reads as bending
        W = [f - f.mean(axis=0) for f in W]
        B = [f - f.mean(axis=0) for f in B]
        base = {"T": T, "R": R, "E": E, "W": W, "B": B}
        # each family carries the rigid fields a clamp mixes into it: a clamped body sways about its
        # clamp (translation + rotation), stretches from it (translation + strain), twists and bends
        # from it (rotation + twist / bending)
        self.parts = {"rigid": ("T", "R"), "strain": ("T", "E"), "twist": ("R", "W"), "bending": ("R", "B")}
        self.axis_of = {"T": [0, 1, 2], "R": [0, 1, 2], "E": [-1] * 6, "W": [0, 1, 2], "B": bend_axis}
        self.fields = {fam: np.column_stack([np.ravel(f) for part in parts for f in base[part]])
                       for fam, parts in self.parts.items()}
        self.Q = {}
        self._pinv = {}  # the SVD's pseudo-inverse factors: least-squares coefficients without an SVD per mode
        for fam, F in self.fields.items():  # orthonormal basis of the span (the three twists sum to 0)
            Uf, s, Vt = np.linalg.svd(F, full_matrices=False)
            self.Q[fam] = Uf[:, s > 1e-10 * s[0]]
            keep = s > np.finfo(float).eps * max(F.shape) * s[0]  # numpy.linalg.lstsq's default cutoff
            self._pinv[fam] = (Uf[:, keep], s[keep], Vt[keep])

    def _coef(self, family: str, u: np.ndarray) -> np.ndarray:
        """Minimum-norm least-squares coefficients of u on the family's fields (= ``lstsq(fields, u)``)."""
        U, s, Vt = self._pinv[family]
        return Vt.T @ ((U.T @ u) / s)

    def _axis_energy(self, family: str, coef: np.ndarray, parts: tuple[str, ...]) -> np.ndarray:
        """Energy (3,) of the fitted field's parts about / along each global axis."""
        B = self.fields[family]
        axes = [a for part in self.parts[family] for a in (self.axis_of[part] if part in parts else
                                                             [-1] * len(self.axis_of[part]))]
        e = np.zeros(3)
        for j in range(3):
            cols = [c for c, a in enumerate(axes) if a == j]
            part = B[:, cols] @ coef[cols]
            e[j] = part @ part
        return e

    def label(self, u: np.ndarray, threshold: float, number: int) -> str:
        """Neutral label of one mode u (3n,); ``number`` is its 1-based column for ``"mode <i>"``."""
        tot = float(u @ u)
        if tot <= 0.0:
            return f"mode {number}"
        share = {key: float(np.sum((Q.T @ u) ** 2)) / tot for key, Q in self.Q.items()}
        best = max(share, key=share.get)
        if share[best] < threshold:
            return f"mode {number}"
        coef = self._coef(best, u)
        if best == "rigid":
            et, er = self._axis_energy(best, coef, ("T",)), self._axis_energy(best, coef, ("R",))
            if et.sum() >= er.sum():
                return _named("sway", "along", _axis_name(np.sqrt(et)))
            return _named("rocking", "about", _axis_name(np.sqrt(er)))
        if best == "twist":
            # x_j (e_j x x) summed over j is 0: the minimum-norm twist rates tau have zero mean, and a
            # twist about e_j alone reads tau ~ 3/2 e_j - 1/2 (1, 1, 1)
            tau = coef[3:]
            pure = 1.5 * _EYE - 0.5
            cos2 = (pure @ tau) ** 2 / max(float(tau @ tau) * 1.5, 1e-300)
            j = int(np.argmax(cos2))
            return _named("twist", "about", "xyz"[j] if cos2[j] >= _AXIS_SHARE else "")
        if best == "bending":
            return _named(best, "about", _axis_name(np.sqrt(self._axis_energy(best, coef, ("R", "B")))))
        coef = coef[3:]
        # uniform strain E (u = E x): principal strains, each with its displacement energy
        E = np.zeros((3, 3))
        for i in range(3):
            E[i, i] = coef[i]
        for c, (i, j) in enumerate(((1, 2), (0, 2), (0, 1))):
            E[i, j] = E[j, i] = coef[3 + c]
        lam, vec = np.linalg.eigh(E)
        energy = lam**2 * np.einsum("ia,ij,ja->a", vec, self.C, vec)
        order = np.argsort(-energy)
        lam, vec, energy = lam[order], vec[:, order], energy[order]
        if energy[0] >= threshold * energy.sum():
            return _named("stretch", "along", _axis_name(vec[:, 0]))
        if np.all(lam > 0) or np.all(lam < 0):
            return "breathing"
        word = "stretch" if lam[0] * lam[1] > 0 else "shear"
        return _named(word, "in", _plane_name(vec[:, 2]))


# ----------------------------------------------------------------------------- labelling one body
def _beam_body_labels(frame: BodyFrame, p_all: np.ndarray, S: np.ndarray, threshold: float) -> list[str]:
    p, U = _local(frame, p_all, S)
    k = S.shape[1]
    fit = _beam_fit(p, U)
    labels = _beam_labels(frame, p, U, fit, threshold)
    n2, n3 = frame.names[1], frame.names[2]
    bend = [f[f"bending-{n2}"] + f[f"bending-{n3}"] >= threshold for f in fit.fractions(frame.names)]
    i = 0
    while i < k - 1:
        if bend[i] and bend[i + 1] and _bending_order(fit, i) == _bending_order(fit, i + 1):
            cols = [i, i + 1]
            _, R = np.linalg.eigh(fit.bend2_gram()[np.ix_(cols, cols)])
            R = R[:, ::-1]  # column 0: most bending-e2
            Ur = U[:, :, cols] @ R
            fit_r = fit.rotated(cols, R)
            fit_r.total = np.einsum("nck,nck->k", Ur, Ur)
            lab = _beam_labels(frame, p, Ur, fit_r, threshold)
            if abs(R[0, 0]) >= abs(R[0, 1]):
                labels[i], labels[i + 1] = lab[0], lab[1]
            else:
                labels[i], labels[i + 1] = lab[1], lab[0]
            i += 2
        else:
            i += 1
    return labels


def _label_body(points: np.ndarray, S: np.ndarray, numbers: list[int], kind: str | None,
                threshold: float) -> tuple[list[str], list[bool], list[str]]:
    """Labels, numbered flags and neutral labels of the columns of S on one body (one piece or all)."""
    k = S.shape[1]
    neutral_of = _Neutral(points)
    neutral = [neutral_of.label(S[:, i], threshold, numbers[i]) for i in range(k)]
    frame = body_frame(points, kind=kind)
    if frame.kind == "plate":
        p, U = _local(frame, points, S)
        labels = [_plate_label(p, U[:, :, i], threshold) for i in range(k)]
        return labels, [lab.startswith("plate (") for lab in labels], neutral
    if frame.kind == "beam":
        labels = _beam_body_labels(frame, points, S, threshold)
        return labels, [lab != "mixed" for lab in labels], neutral
    return list(neutral), [False] * k, neutral


def _unmix_pieces(S: np.ndarray, pieces: np.ndarray, ids: np.ndarray, shares: np.ndarray):
    """Rotate runs of consecutive undominated modes to piece-local vectors where their span allows.

    Returns (S_work, assign): S_work has the rotated vectors in place of each such run; original column
    i takes the label of S_work column assign[i].
    """
    k = S.shape[1]
    S_work = S.copy()
    assign = np.arange(k)
    dominated = shares.max(axis=0) >= PIECE_SHARE
    i = 0
    while i < k:
        if dominated[i]:
            i += 1
            continue
        j = i
        while j < k and not dominated[j]:
            j += 1
        cols = np.arange(i, j)
        i = j
        if len(cols) < 2:
            continue
        A = S[:, cols]
        G = A.T @ A
        if np.linalg.matrix_rank(G) < len(cols):
            continue
        vecs = []
        for pid in ids:
            rows = np.repeat(pieces == pid, 3)
            Gp = A[rows].T @ A[rows]
            import scipy.linalg

            mu, V = scipy.linalg.eigh(Gp, G)
            vecs += [V[:, m] for m in range(len(cols)) if mu[m] >= PIECE_SHARE]
        if len(vecs) != len(cols):
            continue
        W = A @ np.column_stack(vecs)  # piece-local vectors, grouped by piece
        W = W / np.linalg.norm(W, axis=0)
        An = A / np.linalg.norm(A, axis=0)
        overlap = np.abs(An.T @ W)
        taken = np.full(len(cols), -1)
        used = np.zeros(len(cols), dtype=bool)
        for flat in np.argsort(-overlap, axis=None):
            a, b = divmod(int(flat), len(cols))
            if taken[a] < 0 and not used[b]:
                taken[a], used[b] = b, True
        S_work[:, cols] = W
        assign[cols] = cols[taken]
    return S_work, assign


def label_modes(points, shapes, *, kind: str | None = None, threshold: float = 0.6,
                pieces: np.ndarray | None = None) -> tuple[str, ...]:
    """Name each mode from its shape: ``"bending-y 1"``, ``"torsion 1"``, ``"axial 2"``, ``"plate (2,1)"``,
    ``"mixed"`` on beams and plates; ``"bending about x"``, ``"breathing"``, ``"mode 7"`` on other bodies;
    ``"piece 1: ..."`` for a mode held by one piece.

    See the module docstring for the frame, the decomposition, the order convention and the handling
    of degenerate bending pairs.

    Args:
        points: node coordinates (N, 3) [m] (e.g. ``ModalResult.dof_points``).
        shapes: mode shapes (3 N, k), node-major (DOF ``3 a + c``), any normalisation; rigid modes
            should be left out (they are labelled by their largest component, not meaningfully).
        kind: ``"beam"``, ``"plate"``, ``"solid"`` (neutral labels), or None to detect from the geometry
            (extents, fill, slice widths, pieces; module doc). Applies to each labelled piece.
        threshold: minimum energy-like fraction of the dominant component, in (0.5, 1].
        pieces: optional connected-piece label per point (N,) ints, e.g.
            ``modalfem.eigen.rigid.node_pieces(mesh, degree)``; modes held by one piece are labelled on
            it (``"piece <p>: ..."``), the others by neutral labels of the whole body.

    Returns:
        One label per column of ``shapes``.

    Raises:
        InputError: inconsistent shapes or pieces, bad kind or threshold.
    """
    if not (0.5 < threshold <= 1.0):
        raise InputError(f"threshold must lie in (0.5, 1], got {threshold!r}")
    if kind is not None and kind not in KINDS:
        raise InputError(f"kind must be one of {', '.join(KINDS)} or None, got {kind!r}")
    p_all = _check_points(points)
    S = _check_shapes(shapes, len(p_all))
    given = _check_pieces(pieces, len(p_all))
    k = S.shape[1]
    numbers = list(range(1, k + 1))
    ids = np.unique(given) if given is not None else np.zeros(1, dtype=np.int64)
    if len(ids) <= 1:
        labels, numbered, neutral = _label_body(p_all, S, numbers, kind, threshold)
    else:
        U2 = (S**2).reshape(len(p_all), 3, k).sum(axis=1)
        tot = U2.sum(axis=0)
        shares = np.array([U2[given == pid].sum(axis=0) for pid in ids]) / np.where(tot > 0, tot, 1.0)
        S_work, assign = _unmix_pieces(S, given, ids, shares)
        U2 = (S_work**2).reshape(len(p_all), 3, k).sum(axis=1)
        tot = U2.sum(axis=0)
        shares = np.array([U2[given == pid].sum(axis=0) for pid in ids]) / np.where(tot > 0, tot, 1.0)
        owner = np.where(shares.max(axis=0) >= PIECE_SHARE, np.argmax(shares, axis=0), -1)
        # work column j labels original column i with assign[i] == j: number it as that original
        number_of = np.empty(k, dtype=np.int64)
        number_of[assign] = np.arange(1, k + 1)
        labels, numbered, neutral = [""] * k, [False] * k, [""] * k
        for m, pid in enumerate(ids):
            cols = np.flatnonzero(owner == m)
            if len(cols) == 0:
                continue
            mask = given == pid
            nums = [int(number_of[c]) for c in cols]
            if int(mask.sum()) < 4:
                lab, num, neu = [f"mode {n}" for n in nums], [False] * len(cols), [f"mode {n}" for n in nums]
            else:
                rows = np.repeat(mask, 3)
                lab, num, neu = _label_body(p_all[mask], S_work[rows][:, cols], nums, kind, threshold)
            for c, a, b, d in zip(cols, lab, num, neu):
                labels[c], numbered[c], neutral[c] = f"piece {pid}: {a}", b, f"piece {pid}: {d}"
        rest = np.flatnonzero(owner < 0)
        if len(rest):
            whole = _Neutral(p_all)
            for c in rest:
                labels[c] = neutral[c] = whole.label(S_work[:, c], threshold, int(number_of[c]))
        labels = [labels[assign[i]] for i in range(k)]
        numbered = [numbered[assign[i]] for i in range(k)]
        neutral = [neutral[assign[i]] for i in range(k)]
    seen: set[str] = set()
    for i in range(k):
        if numbered[i]:
            if labels[i] in seen:
                labels[i] = neutral[i]
            else:
                seen.add(labels[i])
    return tuple(labels)
