"""modalfem.view.server.Viewer over real HTTP: scene, binary body data, event frames, input, shutdown."""

from __future__ import annotations

import base64
import json
import socket
import urllib.error
import urllib.request

import numpy as np
import pytest

from modalfem.errors import InputError
from modalfem.view import Viewer


def _get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.read()


def _post(viewer: Viewer, msg) -> tuple[int, dict]:
    data = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
    req = urllib.request.Request(viewer.url + "input", data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def _frames(viewer: Viewer, count: int) -> list[dict]:
    """The first ``count`` frames of a fresh event stream."""
    out = []
    with urllib.request.urlopen(viewer.url + "events", timeout=10) as r:
        while len(out) < count:
            line = r.readline()
            if line.startswith(b"data: "):
                out.append(json.loads(line[6:]))
    return out


@pytest.fixture()
def tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    t = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    shapes = np.random.default_rng(1).standard_normal((12, 2))
    return v, t, shapes


def test_page_scene_and_body_data(tetra):
    v, t, shapes = tetra
    viewer = Viewer()
    i = viewer.add_body(v, t, shapes=shapes, name="tet")
    j = viewer.add_body(v + 2, t, name="plain")
    with viewer:
        assert b"<canvas" in _get(viewer.url)
        assert b"EventSource" in _get(viewer.url + "viewer.js")
        scene = json.loads(_get(viewer.url + "scene"))
        assert [b["mode_count"] for b in scene["bodies"]] == [2, 0]
        assert scene["bodies"][0]["vertex_count"] == 4 and scene["bodies"][0]["triangle_count"] == 4
        raw = _get(viewer.url + f"body/{i}")
        assert len(raw) == 4 * (12 + 12 + 24)
        np.testing.assert_array_equal(np.frombuffer(raw[:48], "<f4").reshape(4, 3), v.astype(np.float32))
        np.testing.assert_array_equal(np.frombuffer(raw[48:96], "<u4").reshape(4, 3), t)
        # shapes travel modes-major: row i of the payload is column i of the (3 nv, r) shapes
        np.testing.assert_array_equal(np.frombuffer(raw[96:], "<f4").reshape(2, 12), shapes.T.astype(np.float32))
        assert len(_get(viewer.url + f"body/{j}")) == 4 * (12 + 12)
        with pytest.raises(urllib.error.HTTPError):
            _get(viewer.url + "body/7")


def test_frames_carry_q_positions_pose_and_status(tetra):
    v, t, shapes = tetra
    viewer = Viewer()
    viewer.add_body(v, t, shapes=shapes)
    viewer.add_body(v, t)
    with viewer:
        x = v + 0.25
        viewer.update(0, q=[0.5, -1.5], position=(1, 2, 3), orientation=(2, 0, 0, 0), time_s=0.125)
        viewer.update(1, positions=x)
        viewer.status("hello")
        f = _frames(viewer, 1)[0]
        assert f["bodies"][0]["q"] == [0.5, -1.5]
        assert f["bodies"][0]["pose"] == [1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0]  # quaternion normalised
        got = np.frombuffer(base64.b64decode(f["bodies"][1]["positions"]), "<f4").reshape(4, 3)
        np.testing.assert_array_equal(got, x.astype(np.float32))
        assert f["status"] == "hello" and f["time"] == 0.125
        with pytest.raises(InputError, match="no mode shapes"):
            viewer.update(1, q=[1.0])
        with pytest.raises(InputError, match="2 finite numbers"):
            viewer.update(0, q=[1.0, np.nan])
        with pytest.raises(InputError, match="positions"):
            viewer.update(1, positions=x[:3])


def test_a_new_frame_follows_each_update(tetra):
    v, t, shapes = tetra
    viewer = Viewer(fps=200)
    viewer.add_body(v, t, shapes=shapes)
    with viewer:
        import threading

        def later():
            import time

            time.sleep(0.3)
            viewer.update(0, q=[3.0, 4.0])

        threading.Thread(target=later).start()
        first, second = _frames(viewer, 2)
        assert second["seq"] > first["seq"] and second["bodies"][0]["q"] == [3.0, 4.0]


def test_controls_and_callbacks(tetra):
    v, t, _ = tetra
    calls = []
    viewer = Viewer(on_play=lambda: calls.append("play"), on_reset=lambda: calls.append("reset"))
    viewer.add_body(v, t)
    viewer.add_slider("gain", lambda x: calls.append(("gain", x)), minimum=0, maximum=2, value=1)
    viewer.add_select("pick", lambda i: calls.append(("pick", i)), options=["a", "b"])
    viewer.add_checkbox("on", lambda b: calls.append(("on", b)))
    with viewer:
        names = [c["name"] for c in json.loads(_get(viewer.url + "scene"))["controls"]]
        assert names == ["play", "reset", "gain", "pick", "on"]  # transport buttons only for given callbacks
        assert _post(viewer, {"type": "button", "name": "play"})[0] == 200
        assert _post(viewer, {"type": "control", "name": "gain", "value": 7})[0] == 200  # clamped to the max
        assert _post(viewer, {"type": "control", "name": "pick", "value": 1})[0] == 200
        assert _post(viewer, {"type": "control", "name": "on", "value": True})[0] == 200
        assert calls == ["play", ("gain", 2.0), ("pick", 1), ("on", True)]
        assert _frames(viewer, 1)[0]["controls"] == {"gain": 2.0, "pick": 1, "on": True}
        for msg, words in (({"type": "control", "name": "pick", "value": 2}, "not in [0, 2)"),
                           ({"type": "control", "name": "on", "value": 1}, "true or false"),
                           ({"type": "control", "name": "nope", "value": 1}, "no control named"),
                           ({"type": "strike", "body": 0, "triangle": 0}, "takes no strikes"),
                           ({"type": "dance"}, "unknown input type"),
                           (b"{not json", "not JSON"), ([1, 2], "JSON object")):
            status, out = _post(viewer, msg)
            assert status == 400 and words in out["error"] and "\n" not in out["error"]
        assert len(calls) == 4


def test_strike_input_is_validated_before_the_callback(tetra):
    v, t, shapes = tetra
    hits = []
    viewer = Viewer(on_strike=lambda *a: hits.append(a) or {"rang": True})
    viewer.add_body(v, t, shapes=shapes)
    with viewer:
        ok = {"type": "strike", "body": 0, "triangle": 3, "barycentric": [0.2, 0.3, 0.5], "direction": [0, 0, -2]}
        assert _post(viewer, ok) == (200, {"ok": True, "result": {"rang": True}})
        body, tri, bary, d = hits[0]
        assert (body, tri) == (0, 3) and np.allclose(bary, [0.2, 0.3, 0.5]) and np.allclose(d, [0, 0, -1])
        for change, words in (({"triangle": 4}, "not in [0, 4)"), ({"body": 1}, "no body 1"),
                              ({"barycentric": [0.5, 0.6, 0.1]}, "sum to 1"), ({"direction": [0, 0, 0]}, "non-zero"),
                              ({"direction": [0, "x", 1]}, "must be 3 numbers"), ({"direction": [0, 1e999, 1]}, "3 finite numbers")):
            status, out = _post(viewer, {**ok, **change})
            assert status == 400 and words in out["error"], out
        assert len(hits) == 1


def test_sound_clip_is_normalised_16_bit(tetra):
    v, t, _ = tetra
    viewer = Viewer()
    viewer.add_body(v, t)
    s = 1e-3 * np.sin(np.linspace(0, 20, 1000))
    viewer.play_sound(s, 44100)
    with viewer:
        snd = _frames(viewer, 1)[0]["sound"]
    pcm = np.frombuffer(base64.b64decode(snd["pcm16"]), "<i2")
    assert snd["rate"] == 44100 and len(pcm) == 1000
    assert np.abs(pcm).max() == round(0.9 * 32767)
    np.testing.assert_allclose(pcm / (0.9 * 32767), s / np.abs(s).max(), atol=1.0 / 32767)


def test_close_frees_the_port_and_a_taken_port_is_one_line(tetra):
    v, t, _ = tetra
    viewer = Viewer()
    viewer.add_body(v, t)
    viewer.start()
    port = viewer.port
    other = Viewer(port=port)
    other.add_body(v, t)
    with pytest.raises(InputError, match=f"cannot listen on 127.0.0.1:{port}.*another --port"):
        other.start()
    viewer.close()
    viewer.close()  # idempotent
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))


def test_bad_scene_input(tetra):
    v, t, shapes = tetra
    viewer = Viewer()
    with pytest.raises(InputError, match="no bodies"):
        viewer.start()
    with pytest.raises(InputError, match="triangles"):
        viewer.add_body(v, t + 1)
    with pytest.raises(InputError, match="shapes"):
        viewer.add_body(v, t, shapes=shapes[:6])
    with pytest.raises(InputError, match="vertices"):
        viewer.add_body(v[:, :2], t)
    with pytest.raises(InputError, match="port"):
        Viewer(port=70000)
    viewer.add_button("b", lambda: None)
    with pytest.raises(InputError, match="exists already"):
        viewer.add_checkbox("b", lambda x: None)
