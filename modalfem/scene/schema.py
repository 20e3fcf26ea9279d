"""The scene file schema ``modalfem.scene/1``: what a scene names, validated strictly (pydantic v2).

Every table forbids unknown keys and every value is checked for type (strict: no string-to-number
coercion) and range; every quantity is in SI units, stated in its description (the JSON Schema
exported by ``json_schema()`` and shipped as ``modalfem/scene/scene.schema.json`` carries them, so
editors such as VS Code with Even Better TOML / Taplo check files as you type).

A scene holds ``time``, ``bodies`` (modal, tet, cloth), ``obstacles`` (ground, plane, sphere, box,
mesh; any but the ground may move on a ``path``), ``effects`` (the vocabulary of ``modalfem.effects``,
global or per body), ``events`` (strikes, wind gusts) and ``outputs``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Discriminator, Field, Tag

__all__ = ["SCHEMA", "SCHEMA_VERSION", "Scene", "did_you_mean", "json_schema"]

#: the schema identifier a scene file must start with
SCHEMA_VERSION = 1
SCHEMA = f"modalfem.scene/{SCHEMA_VERSION}"

def did_you_mean(word: str, choices) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices`` to ``word``, or ``""``."""
    import difflib

    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Quaternion = Annotated[list[float], Field(min_length=4, max_length=4, description="a rotation as a quaternion "
                                                                                 "(w, x, y, z), normalised on use")]
Name = Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_.-]{0,63}$",
                            description="a name: 1-64 letters, digits, '_', '-', '.', starting with a letter")]
Positive = Annotated[float, Field(gt=0)]
Bodies = Annotated[list[Name] | None, Field(min_length=1, description="names of the bodies it acts on (default: "
                                                                     "every body that can take it)")]


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


# ---------------------------------------------------------------------------------------------- time
class Time(_Table):
    """How long and how finely the scene runs, and how often outputs are written."""

    dt: float = Field(gt=0, le=1.0, description="simulation step [s], in (0, 1]")
    duration: float = Field(gt=0, le=3600.0, description="simulated time [s], in (0, 3600]")
    frame_rate: float = Field(30.0, gt=0, le=1000.0, description="output frames per second of simulated time "
                                                                  "[1/s]; the steps per frame are derived")


# ---------------------------------------------------------------------------------------------- materials
class Solid(_Table):
    """An isotropic linear elastic material."""

    E: float = Field(gt=0, description="Young's modulus [Pa]")
    nu: float = Field(gt=-1.0, lt=0.5, description="Poisson's ratio [-], in (-1, 0.5)")
    rho: float = Field(gt=0, description="density [kg/m^3]")


def _preset(name: str) -> str:
    from modalfem.material import MATERIALS

    if name not in MATERIALS:
        raise ValueError(f"unknown material preset {name!r}{did_you_mean(name, MATERIALS)}; presets: "
                         f"{', '.join(sorted(MATERIALS))}, or a table {{E, nu, rho}}")
    return name


def _material_kind(v) -> str:
    return "preset" if isinstance(v, str) else "table"


def _preset_names(schema: dict) -> None:  # the JSON Schema lists the presets, so editors flag a misspelt one too
    from modalfem.material import MATERIALS

    schema["enum"] = sorted(MATERIALS)


SolidMaterial = Annotated[Annotated[str, AfterValidator(_preset), Field(json_schema_extra=_preset_names), Tag("preset")] | Annotated[Solid, Tag("table")],
                          Discriminator(_material_kind),
                          Field(description="a preset name (steel, aluminium, brass) or a table "
                                            "{E [Pa], nu [-], rho [kg/m^3]}")]


class Fabric(_Table):
    """A cloth material: areal density and plane-stress elasticity of a thin sheet."""

    areal_density: float = Field(gt=0, description="mass per area [kg/m^2]")
    young: float = Field(gt=0, description="Young's modulus [Pa]")
    poisson: float = Field(0.3, ge=0.0, lt=0.5, description="Poisson's ratio [-], in [0, 0.5)")
    thickness: float = Field(gt=0, description="sheet thickness [m]")
    bending_stiffness: float | None = Field(None, ge=0, description="bending stiffness [N m] (default "
                                                                     "E h^3 / (12 (1 - nu^2)))")


# ---------------------------------------------------------------------------------------------- meshes
class MeshFile(_Table):
    """A mesh file: a volume mesh (.msh, .vtu, .xdmf, ...) or a surface (STL/OBJ/PLY/OFF) tetrahedralised."""

    file: str = Field(description="path, relative to the scene file")
    unit_scale: float = Field(1.0, gt=0, description="factor from the file's units to metres [m/unit]")
    h: float | None = Field(None, gt=0, description="target edge length [m] when a surface is tetrahedralised")


class BoxMesh(_Table):
    generator: Literal["box"]
    size: Vec3 = Field(description="edge lengths (3) [m]")
    cells: Annotated[list[Annotated[int, Field(ge=1, le=200)]], Field(min_length=3, max_length=3)] = Field(
        description="cells along x, y, z")


class PlateMesh(_Table):
    generator: Literal["plate"]
    size: Vec3 = Field(description="edge lengths (3) [m]")
    cells: Annotated[list[Annotated[int, Field(ge=1, le=200)]], Field(min_length=3, max_length=3)] = Field(
        description="cells along x, y, z")


class RodMesh(_Table):
    generator: Literal["rod"]
    length: Positive = Field(description="length [m]")
    radius: Positive = Field(description="radius [m]")
    h: float | None = Field(None, gt=0, description="element size [m]")


class BellMesh(_Table):
    generator: Literal["bell"]
    diameter: Positive = Field(0.2, description="mouth diameter [m]")
    height: Positive = Field(0.16, description="height [m]")
    thickness: Positive = Field(0.006, description="wall thickness [m]")
    h: Positive = Field(0.01, description="element size [m]")


class ForkMesh(_Table):
    generator: Literal["tuning_fork"]
    prong_length: Positive = Field(0.08, description="prong length [m]")
    h: Positive = Field(0.002, description="element size [m]")


Generated = Annotated[BoxMesh | PlateMesh | RodMesh | BellMesh | ForkMesh, Field(discriminator="generator")]
def _mesh_kind(v) -> str:  # a dict when validating, a model when serialising (model_dump)
    return "generator" if (isinstance(v, dict) and "generator" in v) or hasattr(v, "generator") else "file"


SolidMesh = Annotated[Annotated[MeshFile, Tag("file")] | Annotated[Generated, Tag("generator")],
                      Discriminator(_mesh_kind), Field(description="a mesh file {file = ...} or a generator "
                                                                     "{generator = \"box\" | \"plate\" | \"rod\" | "
                                                                     "\"bell\" | \"tuning_fork\", ...}")]


# ---------------------------------------------------------------------------------------------- bodies
class _Pose(_Table):
    name: Name
    position: Vec3 | None = Field(None, description="translation of the rest shape (the mesh as given) at t = 0 [m]")
    velocity: Vec3 | None = Field(None, description="initial velocity [m/s]")
    orientation: Quaternion | None = Field(
        None, description="rotation (w, x, y, z) of the rest shape about its centre (modal: the centre of mass; "
                          "tet, cloth: the mean of its vertices), applied before position [-]")


class ModalBody(_Pose):
    """A modal body: rigid motion plus its linear vibration modes."""

    kind: Literal["modal"]
    model: str | None = Field(None, description="a model file (.npz from `modalfem modes`), relative to the scene "
                                                "file; or give mesh + material + modes")
    mesh: SolidMesh | None = None
    material: SolidMaterial | None = None
    modes: int = Field(12, ge=1, le=500, description="deformation modes to compute (with mesh + material); cached "
                                                      "by content hash, reused after")
    degree: Literal[1, 2] = Field(2, description="finite-element degree of the modal analysis")
    damping: Annotated[list[Annotated[float, Field(ge=0)]], Field(min_length=2, max_length=2)] = Field(
        [2.0, 1e-9], description="model Rayleigh damping [alpha 1/s, beta s] (with mesh + material)")
    angular_velocity: Vec3 | None = Field(None, description="initial angular velocity, world [rad/s]")


class TetBody(_Pose):
    """A large-deformation tetrahedral body (implicit steps)."""

    kind: Literal["tet"]
    mesh: SolidMesh
    material: SolidMaterial
    energy: Literal["stable", "corotated"] = Field("stable", description="elastic energy: inversion-robust fixed "
                                                                        "corotated, or corotational linear")


class ClothGrid(_Table):
    """A rectangular cloth."""

    size: Annotated[list[Positive], Field(min_length=2, max_length=2)] = Field(description="side lengths [m]")
    vertices: Annotated[list[Annotated[int, Field(ge=2, le=512)]], Field(min_length=2, max_length=2)] = Field(
        description="vertex counts along the two sides")
    origin: Vec3 = Field([0.0, 0.0, 0.0], description="corner [m]")
    plane: Literal["xy", "xz", "yz"] = Field("xy", description="the plane the sheet lies in")


class ClothBody(_Pose):
    """A cloth: shells with stretching, shearing and bending."""

    kind: Literal["cloth"]
    grid: ClothGrid | None = None
    mesh: str | None = Field(None, description="a triangle mesh file (OBJ/PLY/STL), relative to the scene file; "
                                               "or give grid")
    unit_scale: float = Field(1.0, gt=0, description="factor from the mesh file's units to metres [m/unit]")
    material: Fabric
    mass_damping: float = Field(0.0, ge=0, description="Rayleigh alpha [1/s]")
    stiffness_damping: float = Field(0.0, ge=0, description="Rayleigh beta [s]")
    pins: list[Literal["-x", "+x", "-y", "+y", "-z", "+z"]] = Field(
        [], description="hold the rest-shape vertices on these sides of the sheet (e.g. a flag's pole at -x)")


Body = Annotated[ModalBody | TetBody | ClothBody, Field(discriminator="kind")]


# ---------------------------------------------------------------------------------------------- obstacles
class Waypoint(_Table):
    t: float = Field(ge=0, description="time [s]")
    offset: Vec3 = Field(description="translation from the obstacle's place at that time [m]")


class _Moving(_Table):
    path: list[Waypoint] | None = Field(None, min_length=1, description="waypoints (increasing t), linear in between")


class GroundObstacle(_Table):
    kind: Literal["ground"]
    height: float = Field(0.0, description="z of the ground [m]")
    size: Positive = Field(5.0, description="extent drawn in pictures [m]")


class PlaneObstacle(_Moving):
    kind: Literal["plane"]
    normal: Vec3 = Field(description="outward normal [-]")
    point: Vec3 = Field([0.0, 0.0, 0.0], description="a point of the plane [m]")
    size: Positive = Field(5.0, description="extent drawn in pictures [m]")


class SphereObstacle(_Moving):
    kind: Literal["sphere"]
    center: Vec3 = Field(description="centre [m]")
    radius: Positive = Field(description="radius [m]")


class BoxObstacle(_Moving):
    kind: Literal["box"]
    center: Vec3 = Field(description="centre [m]")
    half_extents: Annotated[list[Positive], Field(min_length=3, max_length=3)] = Field(description="half sizes [m]")
    rotation: Quaternion | None = Field(None, description="rotation (w, x, y, z) of the box about its centre [-]")


class MeshObstacle(_Moving):
    kind: Literal["mesh"]
    file: str = Field(description="a triangle mesh file (STL/OBJ/PLY/OFF), relative to the scene file")
    unit_scale: float = Field(1.0, gt=0, description="factor from the file's units to metres [m/unit]")
    offset: Vec3 = Field([0.0, 0.0, 0.0], description="translation [m]")


Obstacle = Annotated[GroundObstacle | PlaneObstacle | SphereObstacle | BoxObstacle | MeshObstacle,
                     Field(discriminator="kind")]


# ---------------------------------------------------------------------------------------------- effects
class GravityEffect(_Table):
    kind: Literal["gravity"]
    g: Vec3 = Field([0.0, 0.0, -9.81], description="acceleration [m/s^2]")
    bodies: Bodies = None


class WindEffect(_Table):
    kind: Literal["wind"]
    velocity: Vec3 = Field(description="air velocity [m/s] (gust events add to it)")
    density: float = Field(1.2, ge=0, description="air density [kg/m^3]")
    drag: float = Field(1.0, ge=0, description="pressure coefficient [-]")
    bodies: Bodies = None


class DampingEffect(_Table):
    kind: Literal["damping"]
    alpha: float = Field(0.0, ge=0, description="mass-proportional Rayleigh coefficient [1/s]")
    beta: float = Field(0.0, ge=0, description="stiffness-proportional Rayleigh coefficient [s]")
    bodies: Bodies = None


class ContactEffect(_Table):
    kind: Literal["contact"]
    restitution: float = Field(0.3, ge=0, le=1, description="coefficient of restitution [-], in [0, 1]")
    friction: float = Field(0.5, ge=0, le=10, description="Coulomb friction coefficient [-]")
    margin: float = Field(1e-3, gt=0, description="contact gathering distance [m]")
    thickness: float = Field(2e-3, gt=0, description="cloth collision thickness [m]")
    bodies: Bodies = None


class SelfCollisionEffect(_Table):
    kind: Literal["self-collision"]
    thickness: float | None = Field(None, gt=0, description="collision thickness [m] (default: the contact's)")
    bodies: Bodies = None


class PseudoForcesEffect(_Table):
    kind: Literal["pseudo-forces"]
    coriolis: bool = True
    centripetal: bool = True
    euler: bool = True
    bodies: Bodies = None


class SoundEffect(_Table):
    kind: Literal["sound"]
    listener: Vec3 = Field([1.0, 0.0, 0.0], description="direction from the body to the listener [-]")
    distance: float = Field(1.0, gt=0, description="listener distance [m]")
    bodies: Bodies = None


Effect = Annotated[GravityEffect | WindEffect | DampingEffect | ContactEffect | SelfCollisionEffect | PseudoForcesEffect | SoundEffect, Field(discriminator="kind")]

# ---------------------------------------------------------------------------------------------- events


class StrikeEvent(_Table):
    """An impulse on a body's surface at a given time (a hammer)."""

    kind: Literal["strike"]
    body: Name
    time: float = Field(ge=0, description="when [s]")
    point: Vec3 = Field(description="where, in the body's rest frame [m]: the nearest surface vertex is struck")
    impulse: Vec3 = Field(description="impulse (world) [N s]")


class GustEvent(_Table):
    """A wind gust added to the scene's wind (a smooth 1 - cos pulse)."""

    kind: Literal["gust"]
    start: float = Field(ge=0, description="start time [s]")
    duration: Positive = Field(description="length [s]")
    velocity: Vec3 = Field(description="peak added air velocity [m/s]")


Event = Annotated[StrikeEvent | GustEvent, Field(discriminator="kind")]


# ---------------------------------------------------------------------------------------------- outputs
class Camera(_Table):
    elev: float = Field(22.0, ge=-90, le=90, description="elevation [deg]")
    azim: float = Field(-60.0, description="azimuth [deg]")
    center: Vec3 | None = Field(None, description="the point at the middle of the picture [m]")
    half_width: float | None = Field(None, gt=0, description="half the visible width [m]")


class Outputs(_Table):
    """What `modalfem run` writes into its output folder (summary.json always)."""

    paraview: bool = Field(True, description="ParaView time series: scene.pvd + one file per body and frame")
    video: Literal["gif", "mp4", "none"] = Field("gif", description="preview video")
    video_size: Annotated[list[Annotated[int, Field(ge=64, le=3840)]], Field(min_length=2, max_length=2)] = Field(
        [640, 360], description="video width, height [pixels]")
    sound: bool = Field(True, description="a WAV per sounding body and a mix")
    gltf: bool = Field(True, description="scene.glb: the animation for Blender and web viewers")
    camera: Camera = Camera()
    check_every: int = Field(1, ge=0, description="run the exact intersection check every this many frames "
                                                   "(0: never)")


# ---------------------------------------------------------------------------------------------- scene
class Scene(_Table):
    """A modalfem scene (``schema = "modalfem.scene/1"``)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True,
                              json_schema_extra={"$id": "https://modalfem.org/schema/scene-1.json"})

    schema_: Literal["modalfem.scene/1"] = Field(alias="schema", description="the schema version")
    name: Name | None = Field(None, description="the scene's name")
    description: str = Field("", description="what the scene shows")
    time: Time
    bodies: list[Body] = Field(min_length=1)
    obstacles: list[Obstacle] = []
    effects: list[Effect] = []
    events: list[Event] = []
    outputs: Outputs = Outputs()


def json_schema() -> dict:
    """The JSON Schema of scene files (draft 2020-12), units in the descriptions."""
    out = Scene.model_json_schema(by_alias=True)
    out["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    out["title"] = "modalfem scene (modalfem.scene/1)"
    return out
