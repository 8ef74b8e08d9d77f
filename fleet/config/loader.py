"""Fleet configuration files: loading and validation.

:func:`load_config` reads one YAML file (format: ``docs/config.md``), loads its map, builds
the :class:`~fleet.roadmap.Roadmap` and checks every field. The first problem found raises a
:class:`~fleet.errors.ConfigError` whose ``str()`` reads ``<file>: <field>: <reason>``, e.g.
``configs/bad.yaml: robots[2].start: pose (4.0, 7.5) is inside an obstacle or within 0.3 m
of one``. Problems inside the map files themselves raise :class:`~fleet.errors.MapError` (a
``ConfigError``) naming the map file.

All poses are in the ``map`` frame: meters and radians. Paths inside a config are relative to
the config file."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import yaml

from fleet.config.checks import NAMESPACE_RE, _NearIndex, _Placer, _suggest, _tname, _Validator, _yaml_problem
from fleet.config.model import (
    DEFAULT_ENDPOINT,
    CoordinatorParams,
    FleetConfig,
    NamedPose,
    PickTask,
    Route,
    TrafficSettings,
)
from fleet.errors import ConfigError
from fleet.maps import OccupancyGrid, load_map
from fleet.roadmap.graph import Roadmap
from fleet.robots import BatteryModel, RobotModel, RobotSpec, SimParams
from fleet.types import Pose2D

PARKING_SPACING = 1.0  # m, minimum distance of an added robot's start from any other start


_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml when available: same result, faster


TOP_LEVEL_KEYS = (
    "name",
    "map",
    "roadmap",
    "chargers",
    "stations",
    "routes",
    "tasks",
    "parking",
    "robots",
    "robot_model",
    "battery",
    "sim",
    "agent",
    "coordinator",
    "traffic",
    "bus",
)


REQUIRED_KEYS = ("name", "map", "roadmap", "chargers", "robots")


def load_config(path: str | Path, *, robots: int | None = None) -> FleetConfig:
    """Load and validate the fleet config at ``path``.

    ``robots=N`` overrides the robot count: the first ``N`` listed robots are kept, and if
    ``N`` is larger, robots ``robot<K>`` (the next unused numbers) are added on free start
    spots: first the file's ``parking`` spots, then points every 1 m along roadmap edges,
    each at least 1 m from every other start and from the chargers. Raises
    :class:`ConfigError` for any invalid field (see ``docs/config.md`` for the checks) and
    with field ``robots`` if ``N`` robots do not fit (the reason says how many do).
    """
    p = Path(path)
    v = _Validator(str(path))
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise ConfigError(v.file, "", "config file does not exist") from None
    except (IsADirectoryError, UnicodeDecodeError, PermissionError) as e:
        raise ConfigError(v.file, "", f"cannot read config file ({e})") from None
    try:
        doc = yaml.load(text, Loader=_YAML_LOADER)  # noqa: S506 - a safe loader
    except yaml.YAMLError as e:
        raise ConfigError(v.file, "", f"not valid YAML ({_yaml_problem(e)})") from None
    if not isinstance(doc, dict):
        raise ConfigError(v.file, "", f"expected a mapping of sections at the top level, got {_tname(doc)}")
    v.keys(doc, "", TOP_LEVEL_KEYS)
    for key in REQUIRED_KEYS:
        if key not in doc:
            raise ConfigError(v.file, key, "missing required section")

    name = v.string(doc["name"], "name")
    map_rel = v.string(doc["map"], "map")
    map_path = (p.parent / map_rel).resolve()
    if not map_path.is_file():
        raise ConfigError(v.file, "map", f"map file {map_rel!r} does not exist (looked for {map_path})")
    grid = load_map(map_path)

    model = _robot_model(v, doc.get("robot_model"))
    battery = _battery(v, doc.get("battery"))
    sim_sec = v.section(doc.get("sim"), "sim", ("step_s", "stuck_time_s", "seed", *_SIM_EXTRA))
    step_s = v.positive(sim_sec.get("step_s", 0.05), "sim.step_s")
    sim_kw: dict[str, Any] = {
        "step_s": step_s,
        "stuck_time_s": v.positive(sim_sec.get("stuck_time_s", 8.0), "sim.stuck_time_s"),
        "seed": v.integer(sim_sec.get("seed", 1), "sim.seed"),
    }
    for key in _SIM_EXTRA:
        if key in sim_sec:
            sim_kw[key] = v.positive(sim_sec[key], f"sim.{key}")
    agent = v.section(doc.get("agent"), "agent", ("tick_hz",))
    tick_hz = v.positive(agent.get("tick_hz", 10.0), "agent.tick_hz")
    if 1.0 / tick_hz < step_s - 1e-12:
        raise ConfigError(
            v.file, "agent.tick_hz", f"tick period 1/{tick_hz:g} s is shorter than sim.step_s ({step_s:g} s)"
        )
    coord = v.section(doc.get("coordinator"), "coordinator", ("stuck_reassign_s", "status_timeout_s"))
    coordinator = CoordinatorParams(
        stuck_reassign_s=v.positive(coord.get("stuck_reassign_s", 30.0), "coordinator.stuck_reassign_s"),
        status_timeout_s=v.positive(coord.get("status_timeout_s", 3.0), "coordinator.status_timeout_s"),
    )
    traffic = _traffic(v, doc.get("traffic"))
    bus = v.section(doc.get("bus"), "bus", ("endpoint", "status_hz"))
    endpoint = v.string(bus.get("endpoint", DEFAULT_ENDPOINT), "bus.endpoint")
    if not re.match(r"^[a-z][a-z0-9-]*/\S+$", endpoint):
        raise ConfigError(
            v.file, "bus.endpoint", f"must be a Zenoh endpoint like {DEFAULT_ENDPOINT}, got {endpoint!r}"
        )
    status_hz = v.positive(bus["status_hz"], "bus.status_hz") if "status_hz" in bus else None

    radius = model.radius
    place = _Placer(v, grid, radius)

    roadmap = Roadmap.from_config_dict(doc["roadmap"], v.file, base_dir=p.parent)
    net = roadmap.source_net is not None  # from roadmap.net: fields name SUMO junctions
    for n in roadmap.nodes:
        place.check(Pose2D(*roadmap.pos(n)), f"roadmap.net.junctions.{n}" if net else f"roadmap.nodes.{n}")
    for i, (a, b) in enumerate(roadmap.edges):
        f = f"roadmap.net.edges[{a}, {b}]" if net else f"roadmap.edges[{i}]"
        place.check_segment(roadmap.pos(a), roadmap.pos(b), f, f"edge {a} - {b}")
    if not roadmap.is_connected():
        first = roadmap.nodes[0]
        cut = [n for n in roadmap.nodes if not roadmap.shortest_path(first, n)]
        raise ConfigError(v.file, "roadmap", f"not connected: {cut[0]!r} cannot be reached from {first!r}")

    chargers = [
        NamedPose(nm, pose)
        for nm, pose in _named_poses(v, place, doc["chargers"], "chargers", required=True, names=set())
    ]
    stations: dict[str, NamedPose] = {}
    for nm, pose in _named_poses(v, place, doc.get("stations"), "stations", required=False, names=set()):
        stations[nm] = NamedPose(nm, pose)
    for i, nm in enumerate(stations):
        if nm in roadmap:
            raise ConfigError(v.file, f"stations[{i}].name", f"{nm!r} is also a roadmap node name")

    parking = [place.pose(p_, f"parking[{i}]") for i, p_ in enumerate(v.list(doc.get("parking"), "parking"))]

    robot_specs = _robots(v, place, doc["robots"], battery.initial, radius)
    if robots is not None:
        robot_specs = _override_robots(
            v, grid, roadmap, robot_specs, parking, chargers, robots, radius, battery
        )
    robot_names = {r.name for r in robot_specs}

    routes = _routes(v, place, doc.get("routes"), roadmap, stations, robot_names)
    tasks = _tasks(v, place, doc.get("tasks"), stations, robot_names)

    sim = SimParams(
        **sim_kw,
        chargers=tuple(c.pose for c in chargers),
        model=model,
        battery=battery,
    )
    return FleetConfig(
        name=name,
        path=p,
        map_path=map_path,
        grid=grid,
        roadmap=roadmap,
        chargers=chargers,
        stations=stations,
        routes=routes,
        tasks=tasks,
        robots=robot_specs,
        sim=sim,
        tick_hz=tick_hz,
        coordinator=coordinator,
        endpoint=endpoint,
        status_hz=status_hz,
        parking=parking,
        traffic=traffic,
    )


_SIM_EXTRA = ("charger_radius", "goal_tolerance", "yaw_tolerance")


_MODEL_KEYS = ("radius", "max_linear_speed", "max_angular_speed", "max_linear_accel", "max_angular_accel")


_DRAIN_KEYS = ("drain_per_m", "drain_per_s")


_FRACTION_KEYS = ("low", "resume", "initial")


def _traffic(v: _Validator, sec: Any) -> TrafficSettings:
    d = v.section(sec, "traffic", ("enabled", "deadlock_s", "park_idle_s", "horizon_m", "stall_timeout_s"))
    enabled = d.get("enabled", False)
    if not isinstance(enabled, bool):
        raise ConfigError(v.file, "traffic.enabled", f"must be true or false, got {enabled!r}")
    kw: dict[str, float] = {
        k: v.positive(d[k], f"traffic.{k}") for k in ("deadlock_s", "horizon_m", "stall_timeout_s") if k in d
    }
    if "park_idle_s" in d:
        kw["park_idle_s"] = v.non_negative(d["park_idle_s"], "traffic.park_idle_s")
    return TrafficSettings(enabled=enabled, **kw)


def _robot_model(v: _Validator, sec: Any) -> RobotModel:
    d = v.section(sec, "robot_model", _MODEL_KEYS)
    defaults = RobotModel()
    return RobotModel(
        **{k: v.positive(d.get(k, getattr(defaults, k)), f"robot_model.{k}") for k in _MODEL_KEYS}
    )


def _battery(v: _Validator, sec: Any) -> BatteryModel:
    d = v.section(sec, "battery", ("charge_per_s", *_DRAIN_KEYS, *_FRACTION_KEYS))
    b = BatteryModel()
    kw: dict[str, float] = {k: v.non_negative(d.get(k, getattr(b, k)), f"battery.{k}") for k in _DRAIN_KEYS}
    kw["charge_per_s"] = v.positive(d.get("charge_per_s", b.charge_per_s), "battery.charge_per_s")
    for k in _FRACTION_KEYS:
        kw[k] = v.fraction(d.get(k, getattr(b, k)), f"battery.{k}")
    if kw["low"] >= kw["resume"]:
        raise ConfigError(
            v.file, "battery.low", f"must be below battery.resume ({kw['resume']}), got {kw['low']}"
        )
    return BatteryModel(**kw)


def _named_poses(
    v: _Validator, place: _Placer, sec: Any, field_: str, *, required: bool, names: set[str]
) -> list[tuple[str, Pose2D]]:
    items = v.list(sec, field_)
    if required and not items:
        raise ConfigError(v.file, field_, "needs at least one entry")
    out = []
    for i, item in enumerate(items):
        f = f"{field_}[{i}]"
        d = v.section(item, f, ("name", "pose"), required=("name", "pose"))
        nm = v.name(d["name"], f"{f}.name")
        if nm in names:
            raise ConfigError(v.file, f"{f}.name", f"duplicate name {nm!r}")
        names.add(nm)
        out.append((nm, place.pose(d["pose"], f"{f}.pose")))
    return out


def _robots(v: _Validator, place: _Placer, sec: Any, initial: float, radius: float) -> list[RobotSpec]:
    items = v.list(sec, "robots")
    if not items:
        raise ConfigError(v.file, "robots", "needs at least one robot")
    out: list[RobotSpec] = []
    seen_ns: set[str] = set()
    near = _NearIndex(2 * radius)
    for i, item in enumerate(items):
        f = f"robots[{i}]"
        d = v.section(item, f, ("name", "namespace", "start", "battery"), required=("name", "start"))
        nm = v.name(d["name"], f"{f}.name")
        if any(r.name == nm for r in out):
            raise ConfigError(v.file, f"{f}.name", f"duplicate robot name {nm!r}")
        ns = v.string(d.get("namespace", f"/{nm}"), f"{f}.namespace")
        if not NAMESPACE_RE.match(ns):
            raise ConfigError(
                v.file, f"{f}.namespace", f"must look like /robot1 (/[A-Za-z][A-Za-z0-9_]*), got {ns!r}"
            )
        if ns in seen_ns:
            raise ConfigError(v.file, f"{f}.namespace", f"duplicate namespace {ns!r}")
        seen_ns.add(ns)
        start = place.pose(d["start"], f"{f}.start")
        hit = near.closer_than(start.x, start.y, 2 * radius)
        if hit is not None:
            other = out[hit]
            dist = math.hypot(other.start.x - start.x, other.start.y - start.y)
            raise ConfigError(
                v.file,
                f"{f}.start",
                f"{dist:.2f} m from {other.name}'s start, closer than 2 * robot_model.radius ({2 * radius:g} m)",
            )
        near.add(start.x, start.y, len(out))
        bat = v.fraction(d.get("battery", initial), f"{f}.battery")
        out.append(RobotSpec(name=nm, namespace=ns, start=start, battery=bat))
    return out


def _override_robots(
    v: _Validator,
    grid: OccupancyGrid,
    roadmap: Roadmap,
    listed: list[RobotSpec],
    parking: list[Pose2D],
    chargers: list[NamedPose],
    n: Any,
    radius: float,
    battery: BatteryModel,
) -> list[RobotSpec]:
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ConfigError(v.file, "robots", f"override must be a positive integer, got {n!r}")
    if n <= len(listed):
        return listed[:n]
    spacing = max(PARKING_SPACING, 2 * radius)
    near = _NearIndex(spacing)
    for r in listed:
        near.add(r.start.x, r.start.y, 0)
    for c in chargers:
        near.add(c.pose.x, c.pose.y, 0)
    out = list(listed)
    used = {r.name for r in listed} | {r.namespace.lstrip("/") for r in listed}
    k = 1
    for cand in _start_candidates(roadmap, parking):
        if len(out) == n:
            break
        if near.closer_than(cand.x, cand.y, spacing) is not None or not grid.is_free(cand.x, cand.y, radius):
            continue
        near.add(cand.x, cand.y, 0)
        while f"robot{k}" in used:
            k += 1
        nm = f"robot{k}"
        used.add(nm)
        out.append(RobotSpec(name=nm, namespace=f"/{nm}", start=cand, battery=battery.initial))
    if len(out) < n:
        raise ConfigError(
            v.file,
            "robots",
            f"cannot place {n} robots: only {len(out)} fit ({len(listed)} listed + {len(out) - len(listed)} "
            f"free start spots at least {spacing:g} m apart)",
        )
    return out


def _start_candidates(roadmap: Roadmap, parking: list[Pose2D]) -> list[Pose2D]:
    """Parking spots first, then points every 1 m along roadmap edges (facing along the edge)."""
    out = list(parking)
    for a, b in roadmap.edges:
        (ax, ay), (bx, by) = roadmap.pos(a), roadmap.pos(b)
        length = math.hypot(bx - ax, by - ay)
        th = math.atan2(by - ay, bx - ax)
        steps = int(length // PARKING_SPACING)
        for s in range(steps + 1):
            t = s * PARKING_SPACING / length if length > 0 else 0.0
            out.append(Pose2D(ax + t * (bx - ax), ay + t * (by - ay), th))
    return out


def _routes(
    v: _Validator,
    place: _Placer,
    sec: Any,
    roadmap: Roadmap,
    stations: dict[str, NamedPose],
    robot_names: set[str],
) -> list[Route]:
    out: list[Route] = []
    for i, item in enumerate(v.list(sec, "routes")):
        f = f"routes[{i}]"
        d = v.section(item, f, ("name", "waypoints", "robot"), required=("name", "waypoints"))
        nm = v.name(d["name"], f"{f}.name")
        if any(r.name == nm for r in out):
            raise ConfigError(v.file, f"{f}.name", f"duplicate route name {nm!r}")
        wps = v.list(d["waypoints"], f"{f}.waypoints")
        if len(wps) < 2:
            raise ConfigError(v.file, f"{f}.waypoints", f"a route needs at least 2 waypoints, got {len(wps)}")
        xy: list[tuple[float, float, float | None]] = []
        nodes: list[str | None] = []
        for j, w in enumerate(wps):
            wf = f"{f}.waypoints[{j}]"
            if isinstance(w, str):
                if w in roadmap:
                    x, y = roadmap.pos(w)
                    xy.append((x, y, None))
                    nodes.append(w)
                elif w in stations:
                    s = stations[w].pose
                    xy.append((s.x, s.y, s.theta))
                    nodes.append(None)
                else:
                    raise ConfigError(
                        v.file,
                        wf,
                        f"unknown roadmap node or station {w!r}{_suggest(w, [*roadmap.nodes, *stations])}",
                    )
            else:
                pose = place.pose(w, wf)
                xy.append((pose.x, pose.y, pose.theta))
                nodes.append(None)
        poses = []
        for j, (x, y, th) in enumerate(xy):
            if th is None:
                nx_, ny_, _ = xy[(j + 1) % len(xy)]
                th = math.atan2(ny_ - y, nx_ - x) if (nx_, ny_) != (x, y) else 0.0
            poses.append(Pose2D(x, y, th))
        robot = _robot_ref(v, d.get("robot"), f"{f}.robot", robot_names)
        out.append(Route(name=nm, waypoints=tuple(poses), node_names=tuple(nodes), robot=robot))
    return out


def _tasks(
    v: _Validator, place: _Placer, sec: Any, stations: dict[str, NamedPose], robot_names: set[str]
) -> list[PickTask]:
    out: list[PickTask] = []
    for i, item in enumerate(v.list(sec, "tasks")):
        f = f"tasks[{i}]"
        d = v.section(
            item, f, ("name", "shelf", "drop", "dwell_s", "robot"), required=("name", "shelf", "drop")
        )
        nm = v.name(d["name"], f"{f}.name")
        if any(t.name == nm for t in out):
            raise ConfigError(v.file, f"{f}.name", f"duplicate task name {nm!r}")
        ends: dict[str, tuple[Pose2D, str]] = {}
        for key in ("shelf", "drop"):
            ref = d[key]
            if isinstance(ref, str):
                if ref not in stations:
                    raise ConfigError(
                        v.file, f"{f}.{key}", f"unknown station {ref!r}{_suggest(ref, stations)}"
                    )
                ends[key] = (stations[ref].pose, ref)
            else:
                ends[key] = (place.pose(ref, f"{f}.{key}"), "")
        dwell = v.non_negative(d.get("dwell_s", 5.0), f"{f}.dwell_s")
        robot = _robot_ref(v, d.get("robot"), f"{f}.robot", robot_names)
        out.append(
            PickTask(
                name=nm,
                shelf=ends["shelf"][0],
                drop=ends["drop"][0],
                dwell_s=dwell,
                robot=robot,
                shelf_station=ends["shelf"][1],
                drop_station=ends["drop"][1],
            )
        )
    return out


def _robot_ref(v: _Validator, ref: Any, f: str, robot_names: set[str]) -> str | None:
    if ref is None:
        return None
    nm = v.string(ref, f)
    if nm not in robot_names:
        raise ConfigError(v.file, f, f"unknown robot {nm!r}{_suggest(nm, sorted(robot_names))}")
    return nm
