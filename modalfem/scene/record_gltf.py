"""Blender-friendly animation of a ``World``: one binary glTF (``scene.glb``) with every body and obstacle.

Layout: a root node turns the scene's z-up into glTF's y-up (Blender's importer turns it back), with one
child node (and mesh) per body and per obstacle, and one animation (``simulation``) sampled at the frame
times (LINEAR):

* modal body: the surface of ``modalfem.output.gltf.modal_surface`` (mesh coordinates, vertices split at
  creases) with its excited modes as morph targets, the node's translation and rotation the rigid motion
  (``x = R (X - com + Phi q) + c``: translation ``c - R com``);
* tet and cloth bodies: the first frame's surface (world coordinates) with morph targets from the principal
  components of the motion (an SVD of the displacements of every frame): the fewest components that
  reproduce every vertex of every frame within ``TOLERANCE`` of the body's size (at most
  ``MAX_TARGETS``; the error reached is in the file's ``extras``). Storing one target per frame is exact but
  grows with frames x vertices and gives Blender one shape key per frame; the components keep the file
  at k x vertices (a few MB for a 64 x 64 cloth over 900 frames) and play the same within the tolerance;
* moving obstacles: node translation; planes: a finite patch around the bodies.

Every weight track is mapped affinely onto [0, 1] (the offset folded into the base mesh), because Blender's
shape keys clamp values below their slider minimum of 0; ``extras["modalfem"]`` states the units (m, s).
"""

from __future__ import annotations

import json
import struct

import numpy as np

from modalfem.atomic import write_atomic
from modalfem.errors import InputError
from modalfem.output.gltf import (
    _ARRAY_BUFFER,
    _ELEMENT_ARRAY_BUFFER,
    _FLOAT,
    _UINT16,
    _UINT32,
    _Builder,
    modal_surface,
)
from modalfem.runtime.rotation import quat_to_matrix

__all__ = ["MAX_TARGETS", "TOLERANCE", "GltfAnimation", "principal_targets"]

#: largest vertex error [fraction of the body's bounding-box diagonal] of the principal-component morphs
TOLERANCE = 1e-3
#: most morph targets per tet / cloth body
MAX_TARGETS = 128
_COLOURS = {"modal": [0.78, 0.59, 0.24, 1.0], "tet": [0.35, 0.62, 0.35, 1.0], "cloth": [0.31, 0.5, 0.77, 1.0],
            "obstacle": [0.6, 0.6, 0.6, 1.0]}
_Z_UP_TO_Y_UP = [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476]  # (x, y, z, w): -90 deg about x


def principal_targets(D: np.ndarray, tolerance: float, max_targets: int = MAX_TARGETS
                      ) -> tuple[np.ndarray, np.ndarray, float]:
    """The fewest principal components of displacements ``D`` (F, n, 3) [m] reproducing every vertex within
    ``tolerance`` [m] (at most ``max_targets``).

    Returns:
        ``(targets (k, n, 3) [m], weights (F, k), max vertex error [m])``: ``D ~ weights @ targets``.
    """
    F, n, _ = D.shape
    flat = D.reshape(F, -1)
    if not np.any(flat):
        return np.zeros((0, n, 3)), np.zeros((F, 0)), 0.0
    if F < flat.shape[1] // 4:  # many vertices: the frames' Gram matrix (F x F) instead of a full SVD (~5x faster)
        lam, U = np.linalg.eigh(flat @ flat.T)
        lam, U = lam[::-1], U[:, ::-1]
        S = np.sqrt(np.maximum(lam, 0.0))
        keep = S > S[0] * 1e-7  # below, the Gram matrix has no digits left for them (and they are far below tol)
        U, S = U[:, keep], S[keep]
        Vt = (U.T @ flat) / S[:, None]
    else:
        U, S, Vt = np.linalg.svd(flat, full_matrices=False)
    US = U * S

    def error(k: int) -> float:
        R = flat - US[:, :k] @ Vt[:k]
        return float(np.sqrt(np.einsum("fvc,fvc->fv", R.reshape(F, n, 3), R.reshape(F, n, 3)).max()))

    lo, hi = 1, min(len(S), max_targets)
    if error(hi) > tolerance:
        lo = hi
    while lo < hi:  # the error falls with k (not strictly: the bisection finds a k that meets the tolerance)
        mid = (lo + hi) // 2
        if error(mid) <= tolerance:
            hi = mid
        else:
            lo = mid + 1
    return Vt[:lo].reshape(lo, n, 3), US[:, :lo], error(lo)


def _unit_weights(base: np.ndarray, targets: np.ndarray, weights: np.ndarray):
    """Map each weight track onto [0, 1]: ``base + w @ T = base' + w' @ T'``; drop tracks that never move."""
    lo, hi = weights.min(axis=0), weights.max(axis=0)
    keep = hi > lo
    lo, span = lo[keep], (hi - lo)[keep]
    T = targets[keep]
    base = base + np.einsum("k,kvc->vc", lo, T)
    return base, T * span[:, None, None], (weights[:, keep] - lo) / span


class GltfAnimation:
    """Collects frames and writes ``scene.glb``.

    Args:
        world: the ``World``.
        obstacles: ``(name, obstacle, patch)`` per obstacle (``patch``: vertices and triangles for a plane).
    """

    def __init__(self, world, obstacles: list) -> None:
        self.world = world
        self.obstacles = obstacles
        self.times: list[float] = []
        self.modal: dict[str, list] = {b.name: [] for b in world.bodies if b.kind == "modal"}
        self.deforming: dict[str, list] = {b.name: [] for b in world.bodies if b.kind != "modal"}
        self.triangles: dict[str, np.ndarray] = {}
        self.report: dict[str, dict] = {}

    def add(self, state, surfaces: dict) -> None:
        """Keep frame ``state`` (``surfaces``: body name -> (world surface vertices (n, 3) [m], triangles))."""
        for name, rows in self.modal.items():
            s = state.bodies[name]
            rows.append((s.position.copy(), s.orientation.copy(), s.q.copy()))
        for name, rows in self.deforming.items():
            rows.append(np.asarray(surfaces[name][0], dtype=np.float32).copy())
            self.triangles.setdefault(name, np.asarray(surfaces[name][1]))
        self.times.append(float(state.time))

    def _mesh(self, b, doc, name, base, tris, targets, normals=None, material=0) -> int:
        idx_type, idx_dtype = (_UINT16, np.uint16) if len(base) <= 65535 else (_UINT32, np.uint32)
        attrs = {"POSITION": b.add(base.astype(np.float32), component=_FLOAT, kind="VEC3", target=_ARRAY_BUFFER,
                                   min_max=True)}
        if normals is not None:
            attrs["NORMAL"] = b.add(normals.astype(np.float32), component=_FLOAT, kind="VEC3", target=_ARRAY_BUFFER)
        prim = {"attributes": attrs, "mode": 4, "material": material,
                "indices": b.add(np.asarray(tris).reshape(-1).astype(idx_dtype), component=idx_type, kind="SCALAR",
                                 target=_ELEMENT_ARRAY_BUFFER)}
        mesh = {"name": name, "primitives": [prim]}
        if len(targets):
            prim["targets"] = [{"POSITION": b.add(t.astype(np.float32), component=_FLOAT, kind="VEC3",
                                                  target=_ARRAY_BUFFER, min_max=True)} for t in targets]
            mesh["weights"] = [0.0] * len(targets)
        doc["meshes"].append(mesh)
        return len(doc["meshes"]) - 1

    def glb(self, frames: int) -> bytes:
        """The .glb of the first ``frames`` frames."""
        import modalfem

        F = min(frames, len(self.times))
        if F == 0:
            raise InputError("no frame was recorded: nothing to write to scene.glb")
        b = _Builder()
        times = np.asarray(self.times[:F], dtype=np.float32)
        i_time = b.add(times.reshape(-1, 1), component=_FLOAT, kind="SCALAR", target=None, min_max=True)
        doc = {"asset": {"version": "2.0", "generator": f"modalfem {getattr(modalfem, '__version__', '?')}"},
               "scene": 0, "scenes": [{"nodes": [0]}], "meshes": [],
               "nodes": [{"name": "scene (z up)", "rotation": _Z_UP_TO_Y_UP, "children": []}], "materials": []}
        samplers, channels = [], []

        class _Materials(dict):  # a material per kind, made when first used
            def __missing__(self, kind: str) -> int:
                doc["materials"].append({"name": kind, "doubleSided": kind == "cloth",
                                         "pbrMetallicRoughness": {"baseColorFactor": _COLOURS[kind],
                                                                  "metallicFactor": 0.0, "roughnessFactor": 0.7}})
                self[kind] = len(doc["materials"]) - 1
                return self[kind]

        mat = _Materials()

        def track(node: int, path: str, values: np.ndarray, kind: str) -> None:
            out = b.add(np.ascontiguousarray(values, dtype=np.float32), component=_FLOAT, kind=kind, target=None)
            samplers.append({"input": i_time, "output": out, "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

        def node(name: str, mesh: int) -> int:
            doc["nodes"].append({"name": name, "mesh": mesh})
            doc["nodes"][0]["children"].append(len(doc["nodes"]) - 1)
            return len(doc["nodes"]) - 1

        for body in self.world.bodies:
            name = body.name
            if body.kind == "modal":
                rows = self.modal[name][:F]
                model = body.model
                surf = modal_surface(model, normals=False)
                q = np.array([r[2] for r in rows])
                weights = q * surf.scales[None, :]
                base, T, W = _unit_weights(surf.positions, surf.targets, weights)
                m = self._mesh(b, doc, name, base, surf.indices, T, normals=surf.normals, material=mat["modal"])
                n = node(name, m)
                quat = np.array([r[1] for r in rows])  # (w, x, y, z)
                for i in range(1, len(quat)):  # one hemisphere: interpolation takes the short way
                    quat[i] *= 1.0 if quat[i] @ quat[i - 1] >= 0 else -1.0
                com = np.asarray(model.center_of_mass, dtype=np.float64)
                trans = np.array([r[0] for r in rows]) - np.einsum("fij,j->fi", np.array([quat_to_matrix(r) for r in quat]), com)
                track(n, "translation", trans, "VEC3")
                track(n, "rotation", quat[:, [1, 2, 3, 0]], "VEC4")
                if len(T):
                    track(n, "weights", W.reshape(-1), "SCALAR")
                self.report[name] = {"morph": "modes", "targets": len(T)}  # exact (float32 storage)
            else:
                X = np.array(self.deforming[name][:F], dtype=np.float64)
                tris = self.triangles[name]
                size = float(np.linalg.norm(np.ptp(X[0], axis=0)))
                T, A, err = principal_targets(X - X[0], TOLERANCE * size)
                base, T, W = _unit_weights(X[0], T, A)
                m = self._mesh(b, doc, name, base, tris, T, normals=None, material=mat[body.kind])
                n = node(name, m)
                if len(T):
                    track(n, "weights", W.reshape(-1), "SCALAR")
                else:
                    track(n, "translation", np.zeros((F, 3)), "VEC3")
                self.report[name] = {"morph": "principal components", "targets": len(T),
                                     "max_error_m": err, "tolerance_m": TOLERANCE * size}
        for name, o, patch in self.obstacles:
            V, Fo = patch if patch is not None else o.surface(0.0)
            V = np.asarray(V) - (o.offset(0.0) if patch is None else 0.0)
            n = node(name, self._mesh(b, doc, name, V, Fo, [], normals=None, material=mat["obstacle"]))
            if o.moving:
                track(n, "translation", np.array([o.offset(t) for t in self.times[:F]]), "VEC3")
        doc["animations"] = [{"name": "simulation", "samplers": samplers, "channels": channels}]
        doc["accessors"], doc["bufferViews"], doc["buffers"] = b.accessors, b.views, [{"byteLength": b.offset}]
        doc["extras"] = {"modalfem": {"format": "modalfem.gltf-animation", "format_version": 1,
                                      "units": {"length": "m", "time": "s"}, "up": "z (root node turns it to y)",
                                      "frames": F, "bodies": self.report}}
        text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode("utf-8")
        text += b" " * ((-len(text)) % 4)
        binary = b"".join(b.chunks)
        total = 12 + 8 + len(text) + 8 + len(binary)
        return b"".join([struct.pack("<4sII", b"glTF", 2, total), struct.pack("<I4s", len(text), b"JSON"), text,
                         struct.pack("<I4s", len(binary), b"BIN\0"), binary])

    def write(self, path, frames: int) -> None:
        """Write the .glb of the first ``frames`` frames to ``path`` (atomically)."""
        data = self.glb(frames)
        write_atomic(path, lambda f: f.write(data), error=InputError, kind="glTF")

