"""Mode shapes for ParaView: one VTU or XDMF file with every mode as a point-data vector field.

P1 results are written on the linear tetrahedra; P2 results on quadratic ``tetra10`` cells whose
edge nodes are the P2 edge nodes, so ParaView shows the true quadratic field. The XDMF is written
here as one self-contained XML file (meshio's XDMF writer needs h5py even for inline XML data).
"""

from __future__ import annotations

import io
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from modalfem.errors import InputError
from modalfem.mesh.core import Mesh
from modalfem.result import ModalResult

__all__ = ["VTK_TETRA10_ORDER", "mode_field_names", "modes_meshio", "write_modes", "write_xdmf_xml"]

#: columns of ``Mesh.cell_nodes(2)`` (4 vertices, then edges in ``TET_EDGES`` order
#: 01, 02, 03, 12, 13, 23) in VTK/XDMF quadratic-tetra order (edges 01, 12, 02, 03, 13, 23)
VTK_TETRA10_ORDER = np.array([0, 1, 2, 3, 4, 7, 5, 6, 8, 9])


def mode_field_names(i: int) -> tuple[str, str]:
    """Point-data names of deformation mode ``i`` (0-based): vector ``mode_01``, magnitude ``|mode_01|``."""
    return f"mode_{i + 1:02d}", f"|mode_{i + 1:02d}|"


def modes_meshio(mesh: Mesh, result: ModalResult, *, mode_count: int | None = None):
    """A ``meshio.Mesh`` of ``mesh`` with the mode shapes of ``result`` as point data.

    Args:
        mesh: the mesh the modes were computed on.
        result: its modal analysis (degree 1 -> ``tetra`` cells, degree 2 -> ``tetra10`` cells).
        mode_count: write only the first ``mode_count`` modes (default all).

    Returns:
        ``meshio.Mesh`` with points [m] = the Lagrange nodes, point data ``mode_NN`` (n, 3)
        (mass-normalised displacement, [m / sqrt(kg)]) and ``|mode_NN|`` (n,).
    """
    import meshio

    nodes = result.dof_points
    if len(nodes) != mesh.node_count(result.degree):
        raise InputError(
            f"result has {len(nodes)} nodes but the degree-{result.degree} mesh has {mesh.node_count(result.degree)}"
        )
    if result.degree == 1:
        cells = [("tetra", np.ascontiguousarray(mesh.cells))]
    else:
        cells = [("tetra10", np.ascontiguousarray(mesh.cell_nodes(2)[:, VTK_TETRA10_ORDER]))]
    k = result.shapes.shape[1] if mode_count is None else min(int(mode_count), result.shapes.shape[1])
    point_data = {}
    for i in range(k):
        u = result.shape(i)
        vec, mag = mode_field_names(i)
        point_data[vec] = np.ascontiguousarray(u)
        point_data[mag] = np.linalg.norm(u, axis=1)
    return meshio.Mesh(np.asarray(nodes, dtype=np.float64), cells, point_data=point_data)


def write_modes(path: str | os.PathLike, mesh: Mesh, result: ModalResult, *, mode_count: int | None = None) -> Path:
    """Write the mode shapes to ``path``: ``.vtu`` (binary, one file) or ``.xdmf`` (XML, one file).

    Returns:
        The path written.

    Raises:
        InputError: unsupported suffix, or the file cannot be written.
    """
    import meshio

    path = Path(path)
    m = modes_meshio(mesh, result, mode_count=mode_count)
    try:
        if path.suffix == ".vtu":
            meshio.vtu.write(path, m, binary=True)
        elif path.suffix == ".xdmf":
            write_xdmf_xml(path, m)
        else:
            raise InputError(f"mode shapes can be written as .vtu or .xdmf, not {path.name!r}")
    except OSError as exc:
        raise InputError(f"cannot write {str(path)!r}: {exc.strerror or exc}") from None
    return path


_XDMF_TOPOLOGY = {"tetra": ("Tetrahedron", 4), "tetra10": ("Tetrahedron_10", 10)}


def _data_item(parent: ET.Element, a: np.ndarray, fmt: str) -> None:
    integer = np.issubdtype(a.dtype, np.integer)
    item = ET.SubElement(
        parent,
        "DataItem",
        DataType="Int" if integer else "Float",
        Dimensions=" ".join(map(str, a.shape)),
        Format="XML",
        Precision="8",
    )
    buf = io.StringIO()
    np.savetxt(buf, a.reshape(len(a), -1), fmt=fmt)
    item.text = "\n" + buf.getvalue()


def write_xdmf_xml(path: str | os.PathLike, m) -> None:
    """Write a one-grid ``meshio.Mesh`` (tetra or tetra10 cells, point data) as XDMF 3 with inline XML data."""
    (cell_type, block), = [(c.type, c.data) for c in m.cells]
    topology, _ = _XDMF_TOPOLOGY[cell_type]
    root = ET.Element("Xdmf", Version="3.0")
    grid = ET.SubElement(ET.SubElement(root, "Domain"), "Grid", Name="modes", GridType="Uniform")
    _data_item(ET.SubElement(grid, "Geometry", GeometryType="XYZ"), np.asarray(m.points, dtype=np.float64), "%.17g")
    topo = ET.SubElement(grid, "Topology", TopologyType=topology, NumberOfElements=str(len(block)))
    _data_item(topo, np.asarray(block, dtype=np.int64), "%d")
    for name, a in m.point_data.items():
        a = np.asarray(a, dtype=np.float64)
        kind = "Scalar" if a.ndim == 1 else "Vector"
        _data_item(ET.SubElement(grid, "Attribute", Name=name, AttributeType=kind, Center="Node"), a, "%.12g")
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
