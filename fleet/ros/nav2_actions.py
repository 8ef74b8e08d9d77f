"""The Nav2 action servers of one simulated robot: navigation, behaviors, follow_path and the
planner actions, executed by the :class:`~sim.simulator.Simulator`.

Action names and types are Nav2's (:data:`~fleet.ros.conversions.ACTION_TYPES`), relative to
the robot's namespace. What a client sees:

* navigation and behavior goals (``navigate_through_poses``, ``navigate_to_pose``,
  ``follow_waypoints``, ``spin``, ``backup``, ``drive_on_heading``, ``wait``) are sent to the
  simulator as the fleet goal of the message; feedback is published at most every
  ``feedback_period`` wall seconds; the result carries Nav2's ``error_code`` / ``error_msg``
  (FollowWaypoints lists ``missed_waypoints``; behaviors report ``total_elapsed_time``);
* ``follow_path`` drives the path's poses, thinned to :data:`FOLLOW_PATH_SPACING_M`, as a
  NavigateThroughPoses goal (feedback: ``distance_to_goal``);
* ``compute_path_to_pose`` / ``compute_path_through_poses`` are answered at once by the
  simulator's grid planner (through-poses codes are Nav2's 3xx: the to-pose code + 100);
* BackUp / DriveOnHeading with a lateral target, and DriveOnHeading whose speed and distance
  have opposite signs, end ABORTED with Nav2's ``INVALID_INPUT`` code (713 / 724);
* cancel ends the goal CANCELED; a new goal on any of the robot's action servers preempts
  the running one, which ends ABORTED (the simulator runs one goal per robot).

Threading: execute callbacks are coroutines awaiting a :class:`rclpy.task.Future` that
:meth:`RobotActions.poll` resolves after the server has stepped the simulator, all on the
server's one executor thread, so the simulator is never touched concurrently.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from builtin_interfaces.msg import Time
from nav_msgs.msg import Path as PathMsg
from rclpy.action.server import ActionServer, CancelResponse, GoalResponse, ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future

from fleet.navigation import Clock
from fleet.ros.conversions import (
    ACTION_TYPES,
    NAVIGATION_ACTIONS,
    GoalMsg,
    ResultMsg,
    feedback_to_msg,
    msg_to_goal,
    pose2d_to_pose_stamped,
    pose_stamped_to_pose2d,
    result_to_msg,
    seconds_to_duration,
)
from fleet.types import (
    ErrorCode,
    Feedback,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
)

if TYPE_CHECKING:
    from sim.planner import GridPlanner
    from sim.simulator import Simulator

#: Actions the simulator executes as fleet goals (the navigation ones and follow_path).
EXECUTED_ACTIONS = (*NAVIGATION_ACTIONS, "follow_path")
#: Actions answered by the planner at once.
PLANNER_ACTIONS = ("compute_path_to_pose", "compute_path_through_poses")
#: follow_path drives the path's poses spaced at least this far apart (m).
FOLLOW_PATH_SPACING_M = 0.5
#: Nav2's ComputePathThroughPoses codes are the ComputePathToPose codes + 100.
THROUGH_POSES_CODE_OFFSET = 100
#: ComputePathThroughPoses' code for a goal without poses (Nav2's NO_VIAPOINTS_GIVEN).
NO_VIAPOINTS_GIVEN = 309


@dataclass
class ServedGoal:
    """One goal the simulator is executing for a ROS client."""

    goal_id: str
    kind: str
    handle: ServerGoalHandle
    done: Future
    poses: tuple[Pose2D, ...] = ()
    t0: float = 0.0
    last_feedback: float = field(default=-1.0)


@dataclass(frozen=True)
class PathPlan:
    """A planned polyline through goals: ``points`` (m, ``map``) from the start through every
    goal when ``error_code`` is 0, else empty with the planner's code and message."""

    points: tuple[tuple[float, float], ...] = ()
    error_code: int = 0
    error_msg: str = ""


class RobotActions:
    """The action servers ``actions`` of the robot ``namespace`` on ``node``, executed by
    ``sim``.

    Args:
        node: the robot's node (its namespace is the robot's).
        sim: the simulator; only the server's executor thread touches it.
        namespace: the robot's namespace in the simulator (``/robot1``).
        actions: the action names to serve (keys of ``ACTION_TYPES``).
        stamp: the current header stamp (simulated time).
        feedback_period: wall seconds between two feedback messages of a goal (``None``: no
            feedback).
        wall: the wall clock the feedback period is measured on (the server's).

    The server calls :meth:`poll_all` after every simulator step (and :meth:`destroy` at the
    end).
    """

    def __init__(
        self,
        node: Node,
        sim: Simulator,
        namespace: str,
        actions: tuple[str, ...],
        stamp: Callable[[], Time],
        feedback_period: float | None,
        wall: Clock,
    ) -> None:
        self.sim = sim
        self.ns = namespace
        self._stamp = stamp
        self._feedback_period = feedback_period
        self._wall = wall
        #: Goals executing now, by the simulator's goal id.
        self.active: dict[str, ServedGoal] = {}
        self.servers = [
            ActionServer(
                node,
                ACTION_TYPES[kind],
                kind,
                execute_callback=self._make_execute(kind),
                goal_callback=lambda _req: GoalResponse.ACCEPT,
                cancel_callback=lambda _h: CancelResponse.ACCEPT,
            )
            for kind in actions
        ]

    def _make_execute(self, kind: str) -> Callable[[ServerGoalHandle], Coroutine[None, None, ResultMsg]]:
        async def execute(goal_handle: ServerGoalHandle) -> ResultMsg:
            if kind in PLANNER_ACTIONS:
                return self._compute_path(kind, goal_handle)
            return await self._execute(kind, goal_handle)

        return execute

    async def _execute(self, kind: str, goal_handle: ServerGoalHandle) -> ResultMsg:
        req = goal_handle.request
        invalid = invalid_input(kind, req)
        if invalid is not None:
            result = ACTION_TYPES[kind].Result()
            result.error_code, result.error_msg = invalid
            goal_handle.abort()
            return result
        goal: Goal
        if kind == "follow_path":
            goal = NavigateThroughPoses(
                thin_path([pose_stamped_to_pose2d(p) for p in req.path.poses], FOLLOW_PATH_SPACING_M)
            )
        else:
            goal = msg_to_goal(kind, req)
        poses = goal_poses(goal)
        gid = self.sim.send_goal(self.ns, goal)
        served = ServedGoal(gid, kind, goal_handle, Future(), poses, self.sim.clock.now())
        self.active[gid] = served
        self.poll(served, self._wall.now())
        await served.done
        state: GoalState = served.done.result()
        result = result_to_msg(kind, state, poses, self.sim.clock.now() - served.t0)
        if state.status is GoalStatus.SUCCEEDED:
            goal_handle.succeed()
        elif state.status is GoalStatus.CANCELED and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return result

    def poll_all(self, wall: float) -> None:
        """:meth:`poll` every executing goal (``wall``: monotonic wall seconds, for the
        feedback rate)."""
        for served in list(self.active.values()):
            self.poll(served, wall)

    def poll(self, served: ServedGoal, wall: float) -> None:
        """Forward a cancel request, publish due feedback, resolve a finished goal."""
        if served.done.done():
            return
        if served.handle.is_cancel_requested:
            self.sim.cancel_goal(served.goal_id)
        state = self.sim.goal_state(served.goal_id)
        if state.status.terminal:
            self.active.pop(served.goal_id, None)
            served.done.set_result(state)
            return
        period = self._feedback_period
        if period is not None and wall - served.last_feedback >= period and served.handle.is_active:
            served.last_feedback = wall
            fb = state.feedback
            if served.kind == "follow_path":
                fb = Feedback(distance_remaining_m=fb.distance_remaining_m)
            served.handle.publish_feedback(feedback_to_msg(served.kind, fb, self._stamp()))

    def _compute_path(self, kind: str, goal_handle: ServerGoalHandle) -> ResultMsg:
        req = goal_handle.request
        result = ACTION_TYPES[kind].Result()
        t0 = time.monotonic()
        if req.use_start:
            start = pose_stamped_to_pose2d(req.start)
        else:
            pose = self.sim.robot_state(self.ns).pose
            start = pose if pose is not None else Pose2D(0.0, 0.0)
        if kind == "compute_path_to_pose":
            goals = [pose_stamped_to_pose2d(req.goal)]
        else:
            goals = [pose_stamped_to_pose2d(p) for p in req.goals]
        if not goals:
            result.error_code, result.error_msg = NO_VIAPOINTS_GIVEN, "No goals were given."
            goal_handle.abort()
            return result
        plan = plan_through(self.sim.planner, start, goals)
        if plan.error_code:
            offset = THROUGH_POSES_CODE_OFFSET if kind == "compute_path_through_poses" else 0
            result.error_code, result.error_msg = plan.error_code + offset, plan.error_msg
            goal_handle.abort()
            return result
        result.path = path_msg(plan.points, goals[-1].theta, self._stamp())
        result.planning_time = seconds_to_duration(time.monotonic() - t0)
        goal_handle.succeed()
        return result

    def destroy(self) -> None:
        for server in self.servers:
            server.destroy()


def invalid_input(kind: str, req: GoalMsg) -> tuple[int, str] | None:
    """Nav2's ``INVALID_INPUT`` code and message for a BackUp / DriveOnHeading request it
    refuses (a lateral or vertical target; DriveOnHeading with speed and distance of opposite
    signs), else ``None``."""
    if kind not in ("backup", "drive_on_heading"):
        return None
    code = ErrorCode.BACKUP_INVALID_INPUT if kind == "backup" else ErrorCode.DRIVE_INVALID_INPUT
    if req.target.y != 0.0 or req.target.z != 0.0:
        return int(
            code
        ), "Only forward/backward motion along x is supported (target.y and target.z must be 0)."
    if kind == "drive_on_heading" and req.target.x * req.speed < 0.0:
        return int(code), "Speed and target distance must have the same sign."
    return None


def goal_poses(goal: Goal) -> tuple[Pose2D, ...]:
    """The poses a navigation goal visits (FollowWaypoints' missed waypoints index them);
    ``()`` for behaviors."""
    if isinstance(goal, NavigateToPose):
        return (goal.pose,)
    if isinstance(goal, (NavigateThroughPoses, FollowWaypoints)):
        return goal.poses
    return ()


def plan_through(planner: GridPlanner, start: Pose2D, goals: list[Pose2D]) -> PathPlan:
    """Plan from ``start`` through every pose of ``goals`` in order with the simulator's grid
    planner (``goals`` not empty). Fails with the first failing leg's planner code
    (ComputePathToPose's, 2xx) and message."""
    points: list[tuple[float, float]] = []
    cur = (start.x, start.y)
    for g in goals:
        plan = planner.plan(cur, (g.x, g.y))
        if not plan.ok:
            return PathPlan(error_code=int(plan.error_code), error_msg=plan.error_msg)
        pts = list(plan.path)
        points.extend(pts if not points else pts[1:])
        cur = (g.x, g.y)
    return PathPlan(tuple(points))


def path_msg(points: tuple[tuple[float, float], ...], final_yaw: float, stamp: Time) -> PathMsg:
    """A ``nav_msgs/Path`` in ``map`` through ``points``: each pose faces the next point, the
    last one has ``final_yaw`` (rad)."""
    path = PathMsg()
    path.header.frame_id = "map"
    path.header.stamp = stamp
    out = []
    for i, (x, y) in enumerate(points):
        if i + 1 < len(points):
            yaw = math.atan2(points[i + 1][1] - y, points[i + 1][0] - x)
        else:
            yaw = final_yaw
        out.append(pose2d_to_pose_stamped(Pose2D(x, y, yaw), stamp))
    path.poses = out
    return path


def thin_path(poses: list[Pose2D], spacing: float) -> tuple[Pose2D, ...]:
    """Keep poses at least ``spacing`` meters apart (always the last one; the first one only
    if it is that far from the next kept pose, since the robot starts near it)."""
    if not poses:
        return ()
    out = [poses[0]]
    for p in poses[1:-1]:
        if p.distance_to(out[-1]) >= spacing:
            out.append(p)
    if len(poses) > 1:
        out.append(poses[-1])
    return tuple(out[1:] if len(out) > 1 and out[0].distance_to(out[1]) < spacing else out)
