"""The shipped JSON Schema (modalfem/scene/scene.schema.json): current, valid, and seeing scenes as modalfem does.

The checks use ``jsonschema`` (the reference validator of the JSON Schema organisation), so they see what an
editor sees, not what pydantic sees.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is in the test extra (pip install -e .[test])")

from modalfem.scene import schema_file  # noqa: E402
from modalfem.scene.load import scene_from_text  # noqa: E402
from modalfem.scene.run import EXAMPLES  # noqa: E402
from modalfem.scene.schema import SCHEMA, json_schema  # noqa: E402

BROKEN = Path(__file__).parent / "broken"
EXAMPLE_FILES = sorted(EXAMPLES.glob("*.toml"))


def validator():
    schema = json.loads(schema_file.SCHEMA_FILE.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def test_the_committed_file_is_what_json_schema_gives():
    # if this fails: python -m modalfem.scene.schema_file (and commit modalfem/scene/scene.schema.json)
    assert schema_file.SCHEMA_FILE.read_text(encoding="utf-8") == schema_file.schema_text()
    assert json.loads(schema_file.SCHEMA_FILE.read_text(encoding="utf-8")) == json_schema()


def test_the_file_is_a_valid_draft_2020_12_schema_naming_its_version():
    schema = json.loads(schema_file.SCHEMA_FILE.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["properties"]["schema"]["const"] == SCHEMA
    assert schema["additionalProperties"] is False


def test_every_quantity_states_its_unit():
    """Every number (or list of numbers) that is not a count, a flag or dimensionless says its unit in []."""
    schema = json.loads(schema_file.SCHEMA_FILE.read_text(encoding="utf-8"))
    missing = []
    for name, d in schema["$defs"].items():
        for key, p in d.get("properties", {}).items():
            types = {p.get("type")} | {a.get("type") for a in p.get("anyOf", [])}
            items = p.get("items", {}) if isinstance(p.get("items"), dict) else {}
            types |= {items.get("type")} | {(a.get("items") or {}).get("type") for a in p.get("anyOf", [])
                                             if isinstance(a.get("items"), dict)}
            if "number" in types and "[" not in p.get("description", ""):
                missing.append(f"{name}.{key}")
    assert missing == []


@pytest.mark.parametrize("path", EXAMPLE_FILES, ids=[p.stem for p in EXAMPLE_FILES])
def test_every_example_scene_passes_the_schema_and_modalfem(path):
    assert EXAMPLE_FILES, "no example scenes found"
    text = path.read_text(encoding="utf-8")
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator().iter_errors(tomllib.loads(text))]
    assert errors == []
    scene_from_text(text, label=path.name)  # and modalfem's own validation (files resolve elsewhere: base=None)


BROKEN_FILES = sorted(BROKEN.glob("*.toml"))


@pytest.mark.parametrize("path", BROKEN_FILES, ids=[p.stem for p in BROKEN_FILES])
def test_the_schema_refuses_exactly_the_corpus_files_marked_so(path):
    """Files marked ``# json-schema: rejects`` are refused by the schema too; the others (problems only
    modalfem run can see: files, names, start state) pass it, so editors raise no false alarm."""
    text = path.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        pytest.skip("not TOML: nothing for a JSON Schema to check")
    errors = list(validator().iter_errors(data))
    if "# json-schema: rejects" in text:
        assert errors, f"{path.name}: the JSON Schema accepts what modalfem refuses"
    else:
        assert errors == [], f"{path.name}: the JSON Schema refuses a structurally valid scene: {errors[0].message}"


def test_the_writer_and_its_check(tmp_path, capsys):
    target = tmp_path / "scene.schema.json"
    assert schema_file.main(["--out", str(target), "--check"]) == 1
    assert "OUT OF DATE" in capsys.readouterr().out
    assert schema_file.main(["--out", str(target)]) == 0
    assert target.read_text(encoding="utf-8") == schema_file.schema_text()
    assert schema_file.main(["--out", str(target), "--check"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["scene.schema.json"]  # no temporaries left
