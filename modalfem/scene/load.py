"""Reading a scene file: TOML -> a validated ``Scene``, or one line naming the file, the key and the problem.

``load_scene(path)`` reads the TOML (``tomllib``), checks the schema version first (a newer file is refused
with the version it needs), validates strictly (``modalfem.scene.schema``) and then checks what a schema
cannot: referenced files exist, body names are unique, effects and events name existing bodies, path
waypoints increase. Every problem is a ``SceneError`` whose message is one line:

    scene.toml: bodies[2].material.nu: must be < 0.5 (Poisson's ratio [-], in (-1, 0.5)), got 0.6
    scene.toml: effects[0].kind: unknown effect 'gravty' (did you mean 'gravity'?); one of gravity, wind, ...
    scene.toml: bodies[0].restitusion: unknown key (did you mean 'position'?)
"""

from __future__ import annotations

import itertools
import re
import typing
from pathlib import Path
from types import NoneType, UnionType

import tomllib
from pydantic import BaseModel, ValidationError

from modalfem.errors import SceneError
from modalfem.scene.schema import SCHEMA, SCHEMA_VERSION, Scene, did_you_mean

__all__ = ["load_scene", "scene_from_text"]

_WHAT = {"bodies": "body kind", "obstacles": "obstacle kind", "effects": "effect", "events": "event",
         "mesh": "mesh generator"}


def load_scene(path) -> tuple[Scene, Path]:
    """Read and validate scene file ``path``; returns the scene and the folder its relative paths start from.

    Raises:
        SceneError: unreadable file, bad TOML, a newer schema, any invalid key or value, missing files.
    """
    p = Path(path)
    label = p.name
    if not p.is_file():
        raise SceneError(f"{p}: no such scene file" + ("" if not p.exists() else " (it is a folder)"))
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{label}: cannot read: {exc}") from None
    return scene_from_text(text, label=label, base=p.parent.resolve()), p.parent.resolve()


def scene_from_text(text: str, *, label: str = "scene", base: Path | None = None) -> Scene:
    """Validate the TOML ``text`` of a scene (``label`` names it in messages; files resolve against ``base``)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{label}: not valid TOML: {exc}") from None
    version = data.get("schema")
    if version is None:
        raise SceneError(f"{label}: missing key 'schema' (the first line of a scene file is schema = \"{SCHEMA}\")")
    if not isinstance(version, str) or not re.fullmatch(r"modalfem\.scene/\d+", version):
        raise SceneError(f"{label}: schema: expected \"{SCHEMA}\", got {version!r}")
    n = int(version.split("/")[1])
    if n > SCHEMA_VERSION:
        raise SceneError(f"{label}: schema: {version} is newer than this modalfem reads ({SCHEMA}); upgrade modalfem")
    if n < 1:
        raise SceneError(f"{label}: schema: expected \"{SCHEMA}\", got {version!r}")
    try:
        scene = Scene.model_validate(data)
    except ValidationError as exc:
        # a misspelt key or kind first: a "missing" error is often its consequence
        order = {"extra_forbidden": 0, "union_tag_invalid": 1, "union_tag_not_found": 1}
        errors = sorted(exc.errors(), key=lambda e: order.get(e["type"], 2))
        more = f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})" if len(errors) > 1 else ""
        raise SceneError(f"{label}: {_describe(errors[0], data)}{more}") from None
    _check(scene, label, base)
    return scene


# ---------------------------------------------------------------------------------------------- paths
def _unwrap(t):
    """``t`` without ``Annotated`` and ``Optional``; returns (type, tags of an Annotated wrapper)."""
    while True:
        origin = typing.get_origin(t)
        if origin is typing.Annotated:
            t = typing.get_args(t)[0]
            continue
        if origin in (typing.Union, UnionType):
            args = [a for a in typing.get_args(t) if a is not NoneType]
            if len(args) == 1:
                t = args[0]
                continue
        return t


def _tag(member) -> str | None:
    if typing.get_origin(member) is typing.Annotated:
        for meta in typing.get_args(member)[1:]:
            tag = getattr(meta, "tag", None)
            if isinstance(tag, str):
                return tag
        member = typing.get_args(member)[0]
    if isinstance(member, type) and issubclass(member, BaseModel):
        for key in ("kind", "generator"):
            f = member.model_fields.get(key)
            if f is not None and typing.get_origin(f.annotation) is typing.Literal:
                return typing.get_args(f.annotation)[0]
    return None


def _walk(loc: tuple):
    """The printable key path of pydantic location ``loc`` (union tags dropped) and the model it ends in."""
    out, model, _ = _walk_type(loc)
    return out, model


def _walk_type(loc: tuple):
    """``_walk`` and the (unwrapped) type at ``loc``."""
    t, out, model = Scene, "", Scene
    for el in loc:
        t = _unwrap(t)
        while typing.get_origin(t) in (typing.Union, UnionType):
            members = [m for m in typing.get_args(t) if m is not NoneType]
            hit = next((m for m in members if _tag(m) == el), None)
            if hit is None:
                break
            t = _unwrap(hit)
            el = None
            break
        if el is None:
            if isinstance(t, type) and issubclass(t, BaseModel):
                model = t
            continue
        if isinstance(el, int):
            out += f"[{el}]"
            if typing.get_origin(t) is list:
                t = typing.get_args(t)[0]
            continue
        out += f".{el}" if out else str(el)
        if isinstance(t, type) and issubclass(t, BaseModel):
            model = t
            field = t.model_fields.get(el) or next((f for f in t.model_fields.values() if f.alias == el), None)
            t = field.annotation if field is not None else None
            if field is not None and field.metadata:
                t = typing.Annotated[(t, *field.metadata)]
        else:
            t = None
    t = _unwrap(t)
    if isinstance(t, type) and issubclass(t, BaseModel):
        model = t
    return out, model, t


def _union_tags(loc: tuple) -> list:
    """The tags of the tagged union at ``loc`` (pydantic does not list them when the tag key is missing)."""
    t = _walk_type(loc)[2]
    if typing.get_origin(t) not in (typing.Union, UnionType):
        return []
    return [tag for tag in (_tag(m) for m in typing.get_args(t)) if tag is not None]


def _field_info(loc: tuple):
    """The pydantic FieldInfo of the last key of ``loc``, if it is a model field."""
    while loc and (isinstance(loc[-1], int) or _walk(loc)[0] == _walk(loc[:-1])[0]):
        loc = loc[:-1]  # an element of a list (the list's description), or a union member's tag
    _, model = _walk(tuple(loc[:-1]))
    key = loc[-1] if loc else None
    if isinstance(key, str) and isinstance(model, type) and issubclass(model, BaseModel):
        return model.model_fields.get(key)
    return None


def _keys(model) -> list:
    return [f.alias or k for k, f in model.model_fields.items()]


def _describe(err: dict, data) -> str:
    loc = tuple(err["loc"])
    kind = err["type"]
    path, _ = _walk(loc)
    if kind == "extra_forbidden":
        _, parent = _walk(loc[:-1])
        key = loc[-1]
        return f"{path}: unknown key{did_you_mean(key, _keys(parent))}; allowed: {', '.join(_keys(parent))}"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        ctx = err.get("ctx", {})
        field = ctx.get("discriminator", "'kind'").strip("'")
        tags = re.findall(r"'([^']*)'", ctx.get("expected_tags", "")) or _union_tags(loc)
        top = next((k for k in reversed([el for el in loc if isinstance(el, str)]) if k in _WHAT), "")
        what = _WHAT.get(top, field)
        where = f"{path}.{field}" if path else field
        if kind == "union_tag_not_found":
            return f"{where}: missing (one of {', '.join(tags)})"
        return (f"{where}: unknown {what} {ctx.get('tag')!r}{did_you_mean(ctx.get('tag'), tags)}; "
                f"one of {', '.join(tags)}")
    if kind == "missing":
        return f"{path}: missing required key"
    msg = err["msg"]
    if kind == "value_error":
        msg = msg.removeprefix("Value error, ")
    elif kind in ("model_type", "model_attributes_type", "dict_type"):
        msg = "must be a table"  # not pydantic's "a valid dictionary or instance of <class>"
    else:
        msg = msg[0].lower() + msg[1:]
        msg = msg.replace("input should be", "must be").replace(" after validation", "")
    info = _field_info(loc)
    unit = f" ({info.description})" if info is not None and info.description and kind not in ("value_error",) else ""
    got = err.get("input")
    shown = "" if kind == "value_error" or isinstance(got, (dict, list)) and len(str(got)) > 60 else f", got {got!r}"
    return f"{path}: {msg}{unit}{shown}"


# ---------------------------------------------------------------------------------------------- checks
def _check(scene: Scene, label: str, base: Path | None) -> None:
    def fail(path: str, problem: str):
        raise SceneError(f"{label}: {path}: {problem}")

    names = [b.name for b in scene.bodies]
    for i, b in enumerate(scene.bodies):
        if b.orientation is not None and not any(b.orientation):
            fail(f"bodies[{i}].orientation", "a quaternion must not be zero")
    for i, o in enumerate(scene.obstacles):
        if getattr(o, "rotation", None) is not None and not any(o.rotation):
            fail(f"obstacles[{i}].rotation", "a quaternion must not be zero")
    for i, name in enumerate(names):
        if name in names[:i]:
            fail(f"bodies[{i}].name", f"duplicate body name {name!r}")
    for i, b in enumerate(scene.bodies):
        if b.kind == "modal":
            if b.model is None and (b.mesh is None or b.material is None):
                fail(f"bodies[{i}]", "a modal body needs model = \"file.npz\", or mesh and material (its modes are "
                                     "computed and cached)")
            if b.model is not None and (b.mesh is not None or b.material is not None):
                fail(f"bodies[{i}]", "give model, or mesh + material, not both")
            if b.model is not None:
                _exists(fail, base, f"bodies[{i}].model", b.model)
        if b.kind == "cloth":
            if (b.grid is None) == (b.mesh is None):
                fail(f"bodies[{i}]", "a cloth needs exactly one of grid = {size, vertices} or mesh = \"file\"")
            if b.mesh is not None:
                _exists(fail, base, f"bodies[{i}].mesh", b.mesh)
            if b.pins and b.grid is None:
                pass
        mesh = getattr(b, "mesh", None)
        if b.kind in ("modal", "tet") and mesh is not None and hasattr(mesh, "file"):
            _exists(fail, base, f"bodies[{i}].mesh.file", mesh.file)
    for i, o in enumerate(scene.obstacles):
        if o.kind == "mesh":
            _exists(fail, base, f"obstacles[{i}].file", o.file)
        path = getattr(o, "path", None)
        if path:
            ts = [w.t for w in path]
            if any(b <= a for a, b in itertools.pairwise(ts)):
                fail(f"obstacles[{i}].path", f"waypoint times must increase, got {ts}")
        if o.kind == "plane" and not any(o.normal):
            fail(f"obstacles[{i}].normal", "must not be zero")
    kinds = {b.name: b.kind for b in scene.bodies}
    for i, e in enumerate(scene.effects):
        for j, n in enumerate(e.bodies or ()):
            if n not in kinds:
                fail(f"effects[{i}].bodies[{j}]", f"no body named {n!r}{did_you_mean(n, kinds)}; bodies: "
                                                   f"{', '.join(kinds)}")
        _kind_takes(fail, f"effects[{i}]", e, kinds)
    seen = {}
    for i, e in enumerate(scene.effects):
        for n in (e.bodies or [k for k in kinds if e.kind in _supported(kinds[k])]):
            if (e.kind, n) in seen:
                fail(f"effects[{i}]", f"a second {e.kind} effect on body {n!r} (effects[{seen[(e.kind, n)]}] "
                                      "already acts on it)")
            seen[(e.kind, n)] = i
    for i, ev in enumerate(scene.events):
        if ev.kind == "strike":
            if ev.body not in kinds:
                fail(f"events[{i}].body", f"no body named {ev.body!r}{did_you_mean(ev.body, kinds)}")
            if kinds[ev.body] != "modal":
                fail(f"events[{i}].body", f"strikes act on modal bodies; {ev.body!r} is a {kinds[ev.body]} body")
            if ev.time > scene.time.duration:
                fail(f"events[{i}].time", f"{ev.time:g} s is after the scene ends ({scene.time.duration:g} s)")
        if ev.kind == "gust":
            if not any(e.kind == "wind" for e in scene.effects):
                fail(f"events[{i}]", "a gust adds to the scene's wind: add an effect {kind = \"wind\"}")
            if ev.start >= scene.time.duration:
                fail(f"events[{i}].start", f"{ev.start:g} s is after the scene ends ({scene.time.duration:g} s)")
    if scene.time.dt > scene.time.duration:
        fail("time.dt", f"the step {scene.time.dt:g} s is longer than the duration {scene.time.duration:g} s")
    if 1.0 / scene.time.frame_rate < scene.time.dt * (1 - 1e-9):
        fail("time.frame_rate", f"{scene.time.frame_rate:g} frames/s is more than one frame per step "
                                f"(dt = {scene.time.dt:g} s)")


def _supported(kind: str) -> tuple:
    from modalfem.effects import supported

    return supported(kind)


def _kind_takes(fail, where: str, e, kinds: dict) -> None:
    targets = e.bodies or list(kinds)
    takers = [n for n in targets if e.kind in _supported(kinds[n])]
    if e.bodies:
        for j, n in enumerate(e.bodies):
            if e.kind not in _supported(kinds[n]):
                fail(f"{where}.bodies[{j}]", f"{e.kind} cannot act on {kinds[n]} body {n!r}: a {kinds[n]} body takes "
                                             f"{', '.join(_supported(kinds[n]))}")
    elif not takers:
        fail(where, f"{e.kind} acts on no body of this scene (it acts on "
                    f"{', '.join(k for k in ('modal', 'tet', 'cloth') if e.kind in _supported(k))} bodies)")


def _exists(fail, base: Path | None, where: str, name: str) -> None:
    p = Path(name)
    if not p.is_absolute() and base is not None:
        p = base / p
    if (base is not None or p.is_absolute()) and not p.is_file():
        fail(where, f"no such file {str(p)!r}")
