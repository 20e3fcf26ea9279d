"""``Viewer``: a small live 3D viewer served to the browser (standard library only).

One HTTP server on a local port (``http.server.ThreadingHTTPServer``) serves a page that draws
triangle meshes with WebGL2 (``modalfem/view/static``, no JavaScript dependencies) and talks back:

* at load the page fetches the scene (``GET /scene``: bodies, controls) and each body's fixed data
  once, as binary (``GET /body/<i>``: rest vertices float32 (nv, 3) [m], triangles uint32 (nt, 3),
  and for a modal body its mode shapes float32 (r, 3 nv) [m / sqrt(kg)], modes-major);
* per frame the server sends only what changes (``GET /events``, Server-Sent Events): for a modal
  body its modal coordinates q (r,) and its pose (position [m], quaternion w, x, y, z), and the page
  deforms the surface itself (``x = c + R (X + Phi q)``); for a body without modes (cloth, tet)
  the vertex positions (float32, base64). A slow page simply gets the newest frame (frames are
  never queued);
* the page posts user input (``POST /input``): a control changed, a button pressed, a strike
  (triangle, barycentric coordinates, ray direction). Each calls the callback given in Python; a
  ``ModalfemError`` raised there goes back to the page as its one-line message;
* ``play_sound`` sends a mono clip that the page plays with WebAudio.

The controls are declared in Python (``add_slider``, ``add_select``, ``add_checkbox``,
``add_button``) and built by the page; ``Viewer(on_play=..., on_pause=..., on_step=..., on_reset=...)``
adds the transport buttons of a running simulation. ``modalfem view`` (``modalfem.view.explorer``)
is one user; a world runner can be another: add its bodies, call ``update`` after each step::

    viewer = Viewer(on_play=run.play, on_pause=run.pause, on_step=run.step, on_reset=run.reset)
    bell = viewer.add_body(model.vertices - model.center_of_mass, model.triangles, shapes=model.shapes)
    cloth = viewer.add_body(scene.x, scene.model.mesh.triangles, color=(0.3, 0.5, 0.9))  # a ClothScene
    with viewer:                                   # print(viewer.url)
        while running:
            ...                                    # one step of the world
            viewer.update(bell, q=state.q, position=state.position, orientation=state.orientation,
                          time_s=state.time)
            viewer.update(cloth, positions=scene.x)

Callbacks run on the server's threads: a runner hands them to its own loop (a flag, a queue).
"""

from __future__ import annotations

import base64
import json
import math
import threading
import time
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Callable

import numpy as np

from modalfem.errors import InputError, ModalfemError

__all__ = ["Viewer"]

_STATIC = {"/": ("viewer.html", "text/html; charset=utf-8"),
           "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8")}
#: seconds between keep-alive comments on an idle event stream
_KEEPALIVE = 5.0


@dataclass
class _Body:
    name: str
    vertices: np.ndarray  # (nv, 3) float32
    triangles: np.ndarray  # (nt, 3) uint32
    shapes_t: np.ndarray | None  # (r, 3 nv) float32
    color: tuple
    frame: dict = field(default_factory=dict)

    def header(self, index: int) -> dict:
        return {"id": index, "name": self.name, "vertex_count": len(self.vertices),
                "triangle_count": len(self.triangles),
                "mode_count": 0 if self.shapes_t is None else len(self.shapes_t), "color": list(self.color)}

    def payload(self) -> bytes:
        parts = [self.vertices.tobytes(), self.triangles.tobytes()]
        if self.shapes_t is not None:
            parts.append(self.shapes_t.tobytes())
        return b"".join(parts)


class Viewer:
    """A live browser view of triangle-mesh bodies, with controls and callbacks.

    Args:
        host: interface to listen on (default ``127.0.0.1``: this machine only).
        port: TCP port; 0 picks a free one (see ``url``).
        title: page title.
        fps: most frames per second sent to a page [1/s].
        on_play, on_pause, on_step, on_reset: callbacks without arguments; when any is given the
            page shows the transport buttons (play, pause, step, reset) for the given ones.
        on_strike: ``on_strike(body, triangle, barycentric, direction)`` when the user clicks a
            body: body index, triangle index, barycentric (3,) and the unit view-ray direction (3,)
            in world axes.

    The server runs in background threads from ``start()`` (or ``with Viewer(...) as v:``) until
    ``close()``. All methods are thread-safe.

    Raises:
        InputError: the port is taken or cannot be opened (on ``start``); bad body data.
    """

    def __init__(self, *, host: str = "127.0.0.1", port: int = 0, title: str = "modalfem",
                 fps: float = 60.0, on_play: Callable | None = None, on_pause: Callable | None = None,
                 on_step: Callable | None = None, on_reset: Callable | None = None,
                 on_strike: Callable | None = None) -> None:
        if not (isinstance(port, int) and 0 <= port <= 65535):
            raise InputError(f"port must be an integer in [0, 65535], got {port!r}")
        if not (math.isfinite(float(fps)) and fps > 0):
            raise InputError(f"fps must be > 0, got {fps!r}")
        self.host, self.port, self.title, self.fps = host, port, title, float(fps)
        self.on_strike = on_strike
        self._bodies: list[_Body] = []
        self._controls: list[dict] = []
        self._callbacks: dict[str, Callable] = {}
        self._status = ""
        self._time: float | None = None
        self._seq = 0
        self._sound_seq = 0
        self._sound: dict | None = None
        self._cond = threading.Condition()
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._closed = False
        for name, cb in (("play", on_play), ("pause", on_pause), ("step", on_step), ("reset", on_reset)):
            if cb is not None:
                self.add_button(name, cb)

    # ------------------------------------------------------------------ scene
    def add_body(self, vertices, triangles, *, shapes=None, name: str = "body", color=(0.80, 0.62, 0.42)) -> int:
        """Add a body to the scene (before ``start``); returns its index.

        Args:
            vertices: rest vertices (nv, 3) [m], body axes.
            triangles: outward triangles (nt, 3), indices into ``vertices``.
            shapes: mode shapes (3 nv, r) [m / sqrt(kg)] (node-major rows, as ``ModalModel.shapes``)
                for a modal body, whose frames then carry modal coordinates; None for a body whose
                frames carry vertex positions.
            name: label. color: RGB in [0, 1].
        """
        if self._server is not None:
            raise InputError("add bodies before the viewer starts")
        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or not np.all(np.isfinite(v)):
            raise InputError(f"vertices must be a finite (nv, 3) array, got shape {v.shape}")
        if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0 or t.dtype.kind not in "iu" or t.min() < 0 or t.max() >= len(v):
            raise InputError(f"triangles must be (nt, 3) indices into the {len(v)} vertices")
        s = None
        if shapes is not None:
            s = np.asarray(shapes, dtype=np.float64)
            if s.ndim != 2 or s.shape[0] != 3 * len(v) or not np.all(np.isfinite(s)):
                raise InputError(f"shapes must be a finite (3 nv, r) = ({3 * len(v)}, r) array, got {s.shape}")
            s = np.ascontiguousarray(s.T, dtype="<f4")
        self._bodies.append(_Body(str(name), np.ascontiguousarray(v, dtype="<f4"),
                                  np.ascontiguousarray(t, dtype="<u4"), s, tuple(float(c) for c in color)))
        return len(self._bodies) - 1

    def add_slider(self, name: str, callback: Callable, *, minimum: float, maximum: float, value: float,
                   step: float = 0.0, label: str | None = None) -> None:
        """A slider; ``callback(value: float)`` when it moves (``step`` 0: continuous)."""
        self._add_control(name, callback, kind="slider", min=float(minimum), max=float(maximum),
                          value=float(value), step=float(step), label=label)

    def add_select(self, name: str, callback: Callable, *, options: list[str], value: int = 0,
                   label: str | None = None) -> None:
        """A drop-down list; ``callback(index: int)`` when the choice changes."""
        self._add_control(name, callback, kind="select", options=[str(o) for o in options], value=int(value),
                          label=label)

    def add_checkbox(self, name: str, callback: Callable, *, value: bool = False, label: str | None = None) -> None:
        """A check box; ``callback(checked: bool)``."""
        self._add_control(name, callback, kind="checkbox", value=bool(value), label=label)

    def add_button(self, name: str, callback: Callable, *, label: str | None = None) -> None:
        """A button; ``callback()`` when pressed."""
        self._add_control(name, callback, kind="button", label=label)

    def _add_control(self, name: str, callback: Callable, *, kind: str, label: str | None = None, **spec) -> None:
        if name in self._callbacks:
            raise InputError(f"a control named {name!r} exists already")
        self._callbacks[name] = callback
        with self._cond:
            self._controls.append({"name": name, "kind": kind, "label": label or name, **spec})

    def set_control(self, name: str, value) -> None:
        """Change a control's shown value (the page updates; the callback is not called)."""
        with self._cond:
            for c in self._controls:
                if c["name"] == name:
                    c["value"] = value
                    break
            else:
                raise InputError(f"no control named {name!r}")
            self._seq += 1
            self._cond.notify_all()

    # ------------------------------------------------------------------ frames
    def update(self, body: int = 0, *, q=None, positions=None, position=None, orientation=None,
               time_s: float | None = None) -> None:
        """Publish a body's new state; the next frame a page receives carries it.

        Args:
            body: body index from ``add_body``.
            q: modal coordinates (r,) [sqrt(kg) m] (modal bodies only).
            positions: vertex positions (nv, 3) [m] in body axes (bodies without modes).
            position: body origin in the world (3,) [m]; orientation: unit quaternion (w, x, y, z),
                body -> world. Both default to the last ones sent (at first, identity).
            time_s: simulation time shown on the page [s].
        """
        b = self._body(body)
        frame = {}
        if q is not None:
            if b.shapes_t is None:
                raise InputError(f"body {body} has no mode shapes: send positions")
            qa = np.asarray(q, dtype=np.float64).reshape(-1)
            if qa.shape != (len(b.shapes_t),) or not np.all(np.isfinite(qa)):
                raise InputError(f"q must be {len(b.shapes_t)} finite numbers, got shape {qa.shape}")
            frame["q"] = qa.tolist()
        if positions is not None:
            x = np.asarray(positions, dtype="<f4")
            if x.shape != b.vertices.shape or not np.all(np.isfinite(x)):
                raise InputError(f"positions must be a finite {b.vertices.shape} array, got {x.shape}")
            frame["positions"] = base64.b64encode(x.tobytes()).decode("ascii")
        if position is not None or orientation is not None:
            pose = list(b.frame.get("pose", [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
            if position is not None:
                pose[:3] = [float(c) for c in np.asarray(position, dtype=np.float64).reshape(3)]
            if orientation is not None:
                o = np.asarray(orientation, dtype=np.float64).reshape(4)
                pose[3:] = (o / np.linalg.norm(o)).tolist()
            if not all(math.isfinite(c) for c in pose):
                raise InputError("body position and orientation must be finite")
            frame["pose"] = pose
        with self._cond:
            b.frame.update(frame)
            if time_s is not None:
                self._time = float(time_s)
            self._seq += 1
            self._cond.notify_all()

    def status(self, text: str) -> None:
        """A one-line status message shown on the page."""
        with self._cond:
            self._status = str(text)
            self._seq += 1
            self._cond.notify_all()

    def play_sound(self, samples, sample_rate: int) -> None:
        """Play a mono clip on the page (the newest replaces one not yet played).

        Args:
            samples: (n,) pressure or any signal; normalised to a peak of 0.9 for playback, so only
                its shape (pitch, decay, timbre) matters, not its level.
            sample_rate: [1/s], 8000..192000.
        """
        s = np.asarray(samples, dtype=np.float64).reshape(-1)
        if not (8000 <= int(sample_rate) <= 192000):
            raise InputError(f"sample_rate must be in [8000, 192000] Hz, got {sample_rate!r}")
        peak = float(np.max(np.abs(s))) if len(s) else 0.0
        pcm = np.zeros(len(s), dtype="<i2") if peak == 0 or not math.isfinite(peak) else \
            np.round(s * (0.9 * 32767 / peak)).astype("<i2")
        with self._cond:
            self._sound_seq += 1
            self._sound = {"id": self._sound_seq, "rate": int(sample_rate),
                           "pcm16": base64.b64encode(pcm.tobytes()).decode("ascii")}
            self._seq += 1
            self._cond.notify_all()

    def _body(self, body: int) -> _Body:
        if not isinstance(body, (int, np.integer)) or not 0 <= int(body) < len(self._bodies):
            raise InputError(f"no body {body!r} (the scene has {len(self._bodies)})")
        return self._bodies[int(body)]

    # ------------------------------------------------------------------ server
    @property
    def url(self) -> str:
        """The page's address (valid after ``start``)."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0") else self.host
        return f"http://{host}:{self.port}/"

    def start(self) -> "Viewer":
        """Open the port and serve in a background thread; returns self."""
        if self._server is not None:
            return self
        if not self._bodies:
            raise InputError("the viewer has no bodies: add_body first")
        try:
            server = ThreadingHTTPServer((self.host, self.port), _handler(self))
        except OSError as exc:
            raise InputError(f"cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
                             f"{' (pick another --port)' if self.port else ''}") from None
        server.daemon_threads = True
        self._server = server
        self.port = server.server_address[1]
        self._thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1},
                                        name="modalfem-viewer", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop serving, end the event streams and free the port (idempotent)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._thread.join(timeout=5)
            self._server = None

    def __enter__(self) -> "Viewer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ used by the handler
    def _scene(self) -> dict:
        with self._cond:
            return {"title": self.title, "fps": self.fps, "bodies": [b.header(i) for i, b in enumerate(self._bodies)],
                    "controls": json.loads(json.dumps(self._controls))}

    def _frame(self) -> tuple[int, dict]:
        with self._cond:
            frame = {"seq": self._seq, "status": self._status, "time": self._time,
                     "bodies": [dict(b.frame) for b in self._bodies],
                     "controls": {c["name"]: c.get("value") for c in self._controls if "value" in c}}
            if self._sound is not None:
                frame["sound"] = self._sound
            return self._seq, frame

    def _wait(self, seen: int, timeout: float) -> bool:
        """Wait until a frame newer than ``seen`` exists; False on close or timeout."""
        with self._cond:
            self._cond.wait_for(lambda: self._seq != seen or self._closed, timeout=timeout)
            return not self._closed and self._seq != seen

    def _input(self, msg: dict) -> dict:
        kind = msg.get("type")
        if kind == "strike":
            if self.on_strike is None:
                raise InputError("this view takes no strikes")
            b = self._body(msg.get("body"))
            tri = msg.get("triangle")
            if not isinstance(tri, int) or not 0 <= tri < len(b.triangles):
                raise InputError(f"strike: triangle {tri!r} not in [0, {len(b.triangles)})")
            bary = _vector(msg.get("barycentric"), 3, "strike barycentric")
            if np.any(bary < -1e-6) or abs(bary.sum() - 1) > 1e-5:
                raise InputError(f"strike: barycentric {bary.tolist()} must be >= 0 and sum to 1")
            bary = np.clip(bary, 0, None)
            d = _vector(msg.get("direction"), 3, "strike direction")
            if np.linalg.norm(d) == 0:
                raise InputError("strike: direction must be non-zero")
            result = self.on_strike(int(msg["body"]), tri, bary / bary.sum(), d / np.linalg.norm(d))
            return {"ok": True, "result": result}
        if kind in ("control", "button"):
            name = msg.get("name")
            if name not in self._callbacks:
                raise InputError(f"no control named {name!r}")
            spec = next(c for c in self._controls if c["name"] == name)
            if spec["kind"] == "button":
                result = self._callbacks[name]()
            else:
                value = _control_value(spec, msg.get("value"))
                with self._cond:
                    spec["value"] = value
                result = self._callbacks[name](value)
            return {"ok": True, "result": result}
        raise InputError(f"unknown input type {kind!r} (strike, control, button)")


def _vector(value, n: int, what: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be {n} numbers, got {value!r}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InputError(f"{what} must be {n} finite numbers, got {value!r}")
    return a


def _control_value(spec: dict, value):
    kind = spec["kind"]
    if kind == "checkbox":
        if not isinstance(value, bool):
            raise InputError(f"{spec['name']}: expected true or false, got {value!r}")
        return value
    if kind == "select":
        if not isinstance(value, int) or not 0 <= value < len(spec["options"]):
            raise InputError(f"{spec['name']}: choice {value!r} not in [0, {len(spec['options'])})")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(f"{spec['name']}: expected a number, got {value!r}")
    return float(min(max(value, spec["min"]), spec["max"]))


def _handler(viewer: Viewer):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args) -> None:  # no access log on the terminal
            pass

        def _send(self, status: int, body: bytes, ctype: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: int, obj) -> None:
            self._send(status, json.dumps(obj).encode(), "application/json")

        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            path = self.path.split("?", 1)[0]
            if path in _STATIC:
                fname, ctype = _STATIC[path]
                text = resources.files("modalfem.view").joinpath("static", fname).read_bytes()
                return self._send(200, text, ctype)
            if path == "/scene":
                return self._json(200, viewer._scene())
            if path.startswith("/body/"):
                try:
                    b = viewer._body(int(path[len("/body/"):]))
                except (ValueError, InputError) as exc:
                    return self._json(404, {"error": str(exc)})
                return self._send(200, b.payload(), "application/octet-stream")
            if path == "/events":
                return self._events()
            if path == "/favicon.ico":
                return self._send(204, b"", "image/x-icon")
            self._json(404, {"error": f"no page {path}"})

        def _events(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            seen, period = -1, 1.0 / viewer.fps
            try:
                while not viewer._closed:
                    t0 = time.monotonic()
                    if viewer._wait(seen, _KEEPALIVE):
                        seen, frame = viewer._frame()
                        self.wfile.write(b"data: " + json.dumps(frame).encode() + b"\n\n")
                    elif not viewer._closed:
                        self.wfile.write(b": keep-alive\n\n")
                    self.wfile.flush()
                    time.sleep(max(0.0, period - (time.monotonic() - t0)))
            except (BrokenPipeError, ConnectionResetError, ConnectionAbortedError):
                pass
            self.close_connection = True

        def do_POST(self) -> None:  # noqa: N802
            if self.path != "/input":
                return self._json(404, {"error": f"no input endpoint {self.path}"})
            try:
                n = int(self.headers.get("Content-Length", "0"))
                if not 0 < n <= 1 << 16:
                    raise InputError("input message must be 1 byte to 64 KiB of JSON")
                try:
                    msg = json.loads(self.rfile.read(n))
                except ValueError:
                    raise InputError("input message is not JSON") from None
                if not isinstance(msg, dict):
                    raise InputError("input message must be a JSON object")
                self._json(200, viewer._input(msg))
            except ModalfemError as exc:
                self._json(400, {"error": str(exc).splitlines()[0] if str(exc) else type(exc).__name__})
            except Exception as exc:  # noqa: BLE001 - a failing callback must not kill the server
                self._json(500, {"error": f"unexpected {type(exc).__name__}: {exc}"})

    return Handler
