"""``modalfem run``: simulate a scene and write what it asks for, all or nothing (or, after Ctrl-C, the frames
so far, said so).

The run builds the world (``build_scene``), then steps it ``duration / dt`` times; every ``1 / (frame_rate dt)``
steps it hands the state to the ``Recorder`` (ParaView, video, glTF) and records energies, momenta and the
exact intersection check for the summary. A progress line on stderr shows steps/s, simulated time and the
ETA. Everything is written into a temporary folder next to ``--out`` that replaces it at the end; an error
leaves nothing behind, Ctrl-C finishes the files with the frames so far and keeps them.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from modalfem.errors import SceneError

__all__ = ["RUN_FILES", "SUMMARY_FORMAT", "RunResult", "examples", "find_scene", "plan_scene", "run_scene"]

#: the summary's layout identifier
SUMMARY_FORMAT = "modalfem.run/1"
#: what a run folder holds (an existing --out holding anything else is not replaced)
RUN_FILES = frozenset({"summary.json", "scene.toml", "plan.txt", "paraview", "scene.pvd", "preview.gif",
                       "preview.mp4", "sound", "scene.glb"})

EXAMPLES = Path(__file__).parent / "examples"


def examples() -> dict[str, tuple[Path, str]]:
    """The example scenes shipped with modalfem: name -> (file, one-line description)."""
    import tomllib

    out = {}
    for p in sorted(EXAMPLES.glob("*.toml")):
        try:
            with open(p, "rb") as f:
                d = tomllib.load(f)
        except (OSError, tomllib.TOMLDecodeError):
            d = {}  # listed all the same: running it names the problem
        desc = d.get("description")
        out[p.stem] = (p, desc.strip().splitlines()[0] if isinstance(desc, str) and desc.strip() else "")
    return out


def find_scene(name_or_path) -> Path:
    """A scene file path, or the file of the example scene of that name.

    Raises:
        SceneError: neither a file nor an example (with a "did you mean" among the examples).
    """
    p = Path(name_or_path)
    if p.is_file():
        return p
    ex = examples()
    if str(name_or_path) in ex:
        return ex[str(name_or_path)][0]
    from modalfem.scene.schema import did_you_mean

    if p.suffix or os.sep in str(name_or_path):
        raise SceneError(f"{name_or_path}: no such scene file")
    raise SceneError(f"{name_or_path!r} is neither a scene file nor an example scene{did_you_mean(name_or_path, ex)}"
                     f"; examples: {', '.join(ex)} (modalfem run --list)")


def plan_scene(name_or_path, *, progress=None) -> str:
    """The step plan of a scene: which stages run, in order, for which bodies (builds its world)."""
    from modalfem.scene.build import build_scene
    from modalfem.scene.load import load_scene

    path = find_scene(name_or_path)
    scene, base = load_scene(path)
    built = build_scene(scene, base, label=path.name, progress=progress, check_start=False)
    return built.world.describe_plan()


@dataclass
class RunResult:
    """What a run did: the output folder, the summary (as written to summary.json), whether it was interrupted."""

    out: Path
    summary: dict
    interrupted: bool


class _Ticker:
    """The step loop's countable progress on the command line's progress lines (``modalfem.cli._Progress``):
    steps, steps/s, simulated time, ETA; redrawn at most every 0.2 s on a terminal, every ~10 % in a log."""

    def __init__(self, progress, total: int, dt: float) -> None:
        self.progress, self.total, self.dt = progress, total, dt
        self.t0 = time.perf_counter()
        self.last = 0.0
        self.next_tenth = 1

    def __call__(self, done: int) -> None:
        now = time.perf_counter()
        final = done == self.total
        if not final and (now - self.last < 0.2 if self.progress.live else done * 10 < self.next_tenth * self.total):
            return
        self.last = now
        self.next_tenth = done * 10 // self.total + 1
        rate = done / max(now - self.t0, 1e-9)
        self.progress.bar(done, self.total, f"steps  {rate:,.0f} steps/s  t = {done * self.dt:.3f} s  "
                                            f"ETA {(self.total - done) / rate:.0f} s")


def run_scene(name_or_path, out, *, quiet: bool = False, stream=None, max_steps: int | None = None,
              interrupt_after: int | None = None) -> RunResult:
    """Run a scene file (or example name) into folder ``out``.

    Args:
        name_or_path: a scene file or the name of an example scene.
        out: the output folder (replaced as a whole at the end; an existing one must be a run folder).
        quiet: no progress output.
        max_steps: stop after this many steps (tests; the summary says how far it got).
        interrupt_after: raise KeyboardInterrupt after this many steps (tests of Ctrl-C).

    Raises:
        SceneError: a bad scene (one line with the file and key path); nothing is written.
    """
    from modalfem.cli import _Progress
    from modalfem.output.staging import check_targets
    from modalfem.scene.load import load_scene

    path = find_scene(name_or_path)
    scene, base = load_scene(path)
    out = Path(out)
    check_targets(out_dir=out, out_files=RUN_FILES)

    progress = _Progress(quiet=quiet, stream=stream)
    try:
        return _run(path, scene, base, out, progress, max_steps, interrupt_after)
    finally:
        progress.close()


def _run(path: Path, scene, base: Path, out: Path, progress, max_steps, interrupt_after) -> RunResult:
    from modalfem.output.staging import OutputSet
    from modalfem.scene.build import build_scene

    t_build = time.perf_counter()
    built = build_scene(scene, base, label=path.name, progress=progress)
    t_build = time.perf_counter() - t_build
    o = scene.outputs
    recording = o.paraview or o.video != "none" or o.gltf or o.sound
    interrupted = False
    with OutputSet() as outputs:
        folder = outputs.folder(out)
        recorder = None
        if recording:
            from modalfem.scene.record import Recorder

            recorder = Recorder(built.world, folder, paraview=o.paraview, video=None if o.video == "none" else o.video,
                                video_size=tuple(o.video_size), gltf=o.gltf, sound=o.sound,
                                frame_rate=scene.time.frame_rate, camera=o.camera.model_dump(exclude_none=True),
                                progress=progress)
        steps = built.steps if max_steps is None else min(built.steps, max_steps)
        progress(f"simulating {steps * built.dt:.4g} s in {steps} steps of {built.dt:g} s")
        bar = _Ticker(progress, steps, built.dt)
        log = _Log(built, scene)
        state = built.state
        world = built.world
        strikes = list(built.strikes)
        control = world.control()
        done = 0
        t_run = time.perf_counter()
        stop = _Interrupt()
        try:
            log.frame(state, 0, recorder)
            for k in range(steps):
                if stop.requested or (interrupt_after is not None and k == interrupt_after):
                    raise KeyboardInterrupt
                control.clear()
                t0 = state.time
                while strikes and strikes[0][0] < t0 + built.dt * (1 - 1e-9):
                    _, body, vertex, J = strikes.pop(0)
                    control.add_impulse(body, vertex, J)
                report = world.step(state, state, control, built.dt)
                log.step(report)
                done = k + 1
                if done % built.frame_every == 0:
                    log.frame(state, done, recorder)
                bar(done)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            stop.restore()
        wall = time.perf_counter() - t_run
        files = recorder.finish(interrupted=interrupted) if recorder is not None else {}
        if recorder is not None:  # a Ctrl-C between the recorder's frame and the log's: keep what both have
            log.trim(recorder.frame_count)
        summary = log.summary(path, state, done, steps, wall, t_build, files, interrupted)
        (folder / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
        (folder / "scene.toml").write_bytes(path.read_bytes())
        (folder / "plan.txt").write_text(world.describe_plan() + "\n")
        outputs.commit()
    frames = summary["frames"]
    if interrupted:
        progress.done(f"interrupted at t = {state.time:.4g} s after {done} of {steps} steps: the {frames} frames written so "
                f"far are complete and valid in {out}/")
    else:
        progress.done(f"done: {done} steps in {wall:.1f} s ({done / max(wall, 1e-9):,.0f} steps/s), {frames} frames -> "
                f"{out}/")
    return RunResult(out, summary, interrupted)


class _Interrupt:
    """Ctrl-C during the steps asks the loop to stop after the step at hand (a KeyboardInterrupt raised inside a
    compiled kernel surfaces as a SystemError and would lose the run); a second Ctrl-C stops at once."""

    def __init__(self) -> None:
        import signal
        import threading

        self.requested = False
        self._old = None
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handle)

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def restore(self) -> None:
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
            self._old = None


class _Log:
    """Per-step and per-frame records for the summary."""

    def __init__(self, built, scene) -> None:
        self.built, self.scene = built, scene
        self.world = built.world
        self.names = [b.name for b in scene.bodies]
        self.seconds: dict[str, float] = {}
        self.contacts: dict[str, list] = {}
        self.exchanged = np.zeros(3)
        self.exchanged_abs = 0.0
        self.times, self.energy = [], {n: [] for n in self.names}
        self.momentum = {n: [] for n in self.names}
        self.checks = []  # (time, count)
        self.frame_count = 0
        self.start = None

    def step(self, report) -> None:
        for k, v in report.seconds.items():
            self.seconds[k] = self.seconds.get(k, 0.0) + v
        for k, v in report.contacts.items():
            self.contacts.setdefault(k, []).append(int(v))
        for _a, _b, J, _ in report.exchanged:
            self.exchanged_abs += float(np.linalg.norm(J))

    def frame(self, state, step: int, recorder) -> None:
        if recorder is not None:
            recorder.frame(state)
        if self.frame_count == 0:
            self.start_energy = {n: self.world.energy(state, n) for n in self.names}
        self.frame_count += 1
        self.times.append(state.time)
        for n in self.names:
            self.energy[n].append(self.world.energy(state, n)["total"])
            self.momentum[n].append(self.world.momentum(state, n)[0].tolist())
        every = self.scene.outputs.check_every
        if every and (self.frame_count - 1) % every == 0:
            hits = self.world.intersections(state)
            self.checks.append((state.time, sum(k for _, _, k in hits), [[a, b, k] for a, b, k in hits]))

    def trim(self, frames: int) -> None:
        """Keep the first ``frames`` frames' records."""
        self.frame_count = min(self.frame_count, frames)
        del self.times[self.frame_count:]
        for n in self.names:
            del self.energy[n][self.frame_count:]
            del self.momentum[n][self.frame_count:]
        self.checks = [c for c in self.checks if self.times and c[0] <= self.times[-1]]

    def summary(self, path: Path, state, done: int, steps: int, wall: float, t_build: float, files: dict,
                interrupted: bool) -> dict:
        from modalfem.output.summary import jsonable, versions

        sc = self.scene
        bodies = {}
        for b in sc.bodies:
            n = b.name
            e = np.asarray(self.energy[n])
            end = self.world.energy(state, n)  # the last step's state (the last frame may be earlier)
            model = self.world.by_name[n].model
            entry = {"kind": b.kind,
                     "mass_kg": float(model.mass) if b.kind == "modal" else float(np.sum(model.masses)),
                     "energy_start_J": e[0], "energy_end_J": end["total"], "energy_max_J": max(e.max(), end["total"]),
                     "energy_start": self.start_energy[n], "energy_end": end,
                     "momentum_start": self.momentum[n][0], "momentum_end": self.world.momentum(state, n)[0],
                     "vertices": len(self.world.surface(state, n)[0])}
            if b.kind == "modal":
                model = self.world.by_name[n].model
                entry["model"] = self.built.cached.get(n)
                entry["frequencies_hz"] = (model.omega / (2 * np.pi)).tolist()
            bodies[n] = entry
        sound = {}
        for n in getattr(self.world, "_sounds", {}):
            sound[n] = _peaks(self.world.sound(n), self.world.by_name[n].model, state.time)
        return jsonable({
            "format": SUMMARY_FORMAT,
            "scene": sc.name or path.stem,
            "file": str(path),
            "schema": sc.schema_,
            "interrupted": interrupted,
            "plan": [str(s) for s in self.world.plan],
            "time": {"dt": self.built.dt, "duration": sc.time.duration, "steps": steps, "steps_run": done,
                     "simulated": state.time, "frame_rate": sc.time.frame_rate},
            "frames": self.frame_count,
            "frame_times": self.times,
            "wall_seconds": {"build": t_build, "run": wall, "stages": self.seconds,
                             "steps_per_second": done / wall if wall > 0 else None},
            "contacts": {k: {"max": max(v), "mean": float(np.mean(v))} for k, v in self.contacts.items()},
            "bodies": bodies,
            "energy": {"times": self.times, "total_J": {n: self.energy[n] for n in self.names}},
            "momentum": {"times": self.times, "linear_kg_m_s": {n: self.momentum[n] for n in self.names}},
            "exchanged_impulse_Ns": self.exchanged_abs,
            "intersections": {"checked_frames": len(self.checks), "total": sum(c for _, c, _ in self.checks),
                              "found": [[t, c, pairs] for t, c, pairs in self.checks if c]},
            "sound": sound,
            "outputs": files,
            "versions": versions(),
        })


def _peaks(snd, model, duration: float, count: int = 3, segment: float = 0.25) -> dict:
    """The strongest spectral peaks [Hz] of a body's sound and the model frequency nearest to each.

    The sound is the scene's time and 1 s of ringing after it; its spectrum is Welch's average of Hann-windowed
    ``segment`` [s] pieces overlapping by half (bins of 1 / segment = 4 Hz). A single long FFT resolves finer,
    but the many small impacts of a resting body each restart its modes with another phase, and their sum ripples
    across every line on a scale of one over the time between them: local maxima in a line's skirt, several
    line widths off its mode, that are not peaks of the sound. Peaks are local maxima, strongest first, that
    stand above the window's sidelobes of every stronger peak."""
    x = np.asarray(snd.render(duration + 1.0), dtype=np.float64)
    rate = float(snd.sample_rate)
    out = {"sample_rate": rate, "samples": len(x), "peak_pa": float(np.max(np.abs(x))) if len(x) else 0.0}
    n = min(len(x), max(64, int(round(segment * rate))))
    if len(x) < 64 or not np.any(x):
        out["peaks_hz"], out["nearest_mode_hz"], out["bin_hz"] = [], [], rate / max(n, 1)
        return out
    win = np.hanning(n)
    starts = range(0, len(x) - n + 1, max(n // 2, 1))
    power = np.mean([np.abs(np.fft.rfft(x[i:i + n] * win)) ** 2 for i in starts], axis=0)
    spec = np.sqrt(power)
    freqs = np.fft.rfftfreq(n, 1.0 / rate)
    inner = spec[1:-1]
    cands = np.flatnonzero((inner >= spec[:-2]) & (inner > spec[2:])) + 1
    kept: list[int] = []
    for i in cands[np.argsort(spec[cands])[::-1]]:
        # a Hann window leaks a line of amplitude A into the bin k away as at most A / (pi k (k^2 - 1)) (k >= 2):
        # a maximum under twice that from a stronger peak is its sidelobe; within 2 bins it is the same line
        if all(abs(int(i) - j) >= 2 and spec[i] > 2.0 * spec[j] / (np.pi * abs(int(i) - j) * ((int(i) - j) ** 2 - 1))
               for j in kept):
            kept.append(int(i))
        if len(kept) == count:
            break
    found = [float(freqs[i]) for i in kept]
    f_modes = model.omega / (2 * np.pi)
    out["peaks_hz"] = found
    out["bin_hz"] = rate / n
    out["nearest_mode_hz"] = [float(f_modes[np.argmin(np.abs(f_modes - f))]) for f in found]
    return out
