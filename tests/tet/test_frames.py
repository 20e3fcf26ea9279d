"""The frame-sheet helper writes a PNG with one panel per frame and rejects bad frames."""

from __future__ import annotations

import numpy as np
import pytest

from modalfem.errors import InputError
from modalfem.mesh import box
from modalfem.tet.frames import boundary_faces, plot_frame_sheet


def test_boundary_faces_cover_the_surface():
    mesh = box(size=(0.1, 0.1, 0.1), cells=(2, 2, 2))
    faces, cells = boundary_faces(mesh)
    assert len(faces) == len(mesh.boundary_facets) == 6 * 2 * 2 * 2
    assert np.all(np.isin(faces, mesh.cells[cells]).all(axis=1))
    p = mesh.points[faces]
    area_normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    # divergence theorem: sum of x . n dA / 3 over the closed outward surface = volume
    assert np.einsum("ij,ij->", p.mean(axis=1), area_normal) / 3 == pytest.approx(mesh.volume, rel=1e-12)


def test_frame_sheet_png(tmp_path):
    pytest.importorskip("matplotlib")
    from PIL import Image

    mesh = box(size=(0.1, 0.1, 0.1), cells=(1, 1, 1))
    flat = mesh.points.copy()
    flat[:, 2] = 0.0
    path = plot_frame_sheet(tmp_path / "s.png", mesh, [mesh.points, flat, mesh.points * 1.2],
                            labels=["rest", "flat", "big"], ncols=3, ground=0.0)
    with Image.open(path) as im:
        assert im.size[0] > 2 * im.size[1]  # three panels side by side
    assert not list(tmp_path.glob(".*tmp"))
    with pytest.raises(InputError):
        plot_frame_sheet(tmp_path / "bad.png", mesh, [mesh.points[:-1]])
    with pytest.raises(InputError):
        plot_frame_sheet(tmp_path / "none.png", mesh, [])
