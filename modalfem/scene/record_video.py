"""Preview video of a ``World``: a z-buffer rasteriser and streaming GIF / MP4 writers.

Every frame is drawn from one fixed orthographic camera: modal bodies bronze, tet bodies green, cloth blue
(both sides shaded), obstacles grey (moving ones where they are at the frame's time), the ground (and any
plane) a finite checkered patch, and a time stamp. Triangles are flat shaded (a directional light fixed to
the camera) and resolved per pixel by a compiled z-buffer (numba, cached on disk), so bodies in contact,
a cloth draped over a block and interpenetrating surfaces are drawn correctly, which a painter's sort by
triangle depth does not do. Colours are indices into one fixed 256-entry palette: a GIF frame needs no
quantisation and an MP4 frame is one palette lookup.

Both videos are written as the frames come (nothing is held in memory): the GIF through its own header
and per-frame blocks (each frame holds only the rectangle that changed since the previous one, LZW-encoded
by Pillow), the MP4 through a pipe to the ffmpeg of ``imageio-ffmpeg`` (H.264, yuv420p), started in its
own session so that a Ctrl-C in the terminal reaches only the simulation, which then closes the video
cleanly with the frames written so far.
"""

from __future__ import annotations

import io
import math
import struct
import subprocess
from pathlib import Path

import numba
import numpy as np

from modalfem.errors import InputError

__all__ = ["Camera", "FrameRenderer", "GifStream", "Mp4Stream", "checker_patch", "downsample", "ffmpeg_exe", "palette"]

#: palette: 0 background, 1 text, 2-3 checker squares, 4-5 the same in shadow, then four shade ramps of RAMP each
RAMP = 62
SHADOW = 4
KIND_BASE = {"modal": 6, "tet": 6 + RAMP, "cloth": 6 + 2 * RAMP, "obstacle": 6 + 3 * RAMP}
KIND_RGB = {"modal": (200, 150, 62), "tet": (90, 158, 90), "cloth": (79, 127, 196), "obstacle": (150, 150, 150)}
BACKGROUND, TEXT, CHECKER_LIGHT, CHECKER_DARK = (238, 241, 245), (20, 20, 20), (214, 214, 210), (178, 178, 172)
#: brightness of the ground in a shadow
SHADOW_DIM = 0.62
#: lowest shade (ambient) of a ramp, as a fraction of the base colour
AMBIENT = 0.4


def palette() -> np.ndarray:
    """The (256, 3) uint8 palette of every frame."""
    p = np.zeros((256, 3))
    p[0], p[1], p[2], p[3] = BACKGROUND, TEXT, CHECKER_LIGHT, CHECKER_DARK
    p[SHADOW], p[SHADOW + 1] = SHADOW_DIM * p[2], SHADOW_DIM * p[3]
    shade = AMBIENT + (1.0 - AMBIENT) * np.linspace(0.0, 1.0, RAMP)
    for kind, base in KIND_BASE.items():
        p[base:base + RAMP] = np.outer(shade, KIND_RGB[kind])
    return np.clip(np.round(p), 0, 255).astype(np.uint8)


class Camera:
    """A fixed orthographic camera: z up, matplotlib's ``elev`` / ``azim`` convention.

    Args:
        elev: elevation of the eye above the x-y plane [deg].
        azim: azimuth of the eye about z, from +x [deg].
        center: the point at the middle of the picture (3,) [m].
        half_width: half the picture's width in the scene [m].
        size: picture (width, height) [px].
    """

    def __init__(self, *, elev: float, azim: float, center, half_width: float, size: tuple[int, int]) -> None:
        e, a = math.radians(elev), math.radians(azim)
        self.elev, self.azim = float(elev), float(azim)
        self.eye = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        self.right = np.array([-math.sin(a), math.cos(a), 0.0])
        self.up = np.cross(self.eye, self.right)
        self.center = np.asarray(center, dtype=np.float64).reshape(3)
        self.half_width = float(half_width)
        self.size = (int(size[0]), int(size[1]))
        light = 0.3 * self.right + 0.5 * self.up + 0.8 * self.eye
        self.light = light / np.linalg.norm(light)

    def project(self, x: np.ndarray) -> np.ndarray:
        """Pixel coordinates and depth (k, 3): column, row (0 at the top) [px], nearness [m]."""
        W, H = self.size
        s = 0.5 * W / self.half_width
        d = np.asarray(x, dtype=np.float64) - self.center
        out = np.empty((len(d), 3))
        out[:, 0] = 0.5 * W + s * (d @ self.right)
        out[:, 1] = 0.5 * H - s * (d @ self.up)
        out[:, 2] = d @ self.eye
        return out

    def describe(self) -> dict:
        """The camera as the scene's ``camera`` table takes it."""
        return {"elev": self.elev, "azim": self.azim, "center": self.center.tolist(), "half_width": self.half_width}

    @classmethod
    def fit(cls, boxes: list, planes: list, *, elev: float, azim: float, size: tuple[int, int],
            margin: float = 0.15) -> Camera:
        """A camera whose picture holds every box ``(lo (3,), hi (3,))`` [m] and the foot point on each plane
        ``(point, normal)`` below the boxes' centre, plus ``margin`` of the picture on each side."""
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        mid = 0.5 * (lo + hi)
        pts = [lo, hi]
        for p, n in planes:
            pts.append(mid - n * ((mid - p) @ n))
        lo, hi = np.min(pts, axis=0), np.max(pts, axis=0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        c = 0.5 * (lo + hi)
        probe = cls(elev=elev, azim=azim, center=c, half_width=1.0, size=size)
        d = corners - c
        W, H = size
        half = max(np.abs(d @ probe.right).max(), np.abs(d @ probe.up).max() * W / H, 1e-6)
        return cls(elev=elev, azim=azim, center=c, half_width=half * (1.0 + 2.0 * margin), size=size)


#: barycentric slack of the pixel test (closes cracks between triangles sharing an edge)
EDGE = 1e-7


@numba.njit(cache=True)
def _rasterise(p, tris, colour, depth, image, shadow, dim):  # pragma: no cover - compiled
    """Flat triangles ``tris`` (k, 3) over projected points ``p`` (n, 3) into ``image`` with ``depth``; with
    ``shadow`` the pixels they cover in front of what is drawn become ``dim[pixel]`` (depth unchanged)."""
    H, W = image.shape
    for k in range(tris.shape[0]):
        a, b, c = tris[k, 0], tris[k, 1], tris[k, 2]
        x0, y0, z0 = p[a, 0], p[a, 1], p[a, 2]
        x1, y1, z1 = p[b, 0], p[b, 1], p[b, 2]
        x2, y2, z2 = p[c, 0], p[c, 1], p[c, 2]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        inv = 1.0 / area
        xmin = max(math.floor(min(x0, min(x1, x2))), 0)
        xmax = min(math.ceil(max(x0, max(x1, x2))), W - 1)
        ymin = max(math.floor(min(y0, min(y1, y2))), 0)
        ymax = min(math.ceil(max(y0, max(y1, y2))), H - 1)
        col = colour[k]
        # barycentric weights are linear along a row: w_i = c_i + d_i x (x the pixel column); each row visits
        # only the columns where all three are >= 0 (a thin diagonal triangle's box is mostly empty)
        d0, d1 = (y1 - y2) * inv, (y2 - y0) * inv
        d2 = -d0 - d1
        for y in range(ymin, ymax + 1):
            yc = y + 0.5
            c0 = ((x1 - 0.5) * (y2 - yc) - (x2 - 0.5) * (y1 - yc)) * inv
            c1 = ((x2 - 0.5) * (y0 - yc) - (x0 - 0.5) * (y2 - yc)) * inv
            c2 = 1.0 - c0 - c1
            lo, hi = float(xmin), float(xmax)
            for ci, di in ((c0, d0), (c1, d1), (c2, d2)):
                if di > 0.0:
                    lo = max(lo, (-EDGE - ci) / di)
                elif di < 0.0:
                    hi = min(hi, (-EDGE - ci) / di)
                elif ci < -EDGE:
                    hi = lo - 1.0
            if not lo <= hi:
                continue
            for x in range(math.ceil(lo), math.floor(hi) + 1):
                w0, w1 = c0 + d0 * x, c1 + d1 * x
                w2 = 1.0 - w0 - w1
                if w0 < -EDGE or w1 < -EDGE or w2 < -EDGE:
                    continue
                z = w0 * z0 + w1 * z1 + w2 * z2
                if z > depth[y, x]:
                    if shadow:
                        image[y, x] = dim[image[y, x]]
                    else:
                        depth[y, x] = z
                        image[y, x] = col


@numba.njit(cache=True)
def _average2(image, pal, out):  # pragma: no cover - compiled
    """``out`` (H, W, 3) uint8: the mean colour of each 2 x 2 block of palette image ``image`` (2H, 2W)."""
    H, W = out.shape[0], out.shape[1]
    for y in range(H):
        for x in range(W):
            for c in range(3):
                s = (np.int32(pal[image[2 * y, 2 * x], c]) + pal[image[2 * y, 2 * x + 1], c]
                     + pal[image[2 * y + 1, 2 * x], c] + pal[image[2 * y + 1, 2 * x + 1], c])
                out[y, x, c] = (s + 2) // 4


def downsample(image: np.ndarray, pal: np.ndarray) -> np.ndarray:
    """RGB (H, W, 3) uint8 of a palette image (2H, 2W) drawn at twice the size: each pixel the mean of its four
    (anti-aliased edges)."""
    out = np.empty((image.shape[0] // 2, image.shape[1] // 2, 3), dtype=np.uint8)
    _average2(image, pal, out)
    return out


def _nice(x: float) -> float:
    """The number of the form {1, 2, 5} x 10^k nearest below ``x`` > 0."""
    e = 10.0 ** math.floor(math.log10(x))
    return max(m * e for m in (1.0, 2.0, 5.0) if m * e <= x)


def _edges(lo: float, hi: float, sq: float) -> tuple[np.ndarray, np.ndarray]:
    """Square edges from ``lo`` to ``hi`` on the grid of size ``sq`` (partial squares at both ends), and the grid
    index of each square."""
    inner = np.arange(math.floor(lo / sq) + 1, math.ceil(hi / sq)) * sq
    e = np.concatenate([[lo], inner[(inner > lo + 1e-9 * sq) & (inner < hi - 1e-9 * sq)], [hi]])
    return e, np.floor(0.5 * (e[:-1] + e[1:]) / sq).astype(np.int64)


def checker_patch(point, normal, center, half: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A square checkered patch of half-width ``half`` [m] of a plane, centred on ``center``'s foot point:
    vertices (n, 3) [m], triangles (k, 3) and their palette colours (k,) (squares of a round size, about 10
    across, fixed to the plane: they stay put when the patch moves)."""
    n = np.asarray(normal, dtype=np.float64)
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    foot = np.asarray(center, dtype=np.float64) - n * ((center - np.asarray(point)) @ n)
    sq = _nice(2.0 * half / 10.0)
    ua, ia = _edges(foot @ a - half, foot @ a + half, sq)
    ub, ib = _edges(foot @ b - half, foot @ b + half, sq)
    na, nb = len(ia), len(ib)
    off = n * float(np.asarray(point) @ n)
    V = (off + ua[:, None, None] * a + ub[None, :, None] * b).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(na), np.arange(nb), indexing="ij")
    v00 = (i * (nb + 1) + j).reshape(-1)
    F = np.concatenate([np.stack([v00, v00 + nb + 1, v00 + nb + 2], 1), np.stack([v00, v00 + nb + 2, v00 + 1], 1)])
    parity = ((ia[i] + ib[j]) % 2).reshape(-1)
    colour = np.where(np.concatenate([parity, parity]) == 0, 2, 3).astype(np.uint8)
    return V, F.astype(np.int64), colour


class FrameRenderer:
    """Draws frames of a world into palette images (H, W) uint8 (``palette()`` gives the colours).

    Args:
        camera: the ``Camera``.
    """

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        W, H = camera.size
        self._depth = np.empty((H, W))
        self._image = np.empty((H, W), dtype=np.uint8)
        self._font = None
        self._static: tuple | None = None
        self._dim = np.arange(256, dtype=np.uint8)  # shadow: checker squares to their dim copies, the rest kept
        self._dim[2], self._dim[3] = SHADOW, SHADOW + 1
        self._none = np.zeros(0, dtype=np.uint8)

    def shade(self, x: np.ndarray, tris: np.ndarray, kind: str) -> np.ndarray:
        """Palette colours (k,) of triangles ``tris`` over ``x`` [m] of a ``kind`` body (or ``"obstacle"``):
        Lambert shading of the side that faces the camera."""
        t = x[tris]
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
        n *= np.where(n @ self.camera.eye < 0, -1.0, 1.0)[:, None]
        lam = np.clip(n @ self.camera.light, 0.0, 1.0)
        return (KIND_BASE[kind] + np.round(lam * (RAMP - 1))).astype(np.uint8)

    def shadow(self, x: np.ndarray, height: float) -> np.ndarray:
        """Vertices ``x`` (n, 3) [m] dropped vertically onto the ground at ``height`` [m]: drawn as a part with
        colours ``None``, they dim the ground's squares they cover (a shadow under a light straight above; lifted a
        little over the ground so it wins the depth test)."""
        out = np.array(x, dtype=np.float64)
        out[:, 2] = height + 2e-3 * self.camera.half_width
        return out

    def set_static(self, parts: list) -> None:
        """Draw ``parts`` (as ``draw`` takes them) once: every later frame starts from this picture (fixed
        obstacles and the ground seen by a fixed camera; at 1280 x 720 the ground patch alone cost ~6 ms)."""
        self._depth.fill(-np.inf)
        self._image.fill(0)
        self._raster(parts)
        self._static = (self._depth.copy(), self._image.copy())

    def _raster(self, parts: list) -> None:
        for x, tris, colour in parts:
            if len(tris):
                shadow = colour is None
                _rasterise(self.camera.project(x), np.ascontiguousarray(tris, dtype=np.int64),
                           self._none if shadow else np.ascontiguousarray(colour, dtype=np.uint8), self._depth,
                           self._image, shadow, self._dim)

    def draw(self, parts: list, label: str) -> np.ndarray:
        """Rasterise ``parts``, a list of ``(vertices (n, 3) [m], triangles (k, 3), colours (k,) uint8 or None for a
        shadow)``, over the static picture and write ``label`` at the top left. Returns the image (H, W) uint8
        (reused by the next call)."""
        if self._static is None:
            self._depth.fill(-np.inf)
            self._image.fill(0)
        else:
            np.copyto(self._depth, self._static[0])
            np.copyto(self._image, self._static[1])
        self._raster(parts)
        self._label(label)
        return self._image

    def _label(self, text: str) -> None:
        from PIL import Image, ImageDraw, ImageFont

        H = self._image.shape[0]
        if self._font is None:
            try:
                self._font = ImageFont.load_default(size=max(11, H // 24))
            except (TypeError, OSError, ImportError):  # Pillow < 10.1 or no FreeType: the bitmap font
                self._font = ImageFont.load_default()
        # the label's box only: a small image, pasted back (drawing on the whole frame copies it twice)
        w, h = min(self._image.shape[1], 16 * len(text) + 16), min(H, max(11, H // 24) * 2 + 8)
        box = Image.frombytes("P", (w, h), np.ascontiguousarray(self._image[:h, :w]).tobytes())
        ImageDraw.Draw(box).text((8, 6), text, fill=1, font=self._font)  # P mode: no anti-aliased ink
        self._image[:h, :w] = np.asarray(box, dtype=np.uint8).reshape(h, w)


def ffmpeg_exe() -> str:
    """The ffmpeg executable of ``imageio-ffmpeg``.

    Raises:
        InputError: ``imageio-ffmpeg`` is not installed (the message says how to install it).
    """
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        raise InputError("MP4 video needs an encoder: pip install imageio-ffmpeg (or ask for video = \"gif\")"
                         ) from None


class GifStream:
    """An animated GIF written frame by frame (looping, one global palette).

    Each frame is the rectangle that changed since the previous frame (the first: the whole picture), its
    delay the rounded frame times in 1/100 s (GIF's unit: 30 frames/s alternates 3 and 4). ``close`` ends
    the file; ``close(frames=k)`` first cuts it after frame k (frames started after an interrupt).

    Args:
        path: the .gif file (created).
        size: (width, height) [px].
        frame_rate: frames per second of the video.
    """

    def __init__(self, path: Path, size: tuple[int, int], frame_rate: float) -> None:
        self.path = Path(path)
        self.size = size
        self.frame_rate = float(frame_rate)
        self._pal = palette()
        self._prev: np.ndarray | None = None
        self.offsets: list[int] = []  # file length after each complete frame
        self._f = open(self.path, "wb")  # noqa: SIM115 - open across frames, closed by close()
        W, H = size
        head = b"GIF89a" + struct.pack("<HHBBB", W, H, 0xF7, 0, 0) + self._pal.tobytes()
        head += b"\x21\xff\x0bNETSCAPE2.0\x03\x01\x00\x00\x00"  # loop forever
        self._f.write(head)
        self._f.flush()
        self._start = self._f.tell()

    @property
    def frame_count(self) -> int:
        return len(self.offsets)

    def _block(self, image: np.ndarray, x0: int, y0: int) -> bytes:
        """The image descriptor and LZW data of ``image`` placed at (x0, y0) (Pillow encodes a one-frame GIF,
        whose blocks after its header are copied)."""
        from PIL import Image

        h, w = image.shape
        im = Image.frombytes("P", (w, h), np.ascontiguousarray(image).tobytes())
        im.putpalette(self._pal.tobytes())
        buf = io.BytesIO()
        im.save(buf, format="GIF", optimize=False)
        data = buf.getvalue()
        flags = data[10]
        i = 13 + (3 * 2 ** ((flags & 7) + 1) if flags & 0x80 else 0)
        while data[i] == 0x21:  # skip extensions (Pillow's own control block)
            i += 2
            while data[i]:
                i += data[i] + 1
            i += 1
        if data[i] != 0x2C:
            raise RuntimeError("unexpected GIF block from Pillow")
        end = len(data) - 1 if data[-1] == 0x3B else len(data)
        block = bytearray(data[i:end])
        block[1:5] = struct.pack("<HH", x0, y0)
        return bytes(block)

    def write(self, image: np.ndarray) -> None:
        """Append frame ``image`` (H, W) of palette indices."""
        k = len(self.offsets)
        delay = round(100 * (k + 1) / self.frame_rate) - round(100 * k / self.frame_rate)
        if self._prev is None:
            x0, y0, sub = 0, 0, image
        else:
            changed = image != self._prev
            rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
            if len(rows) == 0:
                x0, y0, sub = 0, 0, image[:1, :1]
            else:
                y0, x0 = int(rows[0]), int(cols[0])
                sub = image[y0:rows[-1] + 1, x0:cols[-1] + 1]
        control = b"\x21\xf9\x04\x04" + struct.pack("<H", max(delay, 1)) + b"\x00\x00"  # dispose: keep
        data = control + self._block(sub, x0, y0)
        self._prev = image.copy()
        self._f.write(data)
        self.offsets.append(self._f.tell())

    def close(self, frames: int | None = None) -> None:
        """End the file after ``frames`` frames (default all written)."""
        if self._f.closed:
            return
        k = len(self.offsets) if frames is None else min(frames, len(self.offsets))
        self._f.flush()
        self._f.truncate(self.offsets[k - 1] if k else self._start)
        self._f.seek(0, 2)
        self._f.write(b"\x3b")
        self._f.close()
        del self.offsets[k:]


class Mp4Stream:
    """An H.264 MP4 (yuv420p, ``-movflags +faststart``) written through a pipe to ffmpeg.

    Args:
        path: the .mp4 file.
        size: (width, height) [px], both even.
        frame_rate: frames per second.
    """

    def __init__(self, path: Path, size: tuple[int, int], frame_rate: float) -> None:
        self.path = Path(path)
        self.size = size
        self.frame_count = 0
        W, H = size
        cmd = [ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{W}x{H}",
               "-r", f"{frame_rate:.6g}", "-i", "-", "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "20",
               "-preset", "veryfast", "-movflags", "+faststart", str(self.path)]
        # own session: a terminal Ctrl-C interrupts the simulation, not the encoder, which is closed cleanly
        try:
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.PIPE, start_new_session=True)
        except OSError as exc:
            raise InputError(f"cannot start ffmpeg ({cmd[0]}): {exc.strerror or exc}") from None

    def write(self, rgb: np.ndarray) -> None:
        """Append frame ``rgb`` (H, W, 3) uint8."""
        try:
            self._proc.stdin.write(np.ascontiguousarray(rgb).tobytes())
        except BrokenPipeError:
            raise InputError(f"ffmpeg stopped while writing {self.path.name}: "
                             f"{self._proc.stderr.read().decode(errors='replace').strip()[:300]}") from None
        self.frame_count += 1

    def close(self) -> None:
        """Finish the file (ffmpeg writes its index) and wait for the encoder."""
        if self._proc.stdin.closed:
            return
        self._proc.stdin.close()
        err = self._proc.stderr.read().decode(errors="replace").strip()
        if self._proc.wait() != 0:
            raise InputError(f"ffmpeg could not write {self.path.name}: {err[:300]}")

    def kill(self) -> None:
        """Stop the encoder without finishing the file."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
