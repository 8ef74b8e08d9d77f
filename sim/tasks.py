"""The goal executors: one :class:`Task` per Nav2 action (the simulator's "Nav2 servers").

Each executing goal is a :class:`Task` bound to one :class:`sim.robot.Robot`. Navigation
goals plan their path and hand it to the simulator's vectorized path follower
(:meth:`World.attach_path`); they hear back only through events: :meth:`Task.arrived` (final
pose reached), :meth:`Task.no_approach` (the remaining path stopped shrinking) and
:meth:`Task.on_stuck` (no motion for ``stuck_time_s``). Other goals (Spin, BackUp,
DriveOnHeading, Wait, FollowWaypoints between waypoints) are asked once per step for a desired
``(v, w)`` command (m/s, rad/s) through :meth:`Task.control` and told about the resulting
motion through :meth:`Task.after_move`. The simulator, not the task, applies acceleration
limits, the reactive safety stop, static collision clamping, battery and faults; a task only
decides where it wants to go and when its goal has succeeded or failed.

A task finishes its goal's :class:`sim.goals.GoalRecord` with :meth:`Task.succeed` /
:meth:`Task.abort`; the goal dispatch (:mod:`sim.dispatch`) handles cancel and preemption.
Feedback is computed on demand (:meth:`Task.feedback`) and frozen when the goal ends, so a
terminal goal keeps its last feedback. :func:`make_task` builds the task of a goal; a goal
that cannot start (:func:`sim.goals.start_error`) ends ABORTED at once.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

from fleet.robots import SimParams
from fleet.types import (
    BackUp,
    DriveOnHeading,
    ErrorCode,
    Feedback,
    FollowPath,
    FollowWaypoints,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
)
from sim.follower import APPROACH_FACTOR
from sim.goals import BEHAVIOR_CODES, GoalRecord, start_error
from sim.planner import GridPlanner, PlanResult
from sim.robot import Robot
from sim.snapshots import make_feedback

if TYPE_CHECKING:
    from fleet.clock import SimClock

#: Spin succeeds when the remaining angle is below this (rad).
SPIN_TOLERANCE_RAD = 0.02
#: BackUp / DriveOnHeading succeed when the remaining distance is below this (m).
DRIVE_TOLERANCE_M = 0.005
#: Nav2 behaviors simulate this far ahead (seconds at the commanded speed) for collisions.
SIMULATE_AHEAD_S = 2.0


class World(Protocol):
    """What tasks may ask of the simulator (the goal dispatch, :class:`sim.dispatch.GoalDispatch`,
    provides it)."""

    params: SimParams
    planner: GridPlanner
    clock: SimClock

    def plan(self, robot: Robot, start: tuple[float, float], goal: tuple[float, float]) -> PlanResult:
        """Plan ``start`` -> ``goal`` (m, ``map``) for ``robot`` on its global costmap: the static
        map and the obstacles it has learned (:meth:`sim.planner.GridPlanner.plan_avoiding`).
        When the learned obstacles close every way the static plan is returned: the robot goes
        to look, and its safety layer and progress checker handle a way that is still blocked."""
        ...

    def free_distance(
        self, robot: Robot, direction: float, lookahead: float, static: bool, heading: float | None = None
    ) -> float:
        """Distance (m) the robot's center can travel straight along ``heading`` (default its
        yaw; ``direction`` +1 forward, -1 backward) before touching another robot or a dynamic
        obstacle (and, if ``static``, a static obstacle), capped at ``lookahead``."""
        ...

    def attach_path(
        self, robot: Robot, path: list[tuple[float, float]], vias: list[int], final_yaw: float, now: float
    ) -> None:
        """Let the vectorized path follower drive ``robot`` along ``path`` (``vias``: indices
        of the poses to pass, the last is the goal), then turn it to ``final_yaw``. The task
        hears back through :meth:`Task.arrived` and :meth:`Task.no_approach`."""
        ...

    def detach_path(self, robot: Robot) -> None:
        """Stop following the robot's path (no-op when it follows none)."""
        ...

    def path_remaining(self, robot: Robot) -> float:
        """Distance (m) along the followed path from the robot to its end (0 once reached)."""
        ...

    def poses_remaining(self, robot: Robot) -> int:
        """Poses of the followed path not yet passed (0 once the final position is reached)."""
        ...

    def path_progress(self, robot: Robot) -> tuple[float, float, float, float, int]:
        """``(x, y, theta)`` of the robot with :meth:`path_remaining` and
        :meth:`poses_remaining`, read together."""
        ...


class Task:
    """Base of the goal executors. Subclasses implement :meth:`control` and may override
    :meth:`after_move`, :meth:`on_stuck` and :meth:`feedback`."""

    #: True while the task wants the robot to translate (used by the stuck detector).
    drives: bool = False

    def __init__(self, record: GoalRecord, robot: Robot, world: World, now: float) -> None:
        self.record = record
        self.robot = robot
        self.world = world
        self.started = now
        self.now = now

    @property
    def done(self) -> bool:
        return self.record.terminal

    def control(self, now: float, dt: float) -> tuple[float, float]:
        """Return the desired ``(v, w)`` for the next step; may end the goal instead."""
        raise NotImplementedError

    def after_move(self, ds: float, dtheta: float) -> None:
        """Called after the step with the signed distance ``ds`` (m, along the heading) and
        the signed rotation ``dtheta`` (rad) the robot actually made."""

    def on_stuck(self) -> None:
        """Called when the robot made no progress for ``stuck_time_s`` while :attr:`drives`."""

    def arrived(self, now: float) -> None:
        """Called when the attached path's final pose is reached (position and yaw)."""

    def no_approach(self, now: float) -> None:
        """Called when the robot following the attached path has not shortened its remaining
        path by :data:`APPROACH_M` for ``APPROACH_FACTOR * stuck_time_s``."""

    def feedback(self) -> Feedback:
        return Feedback()

    def succeed(self) -> None:
        self.record.feedback = self.feedback()
        self.record.finish(GoalStatus.SUCCEEDED)

    def abort(self, code: int, msg: str) -> None:
        self.record.feedback = self.feedback()
        self.record.finish(GoalStatus.ABORTED, code, msg)


def _fmt(p: Pose2D) -> str:
    return f"({p.x:.2f}, {p.y:.2f}, {p.theta:.2f})"


class NavigateTask(Task):
    """NavigateToPose / NavigateThroughPoses: plan through every pose, follow the path, pass
    intermediate poses within ``goal_tolerance`` without stopping, turn to the last pose's yaw.

    The path is followed by the simulator's vectorized follower (:meth:`World.attach_path`);
    this task only hears about events. Aborts with the planner's code (``GOAL_OUTSIDE_MAP``,
    ``GOAL_OCCUPIED``, ``START_OCCUPIED``, ``NO_VALID_PATH``) at start, or
    ``FAILED_TO_MAKE_PROGRESS`` when the robot is stuck or stops getting closer.
    """

    def __init__(
        self, record: GoalRecord, robot: Robot, world: World, now: float, poses: tuple[Pose2D, ...]
    ) -> None:
        super().__init__(record, robot, world, now)
        self.poses = poses
        self.planned = False
        path: list[tuple[float, float]] = [(robot.x, robot.y)]
        vias: list[int] = []
        for i, pose in enumerate(poses):
            res = world.plan(robot, path[-1], (pose.x, pose.y))
            if not res.ok:
                self.abort(res.error_code, self._name_pose(res, i, pose))
                return
            path.extend(res.path[1:])
            vias.append(len(path) - 1)
        if len(path) == 1:
            path.append(path[0])
            vias = [1]
        self.path = path
        self.vias = vias
        self.planned = True

    def start(self, now: float) -> None:
        """Hand the planned path to the follower (called once the task is the robot's)."""
        if self.planned and not self.done:
            self.world.attach_path(self.robot, self.path, self.vias, self.poses[-1].theta, now)

    def _name_pose(self, res: PlanResult, i: int, pose: Pose2D) -> str:
        where = f"pose {i} {_fmt(pose)}" if len(self.poses) > 1 else f"pose {_fmt(pose)}"
        return f"Cannot navigate to {where}: {res.error_msg}"

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        return (0.0, 0.0)

    def arrived(self, now: float) -> None:
        self.now = now
        self.drives = False
        self.succeed()

    def no_approach(self, now: float) -> None:
        self.now = now
        window = APPROACH_FACTOR * self.world.params.stuck_time_s
        self.robot.stuck = True
        self.abort(
            ErrorCode.FAILED_TO_MAKE_PROGRESS,
            f"Failed to make progress towards pose {_fmt(self.poses[-1])}: the robot has not come closer "
            f"for {window:.1f} s.",
        )

    def on_stuck(self) -> None:
        self.abort(
            ErrorCode.FAILED_TO_MAKE_PROGRESS,
            f"Failed to make progress towards pose {_fmt(self.poses[-1])}: the robot has not moved for "
            f"{self.world.params.stuck_time_s:.1f} s.",
        )

    def feedback(self) -> Feedback:
        world = self.world
        x, y, th, rem, left = world.path_progress(self.robot)
        if not self.planned:
            rem = 0.0
            left = 0
        return make_feedback(
            current_pose=Pose2D(x, y, th),
            navigation_time_s=world.clock.now() - self.started,
            estimated_time_remaining_s=rem / world.params.model.max_linear_speed,
            distance_remaining_m=rem,
            number_of_recoveries=0,
            number_of_poses_remaining=left if self.record.kind == "navigate_through_poses" else None,
        )


class FollowPathTask(NavigateTask):
    """FollowPath: drive along the given path (no planning) and turn to its last pose's yaw.

    The robot joins the path at its nearest pose (the one after it, if the robot stands on
    it), so a path re-sent while driving (replanning) continues smoothly. ABORTS with
    ``INVALID_PATH`` for an empty path (at start) and ``FAILED_TO_MAKE_PROGRESS`` when the
    robot is stuck or stops getting closer (a path through an obstacle, a blocked aisle).
    """

    def __init__(
        self, record: GoalRecord, robot: Robot, world: World, now: float, path: tuple[Pose2D, ...]
    ) -> None:
        Task.__init__(self, record, robot, world, now)
        self.poses = path[-1:]
        self.planned = False
        if not path:
            return
        x, y = robot.x, robot.y
        k = min(range(len(path)), key=lambda i: (path[i].x - x) ** 2 + (path[i].y - y) ** 2)
        near = math.hypot(path[k].x - x, path[k].y - y) <= world.params.goal_tolerance
        rest = [(p.x, p.y) for p in path[k + 1 if near else k :]] or [(path[-1].x, path[-1].y)]
        self.path = [(x, y), *rest]
        # every pose is a via, passed in order: a path that returns to where it started is
        # driven, not taken as already reached
        self.vias = list(range(1, len(self.path)))
        self.planned = True


class FollowWaypointsTask(Task):
    """FollowWaypoints: navigate to each pose in turn (NavigateToPose semantics, yaw
    included). A waypoint that cannot be planned to or where the robot gets stuck is recorded
    in ``missed_waypoints`` and skipped; the goal SUCCEEDS at the end (Nav2's default
    ``stop_on_failure: false``). An empty pose list ABORTS with ``WAYPOINT_UNKNOWN``.

    Between waypoints the task plans the next leg in :meth:`control`; while a leg is driven
    the simulator's vectorized follower runs it."""

    def __init__(
        self, record: GoalRecord, robot: Robot, world: World, now: float, poses: tuple[Pose2D, ...]
    ) -> None:
        super().__init__(record, robot, world, now)
        self.poses = poses
        self.index = 0
        self.missed: list[int] = []
        self.following = False

    def _start_next(self) -> None:
        while self.index < len(self.poses):
            p = self.poses[self.index]
            res = self.world.plan(self.robot, (self.robot.x, self.robot.y), (p.x, p.y))
            if res.ok:
                self.following = True
                self.world.attach_path(self.robot, list(res.path), [len(res.path) - 1], p.theta, self.now)
                self.robot.progress_t = self.now
                return
            self._miss()

    def _miss(self) -> None:
        self.missed.append(self.index)
        self.record.missed = tuple(self.missed)
        self.index += 1

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        if not self.following:
            self._start_next()
            if not self.following:
                self.drives = False
                self.succeed()
        return (0.0, 0.0)

    def arrived(self, now: float) -> None:
        self.now = now
        self.following = False
        self.world.detach_path(self.robot)
        self.index += 1

    def no_approach(self, now: float) -> None:
        self.now = now
        self.robot.stuck = True
        self.on_stuck()

    def on_stuck(self) -> None:
        self._miss()
        self.following = False
        self.world.detach_path(self.robot)

    def feedback(self) -> Feedback:
        return make_feedback(
            current_pose=self.robot.pose, current_waypoint=min(self.index, max(len(self.poses) - 1, 0))
        )


class SpinTask(Task):
    """Spin: rotate in place by the signed ``target_yaw``. SUCCEEDS when done; ABORTS with
    ``SPIN_TIMEOUT`` after ``time_allowance_s``."""

    def __init__(
        self, record: GoalRecord, robot: Robot, world: World, now: float, target_yaw: float, allowance: float
    ) -> None:
        super().__init__(record, robot, world, now)
        self.target = float(target_yaw)
        self.allowance = float(allowance)
        self.turned = 0.0

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        remaining = abs(self.target) - self.turned
        if remaining <= SPIN_TOLERANCE_RAD:
            self.succeed()
            return (0.0, 0.0)
        if now - self.started > self.allowance:
            self.abort(
                ErrorCode.SPIN_TIMEOUT,
                f"Spin of {self.target:.2f} rad timed out after {self.allowance:.1f} s at pose {_fmt(self.robot.pose)}.",
            )
            return (0.0, 0.0)
        m = self.world.params.model
        w = max(0.1, min(m.max_angular_speed, math.sqrt(2.0 * m.max_angular_accel * remaining)))
        return (0.0, math.copysign(w, self.target))

    def after_move(self, ds: float, dtheta: float) -> None:
        self.turned += dtheta if self.target >= 0 else -dtheta

    def feedback(self) -> Feedback:
        return make_feedback(angular_distance_traveled=abs(self.turned))


class DriveTask(Task):
    """BackUp (``direction=-1``) and DriveOnHeading (``direction=+1``): drive straight for
    ``distance`` meters at ``speed`` m/s.

    ABORTS with ``*_INVALID_INPUT`` for a non-positive distance or speed, ``*_COLLISION_AHEAD``
    when a robot, dynamic or static obstacle lies within the distance the robot would cover in
    :data:`SIMULATE_AHEAD_S` (capped at the remaining distance), ``*_TIMEOUT`` after
    ``time_allowance_s``.
    """

    def __init__(
        self,
        record: GoalRecord,
        robot: Robot,
        world: World,
        now: float,
        direction: float,
        distance: float,
        speed: float,
        allowance: float,
    ) -> None:
        super().__init__(record, robot, world, now)
        self.direction = direction
        self.distance = float(distance)
        self.speed = float(speed)
        self.allowance = float(allowance)
        self.traveled = 0.0
        codes = BEHAVIOR_CODES["backup" if direction < 0 else "drive_on_heading"]
        self.name = codes.name
        self.code_collision = codes.collision
        self.code_timeout = codes.timeout

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        remaining = self.distance - self.traveled
        if remaining <= DRIVE_TOLERANCE_M:
            self.drives = False
            self.succeed()
            return (0.0, 0.0)
        if now - self.started > self.allowance:
            self.drives = False
            self.abort(
                self.code_timeout,
                f"{self.name} of {self.distance:.2f} m timed out after {self.allowance:.1f} s at pose {_fmt(self.robot.pose)}.",
            )
            return (0.0, 0.0)
        m = self.world.params.model
        ahead = min(remaining, self.speed * SIMULATE_AHEAD_S)
        free = self.world.free_distance(self.robot, self.direction, ahead + 0.05, True)
        if free < ahead:
            self.drives = False
            self.abort(
                self.code_collision,
                f"{self.name} stopped at pose {_fmt(self.robot.pose)}: collision ahead within {ahead:.2f} m.",
            )
            return (0.0, 0.0)
        self.drives = True
        v = min(self.speed, m.max_linear_speed, math.sqrt(2.0 * m.max_linear_accel * remaining))
        return (self.direction * v, 0.0)

    def after_move(self, ds: float, dtheta: float) -> None:
        self.traveled += ds * self.direction

    def feedback(self) -> Feedback:
        return make_feedback(distance_traveled=max(0.0, self.traveled))


class WaitTask(Task):
    """Wait: stand still for ``duration_s``; SUCCEEDS when the time has passed."""

    def __init__(self, record: GoalRecord, robot: Robot, world: World, now: float, duration: float) -> None:
        super().__init__(record, robot, world, now)
        self.duration = float(duration)

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        if now - self.started >= self.duration - 1e-9:
            self.succeed()
        return (0.0, 0.0)

    def feedback(self) -> Feedback:
        return make_feedback(time_left_s=max(0.0, self.duration - (self.now - self.started)))


def make_task(record: GoalRecord, robot: Robot, world: World, now: float) -> Task:
    """The executor of ``record``'s goal on ``robot``, started at ``now`` (s). A goal that
    fails at its start (planning, :func:`sim.goals.start_error`) comes back already done."""
    goal = record.goal
    task: Task
    if isinstance(goal, NavigateToPose):
        task = NavigateTask(record, robot, world, now, (goal.pose,))
    elif isinstance(goal, NavigateThroughPoses):
        task = NavigateTask(record, robot, world, now, tuple(goal.poses))
    elif isinstance(goal, FollowWaypoints):
        task = FollowWaypointsTask(record, robot, world, now, tuple(goal.poses))
    elif isinstance(goal, FollowPath):
        task = FollowPathTask(record, robot, world, now, tuple(goal.path))
    elif isinstance(goal, Spin):
        task = SpinTask(record, robot, world, now, goal.target_yaw, goal.time_allowance_s)
    elif isinstance(goal, BackUp):
        task = DriveTask(
            record, robot, world, now, -1.0, goal.distance_m, goal.speed_mps, goal.time_allowance_s
        )
    elif isinstance(goal, DriveOnHeading):
        task = DriveTask(
            record, robot, world, now, 1.0, goal.distance_m, goal.speed_mps, goal.time_allowance_s
        )
    else:
        assert isinstance(goal, Wait)
        task = WaitTask(record, robot, world, now, goal.duration_s)
    error = start_error(goal)
    if error is not None and not task.done:
        task.abort(*error)
    return task
