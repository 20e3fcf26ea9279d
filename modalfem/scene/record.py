"""What ``modalfem run SCENE --out DIR`` writes: the outputs of a ``World`` run, frame by frame.

``Recorder(world, folder, ...)`` is called by the run loop with every output frame's ``WorldState`` (the first at
t = 0) and finished once; ``finish(interrupted=True)`` after a Ctrl-C leaves every output consistent with the
frames recorded so far. Files, relative to ``folder`` (the run's staging folder):

* ``scene.pvd`` + ``paraview/``: ParaView time series (``modalfem.scene.record_vtk``): per body and frame its
  surface with ``velocity`` [m/s] from the state, ``displacement`` [m] from the first frame and, for modal
  bodies, ``deformation`` [m] (``|Phi q|``); obstacles (moving ones per frame);
* ``preview.gif`` or ``preview.mp4``: a fixed-camera video (``modalfem.scene.record_video``);
* ``sound/<body>.wav`` per sounding body and ``sound/mix.wav``: 16-bit mono, rendered to the last frame's time
  plus the slowest kept mode's 60 dB decay (at most ``SOUND_TAIL`` s). Each body's file is normalised to its
  own peak (-3 dBFS, ``modalfem.runtime.wav``); the mix is the sum of the bodies' pressures [Pa] with one gain,
  so the bodies keep their relative loudness in it (gains in ``sound_levels``);
* ``scene.glb``: glTF animation for Blender (``modalfem.scene.record_gltf``).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from modalfem import effects as fx
from modalfem.errors import InputError
from modalfem.scene.record_gltf import GltfAnimation
from modalfem.scene.record_video import (
    Camera,
    FrameRenderer,
    GifStream,
    Mp4Stream,
    checker_patch,
    downsample,
    ffmpeg_exe,
    palette,
)
from modalfem.scene.record_vtk import ParaviewSeries

__all__ = ["SOUND_TAIL", "Recorder"]

#: longest decay tail [s] rendered after the last frame
SOUND_TAIL = 2.0
_CAMERA_KEYS = ("elev", "azim", "center", "half_width")
_DEFAULT_VIEW = {"elev": 22.0, "azim": -60.0}
#: the checkered patch drawn for a plane: this many camera half-widths around the picture's centre
_PATCH = 2.5


def _number(what: str, value, *, positive: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(x) or (positive and x <= 0):
        raise InputError(f"{what} must be {'> 0' if positive else 'finite'}, got {value!r}")
    return x


def _check_camera(camera) -> dict:
    if camera is None:
        return {}
    if not isinstance(camera, dict):
        raise InputError(f"camera must be a table of {', '.join(_CAMERA_KEYS)}, got {camera!r}")
    bad = sorted(set(camera) - set(_CAMERA_KEYS))
    if bad:
        raise InputError(f"unknown camera key(s) {', '.join(map(str, bad))}: use {', '.join(_CAMERA_KEYS)}")
    out = {}
    for k in ("elev", "azim"):
        if k in camera:
            out[k] = _number(f"camera {k} [deg]", camera[k])
    if "half_width" in camera:
        out["half_width"] = _number("camera half_width [m]", camera["half_width"], positive=True)
    if "center" in camera:
        c = np.asarray(camera["center"], dtype=object).reshape(-1)
        if c.shape != (3,):
            raise InputError(f"camera center must be 3 numbers [m], got {camera['center']!r}")
        out["center"] = np.array([_number("camera center [m]", v) for v in c])
    return out


class Recorder:
    """Writes the outputs of a world run frame by frame (see the module docstring for the files).

    Args:
        world: the ``modalfem.world.World``.
        folder: an existing folder (the run's staging folder).
        paraview: write the ParaView series.
        video: ``None``, ``"gif"`` or ``"mp4"`` (needs ``imageio-ffmpeg``; checked here, before any simulation).
        video_size: (width, height) [px], 16..4096 (even for MP4).
        gltf: write ``scene.glb``.
        sound: write the WAV files of the bodies with a ``Sound`` effect (none: nothing is written).
        frame_rate: video frames per second [1/s] (the run loop calls ``frame`` at this rate of simulated time).
        camera: optional ``{"elev": deg, "azim": deg, "center": [x, y, z] m, "half_width": m}``; what is left out
            is fitted on the first frame (every body plus a margin, the obstacles near them, the ground below).
        progress: optional ``progress(message)`` called as ``finish`` starts each file.

    Raises:
        InputError: a missing folder, bad options, or MP4 without an encoder (naming ``pip install imageio-ffmpeg``).
    """

    def __init__(self, world, folder: Path, *, paraview: bool = True, video: str | None = "gif",
                 video_size: tuple[int, int] = (640, 360), gltf: bool = True, sound: bool = True,
                 frame_rate: float = 30.0, camera: dict | None = None, progress=None) -> None:
        self.world = world
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise InputError(f"output folder {str(self.folder)!r} does not exist")
        if video not in (None, "gif", "mp4"):
            raise InputError(f"video must be none, \"gif\" or \"mp4\", got {video!r}")
        try:
            W, H = (int(v) for v in video_size)
            if (W, H) != tuple(video_size):
                raise ValueError
        except (TypeError, ValueError):
            raise InputError(f"video_size must be two whole numbers (width, height) [px], got {video_size!r}") from None
        if not (16 <= W <= 4096 and 16 <= H <= 4096):
            raise InputError(f"video_size must be 16..4096 px each, got {W} x {H}")
        if video == "mp4":
            if W % 2 or H % 2:
                raise InputError(f"an MP4 video needs an even width and height, got {W} x {H}")
            ffmpeg_exe()
        self.frame_rate = _number("frame_rate [1/s]", frame_rate, positive=True)
        self.video, self.video_size = video, (W, H)
        self._camera_options = _check_camera(camera)
        self.paraview, self.gltf, self.sound = bool(paraview), bool(gltf), bool(sound)
        self.progress = progress
        self.sounding = [b.name for b in world.bodies if b.kind == "modal"
                         and any(isinstance(e, fx.Sound) for e in world.effects_of(b.name))] if self.sound else []
        self.camera: Camera | None = None
        self.seconds = {"sample": 0.0, "paraview": 0.0, "video": 0.0, "gltf": 0.0, "sound": 0.0}
        self.sound_levels: dict[str, dict] = {}
        self._count = 0
        self._times: list[float] = []
        self._start: dict[str, np.ndarray] = {}
        self._series: ParaviewSeries | None = None
        self._gif: GifStream | None = None
        self._mp4: Mp4Stream | None = None
        self._pending = None  # the last MP4 frame, sent once its frame is complete
        self._anim = GltfAnimation(world, []) if self.gltf else None
        self._result: dict[str, list[str]] | None = None

    @property
    def frame_count(self) -> int:
        """Frames recorded completely so far."""
        return self._count

    @property
    def gltf_report(self) -> dict[str, dict]:
        """Per body of ``scene.glb`` (after ``finish``): ``morph`` (``"modes"`` or ``"principal components"``),
        ``targets`` and ``max_error_m`` [m], the largest vertex error of the morphs over every frame (tet and cloth
        bodies, against ``tolerance_m``; above it only when ``MAX_TARGETS`` components were not enough)."""
        return {} if self._anim is None else dict(self._anim.report)

    def ms_per_frame(self) -> dict[str, float]:
        """Wall time per recorded frame [ms] of each writer (``gltf`` and ``sound`` include ``finish``)."""
        n = max(self._count, 1)
        return {k: 1e3 * v / n for k, v in self.seconds.items()}

    # ------------------------------------------------------------------ first frame
    def _setup(self, surfaces: dict) -> None:
        opts = dict(_DEFAULT_VIEW)
        opts.update(self._camera_options)
        boxes = [(x.min(0), x.max(0)) for x, _ in surfaces.values()]
        lo, hi = np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)
        reach = float(np.linalg.norm(hi - lo))
        fit_boxes, planes, named = list(boxes), [], []
        for i, o in enumerate(self.world.obstacles):
            named.append((f"{o.kind}{i}", o))
            if hasattr(o, "normal"):
                p = o.point + o.offset(0.0)
                mid = 0.5 * (lo + hi)
                if o.kind == "ground" or abs((mid - p) @ o.normal) <= reach:
                    planes.append((p, o.normal))
            else:
                V, _ = o.surface(0.0)
                vlo, vhi = V.min(0), V.max(0)
                if np.all(vlo <= hi + reach) and np.all(vhi >= lo - reach):
                    fit_boxes.append((np.maximum(vlo, lo - reach), np.minimum(vhi, hi + reach)))
        fitted = Camera.fit(fit_boxes, planes, elev=opts["elev"], azim=opts["azim"], size=self.video_size)
        self.camera = Camera(elev=opts["elev"], azim=opts["azim"], center=opts.get("center", fitted.center),
                             half_width=opts.get("half_width", fitted.half_width), size=self.video_size)
        self._obstacles, self._draw = [], []
        self._grounds = [o.height for o in self.world.obstacles if o.kind == "ground" and self.camera.eye[2] > 0]
        renderer = FrameRenderer(self.camera)
        for name, o in named:
            if hasattr(o, "normal"):  # a patch around the view, or the plane's own square when that is smaller
                half = _PATCH * self.camera.half_width
                mid = self.camera.center if o.size >= half else o.point
                V, F, colour = checker_patch(o.point, o.normal, mid, min(half, o.size))
                self._obstacles.append((name, o, (V, F)))
                if self.camera.eye @ o.normal <= 0:  # seen from behind (its solid side): not drawn in the video
                    continue
            else:
                V, F = o.surface(0.0)
                V = V - o.offset(0.0)
                colour = renderer.shade(V, F, "obstacle")
                self._obstacles.append((name, o, None))
            self._draw.append((o, V, F, colour))
        if self.paraview:
            self._series = ParaviewSeries(self.folder, self._obstacles)
        if self._anim is not None:
            self._anim.obstacles = self._obstacles
        if self.video is not None:
            self._renderer = renderer
            if self.video == "mp4":  # drawn at twice the size and averaged: anti-aliased edges (a GIF keeps its palette)
                W, H = self.video_size
                self._renderer = FrameRenderer(Camera(elev=self.camera.elev, azim=self.camera.azim,
                                                      center=self.camera.center, half_width=self.camera.half_width,
                                                      size=(2 * W, 2 * H)))
            self._renderer.set_static([(V, F, c) for o, V, F, c in self._draw if not o.moving])
            if self.video == "gif":
                self._gif = GifStream(self.folder / "preview.gif", self.video_size, self.frame_rate)
            else:
                self._mp4 = Mp4Stream(self.folder / "preview.mp4", self.video_size, self.frame_rate)
                self._palette = palette()

    # ------------------------------------------------------------------ frames
    def _sample(self, state) -> tuple[dict, list]:
        """Every body's world surface and point data."""
        w = self.world
        surfaces, bodies = {}, []
        for b in w.bodies:
            x, tris = w.surface(state, b.name)
            s = state.bodies[b.name]
            data = {}
            if b.kind == "modal":
                body = w._modal[b.name]["body"]
                R = s.rotation()
                local_v = np.dot(s.qdot, body.shapes_t).reshape(-1, 3)
                v = s.velocity + np.cross(body.angular_velocity(s), x - s.position) + local_v @ R.T
                data["deformation"] = np.linalg.norm(np.dot(s.q, body.shapes_t).reshape(-1, 3), axis=1)
            elif b.kind == "tet":
                v = s.v[w._tet[b.name]["surface"]]
            else:
                v = s.v
            x = np.asarray(x, dtype=np.float64)
            if b.name not in self._start:
                self._start[b.name] = x.copy()
            data = {"velocity": np.asarray(v, dtype=np.float64),
                    "displacement": np.linalg.norm(x - self._start[b.name], axis=1), **data}
            surfaces[b.name] = (x, tris)
            bodies.append((b.name, x, tris, data))
        return surfaces, bodies

    def frame(self, state) -> None:
        """Record one output frame of ``state`` (a ``WorldState``; the first call is t = 0).

        Raises:
            InputError: after ``finish``, or a file cannot be written (disk full, ...; one line).
        """
        if self._result is not None:
            raise InputError("the recorder is finished: no more frames")
        try:
            self._frame(state)
        except OSError as exc:
            raise InputError(f"cannot write output frame {self._count} in {str(self.folder)!r}: "
                             f"{exc.strerror or exc}") from None

    def _frame(self, state) -> None:
        t0 = time.perf_counter()
        surfaces, bodies = self._sample(state)
        if self.camera is None:
            self._setup(surfaces)
        t1 = time.perf_counter()
        if self._series is not None:
            self._series.write(self._count, state.time, bodies)
        t2 = time.perf_counter()
        if self.video is not None:
            parts = [(V + o.offset(state.time), F, c) for o, V, F, c in self._draw if o.moving]
            for n, (x, tris) in surfaces.items():
                parts.append((x, tris, self._renderer.shade(x, tris, self.world.by_name[n].kind)))
                for h in self._grounds:
                    parts.insert(0, (self._renderer.shadow(x, h), tris, None))
            image = self._renderer.draw(parts, f"t = {state.time:.3f} s")
            if self._gif is not None:
                self._gif.write(image)
            else:
                if self._pending is not None:
                    self._mp4.write(self._pending)
                self._pending = downsample(image, self._palette)
        t3 = time.perf_counter()
        if self._anim is not None:
            self._anim.add(state, surfaces)
        t4 = time.perf_counter()
        self._times.append(float(state.time))
        self._count += 1
        for k, a, b in (("sample", t0, t1), ("paraview", t1, t2), ("video", t2, t3), ("gltf", t3, t4)):
            self.seconds[k] += b - a

    # ------------------------------------------------------------------ the end
    def _say(self, msg: str) -> None:
        if self.progress is not None:
            self.progress(msg)

    def finish(self, *, interrupted: bool = False) -> dict[str, list[str]]:
        """Write what is written at the end and return the files by kind (relative to ``folder``).

        Args:
            interrupted: the run stopped early (Ctrl-C): everything is cut to the frames recorded completely.

        Returns:
            ``{"paraview": [...], "video": [...], "sound": [...], "gltf": [...]}``.
        """
        if self._result is not None:
            return self._result
        n = self._count
        out: dict[str, list[str]] = {"paraview": [], "video": [], "sound": [], "gltf": []}
        try:
            t0 = time.perf_counter()
            if n == 0:  # interrupted before the first frame was complete: nothing to keep
                self._discard()
            if self._series is not None:
                self._say("writing the ParaView series")
                out["paraview"] = self._series.finish(n)
            t1 = time.perf_counter()
            if self._gif is not None:
                self._gif.close(frames=n)
                out["video"] = ["preview.gif"]
            if self._mp4 is not None:
                self._say("finishing the video")
                if self._pending is not None and self._mp4.frame_count < n:
                    self._mp4.write(self._pending)
                self._pending = None
                self._mp4.close()
                out["video"] = ["preview.mp4"]
            t2 = time.perf_counter()
            if self._anim is not None and n:
                self._say("writing scene.glb")
                self._anim.write(self.folder / "scene.glb", n)
                out["gltf"] = ["scene.glb"]
            t3 = time.perf_counter()
            if self.sounding and n:
                self._say("rendering the sound")
                out["sound"] = self._write_sound()
            t4 = time.perf_counter()
        except BaseException as exc:
            if self._mp4 is not None:
                self._mp4.kill()
            if isinstance(exc, OSError):
                raise InputError(f"cannot finish the outputs in {str(self.folder)!r}: {exc.strerror or exc}") from None
            raise
        self.seconds["paraview"] += t1 - t0
        self.seconds["video"] += t2 - t1
        self.seconds["gltf"] += t3 - t2
        self.seconds["sound"] += t4 - t3
        self._result = out
        return out

    def _discard(self) -> None:
        """Remove everything the first (incomplete) frame started."""
        import shutil

        if self._mp4 is not None:
            self._mp4.kill()
            self._mp4 = None
        if self._gif is not None:
            self._gif.close()
            self._gif = None
        for name in ("preview.gif", "preview.mp4"):
            (self.folder / name).unlink(missing_ok=True)
        if self._series is not None:
            shutil.rmtree(self._series.dir, ignore_errors=True)
            self._series = None

    def _write_sound(self) -> list[str]:
        from modalfem.runtime.wav import write_wav

        sounds = {n: self.world.sound(n) for n in self.sounding}
        tail = 0.0
        for snd in sounds.values():
            mu = np.asarray(snd.mu)[snd.band.kept]
            slowest = float(mu.min()) if len(mu) else 0.0
            tail = max(tail, min(SOUND_TAIL, math.log(1000.0) / slowest if slowest > 0 else SOUND_TAIL))
        duration = self._times[-1] + max(tail, 1.0 / next(iter(sounds.values())).sample_rate)
        (self.folder / "sound").mkdir(exist_ok=True)
        rates = {snd.sample_rate for snd in sounds.values()}
        if len(rates) > 1:
            raise InputError(f"sounding bodies render at different sample rates {sorted(rates)}: cannot mix them")
        files, mix = [], None
        for name, snd in sounds.items():
            p = snd.render(duration)
            gain = write_wav(self.folder / "sound" / f"{name}.wav", p, sample_rate=snd.sample_rate)
            self.sound_levels[name] = {"peak_pa": float(np.abs(p).max()), "gain_per_pa": gain}
            files.append(f"sound/{name}.wav")
            mix = p.copy() if mix is None else mix + p
        gain = write_wav(self.folder / "sound" / "mix.wav", mix, sample_rate=rates.pop())
        self.sound_levels["mix"] = {"peak_pa": float(np.abs(mix).max()), "gain_per_pa": gain}
        return files + ["sound/mix.wav"]
