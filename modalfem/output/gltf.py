"""glTF 2.0 export of a ``ModalModel``: the surface with its vibration modes as morph targets.

DyRT (James and Pai 2002) on today's GPUs: the body's surface is one glTF mesh whose morph targets
are its deformation modes, and the morph weights are the modal coordinates, so a renderer deforms
the surface in the vertex shader (three.js packs any number of targets into a morph texture).

Geometry (``modal_surface``):

* vertices are split at sharp edges (faces meeting at more than ``crease_angle`` degrees get their
  own copy of the vertex, so boxes and prongs keep flat faces); the copies carry identical positions
  and displacement targets; triangle j of the file is triangle j of the model, same corner order;
* ``NORMAL``: unit vertex normals (area-weighted over the faces within the crease angle);
* morph target i ``POSITION``: mode i scaled to a peak vertex displacement of 1 m,
  ``t_i = phi_i / c_i`` with ``c_i = max_v |phi_i(v)|`` [m/sqrt(kg)], so the weight ``w_i`` of
  mode i is its peak displacement [m] and ``u = sum_i w_i t_i`` [m];
* morph target i ``NORMAL``: the derivative of the unit normal along ``t_i`` [1/m]
  (``(I - n n^T) dN_i / |N|``, N the area-weighted normal), so a renderer that adds the weighted
  deltas and renormalises (three.js does) shades the deformed surface to first order in w.

Extras (``asset``-independent, in the file's root ``extras["modalfem"]``; all lists have one entry
per mode, in target order; see ``EXTRAS_KEYS``)::

    format            "modalfem.gltf-modes"      format_version  1
    units             {"length": "m", "time": "s", "frequency": "Hz", "angular_frequency": "rad/s",
                       "damping": "1/s", "mass": "kg", "weight": "m", "impulse": "N s", ...}
    mode_count        k
    frequencies_hz    f_i = omega_i / (2 pi) [Hz]
    omega_rad_s       omega_i [rad/s]
    damping_per_s     mu_i = alpha + beta omega_i^2 [1/s]
    rayleigh_damping  {"alpha_per_s": alpha, "beta_s": beta}
    mode_masses_kg    m_i = t_i^T M t_i = 1 / c_i^2 [kg], the modal mass of target i
    target_scales     c_i [m/sqrt(kg)]: mass-normalised mode phi_i = c_i t_i, modal coordinate q_i = w_i / c_i
    equation          "w_i'' + mu_i w_i' + omega_i^2 w_i = (t_i(p) . F) / m_i"
    mass_kg, center_of_mass_m, inertia_kg_m2, material, crease_angle_deg, normals, source

Each weight obeys ``w_i'' + mu_i w_i' + omega_i^2 w_i = (t_i(p) . F) / m_i`` for a force F [N] at a
surface point p, so an impulse J [N s] there changes ``w_i'`` by ``t_i(p) . J / m_i``. The mesh's
own ``extras.targetNames`` names the targets (``mode 1 (523.4 Hz)``), as three.js and Blender read it.
Coordinates are the model's mesh coordinates in metres (glTF's unit), +Y is not forced up.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
import struct
from dataclasses import dataclass

import numpy as np

from modalfem.atomic import write_atomic
from modalfem.errors import InputError, ModelFileError

__all__ = ["EXTRAS_FORMAT", "EXTRAS_KEYS", "ModalSurface", "glb_bytes", "modal_surface", "page_html", "write_glb"]

#: value of ``extras["modalfem"]["format"]``
EXTRAS_FORMAT = "modalfem.gltf-modes"
#: keys of ``extras["modalfem"]`` (documented in the module docstring)
EXTRAS_KEYS = ("format", "format_version", "units", "mode_count", "frequencies_hz", "omega_rad_s",
               "damping_per_s", "rayleigh_damping", "mode_masses_kg", "target_scales", "equation",
               "mass_kg", "center_of_mass_m", "inertia_kg_m2", "material", "crease_angle_deg", "normals",
               "source")
UNITS = {"length": "m", "time": "s", "frequency": "Hz", "angular_frequency": "rad/s", "damping": "1/s",
         "mass": "kg", "weight": "m", "target_position": "m per unit weight (peak 1)",
         "target_normal": "1/m", "target_scale": "m/sqrt(kg)", "impulse": "N s", "inertia": "kg m^2"}

_FLOAT, _UINT16, _UINT32 = 5126, 5123, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


@dataclass(frozen=True)
class ModalSurface:
    """The renderable surface of a modal model with its modes as displacement and normal targets.

    Attributes:
        positions: (n, 3) float64 [m] rest positions (mesh coordinates; crease copies repeat a vertex).
        normals: (n, 3) unit rest normals.
        indices: (nt, 3) int64 triangles into ``positions``; row j is the model's triangle j.
        source_vertex: (n,) int64, the model vertex each vertex copies.
        targets: (k, n, 3) displacement targets ``t_i = phi_i / c_i`` [m per unit weight], peak 1.
        normal_targets: (k, n, 3) or None: d(unit normal)/d w_i [1/m].
        scales: (k,) c_i [m/sqrt(kg)] (phi_i = c_i t_i).
        mode_masses: (k,) m_i = 1 / c_i^2 [kg].
        omega: (k,) [rad/s]; mu: (k,) [1/s] modal damping.
        damping: Rayleigh (alpha [1/s], beta [s]) behind ``mu``.
    """

    positions: np.ndarray
    normals: np.ndarray
    indices: np.ndarray
    source_vertex: np.ndarray
    targets: np.ndarray
    normal_targets: np.ndarray | None
    scales: np.ndarray
    mode_masses: np.ndarray
    omega: np.ndarray
    mu: np.ndarray
    damping: tuple = (0.0, 0.0)

    @property
    def mode_count(self) -> int:
        """k, the number of morph targets."""
        return int(len(self.omega))

    @property
    def vertex_count(self) -> int:
        """n, the number of glTF vertices (crease copies included)."""
        return int(len(self.positions))


def _mode_indices(model, mode_count) -> np.ndarray:
    r = int(model.mode_count)
    if r == 0:
        raise InputError("the model has no deformation modes to export")
    if mode_count is None:
        return np.arange(r)
    if isinstance(mode_count, bool) or not isinstance(mode_count, (int, np.integer)):
        raise InputError(f"mode count must be an integer, got {mode_count!r}")
    if not 1 <= int(mode_count) <= r:
        raise InputError(f"mode count {int(mode_count)} out of range: the model has {r} modes (1..{r})")
    return np.arange(int(mode_count))


def _corner_groups(tris: np.ndarray, face_area_normals: np.ndarray, cos_crease: float):
    """Pairs (corner, face) of the faces each corner's normal averages over, and a vertex key per corner.

    Corner c (triangle c // 3, vertex tris.flat[c]) averages over the faces around its vertex whose
    unit normal is within the crease angle of its own face's. Corners of one vertex with the same
    face set share a glTF vertex (key: the vertex and a 64-bit hash of the set).
    """
    nt = len(tris)
    cv = tris.reshape(-1)
    cf = np.repeat(np.arange(nt), 3)
    order = np.argsort(cv, kind="stable")
    counts = np.bincount(cv)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    # every ordered pair of corners at the same vertex: corner order[s + a] with face of order[s + b]
    k_of = counts[cv[order]]  # valence of each sorted corner's vertex
    pair_c = np.repeat(order, k_of)
    first = np.repeat(starts[cv[order]], k_of)
    offs = np.arange(len(pair_c)) - np.repeat(np.cumsum(k_of) - k_of, k_of)
    pair_f = cf[order[first + offs]]
    unit = face_area_normals / np.maximum(np.linalg.norm(face_area_normals, axis=1), 1e-300)[:, None]
    keep = np.einsum("ij,ij->i", unit[cf[pair_c]], unit[pair_f]) >= cos_crease
    pair_c, pair_f = pair_c[keep], pair_f[keep]
    rng = np.random.default_rng(0x6D6F64)  # fixed: the same file for the same model
    face_hash = rng.integers(0, 2**63, size=nt, dtype=np.uint64) | np.uint64(1)
    h = np.zeros(3 * nt, dtype=np.uint64)
    np.add.at(h, pair_c, face_hash[pair_f])  # wraps modulo 2^64: a hash of the face set
    return pair_c, pair_f, cv, h


def _scatter(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """Sum rows of ``values`` (m, 3) into ``size`` bins by ``index``."""
    out = np.empty((size, 3))
    for c in range(3):
        out[:, c] = np.bincount(index, weights=values[:, c], minlength=size)
    return out


def modal_surface(model, *, mode_count: int | None = None, crease_angle: float = 60.0,
                  normals: bool = True, damping=None, progress=None) -> ModalSurface:
    """The export geometry of ``model`` (see the module docstring).

    Args:
        model: ``ModalModel`` (vertices [m], outward triangles, mass-normalised shapes).
        mode_count: export the first ``mode_count`` modes (default all), 1..r.
        crease_angle: faces meeting at more than this angle [deg] get separate vertex normals;
            180 gives smooth normals everywhere (no vertex is split).
        normals: compute the normal morph targets (``normal_targets``; None otherwise).
        damping: Rayleigh (alpha [1/s], beta [s]) replacing the model's (``mu_i = alpha + beta omega_i^2``).
        progress: optional ``progress(done, total)`` called as the normal targets are built.

    Returns:
        ``ModalSurface``.

    Raises:
        InputError: ``mode_count`` out of 1..r, a crease angle outside [0, 180], damping not two finite
            numbers >= 0, or a model without modes.
        ModelFileError: a mode does not move the surface at all (it cannot be scaled to a peak of 1 m).
    """
    modes = _mode_indices(model, mode_count)
    alpha, beta = _damping(model.damping if damping is None else damping)
    try:
        crease = float(crease_angle)
    except (TypeError, ValueError):
        raise InputError(f"crease angle must be a number of degrees, got {crease_angle!r}") from None
    if not 0.0 <= crease <= 180.0:
        raise InputError(f"crease angle must be in [0, 180] degrees, got {crease_angle!r}")
    X = np.asarray(model.vertices, dtype=np.float64)
    tris = np.asarray(model.triangles, dtype=np.int64)
    nv = len(X)
    phi = np.asarray(model.shapes, dtype=np.float64)[:, modes].reshape(nv, 3, -1)  # (nv, 3, k)
    phi = np.moveaxis(phi, -1, 0)  # (k, nv, 3)
    scales = np.sqrt(np.einsum("kvc,kvc->kv", phi, phi)).max(axis=1)
    if np.any(scales <= 0):
        i = int(np.flatnonzero(scales <= 0)[0])
        raise ModelFileError(f"mode {i + 1} does not move the surface (all its surface displacements are 0)")
    targets_src = phi / scales[:, None, None]
    a, b, c = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    eb, ec = b - a, c - a
    A = np.cross(eb, ec)  # (nt, 3) twice the area times the unit normal
    cos_crease = -1.0 - 1e-12 if crease >= 180.0 else math.cos(math.radians(crease))
    pair_c, pair_f, cv, h = _corner_groups(tris, A, cos_crease)
    keys = np.stack([cv.astype(np.uint64), h], axis=1)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first)  # number the new vertices in order of first appearance (stable files)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    new_of_corner = rank[inverse]
    n = len(first)
    rep = first[order]  # representative corner of each new vertex
    source = cv[rep]
    # area-weighted normal of each representative corner: sum of its faces' A
    is_rep = np.zeros(3 * len(tris), dtype=bool)
    is_rep[rep] = True
    sel = is_rep[pair_c]
    pc, pf = new_of_corner[pair_c[sel]], pair_f[sel]
    N = _scatter(pc, A[pf], n)
    norm = np.linalg.norm(N, axis=1)
    if np.any(norm <= 0):
        raise ModelFileError("the model surface has a vertex with a zero-area neighbourhood (degenerate triangles)")
    n0 = N / norm[:, None]
    normal_targets = None
    if normals:
        normal_targets = np.empty((len(modes), n, 3))
        for i in range(len(modes)):
            if progress is not None:
                progress(i, len(modes))
            U = targets_src[i]
            dA = np.cross(U[tris[:, 1]] - U[tris[:, 0]], ec) + np.cross(eb, U[tris[:, 2]] - U[tris[:, 0]])
            dN = _scatter(pc, dA[pf], n)
            normal_targets[i] = (dN - n0 * np.einsum("ij,ij->i", n0, dN)[:, None]) / norm[:, None]
    omega = np.asarray(model.omega, dtype=np.float64)[modes]
    return ModalSurface(
        positions=X[source], normals=n0, indices=new_of_corner.reshape(-1, 3).astype(np.int64),
        source_vertex=source.astype(np.int64), targets=targets_src[:, source, :], normal_targets=normal_targets,
        scales=scales, mode_masses=1.0 / scales**2, omega=omega, mu=alpha + beta * omega**2, damping=(alpha, beta))


def _damping(value) -> tuple:
    try:
        alpha, beta = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"damping must be (alpha [1/s], beta [s]), got {value!r}") from None
    if not (math.isfinite(alpha) and math.isfinite(beta)) or alpha < 0 or beta < 0:
        raise InputError(f"Rayleigh damping (alpha, beta) must be finite and >= 0, got ({alpha:g}, {beta:g})")
    return alpha, beta


def _extras(model, surface: ModalSurface, crease_angle: float, source: dict | None) -> dict:
    alpha, beta = surface.damping
    src = {"model_checksum": model.checksum()}
    src.update(source or {})
    return {
        "format": EXTRAS_FORMAT,
        "format_version": 1,
        "units": dict(UNITS),
        "mode_count": surface.mode_count,
        "frequencies_hz": (surface.omega / (2 * math.pi)).tolist(),
        "omega_rad_s": surface.omega.tolist(),
        "damping_per_s": surface.mu.tolist(),
        "rayleigh_damping": {"alpha_per_s": alpha, "beta_s": beta},
        "mode_masses_kg": surface.mode_masses.tolist(),
        "target_scales": surface.scales.tolist(),
        "equation": "w_i'' + mu_i w_i' + omega_i^2 w_i = (t_i(p) . F) / m_i",
        "mass_kg": float(model.mass),
        "center_of_mass_m": np.asarray(model.center_of_mass, dtype=np.float64).tolist(),
        "inertia_kg_m2": np.asarray(model.inertia, dtype=np.float64).tolist(),
        "material": dict(model.material),
        "crease_angle_deg": float(crease_angle),
        "normals": "morph" if surface.normal_targets is not None else "rest",
        "source": src,
    }


class _Builder:
    """Accumulates the binary chunk and the bufferViews / accessors of a glTF document."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.offset = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, data: np.ndarray, *, component: int, kind: str, target: int | None,
            min_max: bool = False) -> int:
        raw = np.ascontiguousarray(data).tobytes()
        view = {"buffer": 0, "byteOffset": self.offset, "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        self.views.append(view)
        pad = (-len(raw)) % 4
        self.chunks.append(raw + b"\0" * pad)
        self.offset += len(raw) + pad
        acc = {"bufferView": len(self.views) - 1, "componentType": component,
               "count": int(len(data) if kind != "SCALAR" else data.size), "type": kind}
        if min_max:  # exact float32 bounds, as the spec requires for POSITION accessors
            acc["min"] = [float(x) for x in data.min(axis=0)]
            acc["max"] = [float(x) for x in data.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def glb_bytes(model, *, mode_count: int | None = None, crease_angle: float = 60.0, normals: bool = True,
              damping=None, source: dict | None = None, surface: ModalSurface | None = None) -> bytes:
    """The binary glTF 2.0 file (.glb) of ``model`` with its modes as morph targets.

    Args:
        model: ``ModalModel``.
        mode_count: the first ``mode_count`` modes become targets (default all), 1..r.
        crease_angle: [deg], see ``modal_surface``.
        normals: also write NORMAL morph targets (otherwise only POSITION ones).
        damping: Rayleigh (alpha [1/s], beta [s]) replacing the model's, or None.
        source: extra JSON-able entries for ``extras["modalfem"]["source"]`` (e.g. the model file name).
        surface: a ``modal_surface`` of ``model`` already computed with these options.

    Returns:
        The .glb bytes (one scene, one node, one mesh with k targets, all weights 0).

    Raises:
        InputError, ModelFileError: see ``modal_surface``.
    """
    import modalfem

    s = surface if surface is not None else modal_surface(model, mode_count=mode_count, crease_angle=crease_angle,
                                                          normals=normals, damping=damping)
    b = _Builder()
    f32 = np.float32
    idx_type, idx_dtype = (_UINT16, np.uint16) if s.vertex_count <= 65535 else (_UINT32, np.uint32)
    i_idx = b.add(s.indices.reshape(-1).astype(idx_dtype), component=idx_type, kind="SCALAR",
                  target=_ELEMENT_ARRAY_BUFFER)
    i_pos = b.add(s.positions.astype(f32), component=_FLOAT, kind="VEC3", target=_ARRAY_BUFFER, min_max=True)
    i_nrm = b.add(s.normals.astype(f32), component=_FLOAT, kind="VEC3", target=_ARRAY_BUFFER)
    targets = []
    for i in range(s.mode_count):
        t = {"POSITION": b.add(s.targets[i].astype(f32), component=_FLOAT, kind="VEC3",
                               target=_ARRAY_BUFFER, min_max=True)}
        if s.normal_targets is not None:
            t["NORMAL"] = b.add(s.normal_targets[i].astype(f32), component=_FLOAT, kind="VEC3",
                                target=_ARRAY_BUFFER)
        targets.append(t)
    freqs = s.omega / (2 * math.pi)
    names = [f"mode {i + 1} ({f:.6g} Hz)" for i, f in enumerate(freqs)]
    material = model.material
    doc = {
        "asset": {"version": "2.0", "generator": f"modalfem {getattr(modalfem, '__version__', '?')}"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "modal body"}],
        "meshes": [{
            "name": "modal body",
            "primitives": [{"attributes": {"POSITION": i_pos, "NORMAL": i_nrm}, "indices": i_idx, "mode": 4,
                            "material": 0, "targets": targets}],
            "weights": [0.0] * s.mode_count,
            "extras": {"targetNames": names},
        }],
        "materials": [{"name": str(material.get("name") or "material"), "doubleSided": False,
                       "pbrMetallicRoughness": {"baseColorFactor": [0.72, 0.74, 0.78, 1.0],
                                                "metallicFactor": 0.1, "roughnessFactor": 0.55}}],
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": b.offset}],
        "extras": {"modalfem": _extras(model, s, crease_angle, source)},
    }
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
    text += b" " * ((-len(text)) % 4)
    binary = b"".join(b.chunks)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total), struct.pack("<I4s", len(text), b"JSON"), text,
                     struct.pack("<I4s", len(binary), b"BIN\0"), binary])


def write_glb(path: str | os.PathLike, model, **options) -> None:
    """Write ``glb_bytes(model, **options)`` to ``path`` atomically (complete new file or none).

    Raises:
        InputError: bad options (see ``modal_surface``) or the file cannot be written.
        ModelFileError: see ``modal_surface``.
    """
    data = glb_bytes(model, **options)
    write_atomic(path, lambda f: f.write(data), error=InputError, kind="glTF")


def page_html(glb: bytes, *, title: str = "modalfem modes") -> str:
    """A self-contained HTML page showing ``glb`` (from ``glb_bytes``) and letting a click strike it.

    Everything is inlined: three.js (``modalfem.web``, bundled, MIT), the JavaScript modal runtime
    (``modal.js``: the exact per-mode update of ``modalfem.runtime.integrator``, impulses
    ``t_i(p) . J / m_i`` and the modal sound of ``modalfem.runtime.sound`` played through WebAudio),
    the page script and the .glb in base64: no network and no Python at view time.

    Args:
        glb: the .glb bytes.
        title: page title and heading (HTML-escaped here).

    Returns:
        The page as text (UTF-8).
    """
    import modalfem
    from modalfem import web

    parts = {
        "@@GENERATOR@@": html.escape(f"modalfem {getattr(modalfem, '__version__', '?')}"),
        "@@TITLE@@": html.escape(title),
        "@@THREE_REVISION@@": web.THREE_REVISION,
        "@@GLB_BASE64@@": base64.b64encode(glb).decode("ascii"),
        "@@THREE_JS@@": web.inline_script(web.asset("three.bundle.min.js")),
        "@@MODAL_JS@@": web.inline_script(web.asset("modal.js")),
        "@@PAGE_JS@@": web.inline_script(web.asset("page.js")),
    }
    text = web.asset("page.html")
    pieces = text.split("@@")  # one pass: inserted text is never searched for markers again
    out = [pieces[0]]
    for i in range(1, len(pieces), 2):
        key = f"@@{pieces[i]}@@"
        out.append(parts[key] if key in parts else key)
        out.append(pieces[i + 1])
    return "".join(out)
