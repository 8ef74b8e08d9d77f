"""Eclipse SUMO as a navigation backend: robots are SUMO vehicles on a network of the warehouse.

:class:`SumoWorld` owns one libsumo simulation (:mod:`sim.sumo.launch`): on the SUMO network
of the roadmap (built or reused by :mod:`sim.sumo.net`), or on the ``.net.xml`` the roadmap was
read from (``roadmap: {net: ...}``, :attr:`fleet.roadmap.Roadmap.source_net`). Every robot is a
vehicle of one ``robot`` type (:mod:`sim.sumo.vehicles`); each :meth:`SumoWorld.step` advances
SUMO and the :class:`fleet.clock.SimClock` passed in by ``SimParams.step_s``.
:meth:`SumoWorld.backend` returns the :class:`~fleet.navigation.NavigationBackend` of one robot.

**libsumo is a process-global singleton**: only one :class:`SumoWorld` may be open at a time in
a process. Opening a second one raises :class:`fleet.errors.BackendError`; close the first
(:meth:`SumoWorld.close`, or use the world as a context manager), or run SUMO in another process.

How Nav2 actions map onto SUMO (poses are in the ``map`` frame; SUMO x/y are the same):

* **Poses -> lanes.** A pose is snapped to the nearest lane point; between lanes at similar
  distance, the lane whose direction agrees with the pose's heading wins. A pose farther than
  ``max_snap_m`` from every lane aborts the goal with ``GOAL_OUTSIDE_MAP``. SUMO only knows
  lanes: a goal inside an obstacle, or between aisles, is reached at its lane projection.
  The robot's reported pose is the centre of the vehicle (SUMO reports the front bumper).
* **NavigateToPose / NavigateThroughPoses / FollowWaypoints** set one route through the
  lane points of every pose with a stop at the last one (:mod:`sim.sumo.routes`);
  intermediate poses are passed without stopping. The goal SUCCEEDS when the vehicle has
  stopped at the last pose; an unreachable pose aborts with ``NO_VALID_PATH``.
* **Wait** holds the vehicle on its lane (a blocking stop at the next position it can brake to)
  for ``duration_s``; other robots queue behind it.
* **Spin, BackUp, DriveOnHeading**: SUMO vehicles cannot turn on the spot or reverse. They run
  as a *timed no-op*: the vehicle holds on its lane for the time the motion would take
  (``|target_yaw| / max_angular_speed``, ``distance_m / speed_mps``) and the goal SUCCEEDS with
  zero distance travelled in its feedback. A duration above ``time_allowance_s`` aborts with the
  action's TIMEOUT code after the allowance; non-positive distance or speed aborts with the
  INVALID_INPUT code. Behavior-tree recoveries therefore "succeed" without moving on SUMO.
* **Planner goals** (ComputePathToPose / ThroughPoses, SmoothPath) run on the lanes beside the
  motion goal; FollowPath and ClearCostmaps are REJECTED (:mod:`sim.sumo.planning`).
* **Cancel** ends the goal CANCELED at once; the vehicle brakes to a stop at the next position
  it can reach (never an emergency stop). **Preemption**: a new goal aborts the executing one
  (``error_msg`` names the new goal) and sets a new route from where the vehicle is.
* **Junctions**: by default the network has no lanes inside junctions (a robot crosses a
  junction in one step; lanes are as long as their roadmap edges, so travel times match).
  ``internal_links=True`` models them, but queues inside the warehouse's closely spaced
  junctions then gridlock SUMO (``docs/sumo.md``).
* **Idle** robots (no executing goal) *park* at their lane position (SUMO parking: the vehicle
  leaves the lane, others can pass) unless ``park_idle=False``, where they hold on the lane.

Health signals: contacts and the battery (:mod:`sim.sumo.health`), and **deadlocks =
teleports**: SUMO teleports a vehicle that has waited longer than ``--time-to-teleport``
(default ``SimParams.stuck_time_s``) behind a blocker. Each starting teleport is counted
(:attr:`SumoWorld.teleports`, per robot in :meth:`SumoWorld.teleports_of`), the robot is
reported ``stuck`` until its next goal, and its navigation goal aborts with
``FAILED_TO_MAKE_PROGRESS``; the vehicle then stops at the next position after its jump.

Goals follow the Nav2 semantics shared with the simulator (:mod:`sim.goals`: ids
``<namespace>#<n>`` never reused, validation and reject reasons, preemption, idempotent cancel,
error codes)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from fleet.clock import SimClock, step_until
from fleet.errors import BackendError
from fleet.robots import RobotSpec, SimParams
from fleet.types import (
    BackUp,
    DriveOnHeading,
    ErrorCode,
    Feedback,
    FollowWaypoints,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    RobotState,
    Spin,
    Wait,
)
from sim.backend import NamespacedBackend
from sim.goals import (
    BEHAVIOR_CODES,
    GoalBook,
    GoalRecord,
    goal_poses,
    preempt,
    reject_if_invalid,
    start_error,
)
from sim.history import TRAJECTORY_KEEP_S, trim_oldest
from sim.sumo.health import Chargers, Contacts
from sim.sumo.lanes import LaneIndex, LanePoint
from sim.sumo.launch import (
    ROBOT_TYPE,
    RoadmapLike,
    choose_network,
    define_robot_type,
    load_libsumo,
    map_roadmap,
    sumo_command,
)
from sim.sumo.net import SumoNetwork
from sim.sumo.planning import SumoPlanning
from sim.sumo.routes import RoutePlan, Router
from sim.sumo.vehicles import Vehicle, Vehicles

_ACTIVE: SumoWorld | None = None


def active_world() -> SumoWorld | None:
    """The open :class:`SumoWorld` of this process, if any."""
    return _ACTIVE


@dataclass
class _Goal:
    """An executing goal on SUMO: its shared record, its route (navigation goals) or its hold
    (timed goals: Wait and the no-op recoveries), and the snapshot cached for this epoch."""

    record: GoalRecord
    start_t: float
    plan: RoutePlan = field(default_factory=RoutePlan)
    hold_until: float | None = None
    hold_status: GoalStatus = GoalStatus.SUCCEEDED
    hold_code: int = 0
    hold_msg: str = ""
    cached: GoalState | None = None
    cached_epoch: int = -1


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
        roadmap: RoadmapLike,
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
        ls = load_libsumo()
        if ls.simulation.isLoaded():
            raise BackendError("libsumo already runs a simulation not owned by a SumoWorld; close it first")
        self._ls = ls
        self._closed = True
        self.params = params
        self.clock = clock
        self.park_idle = park_idle
        self.trajectory_period_s = trajectory_period_s
        self.max_snap_m = max_snap_m
        self.network: SumoNetwork
        self.network, mapped, self.vclass = choose_network(
            roadmap, params.model, net_file, vclass, cache_dir, internal_links
        )
        self.time_to_teleport = params.stuck_time_s if time_to_teleport is None else time_to_teleport
        args = sumo_command(
            self.network.net_path, params, clock.now(), self.time_to_teleport, sumo_log, sumo_args
        )
        try:
            ls.start(args)
        except Exception as exc:
            raise BackendError(f"SUMO failed to start with {' '.join(args)}: {exc}") from exc
        _ACTIVE = self
        self._closed = False
        try:
            if mapped is not None:
                self.network = map_roadmap(ls, self.network, mapped)
            self.length = define_robot_type(ls, params.model, self.vclass)
            self.lanes = LaneIndex(ls)
            self._setup(robots)
        except Exception:
            self.close()
            raise

    def _setup(self, robots: Sequence[RobotSpec]) -> None:
        chargers = [self.lanes.nearest(c.x, c.y, c.theta) for c in self.params.chargers]
        self._vehicles = Vehicles(self._ls, self.lanes, self.length, self.park_idle)
        self._router = Router(self._ls, self.lanes, self._vehicles, self.params)
        self._planning = SumoPlanning(self._ls, self.lanes, self.max_snap_m)
        self._contacts = Contacts(self._ls)
        self._charging = Chargers(chargers, self.params.charger_radius + self.length, self.params.battery)
        self._robots: dict[str, Vehicle] = {}
        self._by_vid: dict[str, Vehicle] = {}
        self._backends: dict[str, NamespacedBackend] = {}
        self._goals = GoalBook()
        self._active: dict[str, _Goal] = {}  # namespace -> the robot's executing goal
        self.teleports = 0
        self.steps = 0
        self._next_sample = self.clock.now() + (self.trajectory_period_s or 0.0)
        for spec in robots:
            self.add_robot(spec)

    def add_robot(self, spec: RobotSpec) -> None:
        """Add ``spec`` parked at the lane point nearest its start (BackendError if a duplicate)."""
        if spec.namespace in self._robots:
            raise BackendError(f"robot namespace {spec.namespace} is already in the SUMO world")
        v = self._vehicles.insert(spec, self.clock.now())
        self._robots[spec.namespace] = v
        self._by_vid[v.vid] = v

    # -- public API -----------------------------------------------------------------

    @property
    def collisions(self) -> int:
        """Robot-robot contact events so far (a pair that starts touching counts once)."""
        return self._contacts.total

    @property
    def collision_events(self) -> list[tuple[float, str, str, float, float]]:
        """``(t, namespace_a, namespace_b, x, y)`` of every new contact between two robots."""
        return self._contacts.events

    @property
    def namespaces(self) -> list[str]:
        """Robot namespaces in the order they were added."""
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
        ``trajectory_period_s`` simulated seconds, of the last
        :data:`sim.history.TRAJECTORY_KEEP_S` seconds at least (a copy)."""
        return list(self._robot(namespace).trajectory)

    def teleports_of(self, namespace: str) -> int:
        """How many times SUMO teleported robot ``namespace`` (deadlock signals)."""
        return self._robot(namespace).teleports

    def _robot(self, namespace: str) -> Vehicle:
        try:
            return self._robots[namespace]
        except KeyError:
            raise BackendError(
                f"no robot {namespace!r} in the SUMO world (have {sorted(self._robots)})"
            ) from None

    def close(self) -> None:
        """Stop SUMO (idempotent). Goals still running end ABORTED with SERVER_UNAVAILABLE."""
        global _ACTIVE
        if self._closed:
            return
        self._closed = True
        vehicles = getattr(self, "_vehicles", None)
        if vehicles is not None:
            vehicles.closed = True
        for goal in list(getattr(self, "_active", {}).values()):
            self._finish(
                goal, GoalStatus.ABORTED, int(ErrorCode.SERVER_UNAVAILABLE), "The SUMO world was closed."
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

    def send_goal(self, namespace: str, goal: object) -> str:
        """Start ``goal`` on robot ``namespace``; return its id at once (see module docstring).

        The goal is EXECUTING at once, or already terminal (REJECTED: no poses for
        NavigateThroughPoses, a non-finite pose; ABORTED: an empty FollowWaypoints, invalid
        behavior input, a pose off the network, no route). The goal the robot was executing
        ends ABORTED, naming the new goal. Raises :class:`BackendError` (changing nothing) when
        the world is closed, for an unknown namespace or an object that is not a goal.
        """
        if self._closed:
            raise BackendError("the SUMO world is closed")
        v = self._robot(namespace)
        record = self._goals.open(namespace, goal)
        if self._planning.take(record, lambda: self.robot_state(namespace).pose):
            return record.goal_id
        now = self.clock.now()
        g = _Goal(record, now)
        old = self._active.get(namespace)
        if old is not None:
            preempt(old.record, record, self._feedback(v, old))
            self._release(old, settle=False)
        v.stuck = False
        if reject_if_invalid(record):
            return record.goal_id
        self._active[namespace] = g
        error = start_error(record.goal)
        if error is not None:
            self._finish(g, GoalStatus.ABORTED, int(error[0]), error[1])
        elif goal_poses(record.goal):
            self._start_navigation(v, g)
        else:
            self._start_timed(v, g, now)
        return record.goal_id

    def _start_navigation(self, v: Vehicle, g: _Goal) -> None:
        """Snap the goal's poses to lanes (ABORTED ``GOAL_OUTSIDE_MAP`` beyond ``max_snap_m``)
        and route the vehicle."""
        for i, p in enumerate(goal_poses(g.record.goal)):
            lp = self.lanes.nearest(p.x, p.y, p.theta)
            if lp.dist > self.max_snap_m:
                self._finish(
                    g,
                    GoalStatus.ABORTED,
                    int(ErrorCode.GOAL_OUTSIDE_MAP),
                    f"Pose {i} ({p.x:.2f}, {p.y:.2f}) is {lp.dist:.1f} m from the nearest SUMO lane "
                    f"(max {self.max_snap_m} m).",
                )
                return
            g.plan.targets.append(lp)
        self._apply(v, g)

    def _start_timed(self, v: Vehicle, g: _Goal, now: float) -> None:
        """Wait, and Spin / BackUp / DriveOnHeading as timed no-ops: hold on the lane for the
        time the motion would take (ABORTED with the action's TIMEOUT code after
        ``time_allowance_s`` when it would take longer)."""
        goal = g.record.goal
        m = self.params.model
        duration = 0.0
        allowance = math.inf
        code_timeout = 0
        if isinstance(goal, Wait):
            duration = max(0.0, goal.duration_s)
        elif isinstance(goal, Spin):
            duration = abs(goal.target_yaw) / m.max_angular_speed
            allowance, code_timeout = goal.time_allowance_s, int(BEHAVIOR_CODES[goal.kind].timeout)
        else:
            assert isinstance(goal, (BackUp, DriveOnHeading))
            duration = goal.distance_m / goal.speed_mps
            allowance = goal.time_allowance_s
            code_timeout = int(BEHAVIOR_CODES[goal.kind].timeout)
        if duration > allowance:
            g.hold_until = now + allowance
            g.hold_status, g.hold_code = GoalStatus.ABORTED, code_timeout
            g.hold_msg = f"{goal.kind} would take {duration:.1f} s, more than time_allowance_s={allowance} s."
        else:
            g.hold_until = now + duration
        if v.mode != "parked":
            self._vehicles.rest(v, park=False)

    def goal_state(self, goal_id: str) -> GoalState:
        """Snapshot of goal ``goal_id`` (pure read). Raises ``KeyError`` for an id never issued."""
        record = self._goals.get(goal_id)
        g = None if record.terminal else self._active.get(record.namespace)
        if g is None or g.record is not record:
            return record.snapshot()
        epoch = self._vehicles.epoch
        if g.cached is None or g.cached_epoch != epoch:
            g.cached = record.snapshot(self._feedback(self._robots[record.namespace], g))
            g.cached_epoch = epoch
        return g.cached

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id``: it ends CANCELED at once and the vehicle brakes to a stop at the
        next position it can reach. A no-op for a finished or unknown goal."""
        record = self._goals.live(goal_id)
        if record is None:
            return
        g = self._active.get(record.namespace)
        if g is not None and g.record is record:
            self._finish(g, GoalStatus.CANCELED, 0, "")

    def robot_state(self, namespace: str) -> RobotState:
        """Pose (vehicle centre, ``map`` frame), speed, battery, stuck flag, odometry, collisions."""
        v = self._robot(namespace)
        ls = self._ls
        pose = self._vehicles.pose(v)
        speed = 0.0
        if v.present and not self._closed:
            if not ls.vehicle.isStopped(v.vid):
                speed = float(ls.vehicle.getSpeed(v.vid))
            v.odo_total = max(v.odo_total, v.odo_base + float(ls.vehicle.getDistance(v.vid)))
        odo = v.odo_total
        self._charging.update(v, self.clock.now(), odo, speed, pose)
        return RobotState(
            pose=pose,
            linear_velocity=speed,
            angular_velocity=0.0,
            battery=v.battery,
            charging=v.battery < 1.0 and self._charging.at_charger(pose, speed),
            stuck=v.stuck,
            distance_m=odo,
            collisions=v.collisions,
        )

    def run_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Step until ``predicate()`` holds (checked before each step) or ``timeout_s`` pass."""
        return step_until(self.clock, self.step, predicate, timeout_s)

    # -- stepping ---------------------------------------------------------------------

    def step(self) -> None:
        """Advance SUMO and the clock by ``params.step_s``; update goals, collisions, teleports."""
        if self._closed:
            raise BackendError("the SUMO world is closed")
        ls = self._ls
        ls.simulationStep()
        self._vehicles.epoch += 1
        now = self.clock.advance(self.params.step_s)
        self.steps += 1
        for vid in ls.simulation.getDepartedIDList():
            v = self._by_vid.get(vid)
            if v is not None:
                v.present = True
        arrived = [self._by_vid[x] for x in ls.simulation.getArrivedIDList() if x in self._by_vid]
        for v in arrived:  # only a teleport past the end of a route makes a robot arrive
            v.present = False
        for vid in ls.simulation.getStartingTeleportIDList():
            v = self._by_vid.get(vid)
            if v is not None:
                self._teleported(v)
        for v in arrived:
            self._reinsert(v)
        self._contacts.count(self.clock.now(), self._by_vid, self._vehicles.pose)
        self._sample(now)
        for ns in list(self._active):
            self._update_goal(self._robots[ns], self._active[ns], now)
        for ns, park in list(self._vehicles.resting.items()):
            self._vehicles.rest(self._robots[ns], park)

    def _teleported(self, v: Vehicle) -> None:
        """SUMO teleports ``v`` (a deadlock): count it, mark it stuck, abort its navigation."""
        self.teleports += 1
        v.teleports += 1
        v.stuck = True
        g = self._active.get(v.namespace)
        if g is not None and g.hold_until is None:
            self._finish(
                g,
                GoalStatus.ABORTED,
                int(ErrorCode.FAILED_TO_MAKE_PROGRESS),
                f"SUMO teleported {v.spec.name} after it waited {self.time_to_teleport} s "
                "behind a blocker (deadlock).",
            )
        elif g is None and v.present:
            self._vehicles.rest(v, park=self.park_idle)

    def _reinsert(self, v: Vehicle) -> None:
        g = self._active.get(v.namespace)
        self._vehicles.reinsert(v, g.plan.targets[-1] if g is not None and g.plan.targets else None)
        if g is not None:
            g.plan.applied = False  # re-route from the new position once inserted

    def _sample(self, now: float) -> None:
        if self.trajectory_period_s and now >= self._next_sample - 1e-9:
            for v in self._robots.values():
                p = self._vehicles.pose(v)
                if p is not None:
                    v.trajectory.append((now, p.x, p.y))
                    trim_oldest(v.trajectory, int(TRAJECTORY_KEEP_S / self.trajectory_period_s))
            while self._next_sample <= now + 1e-9:
                self._next_sample += self.trajectory_period_s

    # -- internals ----------------------------------------------------------------------

    def _finish(self, g: _Goal, status: GoalStatus, code: int, msg: str) -> None:
        """End the executing goal ``g`` with ``status`` (feedback frozen); the vehicle rests."""
        v = self._robots[g.record.namespace]
        if not self._closed:
            g.record.feedback = self._feedback(v, g)
        g.record.finish(status, code, msg)
        self._release(g, settle=True)

    def _release(self, g: _Goal, settle: bool) -> None:
        """``g`` ended: it is no longer the robot's goal; ``settle`` brings the vehicle to rest."""
        self._vehicles.epoch += 1
        g.cached = None
        ns = g.record.namespace
        if self._active.get(ns) is g:
            del self._active[ns]
            v = self._robots[ns]
            if settle and not self._closed and v.present:
                self._vehicles.rest(v, park=self.park_idle)

    def _apply(self, v: Vehicle, g: _Goal) -> None:
        failed = self._router.apply(v, g.plan, g.record)
        if failed is not None:
            self._finish(g, GoalStatus.ABORTED, int(ErrorCode.NO_VALID_PATH), failed)

    def _update_goal(self, v: Vehicle, g: _Goal, now: float) -> None:
        if g.hold_until is not None:
            if now >= g.hold_until - 1e-9:
                self._finish(g, g.hold_status, g.hold_code, g.hold_msg)
            return
        if not g.plan.applied:
            self._apply(v, g)
            return
        if v.present and self._router.advance(v, g.plan):
            self._finish(g, GoalStatus.SUCCEEDED, 0, "")

    def _feedback(self, v: Vehicle, g: _Goal) -> Feedback:
        if self._closed:
            return g.record.feedback
        now = self.clock.now()
        goal = g.record.goal
        pose = self._vehicles.pose(v)
        if g.hold_until is not None or isinstance(goal, (Wait, Spin, BackUp, DriveOnHeading)):
            if isinstance(goal, Wait):
                return Feedback(time_left_s=max(0.0, (g.hold_until or now) - now))
            if isinstance(goal, Spin):
                return Feedback(angular_distance_traveled=0.0)
            return Feedback(distance_traveled=0.0)
        plan = g.plan
        remaining: float | None = None
        if plan.applied and v.present and plan.route:
            remaining = self._router.remaining(v, plan)
        elif plan.targets and pose is not None:
            remaining = math.hypot(plan.targets[-1].x - pose.x, plan.targets[-1].y - pose.y)
        speed = self.params.model.max_linear_speed
        return Feedback(
            current_pose=pose,
            navigation_time_s=now - g.start_t,
            estimated_time_remaining_s=None if remaining is None else remaining / speed,
            distance_remaining_m=remaining,
            number_of_recoveries=0,
            number_of_poses_remaining=len(plan.targets) - plan.passed
            if isinstance(goal, NavigateThroughPoses)
            else None,
            current_waypoint=max(0, min(plan.passed, len(plan.targets) - 1))
            if isinstance(goal, FollowWaypoints)
            else None,
        )


__all__ = [
    "LaneIndex",
    "LanePoint",
    "ROBOT_TYPE",
    "SumoWorld",
    "active_world",
]
