"""glTF export (modalfem.output.gltf): the file against the spec (pygltflib, the Khronos validator when
node has it) and against the model it came from (targets, normals, extras), and ``modalfem export``."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import modalfem
from modalfem.errors import InputError
from modalfem.mesh import box
from modalfem.model import ModalModel
from modalfem.output.gltf import EXTRAS_FORMAT, EXTRAS_KEYS, glb_bytes, modal_surface, page_html, write_glb

pygltflib = pytest.importorskip("pygltflib", reason="pygltflib is in the test extras (pip install -e .[test])")

DAMPING = (3.0, 2e-8)


@pytest.fixture(scope="module")
def model():
    """Free steel block 0.2 x 0.1 x 0.05 m, P1, 12 deformation modes."""
    mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=12, degree=1, backend="skfem", solver="scipy")
    return ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=DAMPING, rotation_coupling=False)


@pytest.fixture(scope="module")
def glb(model):
    return glb_bytes(model, source={"model_file": "block.npz"})


def _load(data: bytes):
    return pygltflib.GLTF2.load_from_bytes(data)


def _accessor(g, data_bytes: bytes, index: int) -> np.ndarray:
    """Decode accessor ``index`` of a GLB with plain numpy (independent of the writer)."""
    acc = g.accessors[index]
    view = g.bufferViews[acc.bufferView]
    blob = g.binary_blob()
    dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}[acc.componentType]
    width = {"SCALAR": 1, "VEC3": 3}[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    a = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=start)
    return a.reshape(acc.count, width) if width > 1 else a


def test_glb_structure_is_consistent_with_the_spec(model, glb):
    g = _load(glb)
    assert g.asset.version == "2.0"
    prim = g.meshes[0].primitives[0]
    k = model.mode_count
    assert len(prim.targets) == k and len(g.meshes[0].weights) == k and g.meshes[0].weights == [0.0] * k
    n = g.accessors[prim.attributes.POSITION].count
    blob = g.binary_blob()
    assert g.buffers[0].byteLength == len(blob)
    for view in g.bufferViews:  # every view inside the buffer, 4-byte aligned (float data)
        assert (view.byteOffset or 0) % 4 == 0 and (view.byteOffset or 0) + view.byteLength <= len(blob)
    for acc in g.accessors:
        size = {5126: 4, 5125: 4, 5123: 2}[acc.componentType] * {"SCALAR": 1, "VEC3": 3}[acc.type]
        assert acc.count * size <= g.bufferViews[acc.bufferView].byteLength
    idx = _accessor(g, glb, prim.indices)
    assert len(idx) == 3 * len(model.triangles) and idx.max() < n
    for t in prim.targets:
        assert set(t) == {"POSITION", "NORMAL"}
        assert g.accessors[t["POSITION"]].count == n and g.accessors[t["NORMAL"]].count == n
    # POSITION accessors (attribute and every target) carry the exact min/max of their float32 data
    for i in [prim.attributes.POSITION] + [t["POSITION"] for t in prim.targets]:
        data = _accessor(g, glb, i)
        assert g.accessors[i].min == data.min(axis=0).tolist() and g.accessors[i].max == data.max(axis=0).tolist()
    normals = _accessor(g, glb, prim.attributes.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    names = g.meshes[0].extras["targetNames"]
    assert len(names) == k and names[0].startswith("mode 1 (")


def test_targets_are_the_model_modes_at_a_unit_peak_with_their_modal_masses(model, glb):
    g = _load(glb)
    ex = g.extras["modalfem"]
    assert ex["format"] == EXTRAS_FORMAT and set(ex) == set(EXTRAS_KEYS)
    assert ex["units"]["frequency"] == "Hz" and ex["units"]["damping"] == "1/s" and ex["units"]["weight"] == "m"
    np.testing.assert_allclose(ex["frequencies_hz"], model.frequencies_hz, rtol=1e-15)
    alpha, beta = DAMPING
    np.testing.assert_allclose(ex["damping_per_s"], alpha + beta * model.omega**2, rtol=1e-15)
    assert ex["source"]["model_file"] == "block.npz" and ex["source"]["model_checksum"] == model.checksum()
    prim = g.meshes[0].primitives[0]
    pos = _accessor(g, glb, prim.attributes.POSITION)
    # every glTF vertex is a model vertex (crease copies repeat one); find it by position
    src = np.array([int(np.argmin(np.linalg.norm(model.vertices - p, axis=1))) for p in pos])
    np.testing.assert_allclose(pos, model.vertices[src], atol=1e-7 * np.abs(model.vertices).max())
    # glTF triangle j is model triangle j, corners in the same (outward) order
    idx = _accessor(g, glb, prim.indices).reshape(-1, 3)
    np.testing.assert_array_equal(src[idx], model.triangles)
    phi = model.shapes.reshape(model.vertex_count, 3, -1)
    for i, t in enumerate(prim.targets):
        d = _accessor(g, glb, t["POSITION"]).astype(np.float64)
        assert np.linalg.norm(d, axis=1).max() == pytest.approx(1.0, rel=1e-6)  # peak displacement 1 m
        # phi_i = c_i t_i with the modal mass m_i = 1 / c_i^2 of a mass-normalised mode
        c = 1.0 / np.sqrt(ex["mode_masses_kg"][i])
        assert c == pytest.approx(ex["target_scales"][i], rel=1e-12)
        np.testing.assert_allclose(c * d, phi[src, :, i], atol=1e-6 * np.abs(phi[:, :, i]).max())


def test_crease_split_gives_a_box_flat_faces(model):
    s = modal_surface(model, crease_angle=60.0)
    # every normal of a box split at 60 degrees is a face normal: one axis, unit length
    assert np.all(np.sort(np.abs(s.normals), axis=1)[:, :2] < 1e-12)
    V = model.vertices
    on_faces = ((V == V.min(axis=0)) | (V == V.max(axis=0))).sum(axis=1)  # 3 at corners, 2 on edges, 1 on faces
    copies = np.bincount(s.source_vertex, minlength=model.vertex_count)
    np.testing.assert_array_equal(copies, on_faces)
    smooth = modal_surface(model, crease_angle=180.0)
    assert smooth.vertex_count == model.vertex_count


def _area_normals(x, tris):
    """Area-weighted unit vertex normals of a triangle surface (reference, written here)."""
    a = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    n = np.zeros_like(x)
    for k in range(3):
        np.add.at(n, tris[:, k], a)
    return n / np.linalg.norm(n, axis=1)[:, None]


def test_normal_targets_shade_the_deformed_surface_to_second_order(model):
    """normalize(n0 + sum w_i dn_i) against the normals of the deformed surface: the error falls
    4x per halving of the amplitude (second order) and stays far below the normals' change."""
    s = modal_surface(model, crease_angle=180.0)  # smooth: the reference is the plain area-weighted normal
    rng = np.random.default_rng(1)
    w = rng.normal(size=s.mode_count) * 0.002  # peak displacements ~ a few mm on a 0.2 m body
    errs, changes = [], []
    for scale in (1.0, 0.5, 0.25):
        ws = w * scale
        x = s.positions + np.einsum("k,knc->nc", ws, s.targets)
        exact = _area_normals(x, s.indices)
        approx = s.normals + np.einsum("k,knc->nc", ws, s.normal_targets)
        approx /= np.linalg.norm(approx, axis=1)[:, None]
        errs.append(np.abs(approx - exact).max())
        changes.append(np.abs(exact - s.normals).max())
    assert changes[0] > 0.01  # the deformation does turn the normals
    assert errs[0] < 0.05 * changes[0]
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.15) and errs[1] / errs[2] == pytest.approx(4.0, rel=0.15)


def test_mode_count_selects_the_lowest_modes_and_refuses_out_of_range(model):
    g = _load(glb_bytes(model, mode_count=3, normals=False))
    prim = g.meshes[0].primitives[0]
    assert len(prim.targets) == 3 and set(prim.targets[0]) == {"POSITION"}
    np.testing.assert_allclose(g.extras["modalfem"]["frequencies_hz"], model.frequencies_hz[:3])
    assert g.extras["modalfem"]["normals"] == "rest"
    for bad in (0, model.mode_count + 1):
        with pytest.raises(InputError, match=f"out of range: the model has {model.mode_count} modes"):
            glb_bytes(model, mode_count=bad)
    with pytest.raises(InputError, match="crease angle"):
        modal_surface(model, crease_angle=200)


def test_damping_override_sets_the_modal_damping(model):
    ex = _load(glb_bytes(model, damping=(1.5, 3e-9))).extras["modalfem"]
    np.testing.assert_allclose(ex["damping_per_s"], 1.5 + 3e-9 * model.omega**2, rtol=1e-15)
    assert ex["rayleigh_damping"] == {"alpha_per_s": 1.5, "beta_s": 3e-9}
    for bad in ((-1.0, 0.0), (0.0, float("nan")), (1.0,)):
        with pytest.raises(InputError, match="damping"):
            modal_surface(model, damping=bad)


def test_write_glb_round_trip(model, tmp_path):
    write_glb(tmp_path / "m.glb", model, mode_count=2)
    assert _load((tmp_path / "m.glb").read_bytes()).extras["modalfem"]["mode_count"] == 2


def _gltf_validator() -> Path | None:
    for root in (os.environ.get("MODALFEM_NPM_PREFIX"), Path(sys.prefix) / "npm"):
        if root and (Path(root) / "node_modules" / "gltf-validator" / "index.js").exists():
            return Path(root) / "node_modules" / "gltf-validator"
    return None


def test_khronos_gltf_validator_reports_no_issue(model, tmp_path):
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the Khronos glTF validator (npm gltf-validator) runs on node")
    validator = _gltf_validator()
    if validator is None:
        pytest.skip(f"npm gltf-validator not found under {Path(sys.prefix) / 'npm'} (scripts/setup.sh installs it "
                    "when npm is present) or $MODALFEM_NPM_PREFIX")
    paths = []
    for name, data in (("all.glb", glb_bytes(model)), ("smooth.glb", glb_bytes(model, crease_angle=180)),
                       ("positions.glb", glb_bytes(model, mode_count=5, normals=False))):
        (tmp_path / name).write_bytes(data)
        paths.append(str(tmp_path / name))
    script = ("const v = require(process.argv[1]); const fs = require('fs');"
              "Promise.all(process.argv.slice(2).map(p => v.validateBytes(new Uint8Array(fs.readFileSync(p)))))"
              ".then(rs => console.log(JSON.stringify(rs.map(r => r.issues))))"
              ".catch(e => { console.error(String(e)); process.exit(1); });")
    out = subprocess.run([node, "-e", script, str(validator), *paths], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for path, issues in zip(paths, json.loads(out.stdout)):
        assert (issues["numErrors"], issues["numWarnings"]) == (0, 0), (path, issues["messages"])
        assert issues["numInfos"] == 0, (path, issues["messages"])


def test_page_inlines_everything_and_no_network(model, glb):
    import base64
    import re

    page = page_html(glb, title="block <&>")
    assert "<title>block &lt;&amp;&gt;</title>" in page
    m = re.search(r'<script id="modalfem-glb" type="application/octet-stream">([A-Za-z0-9+/=]+)</script>', page)
    assert m is not None and base64.b64decode(m.group(1)) == glb
    for marker in ("@@GLB_BASE64@@", "@@THREE_JS@@", "@@MODAL_JS@@", "@@PAGE_JS@@", "@@TITLE@@"):
        assert marker not in page
    assert not re.search(r"<script[^>]*\ssrc=|<link\s|<img\s|<iframe\s", page)  # nothing loaded from elsewhere
    scripts = re.findall(r"<script>(.*?)</script>", page, flags=re.S)
    assert len(scripts) == 3 and "var THREE=" in scripts[0] and "ModalRuntime" in scripts[1]
    assert all("</" not in s for s in scripts)


def test_bundled_three_is_the_recorded_version_under_its_mit_licence():
    from modalfem import web

    head = web.asset("three.bundle.min.js")[:400]
    assert f"npm three@{web.THREE_VERSION}" in head and f"three.js r{web.THREE_REVISION} " in head
    assert f'"{web.THREE_REVISION}"' in web.asset("three.bundle.min.js")  # THREE.REVISION inside the bundle
    assert web.asset("THREE_LICENSE").startswith("The MIT License")
