"""The validated fleet configuration: plain dataclasses (``docs/config.md`` is the file format).
All poses are in the ``map`` frame: meters and radians."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fleet.maps import OccupancyGrid
from fleet.messages.codec import DEFAULT_ENDPOINT
from fleet.roadmap.graph import Roadmap
from fleet.robots import RobotSpec, SimParams
from fleet.types import Pose2D


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
    ``status_timeout_s``: a robot silent this long is considered dead; ``ack_timeout_s``: an
    order the robot has not acknowledged this long is re-issued under a new id."""

    stuck_reassign_s: float = 30.0
    status_timeout_s: float = 3.0
    ack_timeout_s: float = 5.0


@dataclass(frozen=True)
class TrafficSettings:
    """The ``traffic`` section (``docs/traffic.md``). ``enabled``: reservation-based traffic
    management on the roadmap, on by default (``fleet run --no-traffic`` turns it off); ``deadlock_s``: a
    set of robots waiting on each other longer than this counts as a deadlock in the report;
    ``park_idle_s``: an idle robot standing off its parking spot this long is sent to park;
    ``horizon_m``: how much path ahead a robot is granted; ``stall_timeout_s``: a robot with
    a grant ahead that makes no progress this long is treated as stopped (its reservations
    ahead are released); ``dead_release_s``: a robot whose agent or bus link died keeps its
    whole grant this long, then only the node it stands on; ``cell_m``: roadmap edges longer
    than this are cut into cells for the traffic manager, so robots driving the same way
    follow each other closely (``None``: not cut; ``TrafficParams.cell_m``);
    ``near_charger_trigger``: a robot so far from its named charger that the battery guard's
    threshold reaches ``resume`` measures to its nearest charger plus ``CHARGE_REACH_M`` (the
    policy sends it to a free charger near it; :class:`nodes.trees.ChargeThreshold`), so it
    is not sent to charge again as soon as it has charged (off by default: measured in
    docs/performance.md, "The charging wave at 1000 robots")."""

    enabled: bool = True
    deadlock_s: float = 30.0
    park_idle_s: float = 5.0
    horizon_m: float = 6.0
    stall_timeout_s: float = 20.0
    dead_release_s: float = 10.0
    cell_m: float | None = 1.5
    near_charger_trigger: bool = False


#: Wall seconds an agent may be without its bus link (its Zenoh router) before its
#: bus-loss watchdog stops its robots (``bus.link_timeout_s``).
DEFAULT_LINK_TIMEOUT_S = 2.0
#: Wall seconds a process of a split fleet waits for a simulator that went silent to come back
#: before it ends its run (``bus.reconnect_s``).
DEFAULT_RECONNECT_S = 60.0


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
    #: With trees ticked on change: a tree nothing woke is still ticked this often (simulated s).
    heartbeat_s: float = 10.0
    coordinator: CoordinatorParams = field(default_factory=CoordinatorParams)
    endpoint: str = DEFAULT_ENDPOINT
    status_hz: float | None = None
    #: The key directory of a secured bus (``bus.secure``, ``docs/security.md``); ``None``: open.
    secure: Path | None = None
    link_timeout_s: float = DEFAULT_LINK_TIMEOUT_S
    reconnect_s: float | None = DEFAULT_RECONNECT_S
    #: Publish statuses on change, at least this often (s); None: at every status period.
    status_max_period_s: float | None = None
    #: A process with several agents sends their statuses as batches (one put per tick).
    status_batch: bool = True
    parking: list[Pose2D] = field(default_factory=list)
    traffic: TrafficSettings = field(default_factory=TrafficSettings)

    def robot(self, name: str) -> RobotSpec:
        """The robot called ``name`` (the first of that name). Raises ``KeyError`` if there is
        none. Looked up in an index of :attr:`robots`, rebuilt when the list changed under it, so
        a fleet of thousands asks in constant time."""
        index: dict[str, int] | None = self.__dict__.get("_robot_index")
        i = index.get(name) if index is not None else None
        if i is None or i >= len(self.robots) or self.robots[i].name != name:
            index = {}
            for k, r in enumerate(self.robots):
                index.setdefault(r.name, k)
            self.__dict__["_robot_index"] = index
            i = index.get(name)
            if i is None:
                raise KeyError(f"no robot named {name!r}")
        return self.robots[i]

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
            # route copies share their waypoints: each lap is expanded once (per roadmap)
            memo: dict[tuple[str | None, ...], tuple[Roadmap, tuple[Pose2D, ...]]]
            memo = self.__dict__.setdefault("_lap_memo", {})
            got = memo.get(names)
            if got is None or got[0] is not self.roadmap:
                dense = self.roadmap.expand_route([n for n in names if n is not None], closed=True)
                got = memo[names] = (self.roadmap, self.roadmap.poses_for(dense, closed=True))
            return got[1]
        return route.waypoints
