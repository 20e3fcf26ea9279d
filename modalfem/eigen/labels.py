"""Mode labels read from the mode shapes: ``"bending-y 1"``, ``"torsion 1"``, ``"axial 1"``, ``"plate (2,1)"``.

Convention (what a label means):

* **Body frame.** The node cloud's principal axes (PCA about the node centroid) give a local frame
  ``e1, e2, e3`` ordered by decreasing spread. When the covariance is diagonal in the global axes (an
  axis-aligned body) or a principal axis is within 1 degree of a global axis, the axis is snapped to
  that global axis and *named* after it (``"x"``, ``"y"``, ``"z"``); otherwise the axes are named
  ``"a"`` (the long axis) and ``"t1"``, ``"t2"`` (the transverse axes, ``t1`` the wider one), or for
  plates ``"p1"``, ``"p2"`` in-plane and ``"n"`` normal. If the two transverse spreads are within 5 % of
  each other (a square or round section) and the long axis is a global axis, the other two global axes
  are used.
* **Kind.** ``"beam"`` when the longest extent is >= 3x the second; ``"plate"`` when the smallest is
  <= 0.2x the second; otherwise ``"solid"`` (analysed like a beam along its longest axis).
* **Beam decomposition.** The displacement is fitted (least squares over all nodes, piecewise-linear
  functions of the axial coordinate s) by rigid section motions plus two section modes:
  ``u = t(s) + theta(s) x r + eps(s) (eta e2 + zeta e3) + w(s) eta zeta e1 + residual``
  (r = (0, eta, zeta) the position in the section). The energy-like fractions are squared-displacement
  norms of the parts over the nodes divided by ``sum |u|^2``:
  ``axial`` = t1 and the Poisson breathing eps; ``bending-<e2>`` = t2 and the section rotation theta3
  (displacement along e2); ``bending-<e3>`` = t3 and theta2; ``torsion`` = theta1 and the warping w;
  the rest is ``residual``. A component with fraction >= ``threshold`` (default 0.6) names the mode,
  provided its rigid-section part alone (t1, t2, t3 or theta1) holds >= 50 % (so a non-prismatic body
  whose motion is mostly "breathing" or "warping", such as tuning-fork prongs, is ``"mixed"``).
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
* Anything else is ``"mixed"``.
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


@dataclass(frozen=True)
class BodyFrame:
    """Principal frame of a node cloud.

    Attributes:
        center: node centroid (3,) [m].
        axes: rows e1, e2, e3 (3, 3), orthonormal, decreasing spread (e3 = plate normal).
        extents: ranges of the nodes along e1, e2, e3 (3,) [m].
        names: axis names used in labels, global letters where aligned (see module doc).
        kind: ``"beam"``, ``"plate"`` or ``"solid"``.
    """

    center: np.ndarray
    axes: np.ndarray
    extents: np.ndarray
    names: tuple[str, str, str]
    kind: str


def _check_points(points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 4:
        raise InputError(f"points must have shape (n, 3) with n >= 4, got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError("points must be finite")
    return p


def body_frame(points, *, kind: str | None = None) -> BodyFrame:
    """Principal axes, extents, axis names and kind of a node cloud (see module doc).

    Args:
        points: node coordinates (N, 3) [m].
        kind: force ``"beam"``, ``"plate"`` or ``"solid"``; None detects it from the extents.

    Raises:
        InputError: bad points or kind.
    """
    p = _check_points(points)
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
    ext = np.ptp(X @ axes.T, axis=0)
    if kind is None:
        if ext[0] >= 3.0 * ext[1]:
            kind = "beam"
        elif ext[2] <= 0.2 * ext[1]:
            kind = "plate"
        else:
            kind = "solid"
    default = ("p1", "p2", "n") if kind == "plate" else ("a", "t1", "t2")
    names = tuple(n if n else default[i] for i, n in enumerate(names))
    return BodyFrame(center=center, axes=axes, extents=ext, names=names, kind=kind)


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
        return G, np.linalg.lstsq(G, B.T @ rhs, rcond=1e-12)[0]

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


def label_modes(points, shapes, *, kind: str | None = None, threshold: float = 0.6) -> tuple[str, ...]:
    """Name each mode from its shape: ``"bending-y 1"``, ``"torsion 1"``, ``"axial 2"``, ``"plate (2,1)"``, ``"mixed"``.

    See the module docstring for the frame, the decomposition, the order convention and the handling
    of degenerate bending pairs.

    Args:
        points: node coordinates (N, 3) [m] (e.g. ``ModalResult.dof_points``).
        shapes: mode shapes (3 N, k), node-major (DOF ``3 a + c``), any normalisation; rigid modes
            should be left out (they are labelled by their largest component, not meaningfully).
        kind: ``"beam"``, ``"plate"``, ``"solid"``, or None to detect from the extents.
        threshold: minimum energy-like fraction of the dominant component, in (0.5, 1].

    Returns:
        One label per column of ``shapes``.

    Raises:
        InputError: inconsistent shapes, bad kind or threshold.
    """
    if not (0.5 < threshold <= 1.0):
        raise InputError(f"threshold must lie in (0.5, 1], got {threshold!r}")
    p_all = _check_points(points)
    S = _check_shapes(shapes, len(p_all))
    frame = body_frame(p_all, kind=kind)
    p, U = _local(frame, p_all, S)
    k = S.shape[1]
    if frame.kind == "plate":
        return tuple(_plate_label(p, U[:, :, i], threshold) for i in range(k))
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
    return tuple(labels)
