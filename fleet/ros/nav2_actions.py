"""The Nav2 action servers of one simulated robot: the navigators (a behavior tree per goal, as
bt_navigator), the behaviors, the controller, the planner and the smoother, executed on the
:class:`~sim.simulator.Simulator`.

Action names and types are Nav2's (:data:`~fleet.ros.conversions.ACTION_TYPES`), relative to
the robot's namespace. Every goal goes through the robot's :class:`nodes.navigator.BtNavigator`
(wrapping the simulator's backend), so what a client sees is:

* ``navigate_to_pose`` / ``navigate_through_poses`` run a navigator tree per goal over the
  simulator's planner and controller (``ComputePathToPose``, ``FollowPath``, ``ClearEntireCostmap``,
  ``Spin`` ...), as Nav2's bt_navigator does: the goal's ``behavior_tree`` (a path to an XML
  file) picks the tree, empty means the default (:meth:`RobotActions.set_default_trees`:
  ``fleet sim-ros --nav-to-pose-xml FILE --nav-through-poses-xml FILE``; else the project's
  ``nodes/trees/navigate_to_pose.xml`` / ``navigate_through_poses.xml``). A tree that cannot be loaded ends the goal
  ABORTED with the reason. Feedback
  (distance remaining along the planned path, number of recoveries ...) and the result's
  ``error_code`` (the lowest of the tree's planner / controller codes) are bt_navigator's. A
  navigation request while the *other* navigator runs is rejected, as bt_navigator rejects it;
  a new goal of the same navigator preempts (the old goal ends ABORTED, the tree continues).
* ``follow_waypoints``, ``spin``, ``backup``, ``drive_on_heading``, ``wait`` and ``follow_path``
  run as the simulator's goals; a new one preempts the robot's running motion goal (the
  simulator runs one per robot; a running navigator tree is halted and its goal ends ABORTED).
* ``compute_path_to_pose``, ``compute_path_through_poses`` and ``smooth_path`` are answered at
  once by the simulator's planner and smoother (codes 2xx / 3xx / 5xx) and disturb nothing.
* BackUp / DriveOnHeading with a lateral target, and DriveOnHeading whose speed and distance
  have opposite signs, end ABORTED with Nav2's ``INVALID_INPUT`` code (713 / 724).
* Feedback is published at most every ``feedback_period`` wall seconds; cancel ends a goal
  CANCELED.

Threading: execute callbacks are coroutines awaiting a :class:`rclpy.task.Future` that
:meth:`RobotActions.poll` resolves after the server stepped the simulator and
:meth:`RobotActions.poll_all` ticked the navigator, all on the server's one executor thread,
so the simulator and the trees are never touched concurrently.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from builtin_interfaces.msg import Time
from rclpy.action.server import ActionServer, CancelResponse, GoalResponse, ServerGoalHandle
from rclpy.node import Node
from rclpy.task import Future

from fleet.navigation import Clock
from fleet.ros.conversions import (
    ACTION_TYPES,
    GoalMsg,
    ResultMsg,
    feedback_to_msg,
    follow_path_feedback,
    msg_to_goal,
    result_to_msg,
)
from fleet.types import ErrorCode, GoalState, GoalStatus, Pose2D
from nodes.navigator import NAVIGATION_KINDS, BtNavigator
from sim.goals import goal_poses

if TYPE_CHECKING:
    from sim.simulator import Simulator


@dataclass
class ServedGoal:
    """One goal executing for a ROS client."""

    goal_id: str
    kind: str
    handle: ServerGoalHandle
    done: Future
    poses: tuple[Pose2D, ...] = ()
    t0: float = 0.0
    last_feedback: float = field(default=-1.0)


class RobotActions:
    """The action servers ``actions`` of the robot ``namespace`` on ``node``, executed by
    ``sim`` through the robot's navigator (:attr:`navigator`).

    Args:
        node: the robot's node (its namespace is the robot's).
        sim: the simulator; only the server's executor thread touches it.
        namespace: the robot's namespace in the simulator (``/robot1``).
        actions: the action names to serve (keys of ``ACTION_TYPES``).
        stamp: the current header stamp (simulated time).
        feedback_period: wall seconds between two feedback messages of a goal (``None``: no
            feedback).
        wall: the wall clock the feedback period is measured on (the server's).

    The server calls :meth:`poll_all` after stepping the simulator (and :meth:`destroy` at the
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
        #: The robot's bt_navigator; every goal goes through it.
        #: Goals with an empty ``behavior_tree`` run the project's navigator trees
        #: (``nodes/trees/navigate_to_pose.xml``, ``navigate_through_poses.xml``) unless
        #: :meth:`set_default_trees` names others.
        self.navigator = BtNavigator(sim.backend(namespace), sim.clock, battery=sim.params.battery)
        #: Goals executing now, by goal id.
        self.active: dict[str, ServedGoal] = {}
        self.servers = [
            ActionServer(
                node,
                ACTION_TYPES[kind],
                kind,
                execute_callback=self._make_execute(kind),
                goal_callback=self.goal_filter(kind),
                cancel_callback=lambda _h: CancelResponse.ACCEPT,
            )
            for kind in actions
        ]

    def set_default_trees(
        self, nav_to_pose_xml: str | Path | None, nav_through_poses_xml: str | Path | None
    ) -> None:
        """The trees of navigation goals with an empty ``behavior_tree`` (``None``: keep)."""
        if nav_to_pose_xml is not None:
            self.navigator.defaults["navigate_to_pose"] = str(nav_to_pose_xml)
        if nav_through_poses_xml is not None:
            self.navigator.defaults["navigate_through_poses"] = str(nav_through_poses_xml)

    def goal_filter(self, kind: str) -> Callable[[GoalMsg], GoalResponse]:
        """The ``kind`` server's goal callback: a navigation goal is refused while the other
        navigator runs (as bt_navigator does); everything else is accepted."""

        def accept(_req: GoalMsg) -> GoalResponse:
            if kind in NAVIGATION_KINDS:
                active = self.navigator.active
                if active is not None and self.navigator.goal_state(active).kind != kind:
                    return GoalResponse.REJECT  # bt_navigator: another navigator is running
            return GoalResponse.ACCEPT

        return accept

    def _make_execute(self, kind: str) -> Callable[[ServerGoalHandle], Coroutine[None, None, ResultMsg]]:
        async def execute(goal_handle: ServerGoalHandle) -> ResultMsg:
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
        goal = msg_to_goal(kind, req)
        poses = goal_poses(goal)
        gid = self.navigator.send_goal(goal)
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
        """Tick the navigator, then :meth:`poll` every executing goal (``wall``: monotonic wall
        seconds, for the feedback rate)."""
        self.navigator.tick()
        for served in list(self.active.values()):
            self.poll(served, wall)

    def poll(self, served: ServedGoal, wall: float) -> None:
        """Forward a cancel request, publish due feedback, resolve a finished goal."""
        if served.done.done():
            return
        if served.handle.is_cancel_requested:
            self.navigator.cancel_goal(served.goal_id)
        state = self.navigator.goal_state(served.goal_id)
        if state.status.terminal:
            self.active.pop(served.goal_id, None)
            served.done.set_result(state)
            return
        period = self._feedback_period
        if period is not None and wall - served.last_feedback >= period and served.handle.is_active:
            served.last_feedback = wall
            if served.kind == "follow_path":
                speed = self.sim.robot_state(self.ns).linear_velocity
                served.handle.publish_feedback(
                    follow_path_feedback(state.feedback.distance_remaining_m or 0.0, abs(speed))
                )
            else:
                served.handle.publish_feedback(feedback_to_msg(served.kind, state.feedback, self._stamp()))

    def destroy(self) -> None:
        self.navigator.close()
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
