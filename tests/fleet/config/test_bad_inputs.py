"""Broken configs and maps a new user writes are each refused with ``<file>: <field>: <reason>``:
a document nested 100,000 levels deep, map YAML with NaN, strings, booleans or binary bytes
where numbers belong, a config naming the map's image, repeated keys, numbers far outside sane
bounds, robot names and namespaces that are not ROS names or that collide with the bus's own
keys or with each other, and the right entry named when a roadmap edge crosses a shelf."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from fleet.bus.keys import RESERVED_CHUNKS
from fleet.cli.main import main
from fleet.config.fields import RESERVED_NAMES
from fleet.config.loader import load_config
from fleet.errors import ConfigError, MapError

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
PATROL = CONFIGS / "warehouse_patrol.yaml"
MAP = CONFIGS / "maps" / "warehouse.yaml"
IMAGE = CONFIGS / "maps" / "warehouse.pgm"

Doc = dict[str, Any]


def _config_doc() -> Doc:
    doc: Doc = yaml.safe_load(PATROL.read_text())
    doc["map"] = str(MAP)
    return doc


def _map_text(**fields: str) -> str:
    """A map YAML (as text, so YAML spellings like ``.nan`` stay) with ``fields`` replaced."""
    base = {"image": str(IMAGE), "resolution": "0.1", "origin": "[0.0, 0.0, 0.0]"}
    return "".join(f"{k}: {v}\n" for k, v in {**base, **fields}.items())


def _set(path: str, value: object) -> Callable[[Doc], None]:
    def mutate(doc: Doc) -> None:
        *head, last = path.split(".")
        node: Any = doc
        for part in head:
            node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
        node[int(last) if last.isdigit() else last] = value

    return mutate


def _swap_namespaces(doc: Doc) -> None:
    doc["robots"][0]["namespace"] = "/robot2"
    doc["robots"][1]["namespace"] = "/robot1"


def _edge_through_shelf_at_43(doc: Doc) -> None:
    edges = doc["roadmap"]["edges"]
    assert len(edges) > 43
    edges.insert(43, ["a1_1", "a2_1"])  # aisles 1 and 2 are split by shelf row 1


# (id, change to the patrol config, field, words of the reason)
CONFIG_CASES: list[tuple[str, Callable[[Doc], None], str, str]] = [
    ("huge_speed", _set("robot_model.max_linear_speed", 1e9), "robot_model.max_linear_speed", "up to 10"),
    (
        "huge_turn_rate",
        _set("robot_model.max_angular_speed", 500.0),
        "robot_model.max_angular_speed",
        "up to 10",
    ),
    ("huge_radius", _set("robot_model.radius", 50.0), "robot_model.radius", "up to 5"),
    ("huge_drain_per_m", _set("battery.drain_per_m", 1e9), "battery.drain_per_m", "in [0, 0.1]"),
    ("huge_drain_per_s", _set("battery.drain_per_s", 5.0), "battery.drain_per_s", "in [0, 0.01]"),
    ("huge_charge_rate", _set("battery.charge_per_s", 10.0), "battery.charge_per_s", "up to 1"),
    ("detour_below_1", _set("battery.detour", 0.5), "battery.detour", "in [1, 10]"),
    ("tiny_step", _set("sim.step_s", 1e-9), "sim.step_s", "in [0.001, 1]"),
    ("huge_step", _set("sim.step_s", 5.0), "sim.step_s", "in [0.001, 1]"),
    ("tiny_tick_period", _set("agent.tick_hz", 1e9), "agent.tick_hz", "up to 1000"),
    ("negative_seed", _set("sim.seed", -1), "sim.seed", "integer in [0, 2**32 - 1]"),
    ("huge_seed", _set("sim.seed", 2**40), "sim.seed", "integer in [0, 2**32 - 1]"),
    ("yaw_tolerance_over_pi", _set("sim.yaw_tolerance", 7.0), "sim.yaw_tolerance", "up to 3.14159"),
    ("huge_status_rate", _set("bus.status_hz", 1e6), "bus.status_hz", "up to 1000"),
    ("endpoint_port_99999", _set("bus.endpoint", "tcp/127.0.0.1:99999"), "bus.endpoint", "port 99999"),
    ("endpoint_port_0", _set("bus.endpoint", "tcp/127.0.0.1:0"), "bus.endpoint", "port 0"),
    ("endpoint_port_word", _set("bus.endpoint", "tcp/127.0.0.1:http"), "bus.endpoint", "not a number"),
    ("huge_dwell", _set("tasks.0.dwell_s", 1e7), "tasks[0].dwell_s", "in [0, 3600]"),
    ("name_with_newline", _set("robots.0.name", "robot\n1"), "robots[0].name", "letter then letters"),
    ("name_ending_in_newline", _set("robots.0.name", "robot1\n"), "robots[0].name", "letter then letters"),
    (
        "namespace_with_newline",
        _set("robots.0.namespace", "/robot1\n"),
        "robots[0].namespace",
        "look like /robot1",
    ),
    ("namespace_two_tokens", _set("robots.0.namespace", "/a/b"), "robots[0].namespace", "look like /robot1"),
    ("name_with_wildcard", _set("robots.0.name", "robot*"), "robots[0].name", "letter then letters"),
    ("robot_named_sim", _set("robots.0.name", "sim"), "robots[0].name", "key the fleet's bus uses"),
    ("robot_named_control", _set("robots.1.name", "control"), "robots[1].name", "key the fleet's bus uses"),
    (
        "namespace_service",
        _set("robots.0.namespace", "/service"),
        "robots[0].namespace",
        "key the fleet's bus",
    ),
    ("swapped_namespaces", _swap_namespaces, "robots[0].namespace", "namespace of robot 'robot2'"),
    (
        "duplicate_namespace",
        _set("robots.1.namespace", "/robot1"),
        "robots[1].namespace",
        "duplicate namespace",
    ),
    ("edge_through_shelf", _edge_through_shelf_at_43, "roadmap.edges[43]", "passes through an obstacle"),
]


@pytest.mark.parametrize(
    ("mutate", "field", "words"), [c[1:] for c in CONFIG_CASES], ids=[c[0] for c in CONFIG_CASES]
)
def test_bad_config_names_file_field_and_reason(
    tmp_path: Path, mutate: Callable[[Doc], None], field: str, words: str
) -> None:
    doc = _config_doc()
    mutate(doc)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    err = ei.value
    assert (err.file, err.field) == (str(path), field), str(err)
    assert words in err.reason, str(err)
    assert str(err).startswith(f"{path}: {field}: ")


def _patrol_text() -> str:
    return PATROL.read_text().replace("map: maps/warehouse.yaml", f"map: {MAP}")


# (id, config text, field, words of the reason)
TEXT_CASES: list[tuple[str, str, str, str]] = [
    (
        "deep_nesting",
        "name: x\nroadmap: " + "[" * 100_000 + "]" * 100_000 + "\n",
        "roadmap",
        "nested more than",
    ),
    ("deep_block_nesting", "".join(f"{'  ' * i}k{i}:\n" for i in range(200)), "k0", "nested more than"),
    ("duplicate_top_key", _patrol_text() + "name: other\n", "name", "appears twice"),
    (
        "duplicate_nested_key",
        _patrol_text().replace("    w_s: [2.5, 5.0]\n", "    w_s: [2.5, 5.0]\n    w_s: [3.0, 5.0]\n", 1),
        "roadmap.nodes.w_s",
        "appears twice",
    ),
    (
        "duplicate_key_in_a_list",
        _patrol_text().replace("  - {name: robot1, ", "  - {name: robot1, name: robot9, ", 1),
        "robots[0].name",
        "appears twice",
    ),
]


@pytest.mark.parametrize(
    ("text", "field", "words"), [c[1:] for c in TEXT_CASES], ids=[c[0] for c in TEXT_CASES]
)
def test_bad_config_text_names_file_field_and_reason(
    tmp_path: Path, text: str, field: str, words: str
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    err = ei.value
    assert (err.file, err.field) == (str(path), field), str(err)
    assert words in err.reason, str(err)


# (id, map YAML text or bytes, field, words of the reason)
MAP_CASES: list[tuple[str, str | bytes, str, str]] = [
    ("nan_resolution", _map_text(resolution=".nan"), "resolution", "positive number"),
    ("inf_resolution", _map_text(resolution=".inf"), "resolution", "positive number"),
    ("true_resolution", _map_text(resolution="true"), "resolution", "got True"),
    ("huge_resolution", _map_text(resolution="1e9"), "resolution", "up to 100"),
    ("nan_origin", _map_text(origin="[.nan, 0.0, 0.0]"), "origin", "[x, y, yaw]"),
    ("far_origin", _map_text(origin="[1e300, 0.0, 0.0]"), "origin", "within +-1e+06"),
    ("inf_origin", _map_text(origin="[0.0, -.inf, 0.0]"), "origin", "[x, y, yaw]"),
    ("string_occupied_thresh", _map_text(occupied_thresh="'0.65'"), "occupied_thresh", "number in [0, 1]"),
    ("fractional_negate", _map_text(negate="0.5"), "negate", "0 or 1"),
    ("boolean_negate", _map_text(negate="true"), "negate", "0 or 1"),
    ("string_negate", _map_text(negate="'1'"), "negate", "0 or 1"),
    ("image_is_a_directory", _map_text(image=str(CONFIGS / "maps")), "image", "is not a file"),
    ("duplicate_key", _map_text() + "resolution: 0.05\n", "resolution", "appears twice"),
    ("deep_nesting", "origin: " + "[" * 100_000 + "]" * 100_000 + "\n", "origin", "nested more than"),
]


@pytest.mark.parametrize(
    ("content", "field", "words"), [c[1:] for c in MAP_CASES], ids=[c[0] for c in MAP_CASES]
)
def test_bad_map_names_the_map_file_field_and_reason(
    tmp_path: Path, content: str | bytes, field: str, words: str
) -> None:
    map_path = tmp_path / "map.yaml"
    if isinstance(content, bytes):
        map_path.write_bytes(content)
    else:
        map_path.write_text(content)
    doc = _config_doc()
    doc["map"] = str(map_path)
    config = tmp_path / "fleet.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(MapError) as ei:
        load_config(config)
    err = ei.value
    assert (err.file, err.field) == (str(map_path), field), str(err)
    assert words in err.reason, str(err)


@pytest.mark.parametrize(
    ("map_file", "words"),
    [(IMAGE, "name the map's YAML file"), ("binary", "name the map's YAML file"), ("nul", "not valid YAML")],
)
def test_a_map_that_is_not_yaml_is_blamed_on_the_configs_map_field(
    tmp_path: Path, map_file: Path | str, words: str
) -> None:
    if map_file == "binary":
        map_file = tmp_path / "map.yaml"
        map_file.write_bytes(bytes(range(256)) * 8)
    elif map_file == "nul":
        map_file = tmp_path / "map.yaml"
        map_file.write_bytes(b"\x00image: map.pgm\n")
    doc = _config_doc()
    doc["map"] = str(map_file)
    config = tmp_path / "fleet.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(MapError) as ei:
        load_config(config)
    err = ei.value
    assert (err.file, err.field) == (str(config), "map"), str(err)
    assert str(map_file) in err.reason and words in err.reason, str(err)


def test_reserved_robot_names_cover_the_bus_keys() -> None:
    assert RESERVED_CHUNKS <= RESERVED_NAMES


def test_robots_may_still_have_their_own_namespaces(tmp_path: Path) -> None:
    doc = _config_doc()
    doc["robots"][0]["namespace"] = "/amr_7"
    doc["robots"][1]["namespace"] = "/robot2"
    path = tmp_path / "ok.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    cfg = load_config(path)
    assert [r.namespace for r in cfg.robots[:2]] == ["/amr_7", "/robot2"]


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("name: x\nroadmap: " + "[" * 100_000 + "]" * 100_000 + "\n", "roadmap: nested more than 64 levels"),
        (_patrol_text() + "name: other\n", "name: key 'name' appears twice"),
        (_patrol_text().replace("  seed: 1\n", "  seed: -1\n"), "sim.seed: must be an integer"),
    ],
    ids=["deep_nesting", "duplicate_key", "negative_seed"],
)
def test_fleet_validate_exits_2_with_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, needle: str
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: "), err
    assert needle in lines[0] and "Traceback" not in err


def test_the_shipped_configs_still_load() -> None:
    for path in sorted(CONFIGS.glob("*.yaml")):
        assert load_config(path).robots, path
