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

Reading fails with one line (``MeshError``) saying what is wrong with the file: missing, empty,
an unknown extension (the known ones are listed), not the format its extension says, truncated
(which section or closing tag is missing) or corrupt. A body larger than 50 m or smaller than
0.1 mm after ``unit_scale`` gives one ``UnitWarning`` suggesting the ``unit_scale`` that fixes it.

Surface files (.stl, .obj, .ply, .off) are tetrahedralised by :func:`modalfem.mesh.from_surface`.

Only tetrahedra and boundary triangles are kept: several volume regions (e.g. gmsh Physical
Volumes) are read as one body, and other cell types (lines, vertices, quads) are ignored.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import re
import sys
import tempfile
import threading
import types
import warnings
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from modalfem.errors import InputError, MeshError
from modalfem.mesh.core import Mesh

__all__ = ["read", "write", "WRITE_FORMATS", "UnitWarning", "LARGE_BODY", "SMALL_BODY"]

#: file suffix -> meshio format name, for :func:`write`
WRITE_FORMATS = {".msh": "gmsh", ".vtu": "vtu", ".xdmf": "xdmf"}
_TAG_PREFIX = "tag:"
_TET_TYPES = ("tetra", "tetra10")
#: surface files, made solid by ``modalfem.mesh.from_surface`` (modalfem.mesh.solid)
SURFACE_SUFFIXES = (".stl", ".obj", ".ply", ".off")
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
#: bounding-box diagonal [m] above or below which :func:`read` warns that the unit looks wrong
#: (modalfem's bodies range from millimetre parts to structures of a few metres; see read())
LARGE_BODY = 50.0
SMALL_BODY = 1e-4


class UnitWarning(UserWarning):
    """A mesh read from a file is implausibly large or small: its unit is probably not metres."""


def read(path, *, unit_scale: float = 1.0) -> Mesh:
    """Read a tetrahedral mesh and its boundary tags.

    Args:
        path: mesh file (.msh gmsh 2.2/4.x, .vtu, .xdmf, or any meshio format with tetrahedra), or a
            surface (.stl, .obj, .ply, .off), made solid by ``modalfem.mesh.from_surface`` with its
            defaults (h 5 % of the diagonal; use that function for other settings and its report).
        unit_scale: factor turning file coordinates into metres, e.g. ``1e-3`` for a file in mm;
            finite and > 0.

    Returns:
        Validated ``Mesh`` (points [m]); tags from the file plus ``"boundary"`` (see module doc).

    Raises:
        InputError: ``unit_scale`` is not a finite number > 0, or ``path`` is not a path.
        MeshError: one line naming the file and what is wrong with it: missing, a directory,
            unreadable, empty (0 bytes, no points or no cells), not a mesh of a known format (the
            message lists the known extensions), not the format its extension says (e.g. binary
            data in a .msh), truncated or corrupt (the message names the format and what was
            expected, e.g. the section cut off), no tetrahedra (the message lists the cell types
            it has), or failing the ``Mesh`` quality checks.

    Warns:
        UnitWarning: the body's bounding-box diagonal (after ``unit_scale``) is larger than
            ``LARGE_BODY`` = 50 m or smaller than ``SMALL_BODY`` = 1e-4 m. Bodies simulated with
            modalfem range from millimetre parts (a 1 mm part has a diagonal of ~2e-3 m) to
            structures of a few metres (a church bell, a frame: up to ~10 m), so both thresholds
            keep a factor 5 or more from real bodies; beyond them the file's unit is most likely
            not metres (a part of 50 mm or more exported in millimetres reads as 50 m or more),
            and the warning suggests the ``unit_scale`` (CLI ``--unit-scale``) that fixes it.
            Parts under 50 mm exported in millimetres look like plausible metre-sized bodies and
            cannot be told apart.
    """
    scale = _check_unit_scale(unit_scale)
    p = _as_path(path, "mesh")
    try:
        if p.suffix.lower() in SURFACE_SUFFIXES:  # a surface: tetrahedralised (modalfem.mesh.from_surface)
            from modalfem.mesh.solid import from_surface

            mesh = from_surface(p, unit_scale=scale)
        else:
            mesh = _read(p, scale)
    except MeshError as exc:
        text = str(exc)
        if "\n" in text or "\r" in text:  # a file name or a parser message with a line break
            raise MeshError(" ".join(text.split())) from exc.__cause__
        raise
    _warn_about_size(mesh, p, scale)
    return mesh


def _read(p: Path, scale: float) -> Mesh:
    kind = _check_file(p)
    import meshio

    no_h5py = kind.suffix == ".xdmf" and importlib.util.find_spec("h5py") is None
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
        raise MeshError(_failure(p, kind, exc)) from exc
    try:
        empty = _emptiness(m)
        if empty:
            raise MeshError(_structure_problem(p, kind) or f"empty mesh file {p}: {empty}")
        mesh = _from_meshio(m, scale, p)
    except MeshError as exc:
        text = str(exc)
        raise MeshError(text if str(p) in text else f"{p}: {text}") from None
    except Exception as exc:
        raise MeshError(
            f"corrupt {kind.name} file {p}: its cells, tags or data arrays do not fit together ({_one_line(exc)})"
        ) from exc
    return mesh


class _Kind:
    """What the file's extension says it is: ``suffix`` (lower case) and a readable ``name``."""

    NAMES = {".msh": "gmsh .msh", ".vtu": "VTK XML .vtu", ".xdmf": "XDMF", ".xmf": "XDMF"}

    def __init__(self, suffix: str, filetypes: list[str]):
        self.suffix = suffix
        self.name = self.NAMES.get(suffix) or f"{suffix} ({'/'.join(filetypes)})"


def _known_suffix(p: Path, table: dict) -> str | None:
    """The longest registered suffix of ``p`` (``.vol.gz`` before ``.gz``), lower case, or None."""
    suffixes = [x.lower() for x in p.suffixes]
    for n in range(min(len(suffixes), 2), 0, -1):
        candidate = "".join(suffixes[-n:])
        if candidate in table:
            return candidate
    return None


def _check_file(p: Path) -> _Kind:
    """Reject, in one line each, what is not a readable mesh file, before meshio sees it."""
    try:
        if not p.exists():
            raise MeshError(f"mesh file not found: {p}")
        if p.is_dir():
            raise MeshError(f"mesh path is a directory, not a file: {p}")
        if not p.is_file():
            raise MeshError(f"mesh path is not a regular file: {p}")
        size = p.stat().st_size
        with open(p, "rb") as f:
            head = f.read(4096)
    except ValueError as exc:  # e.g. an embedded NUL byte in the name
        raise InputError(f"mesh path {str(p)!r} is not a valid file name: {_one_line(exc)}") from None
    except OSError as exc:
        raise MeshError(f"cannot open mesh file {p}: {exc.strerror or _one_line(exc)}") from None
    import meshio

    table = meshio.extension_to_filetypes
    suffix = _known_suffix(p, table)
    if suffix is None:
        others = sorted(s for s in table if s not in WRITE_FORMATS)
        what = f"extension {p.suffix!r}" if p.suffix else "no extension"
        raise MeshError(
            f"{p} is not a mesh of a known format ({what}); known extensions: "
            f"{', '.join(WRITE_FORMATS)} (tested) and, through meshio, {', '.join(others)}"
        )
    kind = _Kind(suffix, table[suffix])
    if size == 0:
        raise MeshError(f"empty mesh file {p}: it has 0 bytes")
    problem = _signature_problem(suffix, head)
    if problem:
        raise MeshError(f"{p} is not a valid {kind.name} file: {problem}")
    return kind


def _looks_binary(head: bytes) -> bool:
    if b"\x00" in head:
        return True
    sample = head[:1024]
    try:
        sample.decode("utf-8")
    except UnicodeDecodeError as exc:
        return exc.start < len(sample) - 4  # a character cut at the end of the sample is no evidence
    return False


#: VTK XML dataset types other than UnstructuredGrid (the only one a .vtu holds)
_VTK_OTHER_TYPES = {b"ImageData", b"RectilinearGrid", b"StructuredGrid", b"PolyData", b"PImageData",
                    b"PRectilinearGrid", b"PStructuredGrid", b"PPolyData", b"PUnstructuredGrid", b"Collection",
                    b"vtkMultiBlockDataSet", b"vtkHierarchicalBoxDataSet", b"HyperTreeGrid"}


def _signature_problem(suffix: str, head: bytes) -> str | None:
    """Why the first bytes cannot start a file of this suffix, or None (only .msh/.vtu/.xdmf checked)."""
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    data = " (it holds binary data)" if _looks_binary(head) else ""
    if suffix == ".msh":
        if text.startswith((b"$NOD", b"$NOE")):
            return "it is in gmsh's MSH 1 format, which is not supported; re-save it as MSH 4.1 or 2.2"
        if not text.startswith(b"$MeshFormat"):
            return f"it does not begin with $MeshFormat{data}"
        lines = text.split(b"\n", 2)
        fields = lines[1].split() if len(lines) > 1 else []
        version = fields[0].decode("ascii", "backslashreplace")[:20] if fields else ""
        if not version.startswith(("2.", "4.")):
            return f"its $MeshFormat line gives version {version or '(none)'!r}; readable are MSH 2.2, 4.0 and 4.1"
    elif suffix == ".vtu":
        if not text.startswith((b"<?xml", b"<VTKFile")):
            return f"it does not begin with '<?xml' or '<VTKFile'{data}"
        match = re.search(rb'<VTKFile[^>]*\stype="(\w+)"', head)
        if match and match.group(1) in _VTK_OTHER_TYPES:
            return f"it is a VTK {match.group(1).decode('ascii', 'replace')} file, not an UnstructuredGrid"
    elif suffix in (".xdmf", ".xmf"):
        if not text.startswith((b"<?xml", b"<Xdmf")):
            return f"it does not begin with '<?xml' or '<Xdmf'{data}"
    return None


def _emptiness(m) -> str | None:
    """Why a meshio mesh is empty (no points, or no cells), or None."""
    if len(np.asarray(m.points)) == 0:
        return "it has no points"
    if sum(len(b.data) for b in m.cells) == 0:
        return f"it has {len(m.points)} points but no cells"
    return None


def _structure_problem(p: Path, kind: _Kind) -> str | None:
    """A one-line message if the file is visibly truncated or empty, else None."""
    try:
        data = p.read_bytes()
    except OSError:
        return None
    if kind.suffix == ".msh":
        return _msh_structure(p, data)
    closing = {".vtu": b"</VTKFile>", ".xdmf": b"</Xdmf>", ".xmf": b"</Xdmf>"}.get(kind.suffix)
    if closing and closing not in data[-65536:]:
        return f"truncated {kind.name} file {p}: it ends before the closing {closing.decode()} tag"
    if kind.suffix == ".vtk":  # legacy VTK: the POINTS keyword line is ASCII even in binary files
        match = re.search(rb"^POINTS\s+(\d+)", data[: 1 << 20], flags=re.MULTILINE)
        if match and int(match.group(1)) == 0:
            return f"empty mesh file {p}: it has no points (POINTS 0)"
        cells = re.search(rb"^CELLS\s+(\d+)\s+(\d+)", data, flags=re.MULTILINE)
        if match and (cells is None or int(cells.group(2)) == 0):
            return f"empty mesh file {p}: it has {match.group(1).decode()} points but no cells"
    if kind.suffix == ".vtu":
        head = data[: 1 << 20]
        for key, noun in ((b"NumberOfPoints", "points"), (b"NumberOfCells", "cells")):
            counts = [int(v) for v in re.findall(rb"\s" + key + rb'="(\d+)"', head)]
            if counts and not any(counts):
                return f'empty mesh file {p}: it has no {noun} ({key.decode()}="0")'
    return None


def _msh_format(data: bytes) -> str:
    """``"gmsh MSH 4.1 binary"`` from the $MeshFormat line (``"gmsh .msh"`` if unreadable)."""
    lines = data.lstrip().split(b"\n", 2)
    fields = lines[1].split() if len(lines) > 1 else []
    if len(fields) >= 2 and fields[1] in (b"0", b"1") and re.fullmatch(rb"\d{1,2}(\.\d{1,2})?", fields[0]):
        return f"gmsh MSH {fields[0].decode('ascii')} {'binary' if fields[1] == b'1' else 'ASCII'}"
    return "gmsh .msh"


def _msh_structure(p: Path, data: bytes) -> str | None:
    """Truncation of a .msh file: a section without its $End line, or no $Nodes/$Elements."""
    fmt = _msh_format(data)
    sections: list[str] = []
    open_section = None
    for match in re.finditer(rb"^\$(\w+)[ \t]*\r?$", data, flags=re.MULTILINE):
        name = match.group(1).decode("ascii", "replace")
        if open_section is None and name.startswith("End"):
            return f"corrupt {fmt} file {p}: ${name} appears without its ${name[3:]} line"
        if open_section is None:
            open_section = name
            sections.append(name)
        elif name == "End" + open_section:
            open_section = None
        elif open_section != "Comments":
            break  # another section starts inside this one: this one was cut
    if open_section is not None and open_section != "Comments":
        return (
            f"truncated {fmt} file {p}: the ${open_section} section has no $End{open_section} "
            "(the file ends inside it)"
        )
    for needed in ("Nodes", "Elements"):
        if needed not in sections:
            return f"truncated or incomplete {fmt} file {p}: it has no ${needed} section"
    for section, noun in (("Nodes", "points"), ("Elements", "cells")):
        if _msh_count(data, section) == 0:
            return f"empty mesh file {p}: it has no {noun} (its ${section} section is empty)"
    return None


def _msh_count(data: bytes, section: str) -> int | None:
    """The node or element count in the header of a .msh section (None if it cannot be read)."""
    lines = data.lstrip().split(b"\n", 2)
    fields = lines[1].split() if len(lines) > 1 else []
    start = data.find(b"\n$" + section.encode() + b"\n")
    if len(fields) < 3 or start < 0:
        return None
    body = data[start + len(section) + 3 :]
    try:
        major, binary, size = fields[0][:1], fields[1] == b"1", int(fields[2])
        if major == b"2":
            return int(body.split(b"\n", 1)[0].split()[0])
        if not binary:
            return int(body.split(b"\n", 1)[0].split()[1])
        if size not in (4, 8) or len(body) < 2 * size:
            return None
        return int(np.frombuffer(body[: 2 * size], dtype=f"<u{size}")[1])
    except (ValueError, IndexError):
        return None


def _failure(p: Path, kind: _Kind, exc: Exception) -> str:
    """One line saying what is wrong with a file meshio could not read."""
    structural = _structure_problem(p, kind)
    if structural:
        return structural
    detail = _one_line(exc)
    if kind.suffix == ".msh":
        try:
            with open(p, "rb") as f:
                fmt = _msh_format(f.read(4096))
        except OSError:
            fmt = kind.name
        return f"corrupt {fmt} file {p}: its sections are complete but their contents do not parse ({detail})"
    if kind.suffix in (".vtu", ".xdmf", ".xmf"):
        return f"corrupt {kind.name} file {p}: it is complete but its XML or data arrays do not parse ({detail})"
    return f"cannot read mesh file {p} as {kind.name}: corrupt, truncated or not in that format ({detail})"


def _meshio_read(meshio, p: Path):
    """meshio's reader for ``p``, silenced: no stray prints, warnings or ``sys.exit`` on failure.

    meshio prints its own "Warning: ..." lines (to whatever ``sys.stderr`` is at the time) and lets
    numpy's DeprecationWarnings through on damaged files; :func:`read` reports in one line what is
    wrong with the file instead, so both are dropped here.
    """
    readers = {".msh": meshio.gmsh.read, ".vtu": meshio.vtu.read, ".xdmf": meshio.xdmf.read}
    reader = readers.get(p.suffix.lower())
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return reader(str(p)) if reader is not None else meshio.read(p)
    except SystemExit:  # meshio exits the process when no reader accepts the file
        known = ", ".join(meshio.extension_to_filetypes.get(p.suffix.lower(), [])) or "none"
        raise MeshError(f"cannot read mesh file {p}: no meshio reader accepted it (tried: {known})") from None


#: file units a unit warning may suggest, most likely first: metres per file unit -> name
_FILE_UNITS = {1e-3: "millimetres", 1.0: "metres", 1e-2: "centimetres", 0.0254: "inches", 1e-6: "micrometres",
               0.3048: "feet", 1e3: "kilometres"}


def _warn_about_size(mesh: Mesh, p: Path, scale: float) -> None:
    """One ``UnitWarning`` if the body is outside [SMALL_BODY, LARGE_BODY], with the likely fix."""
    lo, hi = mesh.bounds
    size = float(np.linalg.norm(hi - lo))
    if SMALL_BODY <= size <= LARGE_BODY:
        return
    bound = f"larger than the {LARGE_BODY:g} m" if size > LARGE_BODY else f"smaller than the {SMALL_BODY:g} m"
    fits = [u for u in _FILE_UNITS if u != scale and SMALL_BODY <= size * u / scale <= LARGE_BODY]
    if not fits:
        advice = "check the file's unit and pass unit_scale = metres per file unit (CLI: --unit-scale)"
    elif fits[0] == 1.0:
        advice = "if the file is in metres, drop unit_scale (CLI: --unit-scale 1)"
    else:
        u = fits[0]
        advice = f"if the file is in {_FILE_UNITS[u]}, pass unit_scale={u:g} (CLI: --unit-scale {u:g})"
    warnings.warn(
        f"mesh {p}: the body is {size:.3g} m across (bounding-box diagonal with unit_scale={scale:g}), "
        f"{bound} expected of a body; {advice}",
        UnitWarning,
        stacklevel=3,
    )


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
