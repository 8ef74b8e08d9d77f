"""Eclipse SUMO as a navigation backend: robots are SUMO vehicles on a network of the warehouse.

:class:`SumoWorld` owns one libsumo simulation. It builds (or reuses, see
:mod:`sim.sumo.net`) the SUMO network of the roadmap, or, when the roadmap was read from a
``.net.xml`` (``roadmap: {net: ...}`` in a fleet config, :attr:`fleet.roadmap.Roadmap.source_net`),
drives on that very file, roadmap nodes being its junctions. It adds every robot as a vehicle of one
``robot`` vehicle type (length and width = robot diameter, ``maxSpeed``/``accel``/``decel``
from :class:`fleet.robots.RobotModel`, no driver imperfection, so runs are deterministic) and
advances SUMO by ``SimParams.step_s`` on the :class:`fleet.clock.SimClock` passed in (each
:meth:`SumoWorld.step` advances the clock, like :class:`sim.simulator.Simulator`).
:meth:`SumoWorld.backend` returns a :class:`NamespacedBackend` implementing
:class:`fleet.navigation.NavigationBackend` for one robot.

**libsumo is a process-global singleton**: only one :class:`SumoWorld` may be open at a time in
a process. Opening a second one raises :class:`fleet.errors.BackendError`; close the first
(:meth:`SumoWorld.close`, or use the world as a context manager), or run SUMO in another process.

How Nav2 actions map onto SUMO (poses are in the ``map`` frame; SUMO x/y are the same):

* **Poses -> lanes.** A pose is snapped to the nearest lane point; between lanes at similar
  distance, the lane whose direction agrees with the pose's heading wins. A pose farther than
  ``max_snap_m`` from every lane aborts the goal with ``GOAL_OUTSIDE_MAP``. SUMO only knows
  lanes: a goal inside an obstacle, or between aisles, is reached at its lane projection.
  The robot's reported pose is the centre of the vehicle (SUMO reports the front bumper).
* **NavigateToPose / NavigateThroughPoses / FollowWaypoints** set one route: the shortest
  (SUMO ``findRoute``) path from the robot's edge through the edges of every pose in order
  (looping round when a pose lies behind the robot on its own lane), with a stop at the last
  pose. Intermediate poses are passed without stopping (FollowWaypoints included; it reports
  ``current_waypoint``). The goal SUCCEEDS when the vehicle has stopped at the last pose. An
  unreachable pose (one-way network) aborts with ``NO_VALID_PATH``. Feedback: the current
  pose, navigation time, remaining route length (junction crossings not counted) and the time
  it takes at the lane speed.
* **Wait** holds the vehicle on its lane (a blocking stop at the next position it can brake to)
  for ``duration_s``; other robots queue behind it.
* **Spin, BackUp, DriveOnHeading**: SUMO vehicles cannot turn on the spot or reverse. They run
  as a *timed no-op*: the vehicle holds on its lane for the time the motion would take
  (``|target_yaw| / max_angular_speed``, ``distance_m / speed_mps``) and the goal SUCCEEDS with
  zero distance travelled in its feedback. A duration above ``time_allowance_s`` aborts with the
  action's TIMEOUT code after the allowance; non-positive distance or speed aborts with the
  INVALID_INPUT code. Behavior-tree recoveries therefore "succeed" without moving on SUMO.
* **Cancel** ends the goal CANCELED at once; the vehicle brakes to a stop at the next position
  it can reach (never an emergency stop). **Preemption**: a new goal aborts the executing one
  (``error_msg`` names the new goal) and sets a new route from where the vehicle is.
* **Junctions**: by default the network has no lanes inside junctions (a robot crosses a
  junction in one step; lanes are as long as their roadmap edges, so travel times match).
  ``internal_links=True`` models them, but queues inside the warehouse's closely spaced
  junctions then gridlock SUMO (``docs/sumo.md``).
* **Idle** robots (no executing goal) *park* at their lane position (SUMO parking: the vehicle
  leaves the lane, others can pass) unless ``park_idle=False``, where they hold on the lane.

Health signals:

* **Collisions**: ``simulation.getCollisions()`` every step (``--collision.action warn``,
  junction checks on, only real overlaps: ``--collision.mingap-factor 0``). A touching pair is
  counted once per contact episode, for both robots, in :attr:`SumoWorld.collisions` and in each
  robot's ``RobotState.collisions``.
* **Deadlocks = teleports**: SUMO teleports a vehicle that has waited longer than
  ``--time-to-teleport`` (default ``SimParams.stuck_time_s``) behind a blocker. Each starting
  teleport is counted (:attr:`SumoWorld.teleports`, per robot in :meth:`SumoWorld.teleports_of`),
  the robot is reported ``stuck`` until its next goal, and its navigation goal aborts with
  ``FAILED_TO_MAKE_PROGRESS``; the vehicle then stops at the next position after its jump.
* **Battery** follows :class:`fleet.robots.BatteryModel` (drain per meter of odometry and per
  second; charging while standing still within ``charger_radius`` of a charger's lane point),
  integrated whenever the robot's state is read.

Goal ids are ``<namespace>#<n>``, never reused within a world."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fleet.clock import SimClock, step_until
from fleet.errors import BackendError
from fleet.robots import RobotSpec, SimParams
from fleet.types import (
    BackUp,
    DriveOnHeading,
    ErrorCode,
    Feedback,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    RobotState,
    Spin,
    Wait,
    normalize_angle,
)
from sim.backend import NamespacedBackend
from sim.sumo.lanes import LaneIndex, LanePoint
from sim.sumo.net import SumoNetwork, as_graph, build_network, roadmap_mapping, settings_for_robot

_ACTIVE: SumoWorld | None = None


#: Vehicle type id of the robots.
ROBOT_TYPE = "robot"


#: Stop duration used for "stay until told otherwise" (s).
_FOREVER = 1.0e7


_POS_TOL_M = 0.3


_TERMINAL = frozenset({GoalStatus.SUCCEEDED, GoalStatus.CANCELED, GoalStatus.ABORTED, GoalStatus.REJECTED})


def _libsumo() -> Any:
    try:
        import libsumo  # type: ignore[import-untyped]
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise BackendError(
            "the SUMO backend needs libsumo: pip install -e '.[sumo]' (or make setup-sumo)"
        ) from exc
    return libsumo


@dataclass
class _GoalRecord:
    goal_id: str
    goal: Goal
    namespace: str
    start_t: float
    status: GoalStatus = GoalStatus.EXECUTING
    error_code: int = 0
    error_msg: str = ""
    feedback: Feedback = field(default_factory=Feedback)
    # navigation plan
    targets: list[LanePoint] = field(default_factory=list)
    target_idx: list[int] = field(default_factory=list)  # route index of each target
    route: list[str] = field(default_factory=list)
    cum: list[float] = field(default_factory=list)  # route length before each route edge
    passed: int = 0  # number of targets passed
    applied: bool = False  # route/stop given to SUMO
    hold_until: float | None = None  # timed goals (Wait, no-op recoveries)
    hold_status: GoalStatus = GoalStatus.SUCCEEDED
    hold_code: int = 0
    hold_msg: str = ""
    cached: GoalState | None = None
    stop_after: int = -1  # route index after which the final stop is set (-1: it is set)
    cached_epoch: int = -1

    def snapshot(self, feedback: Feedback | None = None) -> GoalState:
        missed: tuple[int, ...] = ()
        return GoalState(
            goal_id=self.goal_id,
            kind=self.goal.kind,
            status=self.status,
            feedback=feedback if feedback is not None else self.feedback,
            error_code=self.error_code,
            error_msg=self.error_msg,
            missed_waypoints=missed,
        )


@dataclass
class _Robot:
    spec: RobotSpec
    vid: str
    battery: float
    goal: _GoalRecord | None = None
    stuck: bool = False
    collisions: int = 0
    teleports: int = 0
    mode: str = "parked"  # parked | driving | holding | braking
    last_batt_t: float = 0.0
    last_odo: float = 0.0
    last_pose: Pose2D | None = None
    last_where: tuple[str, float, int] | None = None
    present: bool = False
    trajectory: list[tuple[float, float, float]] = field(default_factory=list)
    reinserted: int = 0
    prog: tuple[int, float] = (0, 0.0)
    prog_epoch: int = -1
    pose_epoch: int = -1
    odo_base: float = 0.0  # odometry of earlier incarnations of the vehicle
    odo_total: float = 0.0


class SumoWorld:
    """One libsumo simulation of a robot fleet on the SUMO network of a roadmap.

    Args:
        roadmap: a ``fleet.roadmap.Roadmap`` or a ``networkx.Graph`` with node ``pos`` (m).
            If it was read from a SUMO network (``Roadmap.source_net``, or
            ``graph.graph["sumo_net"]``), SUMO runs on that file and :attr:`network` maps the
            roadmap's nodes to its junctions (same ids) and its edges to the SUMO edges;
            otherwise a network is generated from it (:func:`sim.sumo.net.build_network`).
            Ignored when ``net_file`` is given, unless it was read from that same file.
        robots: the robots; each becomes a vehicle named after ``RobotSpec.name``, parked at
            the lane point nearest its start pose.
        params: step (``step_s``), seed, stuck time (default teleport time), chargers, robot
            and battery models.
        clock: the simulated clock; :meth:`step` advances it by ``params.step_s``. SUMO starts
            at ``clock.now()``.
        net_file: use this ``.net.xml`` (e.g. drawn in netedit) instead of the roadmap's.
        vclass: SUMO vehicle class of the robots (default: the roadmap's ``source_vclass``,
            the class whose edges were read from its network; else SUMO's ``passenger``).
        cache_dir: cache of generated networks (default :func:`sim.sumo.net.default_cache_dir`).
        time_to_teleport: SUMO's ``--time-to-teleport`` in s (default ``params.stuck_time_s``;
            ``<= 0`` disables teleports).
        park_idle: idle robots park off the lane (default) instead of holding on it.
        internal_links: model the lanes inside junctions. Off by default: vehicles then cross a
            junction in one step instead of queueing inside it, which on the warehouse's closely
            spaced T-junctions gridlocks SUMO (see ``docs/sumo.md`` for the measurements).
        max_snap_m: farthest a goal pose may be from a lane (m); the default covers the
            generated warehouse's parking rows. Start poses are snapped however far they are.
        sumo_args: extra SUMO command-line options.
        trajectory_period_s: sample every robot's pose this often for :meth:`trajectory`
            (``None`` or 0: no samples).
        sumo_log: write SUMO's messages and warnings (teleports, collisions) to this file;
            without it SUMO's warnings are silenced.

    Raises:
        BackendError: another SumoWorld is open, libsumo/eclipse-sumo are missing, the network
            file is missing or lacks a junction of the roadmap read from it, or SUMO refused to
            start (its message is included).
    """

    def __init__(
        self,
        roadmap: Any,
        robots: Sequence[RobotSpec],
        params: SimParams,
        clock: SimClock,
        *,
        net_file: str | Path | None = None,
        vclass: str | None = None,
        cache_dir: str | Path | None = None,
        time_to_teleport: float | None = None,
        park_idle: bool = True,
        internal_links: bool = False,
        max_snap_m: float = 10.0,
        sumo_args: Sequence[str] = (),
        sumo_log: str | Path | None = None,
        trajectory_period_s: float | None = 0.5,
    ) -> None:
        global _ACTIVE
        if _ACTIVE is not None:
            raise BackendError(
                "only one SumoWorld can exist at a time: libsumo is a process-global singleton; "
                "close the open world first (SumoWorld.close() or a `with` block), or run SUMO in "
                "another process"
            )
        if params.step_s <= 0:
            raise BackendError(f"SimParams.step_s must be positive, got {params.step_s}")
        ls = _libsumo()
        if ls.simulation.isLoaded():
            raise BackendError("libsumo already runs a simulation not owned by a SumoWorld; close it first")
        self._ls = ls
        self.params = params
        self.clock = clock
        self.park_idle = park_idle
        self.trajectory_period_s = trajectory_period_s
        self.max_snap_m = max_snap_m
        model = params.model
        self.network: SumoNetwork
        source = _source_net(roadmap)
        if net_file is None:
            net_file = source
        # the roadmap's nodes are junctions of net_file when the roadmap was read from it
        self._mapped_graph = (
            as_graph(roadmap)
            if source is not None and net_file is not None and Path(net_file).resolve() == source.resolve()
            else None
        )
        if self._mapped_graph is not None and vclass is None:
            vclass = as_graph(roadmap).graph.get("sumo_vclass")
        self.vclass = vclass
        if net_file is not None:
            self.network = SumoNetwork(net_path=Path(net_file), cached=True)
            if not self.network.net_path.is_file():
                raise BackendError(f"SUMO network {net_file} does not exist")
        else:
            settings = settings_for_robot(model.radius, model.max_linear_speed, internal_links=internal_links)
            self.network = build_network(as_graph(roadmap), settings, cache_dir)
        self.time_to_teleport = params.stuck_time_s if time_to_teleport is None else time_to_teleport
        args = [
            "sumo",
            "--net-file",
            str(self.network.net_path),
            "--step-length",
            f"{params.step_s}",
            "--begin",
            f"{clock.now()}",
            "--seed",
            str(int(params.seed)),
            "--no-step-log",
            "true",
            *(["--log", str(sumo_log)] if sumo_log is not None else ["--no-warnings", "true"]),
            "--collision.action",
            "warn",
            "--collision.check-junctions",
            "true",
            "--collision.mingap-factor",
            "0",
            "--time-to-teleport",
            f"{self.time_to_teleport if self.time_to_teleport > 0 else -1}",
            "--time-to-teleport.highways",
            "-1",
            "--routing-algorithm",
            "astar",
            *sumo_args,
        ]
        try:
            ls.start(args)
        except Exception as exc:
            raise BackendError(f"SUMO failed to start with {' '.join(args)}: {exc}") from exc
        _ACTIVE = self
        self._closed = False
        try:
            self._setup(robots)
        except Exception:
            self.close()
            raise

    # -- setup ----------------------------------------------------------------------

    def _setup(self, robots: Sequence[RobotSpec]) -> None:
        ls = self._ls
        m = self.params.model
        self.length = 2.0 * m.radius
        if self._mapped_graph is not None:
            self.network = self._map_roadmap(self._mapped_graph)
        ls.vehicletype.copy("DEFAULT_VEHTYPE", ROBOT_TYPE)
        if self.vclass:
            ls.vehicletype.setVehicleClass(ROBOT_TYPE, self.vclass)
        ls.vehicletype.setLength(ROBOT_TYPE, self.length)
        ls.vehicletype.setWidth(ROBOT_TYPE, self.length)
        ls.vehicletype.setMinGap(ROBOT_TYPE, max(0.1, 0.5 * m.radius))
        ls.vehicletype.setMaxSpeed(ROBOT_TYPE, m.max_linear_speed)
        ls.vehicletype.setAccel(ROBOT_TYPE, m.max_linear_accel)
        ls.vehicletype.setDecel(ROBOT_TYPE, m.max_linear_accel)
        ls.vehicletype.setEmergencyDecel(ROBOT_TYPE, 2.0 * m.max_linear_accel)
        ls.vehicletype.setImperfection(ROBOT_TYPE, 0.0)
        ls.vehicletype.setTau(ROBOT_TYPE, 0.5)
        # a robot that has waited at a junction accepts smaller gaps to crossing robots rather
        # than waiting for a perfectly free junction (fewer junction deadlocks)
        ls.vehicletype.setImpatience(ROBOT_TYPE, 1.0)
        self.lanes = LaneIndex(ls)
        self._lane_speed = {e: ls.lane.getMaxSpeed(f"{e}_0") for e in self.lanes.edge_length}
        self._chargers = [self.lanes.nearest(c.x, c.y, c.theta) for c in self.params.chargers]
        self._robots: dict[str, _Robot] = {}
        self._by_vid: dict[str, _Robot] = {}
        self._backends: dict[str, NamespacedBackend] = {}
        self._goals: dict[str, _GoalRecord] = {}
        self._goal_counter: dict[str, int] = {}
        self._active: dict[str, _Robot] = {}  # namespace -> robot with an executing goal
        self._resting: dict[str, bool] = {}  # namespace -> park? for robots being brought to rest
        self._touching: set[tuple[str, str]] = set()
        self.collisions = 0
        self.teleports = 0
        self.steps = 0
        self._epoch = 0  # bumped whenever SUMO steps or a vehicle is commanded (cache key)
        #: ``(t, namespace_a, namespace_b, x, y)`` of every new contact between two robots.
        self.collision_events: list[tuple[float, str, str, float, float]] = []
        self._next_sample = self.clock.now() + (self.trajectory_period_s or 0.0)
        for spec in robots:
            self.add_robot(spec)

    def _map_roadmap(self, graph: Any) -> SumoNetwork:
        """:attr:`network` with ``junction_of`` / ``edge_of`` of a roadmap read from its file."""
        ls = self._ls
        edges = [
            (e, ls.edge.getFromJunction(e), ls.edge.getToJunction(e))
            for e in ls.edge.getIDList()
            if not e.startswith(":")
        ]
        junction_of, edge_of = roadmap_mapping(
            graph, ls.junction.getIDList(), edges, net=str(self.network.net_path)
        )
        return replace(self.network, junction_of=junction_of, edge_of=edge_of)

    def add_robot(self, spec: RobotSpec) -> None:
        """Add ``spec`` as a vehicle parked at the lane point nearest its start pose (however
        far). Raises :class:`BackendError` for a duplicate namespace."""
        if spec.namespace in self._robots:
            raise BackendError(f"robot namespace {spec.namespace} is already in the SUMO world")
        lp = self.lanes.nearest(spec.start.x, spec.start.y, spec.start.theta)
        ls = self._ls
        vid = spec.name
        rid = f"__start_{vid}"
        front = round(self._front_pos(lp.edge, lp.pos), 3)  # the stop must not lie before departPos
        ls.route.add(rid, [lp.edge])
        ls.vehicle.add(
            vid,
            rid,
            ROBOT_TYPE,
            depart="now",
            departPos=f"{front:.3f}",
            departSpeed="0",
            departLane=str(lp.lane),
        )
        ls.vehicle.setStop(
            vid, lp.edge, pos=front, laneIndex=lp.lane, duration=_FOREVER, flags=self._idle_flags()
        )
        r = _Robot(
            spec=spec,
            vid=vid,
            battery=spec.battery,
            last_batt_t=self.clock.now(),
            last_pose=Pose2D(lp.x, lp.y, spec.start.theta),
        )
        r.trajectory.append((self.clock.now(), lp.x, lp.y))
        self._robots[spec.namespace] = r
        self._by_vid[vid] = r
        self._goal_counter[spec.namespace] = 0

    def _idle_flags(self) -> int:
        return 1 if self.park_idle else 0

    def _front_pos(self, edge: str, center_pos: float) -> float:
        """Lane position of the front bumper when the vehicle's centre is at ``center_pos``."""
        return min(max(center_pos + self.length / 2.0, self.length), self.lanes.edge_length[edge])

    # -- public API -----------------------------------------------------------------

    @property
    def namespaces(self) -> list[str]:
        return list(self._robots)

    def backend(self, namespace: str) -> NamespacedBackend:
        """The navigation backend of robot ``namespace`` (one object per robot)."""
        self._robot(namespace)
        b = self._backends.get(namespace)
        if b is None:
            b = self._backends[namespace] = NamespacedBackend(self, namespace)
        return b

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]]:
        """``(t, x, y)`` samples of the robot, one at its addition and then every
        ``trajectory_period_s`` simulated seconds (a copy)."""
        return list(self._robot(namespace).trajectory)

    def teleports_of(self, namespace: str) -> int:
        """How many times SUMO teleported robot ``namespace`` (deadlock signals)."""
        return self._robot(namespace).teleports

    def _robot(self, namespace: str) -> _Robot:
        try:
            return self._robots[namespace]
        except KeyError:
            raise BackendError(
                f"no robot {namespace!r} in the SUMO world (have {sorted(self._robots)})"
            ) from None

    def close(self) -> None:
        """Stop SUMO (idempotent). Goals still running end ABORTED with SERVER_UNAVAILABLE."""
        global _ACTIVE
        if getattr(self, "_closed", True):
            return
        self._closed = True
        for rec in getattr(self, "_goals", {}).values():
            if rec.status not in _TERMINAL:
                self._finish(
                    rec, GoalStatus.ABORTED, int(ErrorCode.SERVER_UNAVAILABLE), "The SUMO world was closed."
                )
        try:
            self._ls.close()
        finally:
            if _ACTIVE is self:
                _ACTIVE = None

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> SumoWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- goals ------------------------------------------------------------------------

    def send_goal(self, namespace: str, goal: Goal) -> str:
        """Start ``goal`` on robot ``namespace``; return its id at once (see module docstring).

        The goal is EXECUTING at once, or already terminal (REJECTED: no poses, a non-finite
        pose, an unknown goal type; ABORTED: a pose off the network, no route). The goal the
        robot was executing ends ABORTED, naming the new goal.
        """
        if self._closed:
            raise BackendError("the SUMO world is closed")
        robot = self._robot(namespace)
        self._goal_counter[namespace] += 1
        gid = f"{namespace}#{self._goal_counter[namespace]}"
        now = self.clock.now()
        rec = _GoalRecord(gid, goal, namespace, now)
        self._goals[gid] = rec
        old = robot.goal
        if old is not None and not old.status.terminal:
            old.feedback = self._feedback(robot, old)
            self._finish(
                old, GoalStatus.ABORTED, 0, f"Goal {old.goal_id} was preempted by goal {gid}.", settle=False
            )
        robot.goal = None
        robot.stuck = False
        reason = _reject_reason(goal)
        if reason is not None:
            self._finish(rec, GoalStatus.REJECTED, 0, reason)
            return gid
        robot.goal = rec
        self._active[namespace] = robot
        if isinstance(goal, (NavigateToPose, NavigateThroughPoses, FollowWaypoints)):
            poses = (goal.pose,) if isinstance(goal, NavigateToPose) else tuple(goal.poses)
            for i, p in enumerate(poses):
                lp = self.lanes.nearest(p.x, p.y, p.theta)
                if lp.dist > self.max_snap_m:
                    self._finish(
                        rec,
                        GoalStatus.ABORTED,
                        int(ErrorCode.GOAL_OUTSIDE_MAP),
                        f"Pose {i} ({p.x:.2f}, {p.y:.2f}) is {lp.dist:.1f} m from the nearest SUMO lane "
                        f"(max {self.max_snap_m} m).",
                    )
                    return gid
                rec.targets.append(lp)
            self._apply(robot, rec)
        else:
            self._start_timed(robot, rec, now)
        return gid

    def _start_timed(self, robot: _Robot, rec: _GoalRecord, now: float) -> None:
        goal = rec.goal
        m = self.params.model
        duration = 0.0
        allowance = math.inf
        code_timeout = 0
        if isinstance(goal, Wait):
            duration = max(0.0, goal.duration_s)
        elif isinstance(goal, Spin):
            duration = abs(goal.target_yaw) / m.max_angular_speed
            allowance, code_timeout = goal.time_allowance_s, int(ErrorCode.SPIN_TIMEOUT)
        else:
            assert isinstance(goal, (BackUp, DriveOnHeading))
            backup = isinstance(goal, BackUp)
            if goal.distance_m <= 0 or goal.speed_mps <= 0:
                code = ErrorCode.BACKUP_INVALID_INPUT if backup else ErrorCode.DRIVE_INVALID_INPUT
                self._finish(
                    rec,
                    GoalStatus.ABORTED,
                    int(code),
                    f"distance_m and speed_mps must be positive (got {goal.distance_m}, {goal.speed_mps}).",
                )
                return
            duration = goal.distance_m / goal.speed_mps
            allowance = goal.time_allowance_s
            code_timeout = int(ErrorCode.BACKUP_TIMEOUT if backup else ErrorCode.DRIVE_TIMEOUT)
        if duration > allowance:
            rec.hold_until = now + allowance
            rec.hold_status, rec.hold_code = GoalStatus.ABORTED, code_timeout
            rec.hold_msg = (
                f"{goal.kind} would take {duration:.1f} s, more than time_allowance_s={allowance} s."
            )
        else:
            rec.hold_until = now + duration
        if robot.mode != "parked":
            self._rest(robot, park=False)

    def goal_state(self, goal_id: str) -> GoalState:
        """Snapshot of goal ``goal_id`` (pure read). Raises ``KeyError`` for an id never issued."""
        rec = self._goals[goal_id]
        if rec.status in _TERMINAL:
            return rec.cached if rec.cached is not None and rec.cached_epoch == -2 else self._freeze(rec)
        if rec.cached is None or rec.cached_epoch != self._epoch:
            rec.cached = rec.snapshot(self._feedback(self._robots[rec.namespace], rec))
            rec.cached_epoch = self._epoch
        return rec.cached

    @staticmethod
    def _freeze(rec: _GoalRecord) -> GoalState:
        rec.cached, rec.cached_epoch = rec.snapshot(), -2
        return rec.cached

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id``: it ends CANCELED at once and the vehicle brakes to a stop at the
        next position it can reach. A no-op for a finished or unknown goal."""
        rec = self._goals.get(goal_id)
        if rec is None or rec.status in _TERMINAL:
            return
        robot = self._robots[rec.namespace]
        rec.feedback = self._feedback(robot, rec)
        self._finish(rec, GoalStatus.CANCELED, 0, "")

    def robot_state(self, namespace: str) -> RobotState:
        """Pose (vehicle centre, ``map`` frame), speed, battery, stuck flag, odometry, collisions."""
        robot = self._robot(namespace)
        ls = self._ls
        pose = self._pose(robot)
        speed = 0.0
        if robot.present and not self._closed:
            if not ls.vehicle.isStopped(robot.vid):
                speed = float(ls.vehicle.getSpeed(robot.vid))
            robot.odo_total = max(robot.odo_total, robot.odo_base + float(ls.vehicle.getDistance(robot.vid)))
        odo = robot.odo_total
        self._update_battery(robot, odo, speed, pose)
        return RobotState(
            pose=pose,
            linear_velocity=speed,
            angular_velocity=0.0,
            battery=robot.battery,
            charging=robot.battery < 1.0 and self._at_charger(robot, pose, speed),
            stuck=robot.stuck,
            distance_m=odo,
            collisions=robot.collisions,
        )

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Step until ``predicate()`` is true (checked before each step) or ``timeout_s``
        simulated seconds have passed. Returns whether the predicate became true."""
        return step_until(self.clock, self.step, predicate, timeout_s)

    # -- stepping ---------------------------------------------------------------------

    def step(self) -> None:
        """Advance SUMO and the clock by ``params.step_s``; update goals, collisions, teleports."""
        if self._closed:
            raise BackendError("the SUMO world is closed")
        ls = self._ls
        ls.simulationStep()
        self._epoch += 1
        now = self.clock.advance(self.params.step_s)
        self.steps += 1
        for vid in ls.simulation.getDepartedIDList():
            r = self._by_vid.get(vid)
            if r is not None:
                r.present = True
        arrived = [self._by_vid[v] for v in ls.simulation.getArrivedIDList() if v in self._by_vid]
        for r in arrived:  # only a teleport past the end of a route makes a robot arrive
            r.present = False
        for vid in ls.simulation.getStartingTeleportIDList():
            r = self._by_vid.get(vid)
            if r is None:
                continue
            self.teleports += 1
            r.teleports += 1
            r.stuck = True
            rec = r.goal
            if rec is not None and rec.status not in _TERMINAL and rec.hold_until is None:
                self._finish(
                    rec,
                    GoalStatus.ABORTED,
                    int(ErrorCode.FAILED_TO_MAKE_PROGRESS),
                    f"SUMO teleported {r.spec.name} after it waited {self.time_to_teleport} s "
                    "behind a blocker (deadlock).",
                )
            elif rec is None and r.present:
                self._rest(r, park=self.park_idle)
        for r in arrived:
            self._reinsert(r)
        self._count_collisions()
        if self.trajectory_period_s and now >= self._next_sample - 1e-9:
            for r in self._robots.values():
                p = self._pose(r)
                if p is not None:
                    r.trajectory.append((now, p.x, p.y))
            while self._next_sample <= now + 1e-9:
                self._next_sample += self.trajectory_period_s
        for ns in list(self._active):
            self._update_goal(self._active[ns], now)
        for ns, park in list(self._resting.items()):
            self._rest(self._robots[ns], park)

    def _count_collisions(self) -> None:
        touching: set[tuple[str, str]] = set()
        for c in self._ls.simulation.getCollisions():
            a, b = c.collider, c.victim
            if a not in self._by_vid or b not in self._by_vid:
                continue
            pair = (a, b) if a < b else (b, a)
            touching.add(pair)
            if pair not in self._touching:
                ra, rb = self._by_vid[a], self._by_vid[b]
                self.collisions += 1
                ra.collisions += 1
                rb.collisions += 1
                pa, pb = self._pose(ra), self._pose(rb)
                x, y = (0.5 * (pa.x + pb.x), 0.5 * (pa.y + pb.y)) if pa and pb else (math.nan, math.nan)
                self.collision_events.append((self.clock.now(), ra.spec.namespace, rb.spec.namespace, x, y))
        self._touching = touching

    # -- internals ----------------------------------------------------------------------

    def _finish(
        self, rec: _GoalRecord, status: GoalStatus, code: int, msg: str, *, settle: bool = True
    ) -> None:
        robot = self._robots.get(rec.namespace)
        if robot is not None and robot.goal is rec and not self._closed:
            rec.feedback = self._feedback(robot, rec)
        self._epoch += 1
        rec.cached = None
        rec.status = status
        rec.error_code = code
        rec.error_msg = msg
        if robot is not None and robot.goal is rec:
            robot.goal = None
            self._active.pop(rec.namespace, None)
            if settle and not self._closed and robot.present:
                self._rest(robot, park=self.park_idle)

    def _where(self, robot: _Robot) -> tuple[str, float, int] | None:
        """``(edge, front lane pos, lane index)`` of a vehicle on a normal edge, else ``None``."""
        ls = self._ls
        if not robot.present:
            return None
        road = ls.vehicle.getRoadID(robot.vid)
        if not road or road.startswith(":"):
            return None
        where = (road, float(ls.vehicle.getLanePosition(robot.vid)), int(ls.vehicle.getLaneIndex(robot.vid)))
        robot.last_where = where
        return where

    def _reinsert(self, robot: _Robot) -> None:
        """Put a vehicle that SUMO removed (teleported past its route's end) back, parked (or
        holding) at the end of the lane it was last seen on, or of its goal's last pose."""
        ls = self._ls
        rec = robot.goal
        if rec is not None and rec.targets:
            t = rec.targets[-1]
            edge, front, lane = t.edge, self._front_pos(t.edge, t.pos), t.lane
        elif robot.last_where is not None:
            edge, _, lane = robot.last_where
            front = self.lanes.edge_length[edge]
        else:
            lp = self.lanes.nearest(robot.spec.start.x, robot.spec.start.y, robot.spec.start.theta)
            edge, front, lane = lp.edge, self._front_pos(lp.edge, lp.pos), lp.lane
        front = round(front, 3)
        robot.reinserted += 1
        rid = f"__re{robot.reinserted}_{robot.vid}"
        ls.route.add(rid, [edge])
        ls.vehicle.add(
            robot.vid,
            rid,
            ROBOT_TYPE,
            depart="now",
            departPos=f"{front:.3f}",
            departSpeed="0",
            departLane=str(lane),
        )
        ls.vehicle.setStop(
            robot.vid, edge, pos=front, laneIndex=lane, duration=_FOREVER, flags=self._idle_flags()
        )
        robot.mode = "parked" if self.park_idle else "holding"
        robot.odo_base = robot.odo_total
        self._resting.pop(robot.spec.namespace, None)
        if rec is not None and rec.status not in _TERMINAL:
            rec.applied = False  # re-route from the new position once inserted

    def _clear_stops(self, robot: _Robot) -> None:
        self._epoch += 1
        ls = self._ls
        if ls.vehicle.isStopped(robot.vid):
            ls.vehicle.resume(robot.vid)
        for _ in range(len(ls.vehicle.getStops(robot.vid))):
            try:
                ls.vehicle.replaceStop(robot.vid, 0, "")
            except Exception:
                break

    def _rest(self, robot: _Robot, park: bool) -> bool:
        """Bring the vehicle to rest where it is: brake (``setSpeed(0)``, within its decel)
        while it moves, then replace its stops by one at its lane position, parked off the lane
        (``park``) or holding on it. Returns True once at rest; until then the robot is kept in
        ``_resting`` and this is retried every step (also while it crosses a junction or is
        teleporting: a stop can only be placed on a normal lane)."""
        ls = self._ls
        ns = robot.spec.namespace
        self._resting[ns] = park
        if not robot.present:
            return False
        want = "parked" if park else "holding"
        stopped = bool(ls.vehicle.isStopped(robot.vid))
        if robot.mode == want and stopped:
            self._resting.pop(ns, None)
            return True
        where = self._where(robot)
        if where is None:
            if robot.mode == "braking" and ls.vehicle.getRoadID(robot.vid):
                # inside a junction: SUMO would teleport a vehicle held there; cross it first
                ls.vehicle.setSpeed(robot.vid, -1.0)
                robot.mode = "crossing"
            return False
        speed = float(ls.vehicle.getSpeed(robot.vid))
        if not stopped and speed > 1e-3:
            self._epoch += 1
            ls.vehicle.setSpeed(robot.vid, 0.0)
            robot.mode = "braking"
            return False
        edge, pos, lane = where
        try:
            self._clear_stops(robot)
            ls.vehicle.setRoute(robot.vid, [edge])
            ls.vehicle.setStop(
                robot.vid, edge, pos=pos, laneIndex=lane, duration=_FOREVER, flags=1 if park else 0
            )
            ls.vehicle.setSpeed(robot.vid, -1.0)
        except Exception:  # retried next step
            return False
        robot.mode = want
        self._resting.pop(ns, None)
        return True

    def _route_between(self, a: str, b: str, loop: bool) -> list[str] | None:
        """Edges from ``a`` to ``b`` (both included); with ``loop`` and ``a == b``, a way round."""
        ls = self._ls
        if a == b and not loop:
            return [a]
        if a != b:
            r = ls.simulation.findRoute(a, b, ROBOT_TYPE)
            return list(r.edges) if r.edges else None
        best: list[str] | None = None
        best_len = math.inf
        for s in self.lanes.successors.get(a, []):
            r = ls.simulation.findRoute(s, b, ROBOT_TYPE) if s != b else None
            edges = list(r.edges) if r is not None and r.edges else ([s] if s == b else None)
            if not edges:
                continue
            length = r.length if r is not None else self.lanes.edge_length[s]
            if length < best_len:
                best, best_len = [a, *edges], length
        return best

    def _apply(self, robot: _Robot, rec: _GoalRecord) -> None:
        """Give SUMO the route and final stop of navigation goal ``rec`` (retried each step
        while the vehicle is not yet on a normal edge)."""
        ls = self._ls
        if not robot.present:
            return
        road = ls.vehicle.getRoadID(robot.vid)
        if not road:
            return
        if road.startswith(":"):
            route = ls.vehicle.getRoute(robot.vid)
            ri = ls.vehicle.getRouteIndex(robot.vid)
            if ri + 1 >= len(route):
                return
            prefix, edge, pos = [route[ri]], route[ri + 1], -1.0
        else:
            prefix, edge, pos = [], road, float(ls.vehicle.getLanePosition(robot.vid))
            v = float(ls.vehicle.getSpeed(robot.vid))
            pos += v * v / (2.0 * self.params.model.max_linear_accel)  # cannot stop before this
        edges = [*prefix, edge]
        idx: list[int] = []
        cur_e, cur_p = edge, pos
        for t in rec.targets:
            front = self._front_pos(t.edge, t.pos)
            if t.edge == cur_e and front >= cur_p - 1e-6:
                idx.append(len(edges) - 1)
            else:
                seg = self._route_between(cur_e, t.edge, loop=True)
                if seg is None:
                    self._finish(
                        rec,
                        GoalStatus.ABORTED,
                        int(ErrorCode.NO_VALID_PATH),
                        f"No SUMO route from edge {cur_e} to edge {t.edge}.",
                    )
                    return
                edges += seg[1:]
                idx.append(len(edges) - 1)
            cur_e, cur_p = t.edge, front
        last = rec.targets[-1]
        # SUMO puts a stop on the first occurrence of its edge ahead in the route: when the
        # route passes the last pose's edge earlier (a loop), the stop is set once that is behind
        earlier = [j for j in range(idx[-1]) if edges[j] == last.edge]
        rec.stop_after = earlier[-1] if earlier else -1
        try:
            self._clear_stops(robot)
            ls.vehicle.setRoute(robot.vid, edges)
            if rec.stop_after < 0:
                self._set_final_stop(robot, rec)
            ls.vehicle.setSpeed(robot.vid, -1.0)
            self._resting.pop(robot.spec.namespace, None)
        except Exception as exc:  # SUMO refused (e.g. cannot brake in time): retry next step
            rec.error_msg = f"retrying route: {exc}"
            return
        rec.error_msg = ""
        rec.route = edges
        rec.target_idx = idx
        cum = [0.0]
        for e in edges:
            cum.append(cum[-1] + self.lanes.edge_length.get(e, 0.0))
        rec.cum = cum
        rec.passed = 0
        rec.applied = True
        self._epoch += 1
        robot.mode = "driving"

    def _set_final_stop(self, robot: _Robot, rec: _GoalRecord) -> None:
        last = rec.targets[-1]
        self._ls.vehicle.setStop(
            robot.vid,
            last.edge,
            pos=self._front_pos(last.edge, last.pos),
            laneIndex=last.lane,
            duration=_FOREVER,
            flags=0,
        )
        rec.stop_after = -1

    def _progress(self, robot: _Robot, rec: _GoalRecord) -> tuple[int, float]:
        """``(route index, front lane pos)`` of the vehicle along the goal's route (cached until
        SUMO steps or is commanded)."""
        if robot.prog_epoch == self._epoch:
            return robot.prog
        ls = self._ls
        ri = int(ls.vehicle.getRouteIndex(robot.vid))
        road = ls.vehicle.getRoadID(robot.vid)
        if road.startswith(":"):
            prog = (ri, self.lanes.edge_length.get(rec.route[ri], 0.0) if 0 <= ri < len(rec.route) else 0.0)
        else:
            prog = (ri, float(ls.vehicle.getLanePosition(robot.vid)))
        robot.prog, robot.prog_epoch = prog, self._epoch
        return prog

    def _update_goal(self, robot: _Robot, now: float) -> None:
        rec = robot.goal
        if rec is None or rec.status in _TERMINAL:
            self._active.pop(robot.spec.namespace, None)
            return
        if rec.hold_until is not None:
            if now >= rec.hold_until - 1e-9:
                self._finish(rec, rec.hold_status, rec.hold_code, rec.hold_msg)
            return
        if not rec.applied:
            self._apply(robot, rec)
            return
        if not robot.present:
            return
        ri, pos = self._progress(robot, rec)
        if 0 <= rec.stop_after < ri:
            try:
                self._set_final_stop(robot, rec)
            except Exception:  # retried next step
                pass
        while rec.passed < len(rec.targets):
            ti = rec.target_idx[rec.passed]
            t = rec.targets[rec.passed]
            if ri > ti or (ri == ti and pos >= self._front_pos(t.edge, t.pos) - _POS_TOL_M):
                rec.passed += 1
            else:
                break
        ls = self._ls
        if rec.passed >= len(rec.targets) and ls.vehicle.isStopped(robot.vid):
            rec.feedback = self._feedback(robot, rec)
            self._finish(rec, GoalStatus.SUCCEEDED, 0, "")

    def _feedback(self, robot: _Robot, rec: _GoalRecord) -> Feedback:
        if self._closed:
            return rec.feedback
        now = self.clock.now()
        goal = rec.goal
        pose = self._pose(robot)
        if rec.hold_until is not None or isinstance(goal, (Wait, Spin, BackUp, DriveOnHeading)):
            if isinstance(goal, Wait):
                return Feedback(time_left_s=max(0.0, (rec.hold_until or now) - now))
            if isinstance(goal, Spin):
                return Feedback(angular_distance_traveled=0.0)
            return Feedback(distance_traveled=0.0)
        remaining: float | None = None
        if rec.applied and robot.present and rec.route:
            ri, pos = self._progress(robot, rec)
            last = rec.targets[-1]
            end = rec.cum[rec.target_idx[-1]] + self._front_pos(last.edge, last.pos)
            here = rec.cum[min(ri, len(rec.route) - 1)] + pos
            remaining = max(0.0, end - here)
        elif rec.targets and pose is not None:
            remaining = math.hypot(rec.targets[-1].x - pose.x, rec.targets[-1].y - pose.y)
        speed = self.params.model.max_linear_speed
        n_left = len(rec.targets) - rec.passed
        return Feedback(
            current_pose=pose,
            navigation_time_s=now - rec.start_t,
            estimated_time_remaining_s=None if remaining is None else remaining / speed,
            distance_remaining_m=remaining,
            number_of_recoveries=0,
            number_of_poses_remaining=n_left if isinstance(goal, NavigateThroughPoses) else None,
            current_waypoint=min(rec.passed, len(rec.targets) - 1)
            if isinstance(goal, FollowWaypoints)
            else None,
        )

    def _pose(self, robot: _Robot) -> Pose2D | None:
        if not robot.present or self._closed or robot.pose_epoch == self._epoch:
            return robot.last_pose
        ls = self._ls
        road = ls.vehicle.getRoadID(robot.vid)
        if not road:  # teleporting
            return robot.last_pose
        theta = normalize_angle(math.radians(90.0 - float(ls.vehicle.getAngle(robot.vid))))
        if not road.startswith(":"):
            # centre = half a vehicle behind the front along the lane, in lane units (a lane may be
            # longer than its drawn shape; parked vehicles are drawn beside the lane)
            lane = min(max(int(ls.vehicle.getLaneIndex(robot.vid)), 0), self.lanes.lane_count[road] - 1)
            c = max(0.0, float(ls.vehicle.getLanePosition(robot.vid)) - self.length / 2.0)
            xy = self.lanes.point(road, lane, c)
            x, y = xy if xy is not None else ls.simulation.convert2D(road, c, lane)
        else:
            fx, fy = ls.vehicle.getPosition(robot.vid)
            x = fx - math.cos(theta) * self.length / 2.0
            y = fy - math.sin(theta) * self.length / 2.0
        pose = Pose2D(float(x), float(y), theta)
        robot.last_pose, robot.pose_epoch = pose, self._epoch
        return pose

    def _at_charger(self, robot: _Robot, pose: Pose2D | None, speed: float) -> bool:
        if pose is None or speed > 1e-3:
            return False
        r = self.params.charger_radius + self.length
        return any(math.hypot(c.x - pose.x, c.y - pose.y) <= r for c in self._chargers)

    def _update_battery(self, robot: _Robot, odo: float, speed: float, pose: Pose2D | None) -> None:
        b = self.params.battery
        now = self.clock.now()
        dt = max(0.0, now - robot.last_batt_t)
        dd = max(0.0, odo - robot.last_odo)
        if self._at_charger(robot, pose, speed) and dd < 1e-6:
            robot.battery = min(1.0, robot.battery + b.charge_per_s * dt)
        else:
            robot.battery = max(0.0, robot.battery - b.drain_per_s * dt - b.drain_per_m * dd)
        robot.last_batt_t = now
        robot.last_odo = odo


def _reject_reason(goal: Goal) -> str | None:
    if isinstance(goal, NavigateThroughPoses) and not goal.poses:
        return "NavigateThroughPoses needs at least one pose."
    if isinstance(goal, FollowWaypoints) and not goal.poses:
        return "FollowWaypoints needs at least one pose."
    poses: tuple[Pose2D, ...] = ()
    if isinstance(goal, NavigateToPose):
        poses = (goal.pose,)
    elif isinstance(goal, (NavigateThroughPoses, FollowWaypoints)):
        poses = tuple(goal.poses)
    elif not isinstance(goal, (Spin, BackUp, DriveOnHeading, Wait)):
        return f"Unsupported goal type {type(goal).__name__}."
    for i, pose in enumerate(poses):
        if not (math.isfinite(pose.x) and math.isfinite(pose.y) and math.isfinite(pose.theta)):
            return f"Pose {i} ({pose.x}, {pose.y}, {pose.theta}) is not finite."
    return None


def _source_net(roadmap: Any) -> Path | None:
    """The ``.net.xml`` a roadmap (``Roadmap`` or graph) was read from, if any."""
    if roadmap is None:
        return None
    src = getattr(roadmap, "source_net", None)
    if src is None and not hasattr(roadmap, "source_net"):
        try:
            src = as_graph(roadmap).graph.get("sumo_net")
        except TypeError:
            return None
    return Path(src) if src else None


__all__ = [
    "LaneIndex",
    "LanePoint",
    "ROBOT_TYPE",
    "SumoWorld",
]
