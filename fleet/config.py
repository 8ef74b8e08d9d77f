"""Fleet configuration files: loading and validation.

:func:`load_config` reads one YAML file (format: ``docs/config.md``), loads its map, builds
the :class:`~fleet.roadmap.Roadmap` and checks every field. The first problem found raises a
:class:`~fleet.errors.ConfigError` whose ``str()`` reads ``<file>: <field>: <reason>``, e.g.
``configs/bad.yaml: robots[2].start: pose (4.0, 7.5) is inside an obstacle or within 0.3 m
of one``. Problems inside the map files themselves raise :class:`~fleet.errors.MapError` (a
``ConfigError``) naming the map file.

All poses are in the ``map`` frame: meters and radians. Paths inside a config are relative to
the config file.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from fleet.errors import ConfigError
from fleet.roadmap import Roadmap
from fleet.types import Pose2D
from sim.occupancy import OccupancyGrid, load_map
from sim.params import BatteryModel, RobotModel, RobotSpec, SimParams

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
NAMESPACE_RE = re.compile(r"^/[A-Za-z][A-Za-z0-9_]*$")
PARKING_SPACING = 1.0  # m, minimum distance of an added robot's start from any other start
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
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


@dataclass(frozen=True)
class NamedPose:
    """A named pose in the ``map`` frame (a charger or a station)."""

    name: str
    pose: Pose2D


@dataclass(frozen=True)
class Route:
    """A patrol route, driven as a loop.

    ``waypoints`` are the poses as listed in the file (a roadmap node gets ``theta`` pointing
    at the next waypoint, cyclically); ``node_names[i]`` is the roadmap node of waypoint ``i``
    or ``None`` for an explicit pose or a station. ``robot`` is an optional preferred robot.
    """

    name: str
    waypoints: tuple[Pose2D, ...]
    node_names: tuple[str | None, ...]
    robot: str | None = None


@dataclass(frozen=True)
class PickTask:
    """A picking task: drive to ``shelf``, stand ``dwell_s`` seconds, drive to ``drop``.

    ``shelf_station`` / ``drop_station`` are the station names used in the file (``""`` for
    an explicit pose); ``robot`` is an optional preferred robot.
    """

    name: str
    shelf: Pose2D
    drop: Pose2D
    dwell_s: float = 5.0
    robot: str | None = None
    shelf_station: str = ""
    drop_station: str = ""


@dataclass(frozen=True)
class CoordinatorParams:
    """``stuck_reassign_s``: a robot stuck this long loses its patrol to another robot;
    ``status_timeout_s``: a robot silent this long is considered dead."""

    stuck_reassign_s: float = 30.0
    status_timeout_s: float = 3.0


@dataclass(frozen=True)
class TrafficSettings:
    """The ``traffic`` section (``docs/traffic.md``). ``enabled``: reservation-based traffic
    management on the roadmap (``fleet run --traffic`` turns it on too); ``deadlock_s``: a
    set of robots waiting on each other longer than this counts as a deadlock in the report;
    ``park_idle_s``: an idle robot standing off its parking spot this long is sent to park;
    ``horizon_m``: how much path ahead a robot is granted; ``stall_timeout_s``: a robot with
    a grant ahead that makes no progress this long is treated as stopped (its reservations
    ahead are released)."""

    enabled: bool = False
    deadlock_s: float = 30.0
    park_idle_s: float = 5.0
    horizon_m: float = 6.0
    stall_timeout_s: float = 20.0


@dataclass
class FleetConfig:
    """A validated fleet configuration. See ``docs/config.md`` for the file format."""

    name: str
    path: Path
    map_path: Path
    grid: OccupancyGrid
    roadmap: Roadmap
    chargers: list[NamedPose]
    stations: dict[str, NamedPose]
    routes: list[Route]
    tasks: list[PickTask]
    robots: list[RobotSpec]
    sim: SimParams
    tick_hz: float = 10.0
    coordinator: CoordinatorParams = field(default_factory=CoordinatorParams)
    endpoint: str = DEFAULT_ENDPOINT
    status_hz: float | None = None
    parking: list[Pose2D] = field(default_factory=list)
    traffic: TrafficSettings = field(default_factory=TrafficSettings)

    def robot(self, name: str) -> RobotSpec:
        """The robot called ``name``. Raises ``KeyError`` if there is none."""
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(f"no robot named {name!r}")

    def route(self, name: str) -> Route:
        """The route called ``name``. Raises ``KeyError`` if there is none."""
        for r in self.routes:
            if r.name == name:
                return r
        raise KeyError(f"no route named {name!r}")

    def route_poses(self, route: Route) -> tuple[Pose2D, ...]:
        """The poses to drive for one lap of ``route``.

        If every waypoint is a roadmap node, the lap follows roadmap shortest paths between
        them (:meth:`Roadmap.expand_route`, closed), each pose facing the next; otherwise the
        waypoints as listed.
        """
        names = route.node_names
        if all(n is not None for n in names):
            dense = self.roadmap.expand_route([n for n in names if n is not None], closed=True)
            return self.roadmap.poses_for(dense, closed=True)
        return route.waypoints


# ---------------------------------------------------------------------------- loading


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


# ---------------------------------------------------------------------------- helpers


class _Validator:
    """Type checks that raise ConfigError naming ``file`` and the field."""

    def __init__(self, file: str) -> None:
        self.file = file

    def keys(self, d: Mapping[Any, Any], prefix: str, allowed: tuple[str, ...]) -> None:
        for key in d:
            if key not in allowed:
                f = f"{prefix}.{key}" if prefix else str(key)
                raise ConfigError(self.file, f, f"unknown key{_suggest(str(key), allowed)}")

    def section(
        self, sec: Any, f: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()
    ) -> dict[str, Any]:
        if sec is None:
            sec = {}
        if not isinstance(sec, dict):
            raise ConfigError(self.file, f, f"must be a mapping, got {_tname(sec)}")
        self.keys(sec, f, allowed)
        for key in required:
            if key not in sec:
                raise ConfigError(self.file, f"{f}.{key}", "missing required field")
        return sec

    def list(self, sec: Any, f: str) -> list[Any]:
        if sec is None:
            return []
        if not isinstance(sec, list):
            raise ConfigError(self.file, f, f"must be a list, got {_tname(sec)}")
        return sec

    def string(self, val: Any, f: str) -> str:
        if not isinstance(val, str) or not val:
            raise ConfigError(self.file, f, f"must be a non-empty string, got {val!r}")
        return val

    def name(self, val: Any, f: str) -> str:
        s = self.string(val, f)
        if not NAME_RE.match(s):
            raise ConfigError(self.file, f, f"must be a letter then letters, digits or _, got {s!r}")
        return s

    def number(self, val: Any, f: str, what: str = "a number") -> float:
        if not _is_number(val):
            raise ConfigError(self.file, f, f"must be {what}, got {val!r}")
        return float(val)

    def positive(self, val: Any, f: str) -> float:
        x = self.number(val, f, "a positive number")
        if x <= 0:
            raise ConfigError(self.file, f, f"must be a positive number, got {x!r}")
        return x

    def non_negative(self, val: Any, f: str) -> float:
        x = self.number(val, f, "a number >= 0")
        if x < 0:
            raise ConfigError(self.file, f, f"must be a number >= 0, got {x!r}")
        return x

    def fraction(self, val: Any, f: str) -> float:
        x = self.number(val, f, "a fraction in [0, 1]")
        if not 0.0 <= x <= 1.0:
            raise ConfigError(self.file, f, f"must be a fraction in [0, 1], got {x!r}")
        return x

    def integer(self, val: Any, f: str) -> int:
        if not isinstance(val, int) or isinstance(val, bool):
            raise ConfigError(self.file, f, f"must be an integer, got {val!r}")
        return val


class _Placer:
    """Pose parsing plus the map checks (inside the map, clear of obstacles by the radius)."""

    def __init__(self, v: _Validator, grid: OccupancyGrid, radius: float) -> None:
        self.v, self.grid, self.radius = v, grid, radius

    def pose(self, val: Any, f: str) -> Pose2D:
        if not (isinstance(val, (list, tuple)) and len(val) == 3 and all(_is_number(x) for x in val)):
            raise ConfigError(
                self.v.file, f, f"must be a pose [x, y, theta] of numbers (m, m, rad), got {val!r}"
            )
        pose = Pose2D(float(val[0]), float(val[1]), float(val[2]))
        self.check(pose, f)
        return pose

    def check(self, pose: Pose2D, f: str) -> None:
        if not self.grid.in_bounds(pose.x, pose.y):
            xmin, xmax, ymin, ymax = self.grid.extent
            raise ConfigError(
                self.v.file,
                f,
                f"pose ({pose.x:g}, {pose.y:g}) is off the map (x in [{xmin:g}, {xmax:g}), y in [{ymin:g}, {ymax:g}))",
            )
        if not self.grid.is_free(pose.x, pose.y, self.radius):
            raise ConfigError(
                self.v.file,
                f,
                f"pose ({pose.x:g}, {pose.y:g}) is inside an obstacle or within robot_model.radius "
                f"({self.radius:g} m) of one",
            )

    def check_segment(self, a: tuple[float, float], b: tuple[float, float], f: str, what: str) -> None:
        (ax, ay), (bx, by) = a, b
        n = max(1, math.ceil(math.hypot(bx - ax, by - ay) / self.grid.resolution))
        for k in range(n + 1):
            x, y = ax + (bx - ax) * k / n, ay + (by - ay) * k / n
            if not self.grid.is_free(x, y, self.radius):
                raise ConfigError(
                    self.v.file,
                    f,
                    f"{what} passes through an obstacle at ({x:.2f}, {y:.2f}) "
                    f"(clearance robot_model.radius = {self.radius:g} m)",
                )


class _NearIndex:
    """A uniform hash grid for "is any stored point closer than d" queries (d <= cell)."""

    def __init__(self, cell: float) -> None:
        self.cell = cell
        self.buckets: dict[tuple[int, int], list[tuple[float, float, int]]] = {}

    def _key(self, x: float, y: float) -> tuple[int, int]:
        return (math.floor(x / self.cell), math.floor(y / self.cell))

    def add(self, x: float, y: float, idx: int) -> None:
        self.buckets.setdefault(self._key(x, y), []).append((x, y, idx))

    def closer_than(self, x: float, y: float, d: float) -> int | None:
        cx, cy = self._key(x, y)
        best: tuple[float, int] | None = None
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                for px, py, idx in self.buckets.get((cx + i, cy + j), ()):
                    dd = math.hypot(px - x, py - y)
                    if dd < d - 1e-9 and (best is None or (dd, idx) < best):
                        best = (dd, idx)
        return None if best is None else best[1]


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _tname(v: object) -> str:
    return "nothing" if v is None else type(v).__name__


def _suggest(word: str, options: Any) -> str:
    match = difflib.get_close_matches(word, [str(o) for o in options], n=1)
    return f" (did you mean {match[0]!r}?)" if match else ""


def _yaml_problem(e: yaml.YAMLError) -> str:
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    if mark is not None:
        return f"line {mark.line + 1}, column {mark.column + 1}: {problem}"
    return str(problem)
