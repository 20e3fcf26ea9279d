"""Scene files: describe a scene once (TOML, ``schema = "modalfem.scene/1"``), simulate exactly what it names.

API::

    from modalfem import scene

    s, base = scene.load_scene("drop.toml")       # validated, or SceneError "drop.toml: key.path: problem"
    built = scene.build_scene(s, base)            # the World, its start state, the events
    print(built.world.describe_plan())            # = `modalfem plan drop.toml`
    result = scene.run_scene("drop.toml", "out/drop")   # = `modalfem run drop.toml --out out/drop`
    result.summary["intersections"]["total"]      # 0
    scene.examples()                              # the example scenes shipped with modalfem

The schema (every key, its unit and range) is ``modalfem.scene.schema``; its JSON Schema is shipped as
``modalfem/scene/scene.schema.json``.
"""

from modalfem.scene.build import BuiltScene, build_scene
from modalfem.scene.load import load_scene, scene_from_text
from modalfem.scene.run import RunResult, examples, find_scene, plan_scene, run_scene
from modalfem.scene.schema import SCHEMA, Scene, json_schema

__all__ = [
    "SCHEMA",
    "BuiltScene",
    "RunResult",
    "Scene",
    "build_scene",
    "examples",
    "find_scene",
    "json_schema",
    "load_scene",
    "plan_scene",
    "run_scene",
    "scene_from_text",
]
