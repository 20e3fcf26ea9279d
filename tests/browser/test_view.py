"""``modalfem view`` in headless Chromium: the page loads, the body renders and moves, a click strikes it
(modal velocities on the server, sound on the page), the mode picker changes the shape."""

from __future__ import annotations

import base64
import io
import time

import numpy as np
import pytest

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def model():
    import modalfem
    from modalfem.mesh import box
    from modalfem.model import ModalModel

    mesh = box(size=(0.2, 0.1, 0.05), cells=(8, 4, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))


@pytest.fixture()
def explorer(model):
    from modalfem.view import ModeExplorer

    with ModeExplorer(model, mode=1, amplitude=0.08) as ex:
        yield ex


def _canvas(page) -> np.ndarray:
    """The WebGL canvas alone (no panel, no status text) as an (h, w, 3) float array in [0, 1]."""
    import matplotlib.image as mpimg

    url = page.evaluate("document.getElementById('canvas').toDataURL('image/png')")
    return mpimg.imread(io.BytesIO(base64.b64decode(url.split(",", 1)[1])), format="png")[..., :3]


def _body_mask(img: np.ndarray) -> np.ndarray:
    background = img[2, 2]  # a corner: the clear colour
    return np.abs(img - background).max(axis=2) > 0.05


def _open(page, explorer):
    page.goto(explorer.url)
    page.wait_for_function("() => window.modalfemViewer.ready && window.modalfemViewer.framesDrawn > 5", timeout=30000)


def test_page_loads_renders_and_moves(page, page_errors, explorer, tmp_path):
    _open(page, explorer)
    a = _canvas(page)
    page.wait_for_timeout(250)  # a quarter of the 1 Hz mode animation
    b = _canvas(page)
    page.screenshot(path=str(tmp_path / "view.png"))
    body = _body_mask(a)
    assert 0.05 < body.mean() < 0.9, body.mean()  # something is drawn, and it is not the whole canvas
    assert a[body].std() > 0.02  # shaded, not a flat silhouette
    moved = np.abs(a - b).max(axis=2) > 0.05
    assert moved.mean() > 0.005, moved.mean()  # the animated mode moves the body between frames
    assert page.evaluate("window.modalfemViewer.framesReceived") > 3
    assert page_errors == [] and page.evaluate("window.modalfemViewer.errors") == []


def test_click_strikes_the_body_and_plays_its_sound(page, page_errors, explorer):
    _open(page, explorer)
    page.evaluate("document.getElementById('control-amplitude')")  # the panel is built
    explorer.set_animate(False)
    assert not explorer.qdot.any()
    box = page.locator("#canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)  # the body is in the middle
    page.wait_for_function("() => window.modalfemViewer.strikes.length === 1 && window.modalfemViewer.soundsReceived === 1",
                           timeout=10000)
    strike = page.evaluate("window.modalfemViewer.strikes[0]")
    assert strike["out"]["ok"] and strike["out"]["result"]["dqdot_norm"] > 0
    assert np.abs(explorer.qdot).max() > 0 and explorer.strikes == 1  # the server's modal velocities changed
    sound = page.evaluate("window.modalfemViewer.lastSound")
    assert sound["samples"] == round(strike["out"]["result"]["sound_s"] * sound["rate"]) and sound["peak"] > 0.8
    assert page.evaluate("window.modalfemViewer.soundsPlayed") == 1  # handed to WebAudio (the click unlocked it)
    # frames after the strike carry the ringing in modes other than the one picked
    page.wait_for_timeout(200)
    q = np.array(page.evaluate("window.modalfemViewer.last.bodies[0].q"))
    assert np.abs(q[1:]).max() > 0
    assert page_errors == []


def test_mode_picker_changes_the_shape(page, page_errors, explorer, tmp_path):
    _open(page, explorer)
    page.uncheck("#controls input[type=checkbox]")  # still shapes: comparable pictures
    page.wait_for_function("() => window.modalfemViewer.last.controls.animate === false")
    page.wait_for_timeout(200)
    first = _canvas(page)
    page.select_option("#control-mode", "4")  # mode 5
    page.wait_for_function("() => window.modalfemViewer.last.bodies[0].q[4] !== 0 && "
                           "window.modalfemViewer.last.bodies[0].q[0] === 0", timeout=10000)
    page.wait_for_timeout(200)
    fifth = _canvas(page)
    assert explorer.mode == 4
    q = np.array(page.evaluate("window.modalfemViewer.last.bodies[0].q"))
    assert np.flatnonzero(q).tolist() == [4]
    changed = np.abs(first - fifth).max(axis=2) > 0.05
    assert changed.mean() > 0.01, changed.mean()
    page.screenshot(path=str(tmp_path / "mode5.png"))
    # the shape is deformed on the GPU (vertex shader, modes in float textures); the CPU path that
    # bodies without modes use draws the same picture (exact normals there, linearised in the shader)
    assert page.evaluate("window.modalfemViewer.bodies[0].gpu") is True
    page.evaluate("explorerOff = () => { const b = window.modalfemViewer.bodies[0]; b.gpu = false; b.stale = true; }")
    explorer.close()  # no more frames: both pictures show the same q
    page.wait_for_timeout(300)
    gpu = _canvas(page)
    page.evaluate("explorerOff()")
    page.wait_for_timeout(300)
    cpu = _canvas(page)
    assert np.abs(_body_mask(gpu) ^ _body_mask(cpu)).mean() < 0.002  # same silhouette
    assert page.evaluate("[window.modalfemViewer.bodies[0].gpu, window.modalfemViewer.bodies[0].buffersDeformed]") == [
        False, True]  # the second picture did come from the CPU path
    assert np.abs(gpu - cpu).mean() < 0.01, np.abs(gpu - cpu).mean()
    assert page_errors == []


def test_viewer_for_a_running_world_positions_pose_and_transport(page, page_errors, model, tmp_path):
    """The server side a later `run --view` reuses: a body without modes gets positions, any body a pose,
    and the transport buttons call back."""
    from modalfem.view import Viewer

    calls = []
    viewer = Viewer(on_play=lambda: calls.append("play"), on_pause=lambda: calls.append("pause"),
                    on_step=lambda: calls.append("step"), on_reset=lambda: calls.append("reset"))
    viewer.add_body(model.vertices, model.triangles, shapes=model.shapes, name="modal")
    viewer.add_body(model.vertices, model.triangles, name="soft", color=(0.3, 0.6, 0.9))
    with viewer:
        page.goto(viewer.url)
        page.wait_for_function("() => window.modalfemViewer.ready && window.modalfemViewer.framesDrawn > 2")
        x = model.vertices * (1.0, 1.0, 1.6)  # the second body stretched, and moved aside
        viewer.update(1, positions=x, position=(0.0, 0.15, 0.0), orientation=(np.cos(0.3), 0, 0, np.sin(0.3)))
        viewer.update(0, q=np.eye(model.mode_count)[0] * 0.5 / np.abs(model.shapes[:, 0]).max() * 0.02)
        page.wait_for_function("() => window.modalfemViewer.bodies[1].positions !== null && "
                               "window.modalfemViewer.bodies[0].q[0] !== 0")
        page.wait_for_timeout(200)
        got = np.array(page.evaluate("Array.from(window.modalfemViewer.bodies[1].cur)")).reshape(-1, 3)
        np.testing.assert_array_equal(got, x.astype(np.float32))
        pose = page.evaluate("window.modalfemViewer.bodies[1].pose")
        np.testing.assert_allclose(pose, [0, 0.15, 0, np.cos(0.3), 0, 0, np.sin(0.3)], rtol=1e-12, atol=1e-15)
        for name in ("play", "pause", "step", "reset"):
            page.click(f"#controls button:text-is('{name}')")
        page.wait_for_timeout(300)
        assert calls == ["play", "pause", "step", "reset"]
        img = _canvas(page)
        page.screenshot(path=str(tmp_path / "world.png"))
        assert _body_mask(img).mean() > 0.03
    assert page_errors == []
