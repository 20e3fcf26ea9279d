"""Offscreen rendering: frames show the body where the camera puts it, GIF/PNG round trips, errors."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from modalfem.errors import InputError
from modalfem.mesh import box
from modalfem.mesh.surface import boundary_surface
from modalfem.output.animation import (
    Camera,
    fit_camera,
    plot_spectrum,
    render_frames,
    write_frame_sheet,
    write_gif,
)

SIZE = (160, 120)
RED = (0.9, 0.1, 0.1)


@pytest.fixture(scope="module")
def cube():
    s = boundary_surface(box(size=(0.1, 0.1, 0.1), cells=(2, 2, 2)))
    return s.vertices - (0.05, 0.05, 0.0), s.triangles  # centred on the z axis, resting on z = 0


def _body_mask(img):
    """Pixels of the (red) body: red clearly above green and blue."""
    rgb = img.astype(float)
    return (rgb[..., 0] > rgb[..., 1] + 40) & (rgb[..., 0] > rgb[..., 2] + 40)


def test_frames_show_the_body_where_it_is(cube):
    v, t = cube
    frames = np.array([v + (0, 0, 0.02), v + (0, 0, 0.12)])  # low, then lifted
    cam = fit_camera(frames, elev=20.0, azim=-60.0, aspect=SIZE[0] / SIZE[1])
    imgs = render_frames(frames, t, camera=cam, size=SIZE, color=RED)
    assert imgs.shape == (2, SIZE[1], SIZE[0], 3) and imgs.dtype == np.uint8
    rows = [np.flatnonzero(_body_mask(im).any(axis=1)) for im in imgs]
    assert all(len(r) > 10 for r in rows)
    assert rows[1].mean() < rows[0].mean() - 10  # lifted body is drawn higher (image rows grow downwards)
    # the camera keeps every vertex in view: the body never touches the picture border
    for im in imgs:
        m = _body_mask(im)
        assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())


def test_shading_follows_the_normals_and_back_faces_are_hidden(cube):
    v, t = cube
    cam = Camera(center=(0.0, 0.0, 0.05), half_width=0.12, elev=35.0, azim=-60.0)
    img = render_frames(v, t, camera=cam, size=SIZE, color=RED, ground_z=None)[0]
    reds = img[_body_mask(img)][:, 0]
    levels = np.unique(reds // 8)
    assert len(levels) >= 2  # three visible faces, lit differently
    # one horizontal triangle seen from above: drawn when its normal points up, culled when down
    tri = np.array([[-0.05, -0.05, 0.05], [0.05, -0.05, 0.05], [0.0, 0.05, 0.05]])
    up = render_frames(tri, np.array([[0, 1, 2]]), camera=cam, size=SIZE, color=RED, ground_z=None)[0]
    down = render_frames(tri, np.array([[0, 2, 1]]), camera=cam, size=SIZE, color=RED, ground_z=None)[0]
    assert _body_mask(up).sum() > 100 and not _body_mask(down).any()
    assert len(np.unique(down.reshape(-1, 3), axis=0)) == 1  # plain background, no ground


def test_ground_and_shadow(cube):
    v, t = cube
    cam = Camera(center=(0.0, 0.0, 0.08), half_width=0.2, elev=30.0, azim=-60.0)
    img = render_frames(v + (0, 0, 0.08), t, camera=cam, size=SIZE, color=RED)[0]
    below = img[SIZE[1] * 3 // 4:]  # lower quarter of the picture: ground
    assert len(np.unique(below.reshape(-1, 3), axis=0)) >= 2  # checkered
    grey = np.abs(img.astype(int) - (115, 120, 128)).max(axis=2) < 12  # the shadow colour
    assert grey.sum() > 50


def test_gif_and_sheet_round_trip(tmp_path, cube):
    from PIL import Image

    v, t = cube
    frames = np.array([v + (0.01 * k, 0, 0.05 * abs(np.sin(k / 3))) for k in range(6)])
    imgs = render_frames(frames, t, size=SIZE, labels=[f"t = {k}" for k in range(6)])
    gif = tmp_path / "a.gif"
    write_gif(gif, imgs, fps=20)
    with Image.open(gif) as im:
        assert im.n_frames == 6 and im.size == SIZE and im.info["duration"] == 50 and im.info["loop"] == 0
        for k in range(6):
            im.seek(k)
            err = np.abs(np.asarray(im.convert("RGB"), dtype=int) - imgs[k]).mean()
            assert err < 4.0, (k, err)
    sheet = tmp_path / "s.png"
    write_frame_sheet(sheet, imgs, columns=4, labels=list("abcdef"))
    with Image.open(sheet) as im:
        assert im.size == (4 * SIZE[0] + 5 * 4, 2 * SIZE[1] + 3 * 4)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "s.png"]  # no temporaries left


def test_spectrum_plot(tmp_path):
    fs = 8000
    t = np.arange(fs) / fs
    x = np.exp(-3 * t) * np.sin(2 * np.pi * 440 * t)
    out = tmp_path / "spec.png"
    plot_spectrum(out, x, fs, model_hz=[440.0], dropped_hz=[3900.0], f_max_hz=3500.0, peaks_hz=[440.0], title="A")
    assert out.stat().st_size > 10_000
    with pytest.raises(InputError, match="finite"):
        plot_spectrum(tmp_path / "bad.png", np.full(100, np.nan), fs)


def test_bad_input_gets_clear_errors(tmp_path, cube):
    v, t = cube
    with pytest.raises(InputError, match=r"\(F, nv, 3\)"):
        render_frames(np.zeros((2, 5, 2)), t)
    with pytest.raises(InputError, match="NaN"):
        render_frames(np.full_like(v, np.nan), t)
    with pytest.raises(InputError, match="triangles"):
        render_frames(v, t + len(v))
    with pytest.raises(InputError, match="labels"):
        render_frames(v, t, labels=["a", "b"])
    with pytest.raises(InputError, match="half_width"):
        Camera(center=(0, 0, 0), half_width=0.0)
    with pytest.raises(InputError, match="uint8"):
        write_gif(tmp_path / "x.gif", np.zeros((2, 8, 8, 3)))
    img = np.zeros((1, 16, 16, 3), dtype=np.uint8)
    with pytest.raises(InputError, match="cannot write GIF"):
        write_gif(tmp_path / "missing" / "x.gif", img)
    assert list(tmp_path.iterdir()) == []


def test_rendering_needs_no_display_and_no_pyplot():
    code = ("import sys, numpy as np\nfrom modalfem.output.animation import render_frames\n"
            "v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])\n"
            "t = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])\n"
            "render_frames(v + (0, 0, 0.1), t, size=(32, 32))\nprint('matplotlib.pyplot' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MPLBACKEND")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"
