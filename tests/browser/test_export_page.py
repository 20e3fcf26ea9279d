"""``modalfem export --html`` in headless Chromium: the page loads without errors, the body renders,
a click strikes it (the JS modal state against the Python runtime), it moves between frames, its
sound equals the Python ModalSound, and all 60 morph targets reach the GPU (morph texture)."""

from __future__ import annotations

import numpy as np
import pytest

import modalfem
from modalfem.mesh import box
from modalfem.model import ModalModel

pytestmark = pytest.mark.browser

MODES = 60
DAMPING = (4.0, 2e-9)
BACKGROUND = np.array([0x20, 0x24, 0x2B])


@pytest.fixture(scope="module")
def model():
    """Free steel plate 0.24 x 0.16 x 0.012 m, P1, 60 deformation modes."""
    mesh = box(size=(0.24, 0.16, 0.012), cells=(12, 8, 1))
    res = modalfem.modes(mesh, modalfem.STEEL, k=MODES, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=DAMPING, rotation_coupling=False)


@pytest.fixture(scope="module")
def page_file(model, tmp_path_factory):
    from modalfem.cli import main

    d = tmp_path_factory.mktemp("export")
    model.save(d / "plate.npz")
    assert main(["export", str(d / "plate.npz"), str(d / "plate.glb"), "--html", str(d / "plate.html"),
                 "--quiet"]) == 0
    return d / "plate.html"


def _ready(bp):
    bp.page.wait_for_function("window.modalfem && (window.modalfem.ready || window.modalfem.error)", timeout=60000)
    assert bp.page.evaluate("window.modalfem.error") is None
    bp.page.wait_for_function("window.modalfem.frames > 3", timeout=30000)


def _body(img: np.ndarray) -> np.ndarray:
    """Pixels that are not the page background (the canvas below the panel)."""
    return np.abs(img.astype(int) - BACKGROUND).max(axis=2) > 12


def _point_shapes(model, triangle, bary) -> np.ndarray:
    """phi_i(p) (3, r) [m/sqrt(kg)] at a surface point, from the model (not from the file)."""
    phi = model.shapes.reshape(model.vertex_count, 3, -1)
    return np.einsum("k,kcr->cr", np.asarray(bary), phi[model.triangles[triangle]])


def test_page_loads_renders_and_a_click_strikes_and_moves_it(open_page, page_file, model, tmp_path):
    bp = open_page(page_file)
    _ready(bp)
    page = bp.page
    assert page.evaluate("[window.modalfem.gl, window.modalfem.modeCount, "
                         "window.modalfem.mesh.morphTargetInfluences.length]") == ["webgl2", MODES, MODES]
    rest = bp.pixels()
    page.wait_for_timeout(200)
    assert np.array_equal(bp.pixels(), rest)  # at rest nothing moves
    body = _body(rest[120:])
    assert 0.05 < body.mean() < 0.9, body.mean()  # the plate is drawn and is not the whole view
    assert rest[120:][body].std() > 8  # shaded faces, not a flat silhouette
    page.screenshot(path=str(tmp_path / "rest.png"))

    page.mouse.click(400, 330)  # the middle of the view: the camera looks at the plate's centre
    page.wait_for_function("window.modalfem.strikes === 1", timeout=10000)
    strike = page.evaluate("window.modalfem.lastStrike")
    state = page.evaluate("[Array.from(window.modalfem.state.w), Array.from(window.modalfem.state.v)]")
    assert np.abs(state[0]).max() + np.abs(state[1]).max() > 0  # the modal state rings
    # the JS impulse projection against the model's own modes: dw_i = c_i phi_i(p) . J, c_i = max_v |phi_i(v)|
    phi_p = _point_shapes(model, strike["triangle"], strike["barycentric"])
    c = np.linalg.norm(model.shapes.reshape(model.vertex_count, 3, -1), axis=1).max(axis=0)
    J = np.array(strike["impulse"])
    expected = c * (J @ phi_p)
    np.testing.assert_allclose(strike["dv"], expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max())
    assert np.linalg.norm(J) > 0 and abs(sum(strike["barycentric"]) - 1) < 1e-6

    shots = []
    for _ in range(3):
        page.wait_for_timeout(150)
        shots.append(bp.pixels())
    moved = [(np.abs(a.astype(int) - b).max(axis=2) > 12).mean() for a, b in zip(shots, shots[1:])]
    assert min(moved) > 0.002, moved  # the body moves between frames
    page.screenshot(path=str(tmp_path / "struck.png"))
    assert bp.errors() == []


def test_sound_is_the_python_modal_sound_of_the_same_strike(open_page, page_file, model):
    from modalfem.runtime import ModalSound, SurfacePoint

    bp = open_page(page_file)
    _ready(bp)
    triangle, bary = 37, [0.2, 0.5, 0.3]
    J, listener = [0.02, -0.01, -0.3], [0.3, -0.4, 1.0]
    out = bp.page.evaluate(
        """([t, b, J, d]) => { const s = window.modalfem.strike({triangle: t, barycentric: b, impulse: J,
               listener: d, sampleRate: 44100});
             return {dv: s.dv, rate: window.modalfem.lastSoundRate, p: Array.from(window.modalfem.lastSound)}; }""",
        [triangle, bary, J, listener])
    assert out["rate"] == 44100
    p_js = np.array(out["p"])
    snd = ModalSound(model, listener=listener)
    snd.add_impulses(0.0, SurfacePoint(triangle, tuple(bary)), J)
    p_py = snd.render(len(p_js) / 44100)
    assert len(p_py) == len(p_js) > 4410
    peak = np.abs(p_py).max()
    assert peak > 0
    # float32 targets and samples in the page: agreement to ~1e-6 of the peak, not bit for bit
    assert np.abs(p_js - p_py).max() < 1e-4 * peak, np.abs(p_js - p_py).max() / peak
    assert bp.errors() == []


def test_all_60_morph_targets_deform_the_rendered_surface(open_page, page_file):
    bp = open_page(page_file)
    _ready(bp)
    page = bp.page
    page.evaluate("window.modalfem.timeScale = 0; window.modalfem.displayGain = 0.03 * window.modalfem.radius;")
    page.wait_for_timeout(100)
    rest = bp.pixels()
    changed = {}
    for i in (0, 29, 44, MODES - 1):  # weight 1 m on one target at a time, the rest 0
        page.evaluate(f"window.modalfem.state.w.fill(0); window.modalfem.state.w[{i}] = 1;")
        page.wait_for_function(f"window.modalfem.mesh.morphTargetInfluences[{i}] > 0")
        page.wait_for_timeout(150)
        img = bp.pixels()
        changed[i] = (np.abs(img.astype(int) - rest).max(axis=2) > 12).mean()
    assert min(changed.values()) > 0.002, changed  # the 60th target moves pixels like the first
    page.evaluate("window.modalfem.state.w.fill(0)")
    page.wait_for_function("window.modalfem.mesh.morphTargetInfluences.every(x => x === 0)")
    page.wait_for_timeout(150)
    assert np.array_equal(bp.pixels(), rest)  # back at rest, the same picture
    assert bp.errors() == []
