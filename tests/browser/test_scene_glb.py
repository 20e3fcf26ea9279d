"""The ``scene.glb`` of ``modalfem run`` played by three.js (GLTFLoader + AnimationMixer, as a web page or a
glTF viewer plays it): at every frame time each body's vertices, morphed and moved by the file's animation, are
where the world had them (z up in the world, y up in glTF)."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

pytestmark = pytest.mark.browser


def _world():
    import modalfem
    from modalfem import tet
    from modalfem import world as mw
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothModel
    from modalfem.cloth.scenes import MATERIAL
    from modalfem.effects import Contact, Gravity
    from modalfem.material import Material
    from modalfem.mesh import box
    from modalfem.model import ModalModel

    mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=6, degree=1, backend="skfem", solver="scipy")
    bar = ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))
    block = tet.tet_model(box(size=(0.1, 0.1, 0.05), cells=(2, 2, 1)), Material(E=1e5, nu=0.3, rho=500.0))
    cloth = ClothModel(grid((0.2, 0.2), (5, 5)), MATERIAL, mass_damping=0.1)
    return mw.World(
        bodies=[mw.Modal(bar, name="bar", position=(0.0, 0.0, 0.1), angular_velocity=(0.5, 0.0, 3.0)),
                mw.Tet(block, name="block", position=(0.2, 0.0, 0.0), velocity=(0.0, 0.5, 0.0)),
                mw.Cloth(cloth, name="cloth", x0=cloth.mesh.points + (-0.1, 0.1, 0.2))],
        obstacles=[mw.Ground(0.0), mw.Sphere((0.0, 0.25, 0.05), 0.05, path=[(0, (0, 0, 0)), (1, (0.5, 0, 0))])],
        effects=[Gravity(), Contact()])


_PAGE = """<!doctype html><html><body><script>@@THREE@@</script>
<script>
const bytes = Uint8Array.from(atob("@@GLB@@"), c => c.charCodeAt(0));
new THREE.GLTFLoader().parse(bytes.buffer, '', function (gltf) {
  const scene = gltf.scene, mixer = new THREE.AnimationMixer(scene);
  const action = mixer.clipAction(gltf.animations[0]);
  action.setLoop(THREE.LoopOnce);  // held at the end: a repeating clip wraps its last time to the first frame
  action.clampWhenFinished = true;
  action.play();
  window.sample = function (t, name) {
    action.reset().play();  // a finished clip is disabled: start it again, then go to t
    mixer.setTime(t);
    scene.updateMatrixWorld(true);
    const mesh = scene.getObjectByName(name), v = new THREE.Vector3(), out = [];
    for (let i = 0; i < mesh.geometry.attributes.position.count; i++) {
      mesh.getVertexPosition(i, v);
      v.applyMatrix4(mesh.matrixWorld);
      out.push(v.x, v.y, v.z);
    }
    return {points: out, index: Array.from(mesh.geometry.index.array)};
  };
  window.duration = gltf.animations[0].duration;
  window.ready = true;
}, function (e) { window.error = String(e); });
</script></body></html>"""


def test_three_js_plays_every_body_where_the_world_had_it(open_page, tmp_path):
    from modalfem import web
    from modalfem.scene.record import Recorder
    from modalfem.scene.record_gltf import TOLERANCE

    world = _world()
    rec = Recorder(world, tmp_path, paraview=False, video=None, sound=False)
    s, states = world.state(), []
    for i in range(31):
        if i % 10 == 0:
            states.append(s.copy())
            rec.frame(s)
        world.step(s, s, world.control().add_impulse("bar", 3, (0.0, 0.0, -0.05)) if i == 2 else None, 1e-3)
    rec.finish()
    glb = (tmp_path / "scene.glb").read_bytes()
    html = _PAGE.replace("@@THREE@@", web.inline_script(web.asset("three.bundle.min.js")))
    html = html.replace("@@GLB@@", base64.b64encode(glb).decode("ascii"))
    (tmp_path / "page.html").write_text(html)
    bp = open_page(tmp_path / "page.html")
    bp.page.wait_for_function("window.ready || window.error", timeout=60000)
    assert bp.page.evaluate("window.error || null") is None and not bp.errors()
    assert bp.page.evaluate("window.duration") == pytest.approx(states[-1].time, rel=1e-6)
    for s in states:
        for b in world.bodies:
            got = bp.page.evaluate(f"window.sample({json.dumps(s.time)}, {json.dumps(b.name)})")
            p = np.array(got["points"]).reshape(-1, 3)
            p = np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)  # glTF y up -> the world's z up
            tris = np.array(got["index"]).reshape(-1, 3)
            ref, ref_tris = world.surface(s, b.name)
            size = np.linalg.norm(np.ptp(ref, axis=0))
            err = np.abs(p[tris] - ref[ref_tris]).max()  # corner by corner (modal vertices are split at creases)
            bound = 2e-6 * size if b.kind == "modal" else (TOLERANCE * 1.01 + 2e-6) * size
            assert err <= bound, (b.name, s.time, err, bound)
