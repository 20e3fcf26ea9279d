"""``ModeExplorer``: a modal model in the browser (``modalfem view MODEL.npz``).

The page shows the model's surface. A mode picker and an amplitude slider show one mode shape,
still or animated; a click on the surface strikes the body there: the impulse changes the modal
velocities (``dqdot = Phi(p)^T J``), the modes ring with the model's own frequencies and damping
(exact per-mode integration, ``modalfem.runtime.integrator``), and the page plays the modal sound of
the strike (``modalfem.runtime.sound``: damped sines, monopole radiation towards the viewer).

What the page draws is ``x = X + Phi q_shown`` with ``q_shown = q_mode + g q_struck``:

* ``q_mode``: the picked mode at the chosen amplitude (peak surface displacement as a fraction of the
  body's bounding-box diagonal), times ``sin(2 pi t)`` when animated (one cycle per second);
* ``q_struck``: the real modal state after the strikes, in slow motion (the lowest mode shown at
  one cycle per second, so simulated time runs ``f_1`` times slower than the wall clock) and
  magnified by ``g``, set at each strike so that the largest displacement the ringing can reach is
  the same amplitude. Audio is real time and real pitch; its level is normalised per strike.

Only q (r numbers) travels per frame; the page holds the mode shapes (``modalfem.view.Viewer``).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from modalfem.errors import InputError
from modalfem.runtime.integrator import ModalIntegrator
from modalfem.runtime.sound import ModalSound
from modalfem.runtime.body import SurfacePoint
from modalfem.view.server import Viewer

__all__ = ["ModeExplorer"]

#: animation rate of a picked mode and display rate of the lowest struck mode [Hz]
DISPLAY_HZ = 1.0


class ModeExplorer:
    """Live mode explorer of a ``ModalModel`` served by a ``Viewer``.

    Args:
        model: the ``ModalModel``.
        mode: mode shown first, 1-based (1 = lowest).
        amplitude: peak surface displacement shown, as a fraction of the bounding-box diagonal (0..0.5).
        impulse: strike impulse [N s]; default: the body's mass times 0.1 m/s.
        animate: animate the picked mode (else it is shown still).
        host, port, fps: passed to ``Viewer``.

    Attributes:
        viewer: the ``Viewer``. q, qdot: the struck modal state (r,) [sqrt(kg) m, sqrt(kg) m/s].
        sim_time: simulated time since the start [s]. strikes: number of strikes so far.

    Raises:
        InputError: mode out of range, amplitude or impulse out of range, port taken (on start).
    """

    def __init__(self, model, *, mode: int = 1, amplitude: float = 0.05, impulse: float | None = None,
                 animate: bool = True, host: str = "127.0.0.1", port: int = 0, fps: float = 60.0) -> None:
        self.model = model
        r = model.mode_count
        if isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 1 <= mode <= r:
            raise InputError(f"mode must be in 1..{r} (the model has {r} modes), got {mode!r}")
        if not (isinstance(amplitude, (int, float)) and 0 <= amplitude <= 0.5):
            raise InputError(f"amplitude must be in [0, 0.5] (fraction of the body size), got {amplitude!r}")
        self.impulse = 0.1 * model.mass if impulse is None else float(impulse)
        if not (math.isfinite(self.impulse) and self.impulse > 0):
            raise InputError(f"impulse must be > 0 N s, got {impulse!r}")
        v = np.asarray(model.vertices, dtype=np.float64)
        self._size = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
        self._shapes3 = np.asarray(model.shapes, dtype=np.float64).reshape(len(v), 3, r)
        self._peak = np.linalg.norm(self._shapes3, axis=1).max(axis=0)  # (r,) largest vertex |phi_i| [m/sqrt(kg)]
        self._tri = np.asarray(model.triangles)
        self._omega = np.asarray(model.omega, dtype=np.float64)
        self._integrator = ModalIntegrator(self._omega, model.modal_damping)
        self.slow_motion = float(self._omega[0] / (2 * math.pi) / DISPLAY_HZ)  # sim time runs this much slower
        self.mode, self.amplitude, self.animate = int(mode) - 1, float(amplitude), bool(animate)
        self.q, self.qdot = np.zeros(r), np.zeros(r)
        self.sim_time, self.strikes, self._gain = 0.0, 0, 0.0
        self._sent: np.ndarray | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()

        self.viewer = Viewer(host=host, port=port, fps=fps, title=f"modalfem view: {r} modes",
                             on_strike=self.strike)
        self.viewer.add_body(model.vertices, model.triangles, shapes=model.shapes, name="model")
        hz = model.frequencies_hz
        self.viewer.add_select("mode", self.select_mode, options=[f"{i + 1}: {f:.6g} Hz" for i, f in enumerate(hz)],
                               value=self.mode, label="mode")
        self.viewer.add_slider("amplitude", self.set_amplitude, minimum=0.0, maximum=max(0.2, self.amplitude),
                               value=self.amplitude,
                               step=0.005, label="amplitude (of size)")
        self.viewer.add_checkbox("animate", self.set_animate, value=self.animate, label="animate")
        self.viewer.add_button("rest", self.rest, label="stop ringing")
        self._show_status()

    # ------------------------------------------------------------------ controls
    def select_mode(self, index: int) -> None:
        """Show mode ``index`` (0-based)."""
        if not 0 <= int(index) < self.model.mode_count:
            raise InputError(f"mode index {index!r} not in [0, {self.model.mode_count})")
        with self._lock:
            self.mode = int(index)
        self.viewer.set_control("mode", self.mode)
        self._show_status()

    def set_amplitude(self, value: float) -> None:
        """Peak displacement shown, fraction of the bounding-box diagonal."""
        with self._lock:
            self.amplitude = float(value)

    def set_animate(self, on: bool) -> None:
        with self._lock:
            self.animate = bool(on)

    def rest(self) -> None:
        """Stop the ringing (struck state to zero)."""
        with self._lock:
            self.q[:] = 0.0
            self.qdot[:] = 0.0

    def strike(self, body: int, triangle: int, barycentric, direction) -> dict:
        """Strike the surface point (triangle, barycentric) seen along the view ray ``direction``.

        The impulse ``J = impulse * (-n)`` pushes along the inward normal n of the triangle; the
        listener is at 1 m towards the viewer (``-direction``).

        Returns:
            ``{"dqdot_norm": |Phi(p)^T J| [sqrt(kg) m/s], "sound_s": clip length [s]}``.
        """
        b = np.asarray(barycentric, dtype=np.float64)
        tri = self._tri[int(triangle)]
        x = np.asarray(self.model.vertices)[tri]
        n = np.cross(x[1] - x[0], x[2] - x[0])
        n = n / np.linalg.norm(n)
        J = -self.impulse * n
        phi = np.einsum("k,kcr->cr", b, self._shapes3[tri])  # (3, r)
        dq = phi.T @ J
        with self._lock:
            self.qdot += dq
            reach = np.sum((np.abs(self.q) + np.abs(self.qdot) / self._omega) * self._peak)
            self._gain = self.amplitude * self._size / reach if reach > 0 else 0.0
            self.strikes += 1
        seconds = self._sound(SurfacePoint(int(triangle), tuple(b)), J, -np.asarray(direction, dtype=np.float64))
        self._show_status()
        return {"dqdot_norm": float(np.linalg.norm(dq)), "sound_s": seconds}

    def _sound(self, point, J, listener) -> float:
        snd = ModalSound(self.model, listener=listener, distance=1.0)
        kept = snd.band.kept
        if len(kept) == 0:
            self.viewer.status(f"no mode below {snd.band.f_max_hz:g} Hz to hear")
            return 0.0
        half_mu = 0.5 * snd.mu[kept]
        slowest = float(np.min(half_mu))
        seconds = float(np.clip(math.log(1000.0) / slowest if slowest > 0 else 3.0, 0.3, 3.0))  # -60 dB
        snd.add_impulses(0.0, point, J)
        p = snd.render(seconds)
        fade = min(len(p), int(0.02 * snd.sample_rate))  # 20 ms fade-out: no click at the cut
        p[len(p) - fade:] *= np.linspace(1.0, 0.0, fade)
        self.viewer.play_sound(p, snd.sample_rate)
        return seconds

    # ------------------------------------------------------------------ frames
    def shown_q(self, wall_time: float) -> np.ndarray:
        """The modal coordinates drawn at wall-clock time ``wall_time`` [s] (r,) [sqrt(kg) m]."""
        with self._lock:
            qs = self._gain * self.q
            i = self.mode
            a = self.amplitude * self._size / self._peak[i]
            qs[i] += a * (math.sin(2 * math.pi * DISPLAY_HZ * wall_time) if self.animate else 1.0)
        return qs

    def tick(self, wall_dt: float, wall_time: float) -> None:
        """Advance the struck state by ``wall_dt`` [s] of wall time (slow motion) and publish a frame."""
        dt = wall_dt / self.slow_motion
        with self._lock:
            self._integrator.step(self.q, self.qdot, None, dt, q_out=self.q, qdot_out=self.qdot)
            self.sim_time += dt
        q = self.shown_q(wall_time)
        if self._sent is None or not np.array_equal(q, self._sent):  # a still picture sends nothing
            self.viewer.update(0, q=q, time_s=self.sim_time)
            self._sent = q

    def _show_status(self) -> None:
        i = self.mode
        ringing = f", ringing magnified x{self._gain:.3g}" if self.strikes else ""
        self.viewer.status(f"mode {i + 1} of {self.model.mode_count}: {self.model.frequencies_hz[i]:.6g} Hz; "
                           f"click the body to strike it (slow motion 1:{self.slow_motion:.3g}{ringing})")

    def _run(self) -> None:
        period = 1.0 / self.viewer.fps
        while not self._stop.wait(period):
            self.tick(period, time.monotonic() - self._t0)

    def start(self) -> "ModeExplorer":
        """Start the server and the frame loop; returns self (``url`` then valid)."""
        self.viewer.start()
        self._thread = threading.Thread(target=self._run, name="modalfem-explorer", daemon=True)
        self._thread.start()
        return self

    @property
    def url(self) -> str:
        return self.viewer.url

    def close(self) -> None:
        """Stop the frame loop and the server (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.viewer.close()

    def __enter__(self) -> "ModeExplorer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
