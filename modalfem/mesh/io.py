"""Read and write tetrahedral meshes (.msh gmsh 2.2/4.1, .vtu, .xdmf) with named boundary tags.

Reading goes through meshio; any meshio-readable file with tetrahedra works, and ``.msh``,
``.vtu`` and ``.xdmf`` are tested. Boundary tags are collected, in this order of precedence, from

1. ``tag:<name>`` cell-data arrays on triangles (what :func:`write` stores in .vtu/.xdmf; the
   value is the 1-based position of the triangle in the tag, 0 elsewhere, so order round-trips);
2. meshio ``cell_sets`` selecting triangles (gmsh 4.1 physical groups, Abaqus/Exodus sets, ...);
3. ``gmsh:physical`` numbers on triangles, named from ``field_data`` (gmsh ``$PhysicalNames``)
   or ``"tag_<number>"`` when unnamed (number 0, "no group", is ignored). Named 2D groups with no
   triangles become empty tags.

Decision on ``"boundary"``: every mesh returned by :func:`read` has a tag ``"boundary"``. If the
file has no tag of that name, it is added as all boundary facets (outward oriented). A file tag
named ``"boundary"`` is kept as it is. So ``read(write(mesh))`` equals ``mesh`` (points, cells and
tags, exactly) when ``mesh`` has a ``"boundary"`` tag, as all generator meshes do, and equals
``mesh`` plus that tag otherwise.

Second-order tetrahedra (tetra10) and triangles (triangle6) are read by their corner vertices;
the mid-edge nodes are dropped (modalfem builds P2 fields on linear geometry).

Writing: ``.msh`` is written with the gmsh API (format 4.1 by default, or 2.2; binary by default
so coordinates round-trip bit for bit), every tag becoming a named 2D physical group and the
volume a 3D physical group ``"domain"`` (``"domain_volume"`` if a tag has that name), so gmsh and
dolfinx's gmshio can use the file. ``.vtu`` and ``.xdmf`` (XML data: one self-contained file, no
.h5) are written by meshio with the ``tag:<name>`` arrays above. Writes are atomic: a temporary
file in the same directory is renamed over the target with ``os.replace``.

Only tetrahedra and boundary triangles are kept: several volume regions (e.g. gmsh Physical
Volumes) are read as one body, and other cell types (lines, vertices, quads) are ignored.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import sys
import tempfile
import threading
import types
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from modalfem.errors import InputError, MeshError
from modalfem.mesh.core import Mesh

__all__ = ["read", "write", "WRITE_FORMATS"]

#: file suffix -> meshio format name, for :func:`write`
WRITE_FORMATS = {".msh": "gmsh", ".vtu": "vtu", ".xdmf": "xdmf"}
_TAG_PREFIX = "tag:"
_TET_TYPES = ("tetra", "tetra10")
_TRI_TYPES = ("triangle", "triangle6")


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    first = text.splitlines()[0] if text else ""
    return f"{type(exc).__name__}: {first}" if first else f"malformed or unsupported file ({type(exc).__name__})"


_H5PY_LOCK = threading.Lock()


@contextmanager
def _xdmf_without_h5py():
    """Let meshio handle XML-only XDMF without importing h5py.

    meshio imports h5py unconditionally in its XDMF reader and writer although XML data never
    uses it. A pip-installed h5py bundles its own HDF5 and breaks ("Not a datatype") in a process
    that has loaded dolfinx's system HDF5, so modalfem does not depend on it: when h5py is not
    installed, a bare placeholder module stands in for the duration of the call (under a lock)
    and is removed afterwards; HDF5-backed XDMF files then fail with a clear message.
    """
    if importlib.util.find_spec("h5py") is not None:
        yield
        return
    with _H5PY_LOCK:
        stub = types.ModuleType("h5py")
        sys.modules["h5py"] = stub
        try:
            yield
        finally:
            if sys.modules.get("h5py") is stub:
                del sys.modules["h5py"]


def _as_path(path, what: str) -> Path:
    if isinstance(path, bool) or not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{what} path must be a str or os.PathLike, got {type(path).__name__}")
    return Path(path)


# ---------------------------------------------------------------------- read
def read(path, *, unit_scale: float = 1.0) -> Mesh:
    """Read a tetrahedral mesh and its boundary tags.

    Args:
        path: mesh file (.msh gmsh 2.2/4.x, .vtu, .xdmf, or any meshio format with tetrahedra).
        unit_scale: factor turning file coordinates into metres, e.g. ``1e-3`` for a file in mm;
            finite and > 0.

    Returns:
        Validated ``Mesh`` (points [m]); tags from the file plus ``"boundary"`` (see module doc).

    Raises:
        InputError: ``unit_scale`` is not a finite number > 0, or ``path`` is not a path.
        MeshError: the file is missing, unreadable or malformed, has no tetrahedra (the message
            lists the cell types it has), or fails the ``Mesh`` quality checks; the message names
            the file.
    """
    scale = _check_unit_scale(unit_scale)
    p = _as_path(path, "mesh")
    if not p.exists():
        raise MeshError(f"mesh file not found: {p}")
    if not p.is_file():
        raise MeshError(f"mesh path is not a file: {p}")
    import meshio

    no_h5py = p.suffix.lower() == ".xdmf" and importlib.util.find_spec("h5py") is None
    try:
        with _xdmf_without_h5py():
            m = _meshio_read(meshio, p)
    except Exception as exc:
        if no_h5py and "h5py" in str(exc):
            raise MeshError(
                f"cannot read mesh file {p}: HDF5-backed XDMF needs h5py (pip install h5py); {_one_line(exc)}"
            ) from exc
        if isinstance(exc, MeshError):
            raise
        raise MeshError(f"cannot read mesh file {p}: {_one_line(exc)}") from exc
    try:
        return _from_meshio(m, scale, p)
    except MeshError as exc:
        raise MeshError(f"{p}: {exc}") from None


def _meshio_read(meshio, p: Path):
    """meshio's reader for ``p``, without meshio's stray prints or its ``sys.exit`` on failure."""
    readers = {".msh": meshio.gmsh.read, ".vtu": meshio.vtu.read, ".xdmf": meshio.xdmf.read}
    reader = readers.get(p.suffix.lower())
    if reader is not None:
        return reader(str(p))
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            return meshio.read(p)
    except SystemExit:  # meshio exits the process when no reader accepts the file
        known = ", ".join(meshio.extension_to_filetypes.get(p.suffix.lower(), [])) or "none"
        raise MeshError(f"cannot read mesh file {p}: no meshio reader accepted it (tried: {known})") from None


def _check_unit_scale(unit_scale) -> float:
    from modalfem.mesh.generators import _positive

    return _positive("unit_scale", unit_scale, unit="metres per file unit")


def _from_meshio(m, scale: float, p: Path) -> Mesh:
    blocks = list(m.cells)
    tets = [b.data[:, :4] for b in blocks if b.type in _TET_TYPES]
    if not tets:
        kinds = Counter()
        for b in blocks:
            kinds[b.type] += len(b.data)
        have = ", ".join(f"{k} x {n}" for k, n in kinds.items()) or "no cells at all"
        hint = ""
        if p.suffix.lower() == ".msh":
            hint = " (gmsh saves only elements in physical groups: add a Physical Volume or set Mesh.SaveAll=1)"
        raise MeshError(f"no tetrahedra in the file; it has {have}{hint}")
    points = np.asarray(m.points, dtype=np.float64)
    if points.ndim == 2 and points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    cells = np.vstack(tets).astype(np.int64)
    tris = {i: b.data[:, :3].astype(np.int64) for i, b in enumerate(blocks) if b.type in _TRI_TYPES}
    tags = _tags_from_meshio(m, tris)
    mesh = Mesh(points * scale, cells, tags)
    if "boundary" not in mesh.tags:
        mesh = Mesh(mesh.points, mesh.cells, {**mesh.tags, "boundary": mesh.boundary_facets})
    return mesh


def _tags_from_meshio(m, tris: dict[int, np.ndarray]) -> dict[str, np.ndarray]:
    empty = np.zeros((0, 3), dtype=np.int64)
    tags: dict[str, np.ndarray] = {}
    # 1. modalfem's own position arrays
    for key, arrays in m.cell_data.items():
        if not key.startswith(_TAG_PREFIX):
            continue
        rows, pos = [empty], [np.zeros(0)]
        for i, tri in tris.items():
            v = np.asarray(arrays[i]).ravel()
            rows.append(tri[v > 0])
            pos.append(v[v > 0])
        tags[key[len(_TAG_PREFIX) :]] = np.vstack(rows)[np.argsort(np.concatenate(pos), kind="stable")]
    # 2. cell sets selecting triangles
    surface_names = {k for k, v in m.field_data.items() if len(np.ravel(v)) >= 2 and int(np.ravel(v)[1]) == 2}
    for name, sets in (m.cell_sets or {}).items():
        if name.startswith("gmsh:") or name in tags:
            continue
        rows = [empty]
        for i, tri in tris.items():
            if i < len(sets) and sets[i] is not None:
                rows.append(tri[np.asarray(sets[i], dtype=np.int64)])
        f = np.vstack(rows)
        if len(f) or name in surface_names:
            tags[name] = f
    # 3. gmsh physical numbers on triangles
    physical = m.cell_data.get("gmsh:physical")
    if physical is not None:
        names = {int(np.ravel(v)[0]): k for k, v in m.field_data.items() if k in surface_names}
        groups: dict[int, list[np.ndarray]] = {}
        for i, tri in tris.items():
            ids = np.asarray(physical[i]).ravel().astype(np.int64)
            for number in np.unique(ids):
                groups.setdefault(int(number), []).append(tri[ids == number])
        for number in sorted(groups):
            name = names.get(number, f"tag_{number}")
            if number != 0 and name not in tags:
                tags[name] = np.vstack(groups[number])
    for name in surface_names:
        tags.setdefault(name, empty)
    return tags


# ---------------------------------------------------------------------- write
def write(mesh: Mesh, path, *, msh_version: str = "4.1", binary: bool = True) -> Path:
    """Write ``mesh`` with its tags, atomically (temporary file + ``os.replace``).

    Args:
        mesh: the mesh; coordinates are written in metres.
        path: target file; the suffix picks the format: ``.msh``, ``.vtu`` or ``.xdmf``.
        msh_version: ``"4.1"`` or ``"2.2"``, for ``.msh`` only.
        binary: binary ``.msh`` (exact coordinates) or ASCII (16 significant digits); ``.vtu``
            data is always binary and ``.xdmf`` always XML text with 17 significant digits.

    Returns:
        The path written, so that ``read(write(mesh, path))`` works.

    Raises:
        InputError: unsupported suffix or msh_version, missing directory, a tag name gmsh cannot
            store (containing ``"`` or a newline), ``mesh`` not a ``Mesh``.
        MeshError: the file could not be written (the message names it).
    """
    if not isinstance(mesh, Mesh):
        raise InputError(f"write() needs a modalfem Mesh, got {type(mesh).__name__}")
    p = _as_path(path, "output")
    suffix = p.suffix.lower()
    if suffix not in WRITE_FORMATS:
        raise InputError(f"cannot write {p}: unsupported suffix {p.suffix!r} (use one of {', '.join(WRITE_FORMATS)})")
    if msh_version not in ("4.1", "2.2"):
        raise InputError(f"msh_version must be '4.1' or '2.2', got {msh_version!r}")
    directory = p.parent if str(p.parent) else Path(".")
    if not directory.is_dir():
        raise InputError(f"cannot write {p}: directory {directory} does not exist")
    for name in mesh.tags:
        if '"' in name or "\n" in name or not name:
            raise InputError(f"tag name {name!r} cannot be stored in a mesh file (empty, or has a quote or newline)")
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{p.name}.", suffix=f".tmp{suffix}")
    os.close(fd)
    try:
        if suffix == ".msh":
            _write_msh(mesh, tmp, msh_version, binary)
        else:
            _write_meshio(mesh, tmp, WRITE_FORMATS[suffix])
        mode = (p.stat().st_mode & 0o777) if p.exists() else 0o644
        os.chmod(tmp, mode)
        os.replace(tmp, p)
    except InputError:
        raise
    except MeshError as exc:
        raise MeshError(f"cannot write mesh file {p}: {exc}") from exc
    except Exception as exc:
        raise MeshError(f"cannot write mesh file {p}: {_one_line(exc)}") from exc
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return p


def _write_meshio(mesh: Mesh, tmp: str, fmt: str) -> None:
    import meshio

    names = sorted(mesh.tags)
    facets = [mesh.tags[n] for n in names]
    tri = np.vstack([np.zeros((0, 3), dtype=np.int64)] + facets)
    blocks = [("tetra", np.asarray(mesh.cells))]
    if len(tri):
        blocks.append(("triangle", tri))
    cell_data = {}
    offset = 0
    for name, f in zip(names, facets):
        pos = np.zeros(len(tri), dtype=np.int64)
        pos[offset : offset + len(f)] = np.arange(1, len(f) + 1)
        offset += len(f)
        cell_data[_TAG_PREFIX + name] = [np.zeros(mesh.cell_count, dtype=np.int64)] + ([pos] if len(tri) else [])
    out = meshio.Mesh(np.asarray(mesh.points), blocks, cell_data=cell_data)
    if fmt == "xdmf":
        with _xdmf_without_h5py():
            meshio.write(tmp, out, file_format="xdmf", data_format="XML")
    else:
        meshio.write(tmp, out, file_format=fmt)


def _write_msh(mesh: Mesh, tmp: str, version: str, binary: bool) -> None:
    from modalfem.mesh.generators import _gmsh_session

    options = {"Mesh.MshFileVersion": float(version), "Mesh.Binary": int(bool(binary)), "Mesh.SaveAll": 0}
    with _gmsh_session("write", options) as gmsh:
        volume = gmsh.model.addDiscreteEntity(3)
        gmsh.model.mesh.addNodes(3, volume, np.arange(1, mesh.point_count + 1), np.asarray(mesh.points).ravel())
        gmsh.model.mesh.addElementsByType(volume, 4, np.arange(1, mesh.cell_count + 1), (mesh.cells + 1).ravel())
        next_element = mesh.cell_count + 1
        names = sorted(mesh.tags)
        for number, name in enumerate(names, start=1):
            f = mesh.tags[name]
            surface = gmsh.model.addDiscreteEntity(2)
            if len(f):
                gmsh.model.mesh.addElementsByType(
                    surface, 2, np.arange(next_element, next_element + len(f)), (f + 1).ravel()
                )
                next_element += len(f)
            gmsh.model.addPhysicalGroup(2, [surface], number)
            gmsh.model.setPhysicalName(2, number, name)
        domain, volume_name = len(names) + 1, "domain"
        while volume_name in mesh.tags:  # readers key physical names by name alone
            volume_name += "_volume"
        gmsh.model.addPhysicalGroup(3, [volume], domain)
        gmsh.model.setPhysicalName(3, domain, volume_name)
        gmsh.write(tmp)
