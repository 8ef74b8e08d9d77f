"""One simulated robot and the goal executors that drive it (the simulator's "Nav2 servers").

:class:`Robot` is the plain mutable state of a differential-drive robot (pose in the ``map``
frame, velocities, battery, odometer, flags). Each executing goal is a :class:`Task` that the
simulator asks once per step for a desired ``(v, w)`` command (m/s, rad/s) through
:meth:`Task.control`, and tells about the motion that resulted through :meth:`Task.after_move`.
The simulator, not the task, applies acceleration limits, the reactive safety stop, static
collision clamping, battery and faults; a task only decides where it wants to go and when
its goal has succeeded or failed.

Goal records (:class:`GoalRecord`) hold the lifecycle of one goal id; a task finishes its
record with :meth:`Task.succeed` / :meth:`Task.abort`; the simulator handles cancel and
preemption. Feedback is computed on demand (:meth:`Task.feedback`) and frozen when the goal
ends, so a terminal goal keeps its last feedback.
"""

from __future__ import annotations

import math
from typing import Protocol

from fleet.types import (
    ErrorCode,
    Feedback,
    Goal,
    GoalState,
    GoalStatus,
    Pose2D,
    normalize_angle,
)
from sim.params import SimParams
from sim.planner import GridPlanner, PlanResult

#: Heading error (rad) above which a path-following robot stops and rotates in place.
ROTATE_IN_PLACE_RAD = 0.8
#: Gain of the heading controller while driving (rad/s per rad of error).
HEADING_GAIN = 2.5
#: Spin succeeds when the remaining angle is below this (rad).
SPIN_TOLERANCE_RAD = 0.02
#: BackUp / DriveOnHeading succeed when the remaining distance is below this (m).
DRIVE_TOLERANCE_M = 0.005
#: Nav2 behaviors simulate this far ahead (seconds at the commanded speed) for collisions.
SIMULATE_AHEAD_S = 2.0
#: A path follower tries to steer around a robot or dynamic obstacle closer than this (m)
#: in the direction it wants to drive.
AVOID_LOOKAHEAD_M = 1.5
#: A detour heading must be free (static map included) for this far (m).
AVOID_CLEAR_M = 0.8
#: A path follower must shorten its remaining path by this much (m) ...
APPROACH_M = 0.1
#: ... at least once every ``APPROACH_FACTOR * stuck_time_s`` seconds, or its goal fails to
#: make progress.
APPROACH_FACTOR = 2.0
#: Detour heading offsets (rad) tried in order: smallest first, the right-hand side first, so
#: two robots meeting head-on both keep right and pass each other.
AVOID_OFFSETS = (-0.35, 0.35, -0.7, 0.7, -1.05, 1.05, -1.4, 1.4, -1.75, 1.75, -2.1, 2.1)


class Robot:
    """Mutable state of one simulated differential-drive robot.

    Pose ``x``, ``y`` (m) and ``theta`` (rad, in ``[-pi, pi)``) in the ``map`` frame; ``v``
    (m/s, negative = backwards) and ``w`` (rad/s, counter-clockwise positive) are the velocities
    applied during the last step. ``battery`` is a fraction in [0, 1]; ``distance_m`` is the
    odometer (absolute distance driven); ``collisions`` counts contact events this robot took
    part in. ``fault`` is ``None`` or ``"stalled"`` (wheels do not respond).
    """

    __slots__ = (
        "name",
        "namespace",
        "x",
        "y",
        "theta",
        "v",
        "w",
        "battery",
        "charging",
        "stuck",
        "distance_m",
        "collisions",
        "fault",
        "task",
        "progress_x",
        "progress_y",
        "progress_t",
        "trajectory",
    )

    def __init__(self, name: str, namespace: str, pose: Pose2D, battery: float, now: float) -> None:
        self.name = name
        self.namespace = namespace
        self.x = float(pose.x)
        self.y = float(pose.y)
        self.theta = normalize_angle(float(pose.theta))
        self.v = 0.0
        self.w = 0.0
        self.battery = min(1.0, max(0.0, float(battery)))
        self.charging = False
        self.stuck = False
        self.distance_m = 0.0
        self.collisions = 0
        self.fault: str | None = None
        self.task: Task | None = None
        self.progress_x = self.x
        self.progress_y = self.y
        self.progress_t = now
        self.trajectory: list[tuple[float, float, float]] = [(now, self.x, self.y)]

    @property
    def pose(self) -> Pose2D:
        return Pose2D(self.x, self.y, self.theta)


class World(Protocol):
    """What tasks may ask of the simulator."""

    params: SimParams
    planner: GridPlanner

    def free_distance(
        self, robot: Robot, direction: float, lookahead: float, static: bool, heading: float | None = None
    ) -> float:
        """Distance (m) the robot's center can travel straight along ``heading`` (default its
        yaw; ``direction`` +1 forward, -1 backward) before touching another robot or a dynamic
        obstacle (and, if ``static``, a static obstacle), capped at ``lookahead``."""
        ...


class GoalRecord:
    """Lifecycle of one goal id. ``status`` moves from EXECUTING (or REJECTED) to exactly one
    terminal status and never changes again."""

    __slots__ = (
        "goal_id",
        "kind",
        "goal",
        "namespace",
        "status",
        "error_code",
        "error_msg",
        "missed",
        "feedback",
    )

    def __init__(self, goal_id: str, goal: Goal, namespace: str) -> None:
        self.goal_id = goal_id
        self.kind = goal.kind
        self.goal = goal
        self.namespace = namespace
        self.status = GoalStatus.EXECUTING
        self.error_code = int(ErrorCode.NONE)
        self.error_msg = ""
        self.missed: tuple[int, ...] = ()
        self.feedback = Feedback()

    def finish(self, status: GoalStatus, code: int = 0, msg: str = "") -> None:
        """Move to terminal ``status`` once; later calls are ignored."""
        if self.status.terminal:
            return
        self.status = status
        self.error_code = int(code)
        self.error_msg = msg

    def snapshot(self, live: Feedback | None = None) -> GoalState:
        return GoalState(
            goal_id=self.goal_id,
            kind=self.kind,
            status=self.status,
            feedback=live if live is not None else self.feedback,
            error_code=self.error_code,
            error_msg=self.error_msg,
            missed_waypoints=self.missed,
        )


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
        return self.record.status.terminal

    def control(self, now: float, dt: float) -> tuple[float, float]:
        """Return the desired ``(v, w)`` for the next step; may end the goal instead."""
        raise NotImplementedError

    def after_move(self, ds: float, dtheta: float) -> None:
        """Called after the step with the signed distance ``ds`` (m, along the heading) and
        the signed rotation ``dtheta`` (rad) the robot actually made."""

    def on_stuck(self) -> None:
        """Called when the robot made no progress for ``stuck_time_s`` while :attr:`drives`."""

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


class PathFollower:
    """Follows a polyline with a turn-then-drive pure-pursuit controller, then turns to a
    final yaw. ``vias`` are indices into ``path`` of the poses to pass through (the last one
    is the final goal)."""

    def __init__(self, path: list[tuple[float, float]], vias: list[int], final_yaw: float) -> None:
        self.path = path
        self.vias = vias
        self.final_yaw = final_yaw
        n = len(path)
        self.seg_len = [
            math.hypot(path[i + 1][0] - path[i][0], path[i + 1][1] - path[i][1]) for i in range(n - 1)
        ]
        suffix = [0.0] * n
        for i in range(n - 2, -1, -1):
            suffix[i] = suffix[i + 1] + self.seg_len[i]
        self.suffix = suffix
        self.seg = 0
        self.proj_t = 0.0
        self.next_via = 0
        self.xy_reached = False
        self.avoid_side = 0  # -1 / +1 while steering around something on the right / left
        self.best_remaining = math.inf
        self.best_time = 0.0

    def seconds_without_approach(self, x: float, y: float, now: float) -> float:
        """Seconds since the remaining path length last shrank by :data:`APPROACH_M` (0 once
        the final position is reached). Catches a robot that keeps moving (so it is never
        "stuck") but never gets closer, e.g. circling around robots parked at its goal."""
        rem = self.remaining(x, y)
        if self.xy_reached or rem < self.best_remaining - APPROACH_M:
            self.best_remaining = rem
            self.best_time = now
        return now - self.best_time

    def _update_progress(self, x: float, y: float, tol: float) -> None:
        path = self.path
        last = len(path) - 2
        while True:
            ax, ay = path[self.seg]
            bx, by = path[self.seg + 1]
            L = self.seg_len[self.seg]
            t = ((x - ax) * (bx - ax) + (y - ay) * (by - ay)) / (L * L) if L > 1e-9 else 1.0
            if t >= 1.0 and self.seg < last:
                self.seg += 1
                continue
            self.proj_t = min(max(t, 0.0), 1.0)
            break
        while self.next_via < len(self.vias) - 1:
            vi = self.vias[self.next_via]
            vx, vy = path[vi]
            if self.seg >= vi or math.hypot(vx - x, vy - y) <= tol:
                self.next_via += 1
            else:
                break

    def remaining(self, x: float, y: float) -> float:
        """Distance (m) along the remaining path from the robot's projection to the end."""
        if self.xy_reached:
            return 0.0
        i = self.seg
        ax, ay = self.path[i]
        bx, by = self.path[i + 1]
        px = ax + self.proj_t * (bx - ax)
        py = ay + self.proj_t * (by - ay)
        return math.hypot(bx - px, by - py) + self.suffix[i + 1] + math.hypot(px - x, py - y)

    def poses_remaining(self) -> int:
        return 0 if self.xy_reached else len(self.vias) - self.next_via

    def command(self, robot: Robot, world: World) -> tuple[float, float] | None:
        """Desired ``(v, w)``; ``None`` once the final pose is reached within tolerance.

        When a robot or dynamic obstacle blocks the direction to the lookahead point within
        :data:`AVOID_LOOKAHEAD_M` (and it is not sitting on the goal), the follower steers to
        the first free detour heading of :data:`AVOID_OFFSETS`, staying on the side it chose
        until the way is clear (a local controller going around what the global plan does not
        know about); with no free detour it waits.
        """
        params = world.params
        m = params.model
        x, y = robot.x, robot.y
        gx, gy = self.path[-1]
        if not self.xy_reached:
            self._update_progress(x, y, params.goal_tolerance)
            if math.hypot(gx - x, gy - y) <= params.goal_tolerance:
                self.xy_reached = True
        if self.xy_reached:
            err = normalize_angle(self.final_yaw - robot.theta)
            if abs(err) <= params.yaw_tolerance:
                return None
            w = min(m.max_angular_speed, math.sqrt(2.0 * m.max_angular_accel * abs(err)))
            return (0.0, math.copysign(w, err))
        rem = self.remaining(x, y)
        lookahead = 0.3 + 0.3 * abs(robot.v)
        tx, ty = self._point_ahead(lookahead)
        desired = math.atan2(ty - y, tx - x)
        blocked = world.free_distance(robot, 1.0, AVOID_LOOKAHEAD_M, False, desired)
        if blocked < AVOID_LOOKAHEAD_M and blocked + 2.0 * m.radius + params.goal_tolerance < rem:
            side = self.avoid_side
            order: tuple[float, ...] = AVOID_OFFSETS
            if side != 0:  # keep going around on the side already chosen
                order = tuple(o for o in AVOID_OFFSETS if o * side > 0) + tuple(
                    o for o in AVOID_OFFSETS if o * side < 0
                )
            for off in order:
                if world.free_distance(robot, 1.0, AVOID_CLEAR_M, True, desired + off) >= AVOID_CLEAR_M:
                    desired += off
                    self.avoid_side = 1 if off > 0 else -1
                    break
        else:
            self.avoid_side = 0
        err = normalize_angle(desired - robot.theta)
        if abs(err) > ROTATE_IN_PLACE_RAD:
            w = min(m.max_angular_speed, math.sqrt(2.0 * m.max_angular_accel * abs(err)))
            return (0.0, math.copysign(w, err))
        v = m.max_linear_speed * (1.0 - 0.6 * abs(err) / ROTATE_IN_PLACE_RAD)
        v = min(v, math.sqrt(2.0 * m.max_linear_accel * 0.8 * rem))
        w = max(-m.max_angular_speed, min(m.max_angular_speed, HEADING_GAIN * err))
        return (v, w)

    def _point_ahead(self, dist: float) -> tuple[float, float]:
        i = self.seg
        ax, ay = self.path[i]
        bx, by = self.path[i + 1]
        px = ax + self.proj_t * (bx - ax)
        py = ay + self.proj_t * (by - ay)
        left = math.hypot(bx - px, by - py)
        while dist > left and i + 1 < len(self.path) - 1:
            dist -= left
            i += 1
            px, py = self.path[i]
            bx, by = self.path[i + 1]
            left = self.seg_len[i]
        if dist >= left:
            return (bx, by)
        f = dist / left
        return (px + f * (bx - px), py + f * (by - py))


class NavigateTask(Task):
    """NavigateToPose / NavigateThroughPoses: plan through every pose, follow the path, pass
    intermediate poses within ``goal_tolerance`` without stopping, turn to the last pose's yaw.

    Aborts with the planner's code (``GOAL_OUTSIDE_MAP``, ``GOAL_OCCUPIED``,
    ``START_OCCUPIED``, ``NO_VALID_PATH``) at start, or ``FAILED_TO_MAKE_PROGRESS`` when the
    robot is stuck.
    """

    def __init__(
        self, record: GoalRecord, robot: Robot, world: World, now: float, poses: tuple[Pose2D, ...]
    ) -> None:
        super().__init__(record, robot, world, now)
        self.poses = poses
        self.follower: PathFollower | None = None
        planner = world.planner
        path: list[tuple[float, float]] = [(robot.x, robot.y)]
        vias: list[int] = []
        for i, pose in enumerate(poses):
            res = planner.plan(path[-1], (pose.x, pose.y))
            if not res.ok:
                self.abort(res.error_code, self._name_pose(res, i, pose))
                return
            path.extend(res.path[1:])
            vias.append(len(path) - 1)
        if len(path) == 1:
            path.append(path[0])
            vias = [1]
        self.follower = PathFollower(path, vias, poses[-1].theta)

    def _name_pose(self, res: PlanResult, i: int, pose: Pose2D) -> str:
        where = f"pose {i} {_fmt(pose)}" if len(self.poses) > 1 else f"pose {_fmt(pose)}"
        return f"Cannot navigate to {where}: {res.error_msg}"

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        if self.follower is None:
            return (0.0, 0.0)
        cmd = self.follower.command(self.robot, self.world)
        if cmd is None:
            self.drives = False
            self.succeed()
            return (0.0, 0.0)
        window = APPROACH_FACTOR * self.world.params.stuck_time_s
        if self.follower.seconds_without_approach(self.robot.x, self.robot.y, now) >= window - 1e-9:
            self.robot.stuck = True
            self.abort(
                ErrorCode.FAILED_TO_MAKE_PROGRESS,
                f"Failed to make progress towards pose {_fmt(self.poses[-1])}: the robot has not come closer "
                f"for {window:.1f} s.",
            )
            return (0.0, 0.0)
        self.drives = cmd[0] != 0.0
        return cmd

    def on_stuck(self) -> None:
        self.abort(
            ErrorCode.FAILED_TO_MAKE_PROGRESS,
            f"Failed to make progress towards pose {_fmt(self.poses[-1])}: the robot has not moved for "
            f"{self.world.params.stuck_time_s:.1f} s.",
        )

    def feedback(self) -> Feedback:
        r = self.robot
        f = self.follower
        rem = f.remaining(r.x, r.y) if f is not None else 0.0
        through = self.record.kind == "navigate_through_poses"
        return Feedback(
            current_pose=r.pose,
            navigation_time_s=self.now - self.started,
            estimated_time_remaining_s=rem / self.world.params.model.max_linear_speed,
            distance_remaining_m=rem,
            number_of_recoveries=0,
            number_of_poses_remaining=(f.poses_remaining() if f is not None else 0) if through else None,
        )


class FollowWaypointsTask(Task):
    """FollowWaypoints: navigate to each pose in turn (NavigateToPose semantics, yaw
    included). A waypoint that cannot be planned to or where the robot gets stuck is recorded
    in ``missed_waypoints`` and skipped; the goal SUCCEEDS at the end (Nav2's default
    ``stop_on_failure: false``). An empty pose list ABORTS with ``WAYPOINT_UNKNOWN``."""

    def __init__(
        self, record: GoalRecord, robot: Robot, world: World, now: float, poses: tuple[Pose2D, ...]
    ) -> None:
        super().__init__(record, robot, world, now)
        self.poses = poses
        self.index = 0
        self.missed: list[int] = []
        self.follower: PathFollower | None = None
        if not poses:
            self.abort(ErrorCode.WAYPOINT_UNKNOWN, "FollowWaypoints got an empty list of waypoints.")

    def _start_next(self) -> None:
        while self.index < len(self.poses):
            p = self.poses[self.index]
            res = self.world.planner.plan((self.robot.x, self.robot.y), (p.x, p.y))
            if res.ok:
                self.follower = PathFollower(list(res.path), [len(res.path) - 1], p.theta)
                self.robot.progress_t = self.now
                return
            self._miss()
        self.follower = None

    def _miss(self) -> None:
        self.missed.append(self.index)
        self.record.missed = tuple(self.missed)
        self.index += 1

    def control(self, now: float, dt: float) -> tuple[float, float]:
        self.now = now
        for _ in range(len(self.poses) + 1):
            if self.follower is None:
                self._start_next()
                if self.follower is None:
                    self.drives = False
                    self.succeed()
                    return (0.0, 0.0)
            cmd = self.follower.command(self.robot, self.world)
            if cmd is not None:
                window = APPROACH_FACTOR * self.world.params.stuck_time_s
                if self.follower.seconds_without_approach(self.robot.x, self.robot.y, now) >= window - 1e-9:
                    self.robot.stuck = True
                    self.on_stuck()
                    continue
                self.drives = cmd[0] != 0.0
                return cmd
            self.follower = None
            self.index += 1
        return (0.0, 0.0)

    def on_stuck(self) -> None:
        self._miss()
        self.follower = None

    def feedback(self) -> Feedback:
        return Feedback(
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
        if not math.isfinite(self.target):
            self.abort(ErrorCode.SPIN_UNKNOWN, f"Spin target {target_yaw} rad is not a finite angle.")

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
        return Feedback(angular_distance_traveled=abs(self.turned))


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
        back = direction < 0
        self.name = "BackUp" if back else "DriveOnHeading"
        self.code_invalid = ErrorCode.BACKUP_INVALID_INPUT if back else ErrorCode.DRIVE_INVALID_INPUT
        self.code_collision = ErrorCode.BACKUP_COLLISION_AHEAD if back else ErrorCode.DRIVE_COLLISION_AHEAD
        self.code_timeout = ErrorCode.BACKUP_TIMEOUT if back else ErrorCode.DRIVE_TIMEOUT
        ok = (
            math.isfinite(self.distance)
            and math.isfinite(self.speed)
            and self.distance > 0
            and self.speed > 0
        )
        if not ok:
            self.abort(
                self.code_invalid,
                f"{self.name} needs a positive distance and speed, got {distance} m at {speed} m/s.",
            )

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
        return Feedback(distance_traveled=max(0.0, self.traveled))


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
        return Feedback(time_left_s=max(0.0, self.duration - (self.now - self.started)))
