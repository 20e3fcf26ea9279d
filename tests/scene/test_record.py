"""The output writers of ``modalfem run`` (modalfem.scene.record): ParaView series, GIF / MP4 preview, WAV, glTF.

One small world (a struck free steel bar, a soft tet block, a 6 x 6 cloth, the ground and a sphere moving on a
path) runs 20 steps of 1 ms with a frame every 5 steps; two recorders watch it (GIF + everything, MP4 only).
Every check reads the files back with other tools (meshio, Pillow, ffmpeg, wave, pygltflib) and compares with the
world's states, which the test keeps.
"""

from __future__ import annotations

import functools
import math
import struct
import sys
import wave
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import modalfem
from modalfem import world as mw
from modalfem.effects import Contact, Gravity, Sound
from modalfem.errors import InputError
from modalfem.scene.record import SOUND_TAIL, Recorder

DT, STEPS, EVERY = 1e-3, 20, 5
SIZE = (320, 180)


@functools.lru_cache(maxsize=1)
def _models():
    from modalfem import tet
    from modalfem.cloth.mesh import grid
    from modalfem.cloth.model import ClothModel
    from modalfem.cloth.scenes import MATERIAL
    from modalfem.material import Material
    from modalfem.mesh import box
    from modalfem.model import ModalModel

    mesh = box(size=(0.2, 0.1, 0.05), cells=(4, 2, 2))
    res = modalfem.modes(mesh, modalfem.STEEL, k=8, degree=1, backend="skfem", solver="scipy")
    bar = ModalModel.from_modes(res, mesh, modalfem.STEEL, damping=(0.0, 1e-7))
    block = tet.tet_model(box(size=(0.1, 0.1, 0.05), cells=(2, 2, 1)), Material(E=1e5, nu=0.3, rho=500.0))
    cloth = ClothModel(grid((0.2, 0.2), (5, 5)), MATERIAL, mass_damping=0.1)  # 6 x 6 vertices
    return bar, block, cloth


def _world():
    bar, block, cloth = _models()
    return mw.World(
        bodies=[mw.Modal(bar, name="bar", position=(0.0, 0.0, 0.1), angular_velocity=(0.0, 0.0, 2.0)),
                mw.Tet(block, name="block", position=(0.2, 0.0, 0.0), velocity=(0.0, 0.5, 0.0)),
                mw.Cloth(cloth, name="cloth", x0=cloth.mesh.points + (-0.1, 0.1, 0.2))],
        obstacles=[mw.Ground(0.0), mw.Sphere((0.0, 0.25, 0.05), 0.05, path=[(0, (0, 0, 0)), (1, (0.5, 0, 0))])],
        effects=[Gravity(), Contact(), Sound(bodies=["bar"])])


def _run(world, recorders, *, steps=STEPS, stop_after=None):
    """Step the world, a frame every EVERY steps; returns the states of the frames."""
    s = world.state()
    states = []
    for i in range(steps + 1):
        if i % EVERY == 0:
            if stop_after is not None and len(states) == stop_after:
                break
            states.append(s.copy())
            for r in recorders:
                r.frame(s)
        if i == steps:
            break
        c = world.control().add_impulse("bar", 3, (0.0, 0.0, -0.05)) if i == 2 else None
        world.step(s, s, c, DT)
    return states


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    world = _world()
    gif = tmp_path_factory.mktemp("gif")
    rec = Recorder(world, gif, video="gif", video_size=SIZE)
    recorders, mp4 = [rec], None
    try:
        import imageio_ffmpeg  # noqa: F401

        mp4 = tmp_path_factory.mktemp("mp4")
        recorders.append(Recorder(world, mp4, video="mp4", video_size=SIZE, paraview=False, gltf=False, sound=False))
    except ImportError:
        pass
    states = _run(world, recorders)
    files = [r.finish() for r in recorders]
    return {"world": world, "states": states, "gif": gif, "files": files[0], "rec": rec, "mp4": mp4,
            "mp4_files": files[1] if mp4 else None}


# ----------------------------------------------------------------------------- ParaView
def _pvd(path):
    rows = [(float(d.get("timestep")), d.get("name"), d.get("file")) for d in ET.parse(path).iter("DataSet")]
    times = sorted({t for t, _, _ in rows})
    return rows, times


def _modal_velocity_by_motion(world, state, name, h=1e-6):
    """Vertex velocities of a modal body as the change of its positions along the state's own rates (q', c', w)
    over a short time h: an independent route to v + w x r + R Phi q'."""
    from modalfem.runtime.rotation import quat_from_axis_angle, quat_multiply

    body = world._modal[name]["body"]
    s = state.bodies[name]
    s1 = s.copy()
    s1.q = s.q + h * s.qdot
    s1.position = s.position + h * s.velocity
    w = body.angular_velocity(s)
    if np.linalg.norm(w) > 0:
        s1.orientation = quat_multiply(quat_from_axis_angle(w / np.linalg.norm(w), h * np.linalg.norm(w)),
                                       s.orientation)
    return (body.positions(s1, precise=True) - body.positions(s, precise=True)) / h


def test_the_pvd_lists_every_frame_and_every_file_reads_back_with_the_states_velocities(recorded):
    import meshio

    world, states, folder = recorded["world"], recorded["states"], recorded["gif"]
    rows, times = _pvd(folder / "scene.pvd")
    assert len(states) == STEPS // EVERY + 1
    assert np.allclose(times, [s.time for s in states], rtol=0, atol=1e-15)
    assert np.all(np.diff(times) > 0)
    listed = {f for _, _, f in rows}
    assert listed <= set(recorded["files"]["paraview"])
    for k, (t, s) in enumerate(zip(times, states)):
        parts = {n: f for tt, n, f in rows if tt == t}
        assert set(parts) == {"bar", "block", "cloth", "ground0", "sphere1"}
        for b in world.bodies:
            m = meshio.read(folder / parts[b.name])
            x, tris = world.surface(s, b.name)
            assert m.points.shape == x.shape and np.array_equal(m.cells_dict["triangle"], tris)
            assert np.allclose(m.points, x, rtol=0, atol=1e-12)
            v = m.point_data["velocity"]
            if b.kind == "modal":
                ref = _modal_velocity_by_motion(world, s, b.name)
                scale = np.abs(ref).max()
                assert scale > 0.1  # spinning at 2 rad/s and struck
                # the difference quotient is first order: its error is ~h |acceleration|, far below 1e-4 m/s
                assert np.abs(v - ref).max() <= 1e-4 * scale
            elif b.kind == "tet":
                assert np.array_equal(v, s[b.name].v[world._tet[b.name]["surface"]])
            else:
                assert np.array_equal(v, s[b.name].v)
            d = m.point_data["displacement"]
            assert np.allclose(d, np.linalg.norm(x - world.surface(states[0], b.name)[0], axis=1), atol=1e-12)
        sphere = meshio.read(folder / parts["sphere1"])
        V, _ = world.obstacles[1].surface(t)
        assert np.allclose(sphere.points, V, atol=1e-12)  # the moving sphere where it is at the frame's time
    assert rows[0][2] != rows[-1][2]
    assert all((folder / f).is_file() for f in listed)


def test_the_modal_body_carries_its_elastic_deformation(recorded):
    import meshio

    world, states, folder = recorded["world"], recorded["states"], recorded["gif"]
    body = world._modal["bar"]["body"]
    last = meshio.read(folder / "paraview" / f"bar_{len(states) - 1:05d}.vtu")
    u = (states[-1]["bar"].q @ body.shapes_t).reshape(-1, 3)
    assert np.abs(states[-1]["bar"].q).max() > 0  # struck
    assert np.allclose(last.point_data["deformation"], np.linalg.norm(u, axis=1), rtol=1e-12, atol=1e-18)


# ----------------------------------------------------------------------------- video
def _project(camera: dict, x: np.ndarray, size) -> np.ndarray:
    """Orthographic projection from the camera's description (z up; matplotlib's elev / azim)."""
    e, a = math.radians(camera["elev"]), math.radians(camera["azim"])
    eye = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    right = np.array([-math.sin(a), math.cos(a), 0.0])
    up = np.cross(eye, right)
    d = x - np.asarray(camera["center"])
    s = 0.5 * size[0] / camera["half_width"]
    return np.stack([0.5 * size[0] + s * (d @ right), 0.5 * size[1] - s * (d @ up)], axis=1)


def _hue_masks(rgb: np.ndarray, margin: int) -> dict:
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return {"modal": (r > g + margin) & (g > b + margin),  # bronze
            "tet": (g > r + margin) & (g > b + margin),  # green
            "cloth": (b > r + margin) & (b > g + margin)}  # blue


def _check_frames(frames, recorded, margin, pad=2):
    world, states = recorded["world"], recorded["states"]
    camera = recorded["rec"].camera.describe()
    assert len(frames) == len(states)
    for rgb, s in zip(frames, states):
        assert rgb.shape == (SIZE[1], SIZE[0], 3)
        masks = _hue_masks(rgb, margin)
        for b in world.bodies:
            p = _project(camera, world.surface(s, b.name)[0], SIZE)
            lo, hi = np.floor(p.min(0)).astype(int) - pad, np.ceil(p.max(0)).astype(int) + pad
            inside = np.zeros(rgb.shape[:2], dtype=bool)
            inside[max(lo[1], 0):hi[1] + 1, max(lo[0], 0):hi[0] + 1] = True
            m = masks[b.kind]
            assert m[inside].sum() >= 20, f"{b.name} not drawn where it projects"
            assert not m[~inside].any(), f"{b.kind} colour outside {b.name}'s projection"


def test_the_gif_has_every_frame_at_its_size_with_each_body_where_it_projects(recorded):
    from PIL import Image, ImageSequence

    path = recorded["gif"] / "preview.gif"
    assert recorded["files"]["video"] == ["preview.gif"]
    with Image.open(path) as im:
        assert im.size == SIZE
        frames = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]
        durations = [f.info["duration"] for f in ImageSequence.Iterator(im)]
    _check_frames(frames, recorded, margin=8)
    # 30 frames/s in GIF's 1/100 s: 3 and 4 alternating, never drifting more than half a unit
    assert set(durations) <= {30, 40}
    assert abs(sum(durations) - 1000 * len(frames) / 30) <= 5


def _mp4_frames(path):
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    w, h = meta["size"]
    return meta, [np.frombuffer(f, dtype=np.uint8).reshape(h, w, 3) for f in gen]


def test_the_mp4_has_every_frame_at_its_size_with_each_body_where_it_projects(recorded):
    if recorded["mp4"] is None:
        pytest.skip("imageio-ffmpeg is not installed (pip install imageio-ffmpeg)")
    assert recorded["mp4_files"]["video"] == ["preview.mp4"]
    assert recorded["mp4_files"]["paraview"] == [] and not (recorded["mp4"] / "scene.pvd").exists()
    meta, frames = _mp4_frames(recorded["mp4"] / "preview.mp4")
    assert tuple(meta["size"]) == SIZE and abs(meta["fps"] - 30.0) < 1e-6
    _check_frames(frames, recorded, margin=25, pad=4)  # H.264 / yuv420p smears colour a little at edges


# ----------------------------------------------------------------------------- sound
def test_the_wav_rings_at_a_mode_of_the_struck_bar_and_lasts_to_the_decay(recorded):
    world, folder = recorded["world"], recorded["gif"]
    assert recorded["files"]["sound"] == ["sound/bar.wav", "sound/mix.wav"]
    snd = world.sound("bar")
    with wave.open(str(folder / "sound" / "bar.wav")) as w:
        fs, n, width = w.getframerate(), w.getnframes(), w.getsampwidth()
        x = np.frombuffer(w.readframes(n), dtype="<i2").astype(float)
    assert fs == snd.sample_rate and width == 2
    slowest = float(np.min(snd.mu[snd.band.kept]))
    tail = min(SOUND_TAIL, math.log(1000.0) / slowest)
    assert n == round((recorded["states"][-1].time + tail) * fs)
    assert abs(np.abs(x).max() / 32767 - 10 ** (-3 / 20)) < 1e-3  # -3 dBFS peak
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    f = np.fft.rfftfreq(len(x), 1.0 / fs)
    peak = f[np.argmax(spec)]
    assert np.min(np.abs(snd.kept_hz - peak)) <= 2 * fs / len(x)
    with wave.open(str(folder / "sound" / "mix.wav")) as w:
        mix = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
    assert np.array_equal(mix, x.astype("<i2"))  # one sounding body: the mix is that body at the same gain
    levels = recorded["rec"].sound_levels
    assert levels["mix"]["gain_per_pa"] == pytest.approx(levels["bar"]["gain_per_pa"], rel=1e-12)


# ----------------------------------------------------------------------------- glTF
def _accessor(g, blob: bytes, i: int) -> np.ndarray:
    a = g.accessors[i]
    v = g.bufferViews[a.bufferView]
    dtype = {5126: "<f4", 5123: "<u2", 5125: "<u4"}[a.componentType]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[a.type]
    start = (v.byteOffset or 0) + (a.byteOffset or 0)
    out = np.frombuffer(blob, dtype=dtype, count=a.count * width, offset=start)
    return out.reshape(a.count, width) if width > 1 else out


def _quat_matrix(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_the_glb_has_one_animation_at_the_frame_times_that_replays_every_body(recorded):
    import pygltflib

    from modalfem.scene.record_gltf import TOLERANCE

    world, states = recorded["world"], recorded["states"]
    g = pygltflib.GLTF2().load(str(recorded["gif"] / "scene.glb"))
    blob = g.binary_blob()
    assert len(g.animations) == 1
    anim = g.animations[0]
    inputs = {anim.samplers[c.sampler].input for c in anim.channels}
    assert len(inputs) == 1
    times = _accessor(g, blob, inputs.pop())
    assert np.allclose(times, [s.time for s in states], rtol=1e-7, atol=0)
    names = {n.name: i for i, n in enumerate(g.nodes)}
    assert {"bar", "block", "cloth", "ground0", "sphere1"} <= set(names)
    root = _quat_matrix(g.nodes[0].rotation)  # z up -> y up
    tracks = {(c.target.node, c.target.path): _accessor(g, blob, anim.samplers[c.sampler].output)
              for c in anim.channels}
    for b in world.bodies:
        i = names[b.name]
        prim = g.meshes[g.nodes[i].mesh].primitives[0]
        base = _accessor(g, blob, prim.attributes.POSITION).astype(float)
        T = np.array([_accessor(g, blob, t["POSITION"]) for t in (prim.targets or [])], dtype=float)
        W = tracks.get((i, "weights"))
        W = np.zeros((len(states), 0)) if W is None else W.reshape(len(states), len(T))
        assert W.min() >= 0 and W.max() <= 1  # Blender's shape keys clamp below 0
        tris = _accessor(g, blob, prim.indices).reshape(-1, 3)
        for k, s in enumerate(states):
            x = base + np.einsum("k,kvc->vc", W[k], T) if len(T) else base.copy()
            if (i, "rotation") in tracks:
                x = x @ _quat_matrix(tracks[(i, "rotation")][k]).T + tracks[(i, "translation")][k]
            ref, ref_tris = world.surface(s, b.name)
            size = np.linalg.norm(np.ptp(ref, axis=0))
            if b.kind == "modal":  # vertices split at creases: compare triangle corners
                corners, ref_corners = x[tris].reshape(-1, 3), ref[ref_tris].reshape(-1, 3)
                assert np.abs(corners - ref_corners).max() <= 1e-6 * size  # float32 storage
            else:
                assert np.array_equal(tris, ref_tris)
                assert np.linalg.norm(x - ref, axis=1).max() <= TOLERANCE * size * 1.01 + 1e-6 * size
            assert np.allclose((x @ root.T)[:, 1], x[:, 2], atol=1e-6)  # the file's y is the scene's z
    sphere = tracks[(names["sphere1"], "translation")]
    assert np.allclose(sphere, [world.obstacles[1].offset(s.time) for s in states], atol=1e-7)


# ----------------------------------------------------------------------------- interrupts and bad input
def _check_consistent(folder, files, frames):
    import pygltflib
    from PIL import Image

    rows, times = _pvd(folder / "scene.pvd")
    assert len(times) == frames
    on_disk = {p.relative_to(folder).as_posix() for p in (folder / "paraview").rglob("*") if p.is_file()}
    assert on_disk == set(files["paraview"]) - {"scene.pvd"} == {f for _, _, f in rows}
    with Image.open(folder / "preview.gif") as im:
        assert im.n_frames == frames
    g = pygltflib.GLTF2().load(str(folder / "scene.glb"))
    assert g.accessors[g.animations[0].samplers[0].input].count == frames
    with wave.open(str(folder / "sound" / "bar.wav")) as w:
        assert w.getnframes() > round(times[-1] * w.getframerate())


def test_an_interrupt_after_two_frames_leaves_a_consistent_set(tmp_path):
    world = _world()
    rec = Recorder(world, tmp_path, video_size=SIZE)
    _run(world, [rec], stop_after=2)
    files = rec.finish(interrupted=True)
    assert rec.frame_count == 2
    _check_consistent(tmp_path, files, 2)


def test_an_interrupt_inside_a_frame_drops_that_frame_everywhere(tmp_path, monkeypatch):
    from modalfem.scene import record_gltf

    world = _world()
    rec = Recorder(world, tmp_path, video_size=SIZE)
    calls = []
    orig = record_gltf.GltfAnimation.add

    def add(self, state, surfaces):  # the third frame is interrupted after its ParaView files and GIF frame
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        orig(self, state, surfaces)

    monkeypatch.setattr(record_gltf.GltfAnimation, "add", add)
    with pytest.raises(KeyboardInterrupt):
        _run(world, [rec])
    assert (tmp_path / "paraview" / "bar_00002.vtu").exists()
    files = rec.finish(interrupted=True)
    assert rec.frame_count == 2 and not (tmp_path / "paraview" / "bar_00002.vtu").exists()
    _check_consistent(tmp_path, files, 2)


def test_an_interrupted_mp4_holds_the_frames_recorded(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="MP4 needs imageio-ffmpeg")
    world = _world()
    rec = Recorder(world, tmp_path, video="mp4", video_size=SIZE, paraview=False, gltf=False, sound=False)
    _run(world, [rec], stop_after=3)
    assert rec.finish(interrupted=True)["video"] == ["preview.mp4"]
    _, frames = _mp4_frames(tmp_path / "preview.mp4")
    assert len(frames) == 3


def test_mp4_without_an_encoder_is_refused_before_any_frame(tmp_path, monkeypatch):
    world = _world()
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails
    with pytest.raises(InputError, match="pip install imageio-ffmpeg"):
        Recorder(world, tmp_path, video="mp4")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("kw, msg", [
    ({"video": "avi"}, "video must be"),
    ({"video_size": (641, 360), "video": "mp4"}, "even width and height"),
    ({"video_size": (8, 8)}, "16..4096"),
    ({"video_size": "big"}, "two whole numbers"),
    ({"frame_rate": 0}, "frame_rate"),
    ({"camera": {"zoom": 2}}, "unknown camera key"),
    ({"camera": {"center": [0, 0]}}, "camera center"),
    ({"camera": {"half_width": -1}}, "half_width"),
])
def test_bad_options_get_one_line(tmp_path, kw, msg):
    pytest.importorskip("imageio_ffmpeg") if kw.get("video") == "mp4" else None
    world = _world()
    with pytest.raises(InputError, match=msg) as e:
        Recorder(world, tmp_path, **kw)
    assert "\n" not in str(e.value)


def test_a_missing_folder_is_refused(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        Recorder(_world(), tmp_path / "nowhere")


def test_a_given_camera_is_kept(tmp_path):
    world = _world()
    cam = {"elev": 40.0, "azim": 30.0, "center": [0.1, 0.0, 0.05], "half_width": 0.5}
    rec = Recorder(world, tmp_path, video_size=SIZE, paraview=False, gltf=False, sound=False, camera=cam)
    rec.frame(world.state())
    rec.finish()
    assert rec.camera.describe() == cam
    assert struct.unpack("<HH", (tmp_path / "preview.gif").read_bytes()[6:10]) == SIZE


@pytest.mark.parametrize("video", ["gif", "mp4"])
def test_an_interrupt_inside_the_first_frame_leaves_nothing(tmp_path, monkeypatch, video):
    from modalfem.scene import record_gltf

    if video == "mp4":
        pytest.importorskip("imageio_ffmpeg", reason="MP4 needs imageio-ffmpeg")

    def add(self, state, surfaces):
        raise KeyboardInterrupt

    monkeypatch.setattr(record_gltf.GltfAnimation, "add", add)
    world = _world()
    rec = Recorder(world, tmp_path, video_size=SIZE, video=video)
    with pytest.raises(KeyboardInterrupt):
        rec.frame(world.state())
    assert (tmp_path / "paraview").is_dir()  # (ffmpeg creates the MP4 file when its first frame comes)
    assert rec.finish(interrupted=True) == {"paraview": [], "video": [], "sound": [], "gltf": []}
    assert rec.frame_count == 0 and not any(tmp_path.iterdir())


def test_a_file_that_cannot_be_written_gets_one_line(tmp_path, monkeypatch):
    from modalfem.scene import record_vtk

    def full(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(record_vtk, "_write_vtu", full)
    world = _world()
    rec = Recorder(world, tmp_path, video=None, gltf=False, sound=False)
    with pytest.raises(InputError, match="cannot write output frame 0 .*No space left on device") as e:
        rec.frame(world.state())
    assert "\n" not in str(e.value)


def test_the_default_camera_holds_every_body_and_the_ground_below_at_the_start(recorded):
    world, s0 = recorded["world"], recorded["states"][0]
    camera = recorded["rec"].camera.describe()
    pts = np.concatenate([world.surface(s0, b.name)[0] for b in world.bodies])
    p = _project(camera, pts, SIZE)
    assert p.min() > 0 and np.all(p.max(0) < SIZE)
    foot = pts.mean(0) * (1, 1, 0)  # the ground under the bodies
    q = _project(camera, foot[None], SIZE)[0]
    assert 0 < q[0] < SIZE[0] and 0 < q[1] < SIZE[1]
    # the margin: the bodies fill most of the picture but touch no edge
    span = (p.max(0) - p.min(0)) / SIZE
    assert span.max() > 0.4


def test_principal_targets_reproduce_a_low_rank_motion_with_its_rank_and_meet_the_tolerance():
    from modalfem.scene.record_gltf import principal_targets

    rng = np.random.default_rng(1)
    modes = rng.normal(size=(2, 50, 3))
    t = np.linspace(0, 1, 30)
    D = np.einsum("fk,kvc->fvc", np.stack([np.sin(3 * t), t**2], 1), modes)
    T, W, err = principal_targets(D, 1e-9)
    assert len(T) == 2 and err <= 1e-9 and np.allclose(W @ T.reshape(2, -1), D.reshape(30, -1), atol=1e-12)
    noisy = D + 1e-3 * rng.normal(size=D.shape)
    T, W, err = principal_targets(noisy, 0.01)
    resid = noisy - (W @ T.reshape(len(T), -1)).reshape(noisy.shape)
    assert err <= 0.01 and np.isclose(np.linalg.norm(resid, axis=2).max(), err)
    assert 2 <= len(T) < 30
    few = D[:, :4]  # more frames than coordinates: the plain SVD path
    T, W, err = principal_targets(few, 1e-9)
    assert len(T) == 2 and np.allclose(W @ T.reshape(2, -1), few.reshape(30, -1), atol=1e-12)
    T, W, err = principal_targets(np.zeros((4, 5, 3)), 1e-3)
    assert T.shape == (0, 5, 3) and W.shape == (4, 0) and err == 0.0


def test_a_wall_seen_from_behind_is_not_drawn_and_a_small_plane_keeps_its_size(tmp_path):
    from PIL import Image

    bar, _, _ = _models()
    # between the camera (azim -60: looking from -y, +x) and the bar, a wall whose free side faces the bar
    front = np.array([np.cos(np.radians(-60)), np.sin(np.radians(-60)), 0.0])
    world = mw.World(bodies=[mw.Modal(bar, name="bar", position=(0.0, 0.0, 0.1))],
                     obstacles=[mw.Ground(0.0), mw.Plane(-front, 0.3 * front, size=10.0),
                                mw.Plane((0.0, 0.0, 1.0), (0.0, 0.0, 0.3), size=0.05)])
    rec = Recorder(world, tmp_path, video_size=SIZE, gltf=False, sound=False)
    rec.frame(world.state())
    rec.finish()
    with Image.open(tmp_path / "preview.gif") as im:
        rgb = np.asarray(im.convert("RGB"))
    assert _hue_masks(rgb, 8)["modal"].sum() > 100  # the wall did not hide the bar
    import meshio

    small = meshio.read(tmp_path / "paraview" / "obstacles" / "plane2.vtu").points
    assert np.allclose(small.min(0), (-0.05, -0.05, 0.3)) and np.allclose(small.max(0), (0.05, 0.05, 0.3))
    wall = meshio.read(tmp_path / "paraview" / "obstacles" / "plane1.vtu").points
    assert np.allclose((wall - 0.3 * front) @ front, 0.0, atol=1e-12)  # the big wall: a patch on its plane
