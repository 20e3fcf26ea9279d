"""Offscreen pictures of a moving, deforming surface: frames, an animated GIF, a frame sheet, a spectrum.

Rendering uses matplotlib's Agg canvas (no display) with our own fixed camera, drawn in 2-D:

* orthographic projection along the view direction given by ``elev`` / ``azim`` [deg] (z up);
* back faces culled, the rest painted far to near (painter's algorithm on triangle centroids);
* Lambert shading by the deformed triangle normal: ``ambient + (1 - ambient) max(n . l, 0)`` with a
  key light above and to the left of the camera;
* a checkered ground plane ``z = ground_z`` with the body's vertical (noon) shadow, so height above
  the ground and bounces read at a glance;
* the same camera and limits for every frame.

``write_gif`` builds one palette for all frames (no flicker) and writes with pillow; every writer
is atomic (temporary file in the target directory + ``os.replace``). ``plot_spectrum`` draws the
waveform, the magnitude spectrum with the model frequencies marked (kept and dropped modes) and a
spectrogram of a sound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from modalfem.atomic import write_atomic
from modalfem.errors import InputError

__all__ = ["Camera", "fit_camera", "plot_spectrum", "render_frames", "write_frame_sheet", "write_gif"]

_BRONZE = (0.80, 0.58, 0.26)


@dataclass(frozen=True)
class Camera:
    """A fixed orthographic camera.

    Attributes:
        center: world point at the middle of the picture (3,) [m].
        half_width: half of the visible width [m].
        elev: elevation of the view direction above the ground [deg], in (0, 90].
        azim: azimuth of the view direction about +z [deg] (0: looking from +x towards -x).
    """

    center: tuple
    half_width: float
    elev: float = 20.0
    azim: float = -60.0

    def __post_init__(self) -> None:
        c = np.asarray(self.center, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise InputError(f"camera center must be a finite 3-vector [m], got {self.center!r}")
        if not (math.isfinite(self.half_width) and self.half_width > 0):
            raise InputError(f"camera half_width must be > 0 m, got {self.half_width!r}")
        if not (math.isfinite(self.elev) and 0 < self.elev <= 90 and math.isfinite(self.azim)):
            raise InputError(f"camera elev must be in (0, 90] deg and azim finite, got {self.elev!r}, {self.azim!r}")
        object.__setattr__(self, "center", tuple(float(x) for x in c))

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Screen right, screen up and the unit vector towards the camera, each (3,)."""
        e, a = math.radians(self.elev), math.radians(self.azim)
        view = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        right = np.array([-math.sin(a), math.cos(a), 0.0])
        return right, np.cross(view, right), view


def fit_camera(frames, *, elev: float = 20.0, azim: float = -60.0, ground_z: float | None = 0.0,
               margin: float = 1.15, aspect: float = 4 / 3) -> Camera:
    """A camera that keeps every vertex of every frame (and its shadow on the ground) in the picture.

    Args:
        frames: vertex positions (F, nv, 3) [m] (or a list of (nv, 3) arrays).
        elev, azim: view direction [deg] (see ``Camera``).
        ground_z: ground height [m], or None for no ground (then shadows are not fitted).
        margin: factor >= 1 on the fitted extent.
        aspect: picture width / height.

    Returns:
        ``Camera``.

    Raises:
        InputError: malformed frames, margin < 1 or aspect <= 0.
    """
    if not (math.isfinite(margin) and margin >= 1 and math.isfinite(aspect) and aspect > 0):
        raise InputError(f"margin must be >= 1 and aspect > 0, got {margin!r}, {aspect!r}")
    pts = _frames(frames).reshape(-1, 3)
    if ground_z is not None:
        pts = np.vstack([pts, np.column_stack([pts[:, :2], np.full(len(pts), float(ground_z))])])
    probe = Camera(center=tuple(pts.mean(axis=0)), half_width=1.0, elev=elev, azim=azim)
    right, up, view = probe.basis()
    x, y = pts @ right, pts @ up
    cx, cy = 0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max())
    half = max(0.5 * (x.max() - x.min()), 0.5 * (y.max() - y.min()) * aspect, 1e-9) * margin
    center = cx * right + cy * up + (pts.mean(axis=0) @ view) * view
    return Camera(center=tuple(center), half_width=float(half), elev=elev, azim=azim)


def render_frames(frames, triangles, *, camera: Camera | None = None, ground_z: float | None = 0.0,
                  size: tuple = (480, 360), color=_BRONZE, labels=None, ambient: float = 0.35) -> np.ndarray:
    """Render a deforming triangle surface offscreen, one image per frame.

    Args:
        frames: world vertex positions (F, nv, 3) [m] (or a list of (nv, 3) arrays).
        triangles: (nt, 3) indices, outward oriented (right-hand rule).
        camera: fixed camera; default ``fit_camera(frames, ground_z=ground_z)``.
        ground_z: height of the ground plane z = ground_z [m], or None for no ground.
        size: picture (width, height) [px].
        color: RGB base colour of the body, components in [0, 1].
        labels: optional text per frame (e.g. the time), drawn in the top-left corner.
        ambient: ambient light fraction in [0, 1].

    Returns:
        images (F, height, width, 3) uint8.

    Raises:
        InputError: malformed frames or triangles, bad size, labels, colour or ambient.
    """
    from matplotlib.backends.backend_agg import (
        FigureCanvasAgg,  # no pyplot: no global backend state
    )
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    X = _frames(frames)
    tri = np.asarray(triangles)
    if tri.ndim != 2 or tri.shape[1] != 3 or tri.dtype.kind not in "iu" or tri.min() < 0 or tri.max() >= X.shape[1]:
        raise InputError(f"triangles must be (nt, 3) integer indices into {X.shape[1]} vertices")
    w, h = _size(size)
    base = np.asarray(color, dtype=np.float64).reshape(-1)
    if base.shape != (3,) or np.any(base < 0) or np.any(base > 1):
        raise InputError(f"color must be an RGB triple in [0, 1], got {color!r}")
    if labels is not None and len(labels) != len(X):
        raise InputError(f"labels must have one entry per frame ({len(X)}), got {len(labels)}")
    if not 0 <= ambient <= 1:
        raise InputError(f"ambient must be in [0, 1], got {ambient!r}")
    cam = camera or fit_camera(X, ground_z=ground_z, aspect=w / h)
    right, up, view = cam.basis()
    center = np.asarray(cam.center)
    light = _unit(view + 0.6 * up - 0.5 * right)
    hw, hh = cam.half_width, cam.half_width * h / w

    fig = Figure(figsize=(w / 100, h / 100), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_xlim(-hw, hw)
    ax.set_ylim(-hh, hh)
    fig.patch.set_facecolor((0.93, 0.95, 0.98))

    def project(p):
        d = p - center
        return np.stack([d @ right, d @ up], axis=-1)

    if ground_z is not None:
        ground, tones = _ground_tiles(center, cam.half_width, float(ground_z), cam.elev)
        ax.add_collection(PolyCollection(project(ground), facecolors=tones, edgecolors="none", zorder=0))
    shadow = PolyCollection([], facecolors=(0.45, 0.47, 0.50), edgecolors=(0.45, 0.47, 0.50), linewidths=0.3,
                            zorder=1)
    body = PolyCollection([], linewidths=0.3, zorder=2)
    text = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", ha="left", fontsize=10, color="0.15", zorder=3)
    ax.add_collection(shadow)
    ax.add_collection(body)
    for artist in (shadow, body, text):
        artist.set_animated(True)  # not part of the background: drawn per frame on top of it

    canvas.draw()  # the static part (background, ground) once; per frame only the body is drawn on it
    background = canvas.copy_from_bbox(fig.bbox)
    images = np.empty((len(X), h, w, 3), dtype=np.uint8)
    for k, x in enumerate(X):
        p = x[tri]  # (nt, 3, 3)
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        front = np.flatnonzero(n @ view > 0)
        order = front[np.argsort(p[front].mean(axis=1) @ view)]  # far to near
        shade = ambient + (1 - ambient) * np.clip(n[order] @ light, 0.0, 1.0)
        rgb = np.clip(shade[:, None] * base, 0, 1)
        body.set_verts(project(p[order]))
        body.set_facecolor(rgb)
        body.set_edgecolor(rgb)
        canvas.restore_region(background)
        if ground_z is not None:
            top = np.flatnonzero(n[:, 2] > 0)
            flat = p[top].copy()
            flat[..., 2] = float(ground_z)
            shadow.set_verts(project(flat))
            ax.draw_artist(shadow)
        ax.draw_artist(body)
        if labels is not None:
            text.set_text(str(labels[k]))
            ax.draw_artist(text)
        images[k] = np.asarray(canvas.buffer_rgba())[..., :3]
    return images


def _ground_tiles(center: np.ndarray, half_width: float, z: float, elev: float) -> tuple[np.ndarray, np.ndarray]:
    """Checker squares (m, 4, 3) [m] covering the view on the plane z, and their colours (m, 3)."""
    tile = 10 ** math.floor(math.log10(half_width / 2))
    tile *= 5 if half_width / tile > 20 else (2 if half_width / tile > 8 else 1)
    reach = half_width * (1.5 + 1.0 / math.sin(math.radians(elev)))  # ground seen up to the top edge
    n = min(int(math.ceil(reach / tile)), 60)
    i0, j0 = int(round(center[0] / tile)), int(round(center[1] / tile))
    ii, jj = np.meshgrid(np.arange(i0 - n, i0 + n), np.arange(j0 - n, j0 + n), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    corners = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], dtype=np.float64)
    xy = (np.stack([ii, jj], axis=1)[:, None, :] + corners[None]) * tile
    squares = np.concatenate([xy, np.full(xy.shape[:2] + (1,), z)], axis=2)
    tones = np.where(((ii + jj) % 2 == 0)[:, None], (0.80, 0.82, 0.80), (0.70, 0.72, 0.70))
    return squares, tones


def write_gif(path, images, *, fps: float = 25.0) -> None:
    """Write frames as a looping animated GIF atomically (one shared palette).

    Args:
        path: target ``.gif`` file; its directory must exist.
        images: (F, height, width, 3) uint8 frames, F >= 1.
        fps: frames per second, > 0.

    Raises:
        InputError: malformed images, bad fps, or the file cannot be written.
    """
    from PIL import Image

    imgs = _images(images)
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be > 0, got {fps!r}")
    step = max(1, len(imgs) // 8)
    mosaic = Image.fromarray(np.concatenate(list(imgs[::step]), axis=0))  # palette from a sample of frames
    palette = mosaic.quantize(colors=255, method=Image.Quantize.MEDIANCUT)
    frames = [Image.fromarray(im).quantize(palette=palette, dither=Image.Dither.NONE) for im in imgs]
    duration = int(round(1000 / fps))
    _atomic(path, lambda f: frames[0].save(f, format="GIF", save_all=True, append_images=frames[1:],
                                           duration=duration, loop=0, optimize=False), "GIF")


def write_frame_sheet(path, images, *, columns: int = 4, labels=None) -> None:
    """Write a PNG sheet of frames (row-major grid, ``columns`` per row) atomically.

    Args:
        path: target ``.png`` file; its directory must exist.
        images: (F, height, width, 3) uint8 frames.
        columns: frames per row, >= 1.
        labels: optional caption per frame.

    Raises:
        InputError: malformed images or labels, or the file cannot be written.
    """
    from PIL import Image, ImageDraw

    imgs = _images(images)
    if not isinstance(columns, int) or columns < 1:
        raise InputError(f"columns must be an integer >= 1, got {columns!r}")
    if labels is not None and len(labels) != len(imgs):
        raise InputError(f"labels must have one entry per frame ({len(imgs)}), got {len(labels)}")
    f, h, w, _ = imgs.shape
    cols = min(columns, f)
    rows = -(-f // cols)
    sheet = Image.new("RGB", (cols * w + (cols + 1) * 4, rows * h + (rows + 1) * 4), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for k, im in enumerate(imgs):
        x, y = 4 + (k % cols) * (w + 4), 4 + (k // cols) * (h + 4)
        sheet.paste(Image.fromarray(im), (x, y))
        if labels is not None:
            draw.text((x + 6, y + h - 16), str(labels[k]), fill=(20, 20, 20))
    _atomic(path, lambda fh: sheet.save(fh, format="PNG"), "PNG")


def plot_spectrum(path, signal, sample_rate: int, *, model_hz=(), dropped_hz=(), f_max_hz: float | None = 20000.0,
                  title: str = "", peaks_hz=(), ylabel: str = "signal") -> None:
    """Write a PNG with the waveform, the magnitude spectrum and a spectrogram of a sound.

    Args:
        path: target ``.png`` file; its directory must exist.
        signal: samples (n,) (e.g. pressure [Pa]).
        sample_rate: [1/s].
        model_hz: frequencies [Hz] of the synthesised modes, marked as grey ticks on the spectrum.
        dropped_hz: frequencies [Hz] of modes dropped by the band limit, marked red (if in view).
        f_max_hz: band limit [Hz] shaded on the spectrum, or None.
        title: figure title.
        peaks_hz: measured spectral peaks [Hz] to mark with dots.
        ylabel: label of the waveform axis, e.g. ``"pressure at 1 m [Pa]"``.

    Raises:
        InputError: empty or non-finite signal, bad sample rate, or the file cannot be written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1 or len(x) < 16 or not np.all(np.isfinite(x)):
        raise InputError("spectrum signal must be a finite 1-D array of at least 16 samples")
    if not isinstance(sample_rate, (int, np.integer)) or sample_rate <= 0:
        raise InputError(f"sample_rate must be a positive integer [1/s], got {sample_rate!r}")
    fs = int(sample_rate)
    n = 1 << int(math.ceil(math.log2(len(x)))) + 1
    X = np.abs(np.fft.rfft(x, n=n))
    f = np.fft.rfftfreq(n, 1 / fs)
    db = 20 * np.log10(np.maximum(X / max(X.max(), 1e-300), 1e-12))

    fig = Figure(figsize=(10, 8), dpi=100, constrained_layout=True)
    FigureCanvasAgg(fig)
    a1, a2, a3 = fig.subplots(3, 1, gridspec_kw={"height_ratios": [1, 1.4, 1.4]})
    t = np.arange(len(x)) / fs
    a1.plot(t, x, lw=0.4, color="C0")
    a1.set_xlim(0, t[-1])
    a1.set_xlabel("time [s]")
    a1.set_ylabel(ylabel)
    a2.plot(f / 1e3, db, lw=0.6, color="C0")
    for fm in np.asarray(model_hz, dtype=float):
        a2.axvline(fm / 1e3, ymin=0.93, ymax=1.0, color="0.35", lw=0.8)
    for fd in np.asarray(dropped_hz, dtype=float):
        if fd < fs / 2:
            a2.axvline(fd / 1e3, ymin=0.93, ymax=1.0, color="C3", lw=0.8)
    pk = np.asarray(peaks_hz, dtype=float)
    if len(pk):
        a2.plot(pk / 1e3, np.interp(pk, f, db), "o", ms=3, color="C1", label="measured peaks")
        a2.legend(loc="lower left", fontsize=8)
    if f_max_hz is not None and f_max_hz < fs / 2:
        a2.axvspan(f_max_hz / 1e3, fs / 2e3, color="C3", alpha=0.08)
        a2.text(f_max_hz / 1e3, -112, " band limit", color="C3", fontsize=8, va="bottom")
    a2.set_xlim(0, fs / 2e3)
    a2.set_ylim(-120, 5)
    a2.set_xlabel("frequency [kHz]   (ticks: model modes, grey kept, red dropped)")
    a2.set_ylabel("magnitude [dB]")
    nfft, hop = 2048, 512  # spectrogram: Hann frames of 46 ms every 12 ms
    if len(x) >= nfft:
        starts = np.arange(0, len(x) - nfft + 1, hop)
        S = np.abs(np.fft.rfft(np.hanning(nfft) * x[starts[:, None] + np.arange(nfft)], axis=1))
        S_db = 20 * np.log10(np.maximum(S / max(S.max(), 1e-300), 1e-12))
        a3.imshow(S_db.T, origin="lower", aspect="auto", cmap="magma", vmin=-100, vmax=0, interpolation="nearest",
                  extent=(starts[0] / fs, (starts[-1] + nfft) / fs, 0, fs / 2e3))
    a3.set_xlim(0, t[-1])
    a3.set_xlabel("time [s]")
    a3.set_ylabel("frequency [kHz]")
    if title:
        fig.suptitle(title)
    _atomic(path, lambda fh: fig.savefig(fh, format="png"), "PNG")


# ------------------------------------------------------------------------------ helpers
def _frames(frames) -> np.ndarray:
    try:
        X = np.asarray(frames, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("frames must be vertex positions (F, nv, 3) [m]") from None
    if X.ndim == 2:
        X = X[None]
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[0] < 1 or X.shape[1] < 3:
        raise InputError(f"frames must be vertex positions (F, nv, 3) [m], got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise InputError("frames hold NaN/inf vertex positions")
    return X


def _images(images) -> np.ndarray:
    imgs = np.asarray(images)
    if imgs.ndim != 4 or imgs.shape[-1] != 3 or imgs.dtype != np.uint8 or len(imgs) < 1:
        raise InputError(f"images must be (F, height, width, 3) uint8, got {imgs.shape} {imgs.dtype}")
    return imgs


def _size(size) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise InputError(f"size must be (width, height) [px], got {size!r}") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise InputError(f"size must be between 16 and 4096 px per side, got {size!r}")
    return w, h


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _atomic(path, write, kind: str) -> None:
    """Call ``write(file object)`` on a temporary file next to ``path``, then rename it to ``path``."""
    write_atomic(path, write, error=InputError, kind=kind)
