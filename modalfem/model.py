"""``ModalModel``: the file that joins the offline modal analysis to the numpy-only runtime.

A model holds the boundary surface of a body at rest (vertices [m], outward triangles), the
mass-normalised deformation modes restricted to the surface vertices, their angular frequencies
[rad/s], the rigid-body mass properties (mass [kg], centre of mass [m], inertia about the centre
of mass [kg m^2]), the material, Rayleigh damping defaults and provenance. Schema v1 is described
in the class docstring.

File format (``.npz``, written by ``numpy.savez`` without pickles):
  * ``schema_version``: int64 scalar;
  * ``vertices``, ``triangles``, ``shapes``, ``omega``, ``center_of_mass``, ``inertia``: arrays
    (float64, except ``triangles`` int64), little-endian;
  * optional, both or neither: ``rotation_T`` (3, 3, r, r) and ``rotation_S`` (3, 3, r), float64,
    the rotation-coupling tensors of the pseudo-forces (``modalfem.runtime.effects``); files
    written before they existed lack them and still load (with None);
  * ``meta``: JSON text (sorted keys) with ``mass``, ``material``, ``damping``, ``provenance``;
  * ``checksum``: hex SHA-256 over a canonical serialisation of everything above
    (see ``payload_checksum``).

This module imports numpy and the standard library only (the runtime loads it without scipy).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from modalfem.atomic import write_atomic
from modalfem.errors import InputError, ModelFileError

__all__ = ["ModalModel", "payload_checksum", "storage_report"]

#: float64 arrays of the file, in canonical (checksum) order together with ``triangles``
_FLOAT_KEYS = ("center_of_mass", "inertia", "omega", "shapes", "vertices")
_INT_KEYS = ("triangles",)
_ARRAY_KEYS = tuple(sorted(_FLOAT_KEYS + _INT_KEYS))
#: optional float64 arrays (both or neither): hashed only when present, so older files keep their checksum
_OPTIONAL_KEYS = ("rotation_S", "rotation_T")
_FILE_KEYS = frozenset(_ARRAY_KEYS + ("schema_version", "meta", "checksum"))
_MATERIAL_KEYS = ("name", "E", "nu", "rho")


def payload_checksum(schema_version: int, arrays: dict, meta: str) -> str:
    """Hex SHA-256 of a model payload in canonical form.

    The hash covers, in this order: a format tag, the schema version, then for each array key in
    sorted order its name, dtype (little-endian), shape and raw C-order bytes, and finally the
    UTF-8 bytes of the JSON ``meta`` text exactly as stored. The optional arrays (``rotation_S``,
    ``rotation_T``) take part in the sorted order only when present (not None), so a model
    without them hashes as before they existed.

    Args:
        schema_version: schema version written in the file.
        arrays: the six model arrays by key (``vertices``, ``triangles``, ``shapes``, ``omega``,
            ``center_of_mass``, ``inertia``), plus the optional ones when present.
        meta: JSON metadata text.

    Returns:
        64 hexadecimal characters.
    """
    h = hashlib.sha256()
    h.update(b"modalfem.ModalModel\0")
    h.update(f"schema={int(schema_version)}\0".encode())
    keys = sorted(_ARRAY_KEYS + tuple(k for k in _OPTIONAL_KEYS if arrays.get(k) is not None))
    for key in keys:
        a = np.asarray(arrays[key])
        dt = np.dtype("<i8") if key in _INT_KEYS else np.dtype("<f8")
        a = np.ascontiguousarray(a, dtype=dt)
        h.update(f"{key}\0{dt.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    h.update(b"meta\0")
    h.update(meta.encode("utf-8"))
    return h.hexdigest()


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True, order="C")
    a.setflags(write=False)
    return a


def _float_array(name: str, value, shape_desc: str) -> np.ndarray:
    try:
        a = np.asarray(value)
    except Exception:  # noqa: BLE001 - any unconvertible object is a malformed model
        raise ModelFileError(f"model {name} must be a numeric array {shape_desc}") from None
    if a.dtype.kind not in "fiu" or a.dtype == np.bool_:
        raise ModelFileError(f"model {name} must be a real numeric array {shape_desc}, got dtype {a.dtype}")
    a = a.astype(np.float64)
    return a


def _finite(name: str, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        raise ModelFileError(f"model {name} holds {int(np.sum(~np.isfinite(a)))} NaN/inf values")


def _number(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ModelFileError(f"model {name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ModelFileError(f"model {name} must be finite, got {value!r}")
    return v


@dataclass(frozen=True, eq=False)
class ModalModel:
    """Reduced modal model of an elastic body (schema v1), validated on construction.

    Attributes:
        vertices: boundary-surface vertices at rest (nv, 3) [m], mesh coordinates.
        triangles: surface triangles (nt, 3) int64 indices into ``vertices``, outward oriented
            (right-hand rule).
        shapes: mass-normalised deformation modes restricted to the vertices (3 nv, r)
            [m / sqrt(kg)]; row ``3 i + c`` is component c (x, y, z) of vertex i, so the surface
            displacement is ``u = shapes @ q`` for modal coordinates q [sqrt(kg) m].
        omega: angular frequencies (r,) [rad/s], ascending, > 0 (rigid modes are not included).
        mass: total mass [kg].
        center_of_mass: (3,) [m] in mesh coordinates.
        inertia: (3, 3) inertia tensor about the centre of mass [kg m^2], mesh axes, symmetric
            positive definite.
        material: ``{"name": str, "E": Pa, "nu": -, "rho": kg/m^3}``.
        damping: Rayleigh coefficients (alpha [1/s], beta [s]); the modal damping of mode i is
            ``mu_i = alpha + beta * omega_i**2`` [1/s] (``q'' + mu q' + omega^2 q = f``).
        provenance: JSON-able dict: ``mesh_hash``, ``backend``, ``solver``, ``degree``, ``fixed``
            (str or None), ``rigid_mode_count``, ``versions``, ``created`` (UTC ISO 8601), ...
        rotation_T: optional (3, 3, r, r) [-], ``T[a, b] = Phi_a^T m Phi_b`` over the full mesh
            (m the scalar mass matrix, Phi_a the component-a rows of the modes), or None.
        rotation_S: optional (3, 3, r) [sqrt(kg) m], ``S[a, b] = Phi_a^T m X_b`` (X the node
            positions relative to the centre of mass), or None. Both or neither: together they are
            the ``RotationCoupling`` of the runtime's ``PseudoForces``.

    Raises:
        ModelFileError: a shape, dtype or value is inconsistent (non-finite data, omega not
            positive ascending, mass <= 0, inertia not symmetric positive definite, triangle
            index out of range, provenance not JSON-serialisable, only one of the rotation
            tensors or one of the wrong shape, ...).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    shapes: np.ndarray
    omega: np.ndarray
    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    material: dict
    damping: tuple
    provenance: dict = field(default_factory=dict)
    rotation_T: np.ndarray | None = None
    rotation_S: np.ndarray | None = None

    SCHEMA_VERSION: ClassVar[int] = 1

    def __post_init__(self) -> None:
        v = _float_array("vertices", self.vertices, "(nv, 3)")
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise ModelFileError(f"model vertices must have shape (nv, 3) with nv >= 3, got {v.shape}")
        _finite("vertices", v)
        nv = len(v)
        t = np.asarray(self.triangles)
        if t.dtype.kind not in "iu":
            raise ModelFileError(f"model triangles must be integer indices, got dtype {t.dtype}")
        if t.ndim != 2 or t.shape[1] != 3 or len(t) < 1:
            raise ModelFileError(f"model triangles must have shape (nt, 3) with nt >= 1, got {t.shape}")
        if t.min() < 0 or t.max() >= nv:
            raise ModelFileError(
                f"model triangles index vertices {int(t.min())}..{int(t.max())}, but there are {nv} vertices"
            )
        t = t.astype(np.int64)
        s = _float_array("shapes", self.shapes, "(3 nv, r)")
        if s.ndim != 2 or s.shape[0] != 3 * nv:
            raise ModelFileError(f"model shapes must have shape (3 nv, r) = ({3 * nv}, r), got {s.shape}")
        _finite("shapes", s)
        w = _float_array("omega", self.omega, "(r,)")
        if w.ndim != 1 or len(w) != s.shape[1]:
            raise ModelFileError(f"model omega must have shape (r,) = ({s.shape[1]},), got {w.shape}")
        _finite("omega", w)
        if len(w) and w.min() <= 0:
            raise ModelFileError(f"model omega must be > 0 rad/s (rigid modes excluded), got min {w.min():.6g}")
        if np.any(np.diff(w) < 0):
            raise ModelFileError("model omega must be in ascending order")
        mass = _number("mass", self.mass)
        if mass <= 0:
            raise ModelFileError(f"model mass must be > 0 kg, got {mass:g}")
        c = _float_array("center_of_mass", self.center_of_mass, "(3,)")
        if c.shape != (3,):
            raise ModelFileError(f"model center_of_mass must have shape (3,), got {c.shape}")
        _finite("center_of_mass", c)
        inertia = _float_array("inertia", self.inertia, "(3, 3)")
        if inertia.shape != (3, 3):
            raise ModelFileError(f"model inertia must have shape (3, 3), got {inertia.shape}")
        _finite("inertia", inertia)
        scale = float(np.abs(inertia).max())
        if scale == 0 or np.abs(inertia - inertia.T).max() > 1e-9 * scale:
            raise ModelFileError("model inertia tensor must be symmetric and non-zero")
        if np.linalg.eigvalsh(0.5 * (inertia + inertia.T)).min() <= 0:
            raise ModelFileError("model inertia tensor must be positive definite")
        material = self._check_material(self.material)
        try:
            alpha, beta = (float(x) for x in self.damping)
        except (TypeError, ValueError):
            raise ModelFileError(f"model damping must be (alpha [1/s], beta [s]), got {self.damping!r}") from None
        if not (math.isfinite(alpha) and math.isfinite(beta)) or alpha < 0 or beta < 0:
            raise ModelFileError(f"model damping must be finite and >= 0, got ({alpha:g}, {beta:g})")
        if not isinstance(self.provenance, dict):
            raise ModelFileError(f"model provenance must be a dict, got {type(self.provenance).__name__}")
        try:
            provenance = json.loads(json.dumps(self.provenance, sort_keys=True, allow_nan=False))
        except (TypeError, ValueError) as exc:
            raise ModelFileError(f"model provenance must be JSON-serialisable: {exc}") from None
        rot_T, rot_S = self._check_rotation(self.rotation_T, self.rotation_S, s.shape[1])
        for name, value in (("vertices", v), ("triangles", t), ("shapes", s), ("omega", w),
                            ("center_of_mass", c), ("inertia", inertia)):
            object.__setattr__(self, name, _frozen(value))
        object.__setattr__(self, "rotation_T", None if rot_T is None else _frozen(rot_T))
        object.__setattr__(self, "rotation_S", None if rot_S is None else _frozen(rot_S))
        object.__setattr__(self, "mass", mass)
        object.__setattr__(self, "material", material)
        object.__setattr__(self, "damping", (alpha, beta))
        object.__setattr__(self, "provenance", provenance)

    @staticmethod
    def _check_rotation(T, S, r: int):
        if T is None and S is None:
            return None, None
        if T is None or S is None:
            raise ModelFileError(f"model has rotation_{'S' if T is None else 'T'} without "
                                 f"rotation_{'T' if T is None else 'S'}: the rotation coupling needs both or neither")
        T = _float_array("rotation_T", T, "(3, 3, r, r)")
        if T.shape != (3, 3, r, r):
            raise ModelFileError(f"model rotation_T must have shape (3, 3, r, r) = (3, 3, {r}, {r}), got {T.shape}")
        _finite("rotation_T", T)
        S = _float_array("rotation_S", S, "(3, 3, r)")
        if S.shape != (3, 3, r):
            raise ModelFileError(f"model rotation_S must have shape (3, 3, r) = (3, 3, {r}), got {S.shape}")
        _finite("rotation_S", S)
        return T, S

    @property
    def has_rotation_coupling(self) -> bool:
        """True when the model carries ``rotation_T`` and ``rotation_S`` (pseudo-forces need no extra data)."""
        return self.rotation_T is not None

    @staticmethod
    def _check_material(material) -> dict:
        if not isinstance(material, dict):
            raise ModelFileError(f"model material must be a dict {{name, E, nu, rho}}, got {type(material).__name__}")
        missing = [k for k in _MATERIAL_KEYS if k not in material]
        if missing:
            raise ModelFileError(f"model material lacks {', '.join(missing)}")
        out = {"name": str(material["name"])}
        for k in ("E", "nu", "rho"):
            out[k] = _number(f"material {k}", material[k])
        if out["E"] <= 0 or out["rho"] <= 0 or not (-1.0 < out["nu"] < 0.5):
            raise ModelFileError(
                f"model material is not physical: E={out['E']:g} Pa, nu={out['nu']:g}, rho={out['rho']:g} kg/m^3"
            )
        return out

    # ------------------------------------------------------------------ sizes and views
    @property
    def frequencies_hz(self) -> np.ndarray:
        """Deformation-mode frequencies (r,) [Hz], ascending."""
        return self.omega / (2.0 * np.pi)

    @property
    def mode_count(self) -> int:
        """r, the number of deformation modes."""
        return int(self.shapes.shape[1])

    @property
    def vertex_count(self) -> int:
        """nv, the number of boundary-surface vertices."""
        return int(self.vertices.shape[0])

    @property
    def modal_damping(self) -> np.ndarray:
        """Per-mode damping mu_i = alpha + beta omega_i^2 (r,) [1/s]."""
        alpha, beta = self.damping
        return alpha + beta * self.omega**2

    def displacement(self, q: np.ndarray) -> np.ndarray:
        """Surface displacement (nv, 3) [m] for modal coordinates ``q`` (r,) [sqrt(kg) m]."""
        return (self.shapes @ np.asarray(q, dtype=np.float64)).reshape(-1, 3)

    # ------------------------------------------------------------------ file format
    def _arrays(self) -> dict:
        out = {k: getattr(self, k) for k in _ARRAY_KEYS}
        out.update({k: getattr(self, k) for k in _OPTIONAL_KEYS if getattr(self, k) is not None})
        return out

    def _meta(self) -> str:
        meta = {"format": "modalfem.ModalModel", "mass": self.mass, "material": self.material,
                "damping": list(self.damping), "provenance": self.provenance}
        return json.dumps(meta, sort_keys=True, separators=(",", ":"), allow_nan=False)

    def checksum(self) -> str:
        """Hex SHA-256 of this model's payload (the value stored in its file)."""
        return payload_checksum(self.SCHEMA_VERSION, self._arrays(), self._meta())

    def save(self, path: str | os.PathLike) -> None:
        """Write the model to ``path`` (.npz) atomically: temporary file in the same directory + rename.

        Either the complete new file is at ``path`` afterwards, or (on any error) ``path`` is
        unchanged and no temporary file is left.

        Args:
            path: target file; its directory must exist. The name is used as given (no suffix added).

        Raises:
            ModelFileError: the file cannot be written (missing directory, permissions, disk full).
        """
        path = Path(path)
        if path.is_dir():
            raise ModelFileError(f"cannot write model file {str(path)!r}: it is a directory")
        meta = self._meta()
        arrays = {k: np.ascontiguousarray(a, dtype="<i8" if k in _INT_KEYS else "<f8")
                  for k, a in self._arrays().items()}
        payload = dict(arrays, schema_version=np.array(self.SCHEMA_VERSION, dtype="<i8"), meta=np.array(meta),
                       checksum=np.array(payload_checksum(self.SCHEMA_VERSION, arrays, meta)))
        write_atomic(path, lambda f: np.savez(f, **payload), error=ModelFileError, kind="model")

    @classmethod
    def load(cls, path: str | os.PathLike) -> ModalModel:
        """Read and validate a model file written by ``save``.

        Args:
            path: the .npz model file.

        Returns:
            The validated ``ModalModel``.

        Raises:
            ModelFileError: the file does not exist, is not an .npz archive, is truncated or
                damaged, lacks entries, has a newer schema version (both versions are named),
                fails its SHA-256 checksum (edited), or holds inconsistent data. One line.
        """
        path = Path(path)
        name = repr(str(path))
        if not path.exists():
            raise ModelFileError(f"model file {name} does not exist")
        if path.is_dir():
            raise ModelFileError(f"model file {name} is a directory")
        try:
            with open(path, "rb") as f:
                magic = f.read(6)
        except OSError as exc:
            raise ModelFileError(f"cannot read model file {name}: {exc.strerror or exc}") from None
        if magic.startswith(b"\x93NUMPY"):
            raise ModelFileError(f"model file {name} is a single .npy array, not a .npz model archive")
        if not magic.startswith(b"PK"):
            raise ModelFileError(f"model file {name} is not a .npz archive (no zip header): not a model file")
        try:
            z = np.load(path, allow_pickle=False)
        except Exception as exc:  # noqa: BLE001 - any parse failure of a damaged file is one clear error
            raise ModelFileError(f"model file {name} is truncated or damaged (unreadable zip archive): "
                                 f"{_detail(exc)}") from None
        try:
            with z:
                data = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001 - CRC errors, truncated members, bad .npy headers
            raise ModelFileError(f"model file {name} is damaged (truncated or edited): {_detail(exc)}") from None
        foreign = sorted(k for k, a in data.items() if not isinstance(a, np.ndarray))
        if foreign:
            raise ModelFileError(f"model file {name} holds non-numpy entries ({', '.join(foreign)}): not a model file")
        if "schema_version" not in data:
            raise ModelFileError(f"model file {name} has no schema_version entry: not a modalfem model file")
        sv = data["schema_version"]
        if sv.shape != () or sv.dtype.kind not in "iu":
            raise ModelFileError(f"model file {name} has a malformed schema_version {sv!r}")
        version = int(sv)
        if version > cls.SCHEMA_VERSION:
            raise ModelFileError(f"model file {name} has schema version {version}, newer than the version "
                                 f"{cls.SCHEMA_VERSION} this modalfem reads; upgrade modalfem")
        if version < 1:
            raise ModelFileError(f"model file {name} has an invalid schema version {version}")
        missing = sorted(_FILE_KEYS - set(data))
        if missing:
            raise ModelFileError(f"model file {name} lacks {', '.join(missing)}: incomplete model file")
        extra = sorted(set(data) - _FILE_KEYS - set(_OPTIONAL_KEYS))
        if extra:
            raise ModelFileError(f"model file {name} has unexpected entries {', '.join(extra)}")
        for key in ("meta", "checksum"):
            if data[key].shape != () or data[key].dtype.kind != "U":
                raise ModelFileError(f"model file {name}: {key} must be a text entry")
        meta_text = str(data["meta"])
        optional = [k for k in _OPTIONAL_KEYS if k in data]
        for key in _ARRAY_KEYS + tuple(optional):
            want = np.dtype("<i8") if key in _INT_KEYS else np.dtype("<f8")
            if data[key].dtype.newbyteorder("<") != want:
                raise ModelFileError(f"model file {name}: {key} has dtype {data[key].dtype}, expected {want}")
        if payload_checksum(version, data, meta_text) != str(data["checksum"]):
            raise ModelFileError(f"model file {name} fails its SHA-256 checksum: the file was edited or corrupted")
        try:
            meta = json.loads(meta_text)
            fields = {k: meta[k] for k in ("mass", "material", "damping", "provenance")}
        except (ValueError, KeyError, TypeError) as exc:
            raise ModelFileError(f"model file {name} has malformed metadata: {_detail(exc)}") from None
        try:
            return cls(**{k: data[k] for k in _ARRAY_KEYS + tuple(optional)}, **fields)
        except ModelFileError as exc:
            raise ModelFileError(f"model file {name}: {exc}") from None

    # ------------------------------------------------------------------ offline construction
    @classmethod
    def from_modes(cls, result, mesh, material, *, damping=(0.0, 1e-6), provenance: dict | None = None,
                   rotation_coupling: bool = True, mass_matrix=None) -> ModalModel:
        """Build a model from a modal analysis: boundary surface, restricted modes, mass properties.

        Only the deformation modes of ``result`` are kept (a free body's rigid modes are handled by
        the runtime's rigid-body state from ``mass``, ``center_of_mass`` and ``inertia``). Clamped
        bodies are stored too; ``provenance["fixed"]`` then describes the held DOFs.

        With ``rotation_coupling`` (default) the rotation-coupling tensors ``rotation_T`` /
        ``rotation_S`` of the pseudo-forces are computed over the full mesh
        (``RotationCoupling.from_matrices``) from ``mass_matrix`` or, when it is None, from the
        mass matrix assembled here with scikit-fem (consistent or lumped as the result was; this
        imports scipy and scikit-fem). Storing them costs 9 r^2 + 9 r floats.

        Args:
            result: ``ModalResult`` of ``modalfem.modes`` on ``mesh`` with ``material``.
            mesh: the ``Mesh`` the result was computed on.
            material: the ``Material`` (E [Pa], nu, rho [kg/m^3]) used for the result, or a dict
                ``{"name", "E", "nu", "rho"}``.
            damping: Rayleigh (alpha [1/s], beta [s]); mu_i = alpha + beta omega_i^2.
            provenance: extra JSON-able entries merged over the generated provenance (e.g.
                ``{"fixed": "x0", "source": {...}}``).
            rotation_coupling: compute and store ``rotation_T`` and ``rotation_S``.
            mass_matrix: the mass matrix (3 n, 3 n) [kg] of the analysis in the canonical DOF order
                (e.g. from ``modalfem.backends.skfem.assemble``), to avoid assembling it again.

        Returns:
            The ``ModalModel``.

        Raises:
            InputError: ``result`` does not match ``mesh`` (DOF count or node coordinates), or
                ``mass_matrix`` has the wrong size.
            ModelFileError: the assembled model is inconsistent (see the class docstring).
        """
        import datetime

        import modalfem
        from modalfem.mesh.surface import boundary_surface, mass_properties

        degree = int(result.degree)
        n_dof = 3 * mesh.node_count(degree)
        if result.shapes.shape[0] != n_dof:
            raise InputError(f"result has {result.shapes.shape[0]} DOFs but the mesh has {n_dof} at degree {degree}: "
                             "the result was not computed on this mesh")
        if not np.array_equal(np.asarray(result.dof_points), mesh.dof_points(degree)):
            raise InputError("result node coordinates differ from the mesh's: the result was not computed on this mesh")
        if isinstance(material, dict):
            mat = ModalModel._check_material(material)
        else:
            mat = {"name": getattr(material, "name", ""), "E": material.E, "nu": material.nu, "rho": material.rho}
        surf = boundary_surface(mesh)
        rows = (3 * surf.mesh_vertices[:, None] + np.arange(3)).ravel()
        fixed_dofs = np.asarray(result.fixed_dofs, dtype=bool)
        mp = mass_properties(mesh, mat["rho"])
        versions = {"modalfem": getattr(modalfem, "__version__", "?"), "numpy": np.__version__}
        versions.update({str(k): str(v) for k, v in dict(result.info.get("versions", {})).items()})
        held = int(fixed_dofs.sum())
        prov = {
            "mesh_hash": mesh.fingerprint,
            "backend": str(result.backend),
            "solver": str(result.solver),
            "degree": degree,
            "fixed": None if held == 0 else f"{held} of {fixed_dofs.size} DOFs held",
            "rigid_mode_count": int(result.rigid_mode_count),
            "certificate_passed": bool(result.certificate.passed),
            "lumped": bool(result.info.get("lumped", False)),
            "mesh_vertex_count": int(mesh.point_count),
            "mesh_cell_count": int(mesh.cell_count),
            "full_dof_count": int(n_dof),
            "versions": versions,
            "created": datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat(),
        }
        prov.update(provenance or {})
        rot_T = rot_S = None
        if rotation_coupling:
            rot_T, rot_S = _rotation_tensors(result, mesh, mat, mp.center_of_mass, mass_matrix)
        return cls(
            vertices=surf.vertices, triangles=surf.triangles, shapes=np.asarray(result.shapes)[rows],
            omega=np.asarray(result.omega), mass=mp.mass, center_of_mass=mp.center_of_mass, inertia=mp.inertia,
            material=mat,
            damping=tuple(damping), provenance=prov, rotation_T=rot_T, rotation_S=rot_S,
        )

    def __repr__(self) -> str:
        f = self.frequencies_hz
        band = f"{f[0]:.4g}..{f[-1]:.4g} Hz" if len(f) else "no modes"
        return (f"ModalModel({self.vertex_count} surface vertices, {len(self.triangles)} triangles, "
                f"{self.mode_count} modes {band}, mass {self.mass:.4g} kg, {self.material['name'] or 'custom'})")


def _rotation_tensors(result, mesh, mat: dict, center_of_mass, mass_matrix):
    """``(T, S)`` of ``RotationCoupling.from_matrices`` for a modal result (offline side)."""
    from modalfem.runtime.effects import RotationCoupling

    n_dof = int(np.asarray(result.shapes).shape[0])
    M = mass_matrix
    if M is None:
        from modalfem.backends.skfem import assemble
        from modalfem.material import Material

        material = Material(mat["E"], mat["nu"], mat["rho"], mat["name"])
        _, M = assemble(mesh, material, degree=int(result.degree), lumped=bool(result.info.get("lumped", False)))
    if getattr(M, "shape", None) != (n_dof, n_dof):
        raise InputError(f"mass matrix must have shape ({n_dof}, {n_dof}) like the result's DOFs, "
                         f"got {getattr(M, 'shape', None)}")
    c = RotationCoupling.from_matrices(result.shapes, M, result.dof_points, center_of_mass)
    return c.T, c.S


def _detail(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def storage_report(result, model: ModalModel) -> dict:
    """Bytes of the full-mesh mode shapes versus the boundary-only shapes stored in ``model``.

    Args:
        result: the ``ModalResult`` the model was built from.
        model: the ``ModalModel``.

    Returns:
        dict with ``full_nodes``, ``boundary_vertices``, ``modes``, ``full_bytes`` (``result.shapes``,
        all nodes incl. P2 edge midpoints), ``boundary_bytes`` (``model.shapes``) and ``ratio``
        (full / boundary); when the provenance has ``mesh_vertex_count``, also ``mesh_vertices``
        and ``all_vertex_bytes`` (shapes on every mesh vertex, interior ones included).
    """
    full = int(np.asarray(result.shapes).nbytes)
    boundary = int(model.shapes.nbytes)
    report = {
        "full_nodes": int(np.asarray(result.shapes).shape[0] // 3),
        "boundary_vertices": model.vertex_count,
        "modes": model.mode_count,
        "full_bytes": full,
        "boundary_bytes": boundary,
        "ratio": full / boundary if boundary else float("inf"),
    }
    nv = model.provenance.get("mesh_vertex_count")
    if isinstance(nv, int):  # the share of the saving from dropping interior vertices (vs P2 edge nodes)
        report["mesh_vertices"] = nv
        report["all_vertex_bytes"] = 3 * nv * model.mode_count * model.shapes.itemsize
    return report
