"""Fleet config loading: the shipped configs validate, every class of mistake gets a clear
``<file>: <field>: <reason>`` error, and ``robots=N`` resizes the fleet."""

from __future__ import annotations

import copy
import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from fleet.config.loader import load_config
from fleet.config.model import FleetConfig
from fleet.errors import ConfigError, MapError
from fleet.types import Pose2D

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
PATROL = CONFIGS / "warehouse_patrol.yaml"
SHIPPED = ["warehouse_patrol.yaml", "warehouse_patrol_30.yaml", "warehouse_picking.yaml"]

# In the shipped map: shelf row 0 spans x 4.0..5.0, y 6.5..16.5; walls are 0.2 m thick.
IN_SHELF = [4.5, 10.0, 0.0]


@pytest.fixture(scope="module")
def base() -> dict[str, Any]:
    return yaml.safe_load(PATROL.read_text())


def write(tmp_path: Path, doc: dict[str, Any], name: str = "bad.yaml") -> Path:
    doc = copy.deepcopy(doc)
    if isinstance(doc.get("map"), str) and not Path(doc["map"]).is_absolute():
        doc["map"] = str(CONFIGS / doc["map"])
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_configs_load(name: str) -> None:
    cfg = load_config(CONFIGS / name)
    assert isinstance(cfg, FleetConfig)
    assert len(cfg.chargers) >= 2
    assert len(cfg.routes) >= 3
    assert cfg.tasks
    assert cfg.map_path == (CONFIGS / "maps" / "warehouse.yaml").resolve()
    r = cfg.sim.model.radius
    for spec in cfg.robots:
        assert cfg.grid.is_free(spec.start.x, spec.start.y, r)
        assert spec.namespace == f"/{spec.name}"
    assert cfg.sim.chargers == tuple(c.pose for c in cfg.chargers)
    for task in cfg.tasks:
        assert task.shelf_station in cfg.stations and task.drop_station in cfg.stations
        assert task.shelf == cfg.stations[task.shelf_station].pose


def test_shipped_patrol_values() -> None:
    cfg = load_config(PATROL)
    assert cfg.name == "warehouse_patrol"
    assert [r.name for r in cfg.robots] == [f"robot{i}" for i in range(1, 7)]
    assert cfg.tick_hz == 10.0 and cfg.sim.step_s == 0.05 and cfg.sim.seed == 1
    assert cfg.coordinator.stuck_reassign_s == 30.0 and cfg.coordinator.status_timeout_s == 3.0
    assert cfg.endpoint == "tcp/127.0.0.1:7447"
    assert cfg.sim.battery.low == 0.1 and cfg.sim.battery.resume == 0.95
    assert cfg.sim.model.radius == 0.3
    xmin, xmax, ymin, ymax = cfg.grid.extent
    assert xmax - xmin == pytest.approx(30.0) and ymax - ymin == pytest.approx(20.0)
    assert len(load_config(CONFIGS / "warehouse_patrol_30.yaml").robots) == 30


def test_route_waypoints_and_dense_lap() -> None:
    cfg = load_config(PATROL)
    route = cfg.route("aisles_1_2")
    assert route.node_names == ("a1_s", "a1_n", "a2_n", "a2_s")
    assert route.waypoints[0].theta == pytest.approx(math.pi / 2)  # a1_s faces up aisle 1
    lap = cfg.route_poses(route)
    assert len(lap) > len(route.waypoints)  # passes the aisle nodes in between
    for a, b in zip(lap, lap[1:] + lap[:1], strict=True):
        assert cfg.roadmap.nearest_node(b.x, b.y) in cfg.roadmap.neighbors(cfg.roadmap.nearest_node(a.x, a.y))


def test_defaults_when_optional_sections_are_left_out(tmp_path: Path, base: dict[str, Any]) -> None:
    doc = {k: base[k] for k in ("name", "map", "roadmap", "chargers", "robots")}
    cfg = load_config(write(tmp_path, doc, "minimal.yaml"))
    assert cfg.routes == [] and cfg.tasks == [] and cfg.stations == {}
    assert cfg.tick_hz == 10.0 and cfg.endpoint == "tcp/127.0.0.1:7447" and cfg.status_hz is None
    assert cfg.sim.model.max_linear_speed == 1.0 and cfg.sim.battery.initial == 1.0


def test_optional_fields_are_read(tmp_path: Path, base: dict[str, Any]) -> None:
    doc = copy.deepcopy(base)
    doc["robots"][1].update(namespace="/fast_one", battery=0.5)
    doc["routes"][0]["robot"] = "robot2"
    doc["routes"].append({"name": "mixed", "waypoints": ["a1_s", "pick_a1_1_e", [2.0, 1.0, 0.0]]})
    doc["tasks"][0].update(robot="robot3", dwell_s=2.5)
    doc["tasks"][1]["shelf"] = [6.6, 9.0, 0.0]
    doc["sim"]["goal_tolerance"] = 0.1
    doc["bus"]["status_hz"] = 2
    cfg = load_config(write(tmp_path, doc))
    assert cfg.robot("robot2").namespace == "/fast_one" and cfg.robot("robot2").battery == 0.5
    assert cfg.routes[0].robot == "robot2"
    mixed = cfg.route("mixed")
    assert mixed.node_names == ("a1_s", None, None)
    assert cfg.route_poses(mixed) == mixed.waypoints
    assert cfg.tasks[0].robot == "robot3" and cfg.tasks[0].dwell_s == 2.5
    assert cfg.tasks[1].shelf == Pose2D(6.6, 9.0, 0.0) and cfg.tasks[1].shelf_station == ""
    assert cfg.sim.goal_tolerance == 0.1 and cfg.status_hz == 2.0


# ---------------------------------------------------------------------------- bad configs

Mutator = Callable[[dict[str, Any]], None]


def _set(path: str, value: Any) -> Mutator:
    """Mutator setting a dotted path; integer parts index lists."""

    def mutate(doc: dict[str, Any]) -> None:
        parts = path.split(".")
        node: Any = doc
        for p in parts[:-1]:
            node = node[int(p)] if p.isdigit() else node[p]
        last = parts[-1]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value

    return mutate


def _del(key: str) -> Mutator:
    return lambda doc: doc.pop(key)


def _too_close(doc: dict[str, Any]) -> None:
    x, y, th = doc["robots"][0]["start"]
    doc["robots"][3]["start"] = [x + 0.5, y, th]


def _dup_robot(doc: dict[str, Any]) -> None:
    doc["robots"][4]["name"] = "robot2"


def _dup_namespace(doc: dict[str, Any]) -> None:
    doc["robots"][4]["namespace"] = "/robot1"


def _edge_through_shelf(doc: dict[str, Any]) -> None:
    doc["roadmap"]["edges"].append(["w_1", "a1_1"])


def _edge_unknown(doc: dict[str, Any]) -> None:
    doc["roadmap"]["edges"].append(["w_1", "a99_1"])


def _disconnected(doc: dict[str, Any]) -> None:
    doc["roadmap"]["nodes"]["island"] = [2.0, 1.0]


def _edge_misspelled(doc: dict[str, Any]) -> None:
    doc["roadmap"]["edges"].append(["w_1", "a1_11"])


def _dup_route(doc: dict[str, Any]) -> None:
    doc["routes"][1]["name"] = doc["routes"][0]["name"]


def _no_charger_pose(doc: dict[str, Any]) -> None:
    doc["chargers"][0].pop("pose")


BAD: list[tuple[str, Mutator, str, str]] = [
    # (id, mutation, field, reason keyword)
    ("unknown_top_level_key", _set("robot", []), "robot", "did you mean 'robots'"),
    ("unknown_nested_key", _set("robot_model.max_speed", 2.0), "robot_model.max_speed", "did you mean"),
    ("missing_section", _del("roadmap"), "roadmap", "missing required section"),
    ("missing_chargers", _del("chargers"), "chargers", "missing required section"),
    ("map_missing", _set("map", "maps/nope.yaml"), "map", "does not exist"),
    ("name_not_string", _set("name", 12), "name", "non-empty string"),
    (
        "speed_negative",
        _set("robot_model.max_linear_speed", -1.0),
        "robot_model.max_linear_speed",
        "must be a positive number up to 10, got -1.0",
    ),
    (
        "speed_not_number",
        _set("robot_model.max_linear_speed", "fast"),
        "robot_model.max_linear_speed",
        "positive number",
    ),
    ("radius_zero", _set("robot_model.radius", 0), "robot_model.radius", "positive"),
    (
        "accel_negative",
        _set("robot_model.max_angular_accel", -3),
        "robot_model.max_angular_accel",
        "positive",
    ),
    ("step_zero", _set("sim.step_s", 0.0), "sim.step_s", "in [0.001, 1]"),
    ("seed_float", _set("sim.seed", 1.5), "sim.seed", "integer"),
    ("tick_faster_than_step", _set("agent.tick_hz", 100.0), "agent.tick_hz", "shorter than sim.step_s"),
    (
        "timeout_negative",
        _set("coordinator.status_timeout_s", -1),
        "coordinator.status_timeout_s",
        "positive",
    ),
    ("bad_endpoint", _set("bus.endpoint", "localhost"), "bus.endpoint", "Zenoh endpoint"),
    ("battery_fraction", _set("battery.low", 1.5), "battery.low", "[0, 1]"),
    ("battery_low_above_resume", _set("battery.low", 0.96), "battery.low", "below battery.resume"),
    ("battery_drain_negative", _set("battery.drain_per_m", -0.1), "battery.drain_per_m", "in [0, 0.1]"),
    ("robot_battery", _set("robots.1.battery", 2), "robots[1].battery", "[0, 1]"),
    ("pose_two_numbers", _set("robots.0.start", [1.0, 2.0]), "robots[0].start", "[x, y, theta]"),
    ("pose_strings", _set("chargers.0.pose", ["a", "b", "c"]), "chargers[0].pose", "[x, y, theta]"),
    ("start_in_obstacle", _set("robots.2.start", IN_SHELF), "robots[2].start", "inside an obstacle"),
    ("start_off_map", _set("robots.2.start", [-5.0, 1.0, 0.0]), "robots[2].start", "off the map"),
    ("start_touching_wall", _set("robots.2.start", [0.35, 1.2, 0.0]), "robots[2].start", "radius"),
    ("charger_in_wall", _set("chargers.1.pose", [0.1, 8.0, 0.0]), "chargers[1].pose", "obstacle"),
    ("station_in_shelf", _set("stations.3.pose", IN_SHELF), "stations[3].pose", "obstacle"),
    (
        "route_pose_in_shelf",
        _set("routes.1.waypoints", ["a3_s", IN_SHELF]),
        "routes[1].waypoints[1]",
        "obstacle",
    ),
    ("robots_too_close", _too_close, "robots[3].start", "closer than 2 * robot_model.radius"),
    ("duplicate_robot", _dup_robot, "robots[4].name", "duplicate robot name"),
    ("duplicate_namespace", _dup_namespace, "robots[4].namespace", "duplicate namespace"),
    ("namespace_no_slash", _set("robots.0.namespace", "robot1"), "robots[0].namespace", "/robot1"),
    ("namespace_digit", _set("robots.0.namespace", "/1robot"), "robots[0].namespace", "/[A-Za-z]"),
    ("robot_name_bad", _set("robots.0.name", "robot 1"), "robots[0].name", "letter"),
    ("edge_unknown_node", _edge_unknown, "roadmap.edges[", "unknown roadmap node 'a99_1'"),
    ("edge_through_shelf", _edge_through_shelf, "roadmap.edges[", "passes through an obstacle"),
    ("node_in_shelf", _set("roadmap.nodes.a1_1", IN_SHELF[:2]), "roadmap.nodes.a1_1", "obstacle"),
    ("roadmap_disconnected", _disconnected, "roadmap", "not connected"),
    (
        "route_unknown_node",
        _set("routes.0.waypoints", ["a1_s", "a1_nn"]),
        "routes[0].waypoints[1]",
        "unknown roadmap node or station 'a1_nn' (did you mean 'a1_n'?)",
    ),
    ("route_one_waypoint", _set("routes.0.waypoints", ["a1_s"]), "routes[0].waypoints", "at least 2"),
    ("route_unknown_robot", _set("routes.0.robot", "robot9"), "routes[0].robot", "unknown robot 'robot9'"),
    ("task_unknown_robot", _set("tasks.0.robot", "robotx"), "tasks[0].robot", "unknown robot"),
    ("task_unknown_station", _set("tasks.0.shelf", "pick_a9_9_e"), "tasks[0].shelf", "unknown station"),
    ("task_negative_dwell", _set("tasks.0.dwell_s", -1), "tasks[0].dwell_s", "in [0, 3600]"),
    ("no_chargers", _set("chargers", []), "chargers", "at least one"),
    ("no_robots", _set("robots", []), "robots", "at least one"),
    ("duplicate_charger", _set("chargers.1.name", "charger1"), "chargers[1].name", "duplicate"),
    ("station_named_like_node", _set("stations.0.name", "a1_s"), "stations[0].name", "roadmap node"),
    ("section_wrong_type", _set("robot_model", [1, 2]), "robot_model", "mapping"),
    ("robots_not_list", _set("robots", {"robot1": [1, 1, 0]}), "robots", "must be a list"),
    ("edge_misspelled_node", _edge_misspelled, "roadmap.edges[", "(did you mean 'a1_1'?)"),
    ("duplicate_route", _dup_route, "routes[1].name", "duplicate route name"),
    ("charger_without_pose", _no_charger_pose, "chargers[0].pose", "missing required field"),
    ("start_not_a_number", _set("robots.0.start", [math.nan, 1.0, 0.0]), "robots[0].start", "[x, y, theta]"),
    ("traffic_enabled_not_bool", _set("traffic", {"enabled": "yes"}), "traffic.enabled", "true or false"),
    ("status_hz_zero", _set("bus.status_hz", 0), "bus.status_hz", "positive"),
    (
        "waypoint_not_a_name_or_pose",
        _set("routes.0.waypoints", ["a1_s", 5]),
        "routes[0].waypoints[1]",
        "a roadmap node name, a station name or a pose",
    ),
    (
        "shelf_not_a_name_or_pose",
        _set("tasks.0.shelf", {"x": 1}),
        "tasks[0].shelf",
        "a station name or a pose",
    ),
    ("roadmap_node_not_xy", _set("roadmap.nodes.a1_1", [6.0]), "roadmap.nodes.a1_1", "[x, y] in meters"),
    ("roadmap_empty", _set("roadmap", None), "roadmap", "must be a mapping with nodes and edges"),
]


@pytest.mark.parametrize(("mutate", "field", "word"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_config_names_file_field_and_reason(
    tmp_path: Path, base: dict[str, Any], mutate: Mutator, field: str, word: str
) -> None:
    doc = copy.deepcopy(base)
    mutate(doc)
    path = write(tmp_path, doc)
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    msg = str(ei.value)
    assert msg.startswith(f"{path}: {field}"), msg
    assert word in msg, msg


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match=r"nope\.yaml: config file does not exist"):
        load_config(path)


def test_invalid_yaml_reports_the_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("name: x\nmap: maps/warehouse.yaml\nrobots: [\n  {name: robot1,\n chargers: ]\n")
    with pytest.raises(ConfigError) as ei:
        load_config(path)
    assert str(ei.value).startswith(f"{path}: not valid YAML (line ")


def test_top_level_not_a_mapping(tmp_path: Path) -> None:
    path = tmp_path / "list.yaml"
    path.write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="expected a mapping of sections"):
        load_config(path)


def test_map_image_missing_is_a_map_error(tmp_path: Path, base: dict[str, Any]) -> None:
    shutil.copy(CONFIGS / "maps" / "warehouse.yaml", tmp_path / "warehouse.yaml")
    doc = copy.deepcopy(base)
    doc["map"] = "warehouse.yaml"
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(MapError) as ei:
        load_config(path)
    assert isinstance(ei.value, ConfigError)
    assert "image" in str(ei.value) and "does not exist" in str(ei.value)


def test_a_png_map_loads_like_the_pgm(tmp_path: Path, base: dict[str, Any]) -> None:
    from PIL import Image

    with Image.open(CONFIGS / "maps" / "warehouse.pgm") as img:
        img.save(tmp_path / "warehouse.png")
    meta = yaml.safe_load((CONFIGS / "maps" / "warehouse.yaml").read_text())
    (tmp_path / "warehouse.yaml").write_text(yaml.safe_dump({**meta, "image": "warehouse.png"}))
    doc = copy.deepcopy(base)
    doc["map"] = "warehouse.yaml"
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(doc))
    cfg, shipped = load_config(path), load_config(PATROL)
    assert (cfg.grid.cells == shipped.grid.cells).all()
    assert cfg.robots == shipped.robots and cfg.routes == shipped.routes


def test_a_map_naming_the_image_instead_of_the_yaml_is_blamed_on_map(
    tmp_path: Path, base: dict[str, Any]
) -> None:
    doc = copy.deepcopy(base)
    doc["map"] = str(CONFIGS / "maps" / "warehouse.pgm")
    path = write(tmp_path, doc)
    with pytest.raises(MapError) as ei:
        load_config(path)
    assert (ei.value.file, ei.value.field) == (str(path), "map")
    assert "warehouse.pgm" in ei.value.reason and "name the map's YAML file" in ei.value.reason


def test_an_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.yaml"
    path.write_text("")
    with pytest.raises(
        ConfigError, match=r"empty\.yaml: expected a mapping of sections at the top level, got nothing"
    ):
        load_config(path)


def test_map_path_is_relative_to_the_config(tmp_path: Path) -> None:
    shutil.copytree(CONFIGS, tmp_path / "configs")
    cfg = load_config(tmp_path / "configs" / "warehouse_patrol.yaml")
    assert cfg.map_path == (tmp_path / "configs" / "maps" / "warehouse.yaml").resolve()


# ---------------------------------------------------------------------------- robots=N


def test_robots_override_smaller_keeps_the_first() -> None:
    cfg = load_config(PATROL, robots=3)
    assert [r.name for r in cfg.robots] == ["robot1", "robot2", "robot3"]


def test_robots_override_larger_adds_robots_on_free_spread_spots() -> None:
    small = load_config(PATROL)
    cfg = load_config(PATROL, robots=80)
    assert len(cfg.robots) == 80
    assert cfg.robots[:6] == small.robots
    assert [r.name for r in cfg.robots[6:9]] == ["robot7", "robot8", "robot9"]
    assert len({r.namespace for r in cfg.robots}) == 80
    r = cfg.sim.model.radius
    starts = [s.start for s in cfg.robots]
    for i, a in enumerate(starts):
        assert cfg.grid.is_free(a.x, a.y, r)
        for b in starts[i + 1 :]:
            assert a.distance_to(b) >= 1.0 - 1e-9
    assert load_config(PATROL, robots=80).robots == cfg.robots  # deterministic


def test_robots_override_too_many_says_how_many_fit() -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(PATROL, robots=100_000)
    msg = str(ei.value)
    assert msg.startswith(f"{PATROL}: robots: cannot place 100000 robots: only ")
    fit = int(msg.split("only ")[1].split()[0])
    assert 58 <= fit < 100_000
    assert len(load_config(PATROL, robots=fit).robots) == fit


def test_robots_override_must_be_positive() -> None:
    with pytest.raises(ConfigError, match="robots: override must be a positive integer"):
        load_config(PATROL, robots=0)


def test_the_example_in_docs_loads(tmp_path: Path) -> None:
    text = (CONFIGS.parent / "docs" / "config.md").read_text()
    example = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    doc = yaml.safe_load(example)
    cfg = load_config(write(tmp_path, doc, "example.yaml"))
    assert cfg.route("west_loop").robot == "robot2"
    assert cfg.robot("robot2").battery == 0.6
    assert [r.name for r in load_config(write(tmp_path, doc, "example.yaml"), robots=4).robots][2:] == [
        "robot3",
        "robot4",
    ]
