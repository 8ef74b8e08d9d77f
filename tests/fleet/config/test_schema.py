"""The JSON Schema published for editors: ``fleet config-schema`` prints it, the checked-in
``docs/config.schema.json`` is the same, it agrees with the field table of ``docs/config.md``
and with what the loader rejects."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from fleet.cli.main import main
from fleet.config.schema import json_schema, json_schema_text, validate_document
from fleet.errors import ConfigError

ROOT = Path(__file__).resolve().parents[3]
SCHEMA_FILE = ROOT / "docs" / "config.schema.json"
PATROL = ROOT / "configs" / "warehouse_patrol.yaml"


def test_the_checked_in_schema_is_the_generated_one() -> None:
    assert SCHEMA_FILE.read_text() == json_schema_text(), (
        "docs/config.schema.json is stale: run `fleet config-schema --out docs/config.schema.json`"
    )


def test_the_command_prints_the_schema_and_writes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["config-schema"]) == 0
    assert json.loads(capsys.readouterr().out) == json_schema()
    out = tmp_path / "schema.json"
    assert main(["config-schema", "--out", str(out)]) == 0
    assert out.read_text() == json_schema_text()
    assert main(["config-schema", "--out", str(tmp_path / "no" / "such" / "dir.json")]) == 2
    assert "cannot write" in capsys.readouterr().err


def resolve(schema: dict[str, Any], node: dict[str, Any]) -> dict[str, Any]:
    """``node``, or the definition its ``$ref`` points at."""
    if "$ref" in node:
        target: dict[str, Any] = schema["definitions"][node["$ref"].rsplit("/", 1)[1]]
        return target
    return node


def schema_fields(schema: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Every top-level key and every key of a top-level section, as ``section.key``."""
    out: dict[str, dict[str, Any]] = {}
    for key, node in schema["properties"].items():
        out[key] = node
        target = resolve(schema, node)
        if target.get("type") == "object" and "properties" in target:
            for sub, subnode in target["properties"].items():
                out[f"{key}.{sub}"] = subnode
    return out


def documented_fields() -> dict[str, str]:
    """Field path -> the "Type / default" column of the table in docs/config.md."""
    text = (ROOT / "docs" / "config.md").read_text()
    text = text.split("## Sections and fields", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([a-z_.]+)` \| ([^|]+) \|", text, flags=re.M)
    return {field: kind.strip() for field, kind in rows}


def test_the_documented_fields_are_the_schema_fields_with_the_same_defaults() -> None:
    schema = json_schema()
    fields = schema_fields(schema)
    documented = documented_fields()
    sections = {k for k in fields if any(f.startswith(f"{k}.") for f in fields)}
    assert set(documented) == set(fields) - sections
    for field, kind in documented.items():
        number = re.search(r", (-?\d+(?:\.\d+)?)$", kind)
        if number:
            assert fields[field]["default"] == pytest.approx(float(number.group(1))), field


@pytest.fixture(scope="module")
def patrol() -> dict[str, Any]:
    return yaml.safe_load(PATROL.read_text())


def numeric_fields(schema: dict[str, Any]) -> list[tuple[str, str, dict[str, Any]]]:
    """(section, key, schema) of every number in a section, ``X | None`` ones included."""
    out = []
    for section, node in schema["properties"].items():
        target = resolve(schema, node)
        for key, sub in target.get("properties", {}).items():
            sub = next((s for s in sub.get("anyOf", []) if s.get("type") != "null"), sub)
            if sub.get("type") in ("number", "integer"):
                out.append((section, key, sub))
    return out


def test_the_loader_rejects_what_the_schema_bounds_exclude(patrol: dict[str, Any]) -> None:
    fields = numeric_fields(json_schema())
    assert len(fields) >= 25
    for section, key, sub in fields:
        outside: list[object] = ["fast", True]
        if "exclusiveMinimum" in sub:
            outside += [sub["exclusiveMinimum"], sub["exclusiveMinimum"] - 1]
        if "minimum" in sub:
            outside.append(sub["minimum"] - 0.5)
        if "maximum" in sub:
            outside.append(sub["maximum"] + 0.5)
        if sub["type"] == "integer":
            outside.append(1.5)
        for value in outside:
            doc = copy.deepcopy(patrol)
            doc.setdefault(section, {})[key] = value
            with pytest.raises(ConfigError) as ei:
                validate_document(doc, "f.yaml")
            assert ei.value.field == f"{section}.{key}", (section, key, value, str(ei.value))
        if "default" in sub and sub["default"] is not None:
            doc = copy.deepcopy(patrol)
            doc.setdefault(section, {})[key] = sub["default"]
            validate_document(doc, "f.yaml")


def test_names_follow_the_published_pattern(patrol: dict[str, Any]) -> None:
    schema = json_schema()
    pattern = schema["definitions"]["RobotEntry"]["properties"]["name"]["pattern"]
    for name, ok in (("robot_7", True), ("r", True), ("7robot", False), ("robot-7", False), ("", False)):
        assert bool(re.match(pattern, name)) == ok
        doc = copy.deepcopy(patrol)
        doc["robots"][0]["name"] = name
        if ok:
            validate_document(doc, "f.yaml")
        else:
            with pytest.raises(ConfigError, match=r"robots\[0\]\.name"):
                validate_document(doc, "f.yaml")
