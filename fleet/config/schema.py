"""The schema of a fleet config file: one pydantic model per YAML section (``docs/config.md``).

This is the first stage of :func:`fleet.config.load_config`: the YAML document's shape, types,
defaults and ranges, names, and the few rules between fields of the file itself (unique names,
``battery.low`` below ``battery.resume``, the tick period not shorter than the step). What
needs the map or the roadmap (poses free of obstacles, references to nodes, stations and
robots, robots apart) is the second stage, :mod:`fleet.config.checks`.

:func:`validate_document` raises a :class:`~fleet.errors.ConfigError` for the first problem;
:func:`json_schema` is the JSON Schema published for editors (``fleet config-schema``,
``docs/config.schema.json``). Units: meters, radians, seconds; poses in the ``map`` frame.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Annotated, ClassVar

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)
from pydantic_core import ErrorDetails

from fleet.config.fields import (
    ENDPOINT_PATTERN,
    NAME_PATTERN,
    NAMESPACE_PATTERN,
    PROBLEM,
    Bounds,
    Flag,
    Items,
    Numbers,
    Text,
    not_reserved,
    problem,
    suggest,
    tname,
    unique_by,
    valid_port,
)
from fleet.config.model import DEFAULT_LINK_TIMEOUT_S, DEFAULT_RECONNECT_S, CoordinatorParams, TrafficSettings
from fleet.errors import ConfigError
from fleet.messages import DEFAULT_ENDPOINT
from fleet.robots import BatteryModel, RobotModel, SimParams
from fleet.types import Pose2D

_MODEL, _BATTERY, _SIM = RobotModel(), BatteryModel(), SimParams()
_COORDINATOR, _TRAFFIC = CoordinatorParams(), TrafficSettings()

POSE = "a pose [x, y, theta] of numbers (m, m, rad)"

Fraction = Annotated[float, Bounds("a fraction in [0, 1]", ge=0, le=1)]
Name = Annotated[str, Text(NAME_PATTERN, "be a letter then letters, digits or _")]
#: A robot's name: also a ROS name token and a bus key chunk, so not one the bus uses itself.
RobotName = Annotated[Name, AfterValidator(not_reserved)]
Namespace = Annotated[
    str,
    Text(NAMESPACE_PATTERN, f"look like /robot1 ({NAMESPACE_PATTERN[1:-1]})"),
    AfterValidator(not_reserved),
]
Reference = Annotated[str, Text()]
Pose = Annotated[tuple[float, float, float], Numbers(3, POSE)]
XY = Annotated[tuple[float, float], Numbers(2, "[x, y] in meters")]
Waypoint = Annotated[
    str | tuple[float, float, float],
    Numbers(3, f"a roadmap node name, a station name or {POSE}", names=True),
]
Place = Annotated[str | tuple[float, float, float], Numbers(3, f"a station name or {POSE}", names=True)]


class Section(BaseModel):
    """A mapping of known keys: an unknown key is an error with a did-you-mean suggestion.

    An empty YAML value (``battery:`` with nothing after it) is an empty mapping, so every
    field takes its default.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    #: What the reason says the section must be when it is not a mapping.
    expected: ClassVar[str] = "a mapping"
    #: Said after ``unknown key`` when no known key is close.
    no_match: ClassVar[str] = ""
    #: Whether an empty YAML value stands for an empty mapping.
    empty_ok: ClassVar[bool] = True

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: object) -> object:
        if data is None and cls.empty_ok:
            return {}
        if not isinstance(data, dict):
            raise problem(cls._not_a_mapping(data))
        for key in data:
            if key not in cls.model_fields:
                raise problem(f"unknown key{suggest(str(key), cls.model_fields, cls.no_match)}", str(key))
        return data

    @classmethod
    def _not_a_mapping(cls, data: object) -> str:
        return f"must be {cls.expected}, got {tname(data)}"


class RobotModelSection(Section):
    """robot_model: the shape and limits every robot shares."""

    radius: Annotated[float, Bounds(gt=0, le=5)] = Field(
        default=_MODEL.radius, description="robot radius (m); poses and edges keep this clear"
    )
    max_linear_speed: Annotated[float, Bounds(gt=0, le=10)] = Field(
        default=_MODEL.max_linear_speed, description="m/s"
    )
    max_angular_speed: Annotated[float, Bounds(gt=0, le=10)] = Field(
        default=_MODEL.max_angular_speed, description="rad/s"
    )
    max_linear_accel: Annotated[float, Bounds(gt=0, le=20)] = Field(
        default=_MODEL.max_linear_accel, description="m/s^2"
    )
    max_angular_accel: Annotated[float, Bounds(gt=0, le=40)] = Field(
        default=_MODEL.max_angular_accel, description="rad/s^2"
    )

    def to_model(self) -> RobotModel:
        return RobotModel(**self.model_dump())


class BatterySection(Section):
    """battery: levels are fractions of a full battery."""

    drain_per_m: Annotated[float, Bounds(ge=0, le=0.1)] = Field(
        default=_BATTERY.drain_per_m, description="fraction per meter driven"
    )
    drain_per_s: Annotated[float, Bounds(ge=0, le=0.01)] = Field(
        default=_BATTERY.drain_per_s, description="fraction per second, always"
    )
    charge_per_s: Annotated[float, Bounds(gt=0, le=1)] = Field(
        default=_BATTERY.charge_per_s, description="fraction per second on a charger"
    )
    low: Fraction = Field(
        default=_BATTERY.low,
        description="below this the robot always goes to charge (farther from a charger it goes earlier); below resume",
    )
    resume: Fraction = Field(default=_BATTERY.resume, description="charging stops at this level")
    initial: Fraction = Field(
        default=_BATTERY.initial, description="start level (per robot: robots[i].battery)"
    )
    reserve: Fraction = Field(default=_BATTERY.reserve, description="kept on arrival at a charger")
    margin: Annotated[float, Bounds(ge=0, le=10)] = Field(
        default=_BATTERY.margin, description="extra on the energy a trip to a charger needs (0.5 = 50 %)"
    )
    wait_s: Annotated[float, Bounds(ge=0, le=3600)] = Field(
        default=_BATTERY.wait_s, description="s of waiting for a charger budgeted"
    )
    detour: Annotated[float, Bounds(ge=1, le=10)] = Field(
        default=_BATTERY.detour, description="roadmap length per meter of map distance"
    )
    cruise_mps: Annotated[float, Bounds(gt=0, le=10)] = Field(
        default=_BATTERY.cruise_mps, description="m/s assumed on the way to a charger"
    )

    @model_validator(mode="after")
    def _low_below_resume(self) -> BatterySection:
        if self.low >= self.resume:
            raise problem(f"must be below battery.resume ({self.resume}), got {self.low}", "low")
        return self

    def to_model(self) -> BatteryModel:
        return BatteryModel(**self.model_dump())


class SimSection(Section):
    """sim: the simulator's fixed step, tolerances and seed."""

    step_s: Annotated[float, Bounds(ge=0.001, le=1)] = Field(
        default=_SIM.step_s, description="fixed simulation step (s)"
    )
    stuck_time_s: Annotated[float, Bounds(gt=0, le=3600)] = Field(
        default=_SIM.stuck_time_s, description="no progress this long while driving = stuck (s)"
    )
    seed: Annotated[int, Bounds("an integer in [0, 2**32 - 1]", ge=0, le=2**32 - 1)] = Field(
        default=_SIM.seed, description="random seed: the same seed gives the same run"
    )
    charger_radius: Annotated[float, Bounds(gt=0, le=10)] = Field(
        default=_SIM.charger_radius, description="how close to a charger a robot charges (m)"
    )
    goal_tolerance: Annotated[float, Bounds(gt=0, le=10)] = Field(
        default=_SIM.goal_tolerance, description="m"
    )
    yaw_tolerance: Annotated[float, Bounds(gt=0, le=math.pi)] = Field(
        default=_SIM.yaw_tolerance, description="rad"
    )


class AgentSection(Section):
    """agent: the robots' behavior trees."""

    tick_hz: Annotated[float, Bounds(gt=0, le=1000)] = Field(
        default=10.0, description="behavior-tree ticks per simulated second (Hz)"
    )
    heartbeat_s: Annotated[float, Bounds(gt=0, le=3600)] = Field(
        default=10.0,
        description="with trees ticked on change, a tree nothing woke is still ticked this often (s)",
    )


class CoordinatorSection(Section):
    """coordinator: when work moves to another robot."""

    stuck_reassign_s: Annotated[float, Bounds(gt=0, le=86400)] = Field(
        default=_COORDINATOR.stuck_reassign_s, description="a robot stuck this long loses its patrol (s)"
    )
    status_timeout_s: Annotated[float, Bounds(gt=0, le=86400)] = Field(
        default=_COORDINATOR.status_timeout_s, description="a robot silent this long is considered dead (s)"
    )
    ack_timeout_s: Annotated[float, Bounds(gt=0, le=86400)] = Field(
        default=_COORDINATOR.ack_timeout_s,
        description="an order the robot has not acknowledged this long is re-issued under a new id (s)",
    )

    def to_params(self) -> CoordinatorParams:
        return CoordinatorParams(**self.model_dump())


class TrafficSection(Section):
    """traffic: reservation-based traffic management on the roadmap (docs/traffic.md)."""

    enabled: Annotated[bool, Flag()] = Field(
        default=_TRAFFIC.enabled, description="on by default; `fleet run --no-traffic` turns it off"
    )
    deadlock_s: Annotated[float, Bounds(gt=0, le=3600)] = Field(
        default=_TRAFFIC.deadlock_s, description="robots waiting on each other this long (s)"
    )
    park_idle_s: Annotated[float, Bounds(ge=0, le=86400)] = Field(
        default=_TRAFFIC.park_idle_s, description="an idle robot off its spot parks after (s)"
    )
    horizon_m: Annotated[float, Bounds(gt=0, le=1000)] = Field(
        default=_TRAFFIC.horizon_m, description="path granted ahead of a robot (m)"
    )
    stall_timeout_s: Annotated[float, Bounds(gt=0, le=3600)] = Field(
        default=_TRAFFIC.stall_timeout_s, description="no progress with a grant ahead = stopped robot (s)"
    )
    dead_release_s: Annotated[float, Bounds(ge=0, le=3600)] = Field(
        default=_TRAFFIC.dead_release_s,
        description="a robot whose agent died keeps its grant this long, then only its node (s)",
    )
    cell_m: Annotated[float, Bounds(gt=0, le=1000)] | None = Field(
        default=_TRAFFIC.cell_m,
        description="roadmap edges longer than this are cut into cells so same-way robots follow closely (m); "
        "null: not cut",
    )
    near_charger_trigger: bool = Field(
        default=_TRAFFIC.near_charger_trigger,
        description="far from its named charger (threshold at resume) the battery guard measures to the "
        "nearest one plus the policy's charger reach (false: to the named charger only)",
    )

    def to_settings(self) -> TrafficSettings:
        return TrafficSettings(**self.model_dump())


class BusSection(Section):
    """bus: the Zenoh status bus."""

    endpoint: Annotated[
        str,
        Text(ENDPOINT_PATTERN, f"be a Zenoh endpoint like {DEFAULT_ENDPOINT}"),
        AfterValidator(valid_port),
    ] = Field(default=DEFAULT_ENDPOINT, description="Zenoh endpoint <protocol>/<address>")
    status_hz: Annotated[float, Bounds(gt=0, le=1000)] | None = Field(
        default=None, description="status messages per second (Hz); unset: every tick"
    )
    secure: str | None = Field(
        default=None,
        min_length=1,
        description="key directory of a secured bus (`fleet keys init`), relative to this file; "
        "unset: an open bus (or --secure DIR)",
    )
    link_timeout_s: Annotated[float, Bounds(gt=0, le=3600)] = Field(
        default=DEFAULT_LINK_TIMEOUT_S,
        description="an agent whose bus link (its Zenoh router) is gone this long stops its robots (wall s)",
    )
    reconnect_s: Annotated[float, Bounds(gt=0, le=86400)] | None = Field(
        default=DEFAULT_RECONNECT_S,
        description="a process of a split fleet waits this long for a lost simulator to come back "
        "before it ends its run (wall s); unset (null): forever",
    )
    status_max_period_s: Annotated[float, Bounds(gt=0, le=3600)] | None = Field(
        default=None,
        description="publish a robot's status only when it changed, and at least this often (s; keep it "
        "below coordinator.status_timeout_s); unset: at every status period",
    )
    status_batch: bool = Field(
        default=True,
        description="a process running several agents sends their statuses in batches on "
        "fleet/batch/<process>/status (one message per tick) instead of one per robot",
    )


def _nodes(v: object) -> object:
    if not isinstance(v, dict) or not v:
        raise problem("must be a non-empty mapping of name: [x, y]")
    for name in v:
        if not isinstance(name, str) or not name:
            raise problem("node names must be non-empty strings", str(name))
    return v


def _edge(v: object) -> object:
    if not (isinstance(v, list | tuple) and len(v) == 2 and all(isinstance(end, str) for end in v)):
        raise problem(f"must be a pair [a, b] of node names, got {v!r}")
    return tuple(v)


class RoadmapSection(Section):
    """roadmap: nodes and edges (map frame, meters), or a SUMO network (net)."""

    expected: ClassVar[str] = "a mapping with nodes and edges (or net)"
    no_match: ClassVar[str] = " (expected nodes and edges, or net)"
    empty_ok: ClassVar[bool] = False

    nodes: Annotated[dict[str, XY], BeforeValidator(_nodes)] | None = Field(
        default=None, description="name: [x, y] (m)"
    )
    edges: Annotated[list[Annotated[tuple[str, str], BeforeValidator(_edge)]], Items()] = Field(
        default_factory=list, description="undirected straight segments [a, b] between node names"
    )
    net: Annotated[str, Text(what="the path of a SUMO .net.xml file")] | None = Field(
        default=None, description="a SUMO .net.xml (relative to the config) instead of nodes and edges"
    )
    vclass: Annotated[str, Text(what="a SUMO vehicle class name")] | None = Field(
        default=None,
        description="with net: keep the SUMO edges this vehicle class may use (default passenger)",
    )

    @model_validator(mode="after")
    def _nodes_or_net(self) -> RoadmapSection:
        given = self.model_fields_set
        if self.net is not None:
            both = sorted(given & {"nodes", "edges"})
            if both:
                raise problem("give either net (a SUMO network) or nodes and edges, not both", both[0])
        elif "vclass" in given:
            raise problem("only applies to a SUMO network (roadmap.net)", "vclass")
        elif self.nodes is None:
            raise problem("must be a non-empty mapping of name: [x, y]", "nodes")
        return self

    def to_dict(self) -> dict[str, object]:
        """The section as :meth:`fleet.roadmap.Roadmap.from_config_dict` reads it."""
        return self.model_dump(exclude_unset=True)


class NamedPoseEntry(Section):
    """A charger or a station."""

    name: Name
    pose: Pose


class RouteEntry(Section):
    """A patrol route, driven as a loop."""

    name: Name
    waypoints: Annotated[list[Waypoint], Items(2, "a route needs at least 2 waypoints, got {n}")] = Field(
        description="roadmap node names, station names or poses [x, y, theta]"
    )
    robot: Reference | None = Field(default=None, description="preferred robot")


class TaskEntry(Section):
    """A picking task: drive to shelf, stand dwell_s seconds, drive to drop."""

    name: Name
    shelf: Place
    drop: Place
    dwell_s: Annotated[float, Bounds(ge=0, le=3600)] = Field(default=5.0, description="s")
    robot: Reference | None = Field(default=None, description="preferred robot")


class RobotEntry(Section):
    """A robot of the fleet."""

    name: RobotName
    start: Pose
    namespace: Namespace | None = Field(default=None, description="ROS namespace (default /<name>)")
    battery: Fraction | None = Field(default=None, description="start level (default battery.initial)")

    @property
    def ns(self) -> str:
        """The namespace, ``/<name>`` unless given."""
        return self.namespace or f"/{self.name}"


def _unique_namespaces(robots: Sequence[RobotEntry]) -> Sequence[RobotEntry]:
    unique_by(robots, lambda r: r.ns, "namespace", "duplicate namespace {name}")
    names = {r.name for r in robots}
    for i, r in enumerate(robots):
        other = r.ns.strip("/")
        if other != r.name and other in names:
            raise problem(
                f"{r.ns!r} is the namespace of robot {other!r}: robot {r.name!r} would speak for it "
                f"on the bus (use /{r.name} or a namespace no other robot is named after)",
                i,
                "namespace",
            )
    return robots


class ConfigFile(Section):
    """A fleet config file (docs/config.md). Paths are relative to the file; poses are
    [x, y, theta] in the map frame (m, m, rad). `fleet validate` also checks the poses and
    the roadmap against the map."""

    model_config = ConfigDict(extra="forbid", frozen=True, title="Fleet config")
    empty_ok: ClassVar[bool] = False

    name: Annotated[str, Text()] = Field(description="the fleet's name")
    map: Annotated[str, Text()] = Field(description="Nav2 map_server YAML (relative to this file)")
    roadmap: RoadmapSection = Field(description="the graph robots drive on: nodes and edges, or net")
    chargers: Annotated[
        list[NamedPoseEntry], Items(1, "needs at least one entry", unique="duplicate name {name}")
    ] = Field(description="charger poses; at least one")
    stations: Annotated[list[NamedPoseEntry], Items(unique="duplicate name {name}")] = Field(
        default_factory=list, description="named poses for picking (shelves, drop-offs)"
    )
    routes: Annotated[list[RouteEntry], Items(unique="duplicate route name {name}")] = Field(
        default_factory=list, description="patrol loops"
    )
    tasks: Annotated[list[TaskEntry], Items(unique="duplicate task name {name}")] = Field(
        default_factory=list, description="picking tasks"
    )
    parking: Annotated[list[Pose], Items()] = Field(
        default_factory=list, description="free start spots for extra robots (--robots N)"
    )
    robots: Annotated[
        list[RobotEntry],
        Items(1, "needs at least one robot", unique="duplicate robot name {name}"),
        AfterValidator(_unique_namespaces),
    ] = Field(description="the robots and their start poses; at least one")
    robot_model: RobotModelSection = Field(
        default_factory=RobotModelSection, description="shared by all robots"
    )
    battery: BatterySection = Field(default_factory=BatterySection, description="battery model")
    sim: SimSection = Field(default_factory=SimSection, description="simulator")
    agent: AgentSection = Field(default_factory=AgentSection, description="behavior-tree agents")
    coordinator: CoordinatorSection = Field(
        default_factory=CoordinatorSection, description="task coordinator"
    )
    traffic: TrafficSection = Field(default_factory=TrafficSection, description="traffic management")
    bus: BusSection = Field(default_factory=BusSection, description="Zenoh status bus")

    @classmethod
    def _not_a_mapping(cls, data: object) -> str:
        return f"expected a mapping of sections at the top level, got {tname(data)}"

    @model_validator(mode="after")
    def _tick_not_shorter_than_step(self) -> ConfigFile:
        tick_hz, step_s = self.agent.tick_hz, self.sim.step_s
        if 1.0 / tick_hz < step_s - 1e-12:
            raise problem(
                f"tick period 1/{tick_hz:g} s is shorter than sim.step_s ({step_s:g} s)", "agent", "tick_hz"
            )
        return self

    def sim_params(self, chargers: tuple[Pose2D, ...]) -> SimParams:
        """The simulator parameters of this file, with the charger poses ``chargers``."""
        return SimParams(
            **self.sim.model_dump(),
            chargers=chargers,
            model=self.robot_model.to_model(),
            battery=self.battery.to_model(),
        )


def validate_document(doc: object, file: str) -> ConfigFile:
    """Check the YAML document ``doc`` of config ``file`` against the schema.

    Raises :class:`ConfigError` for the first problem: ``<file>: <field>: <reason>``, the field
    named as in ``docs/config.md`` (``robots[2].start``, ``battery.low``).
    """
    try:
        return ConfigFile.model_validate(doc)
    except ValidationError as err:
        first = err.errors(include_url=False)[0]
        raise ConfigError(file, *_field_and_reason(first)) from None


def _field_and_reason(e: ErrorDetails) -> tuple[str, str]:
    ctx = e.get("ctx", {})
    loc = (*e["loc"], *ctx.get("at", ())) if e["type"] == PROBLEM else tuple(e["loc"])
    field = ""
    for part in loc:
        field += f"[{part}]" if isinstance(part, int) else f".{part}" if field else str(part)
    if e["type"] == PROBLEM:
        return field, str(ctx["reason"])
    if e["type"] == "missing":
        return field, "missing required section" if len(loc) == 1 else "missing required field"
    return field, f"{e['msg']}, got {e['input']!r}"


def json_schema() -> dict[str, object]:
    """The JSON Schema of a fleet config file, for editors.

    Written for JSON Schema draft-07, the draft the YAML language server (VS Code's YAML
    extension) implements: definitions under ``definitions``, fixed-length lists (poses) as
    ``items`` arrays.
    """
    schema = ConfigFile.model_json_schema(ref_template="#/definitions/{model}")
    definitions = schema.pop("$defs", {})
    top = {"$schema": "http://json-schema.org/draft-07/schema#", **schema, "definitions": definitions}
    return {key: _draft07(value) for key, value in top.items()}


def _draft07(node: object) -> object:
    if isinstance(node, list):
        return [_draft07(v) for v in node]
    if isinstance(node, dict):
        return {("items" if k == "prefixItems" else k): _draft07(v) for k, v in node.items()}
    return node


def json_schema_text() -> str:
    """:func:`json_schema` as the text of ``docs/config.schema.json``."""
    return json.dumps(json_schema(), indent=2) + "\n"
