"""Nav2's action nodes (``nav2_behavior_tree``) as py_trees leaves over the
:class:`~fleet.navigation.NavigationBackend`, registered under their Nav2 names.

Every goal node is a :class:`PortedAction` (the :class:`nodes.leaves.GoalAction` contract:
send in ``initialise``, poll in ``update``, cancel in ``terminate`` only when RUNNING) whose goal
comes from its input ports when it starts, and which writes its outputs when the goal ends, as
Nav2's ``BtActionNode`` does: ``error_code_id`` is 0 on success or cancel and the goal's code on
failure; the planners write ``path`` (the empty path on failure or when halted while running);
``SmoothPath`` writes ``smoothed_path``, ``smoothing_duration`` and ``was_completed``.
``FollowPath`` sends a new goal with the new path when ``path`` changes while it runs
(replanning). ``Spin`` (with ``is_recovery``), ``BackUp`` and ``Wait`` count a recovery in the
tree's ``number_recoveries`` when they start.

Ports Nav2 uses to find its servers (``server_name``, ``server_timeout``, ``global_frame``,
``robot_base_frame``, ``topic_name``) are accepted and have no effect: a backend drives one
robot in the ``map`` frame. Each goal node also takes this project's ``mode`` port (a
:class:`fleet.types.Mode` written to the robot's blackboard when the node starts).

Other action nodes: ``RemovePassedGoals``, ``TruncatePath``, ``GetPoseFromPath``,
``GetCurrentPose``, the ``*Selector`` nodes (they output their default: there is no selector
topic) and the ``Cancel*`` nodes (cancel the robot's running goal of their action).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import py_trees
from py_trees.common import Status

from fleet.navigation import NavigationBackend
from fleet.types import (
    BackUp,
    ClearCostmaps,
    ComputePathThroughPoses,
    ComputePathToPose,
    Costmap,
    DriveOnHeading,
    FollowPath,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    Mode,
    NavigateThroughPoses,
    NavigateToPose,
    Path,
    Pose2D,
    SmoothPath,
    Spin,
    Wait,
)
from nodes.blackboard import read_key
from nodes.leaves import GoalAction
from nodes.ports import Ports

MakeGoal = Callable[[Ports], Goal | None]
#: Called with the ports, the last goal state (``None``: no goal was sent) and the leaf's status.
OnDone = Callable[[Ports, GoalState | None, Status], None]
Refresh = Callable[[Ports, Goal], Goal | None]


class PortedAction(GoalAction):
    """A goal leaf whose goal is built from its ports (see the module docstring).

    Args:
        name: the node's name; ``backend``: the robot's; ``ports``: its bound ports.
        make: builds the goal from the ports when the node starts (``None``: no goal, FAILURE).
        on_done: writes the outputs when the goal ended (default: ``error_code_id`` only).
        refresh: while RUNNING, returns a new goal to send when the inputs changed.
        recovery_key: the storage name of the recovery counter this node increments on start.
        clear_on_halt: output ports reset to the empty path when the node is halted running.
        mode: written to the robot's blackboard ``mode`` on start.
    """

    def __init__(
        self,
        name: str,
        backend: NavigationBackend,
        ports: Ports,
        make: MakeGoal,
        *,
        on_done: OnDone | None = None,
        refresh: Refresh | None = None,
        recovery_key: str | None = None,
        clear_on_halt: tuple[str, ...] = (),
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self.ports = ports
        self._make = make
        self._on_done = on_done
        self._refresh = refresh
        self._recovery_key = recovery_key
        self._clear_on_halt = clear_on_halt
        self._fresh = True

    def make_goal(self) -> Goal | None:
        return self._make(self.ports)

    def initialise(self) -> None:
        if self._recovery_key is not None:
            storage = py_trees.blackboard.Blackboard.storage
            count = storage.get(self._recovery_key, 0)
            storage[self._recovery_key] = (count if isinstance(count, int) else 0) + 1
        self._fresh = True
        super().initialise()

    def update(self) -> Status:
        if not self._fresh and self._refresh is not None and self.goal is not None:
            newer = self._refresh(self.ports, self.goal)
            if newer is not None:
                self.send(newer)
        self._fresh = False
        status = super().update()
        if status != Status.RUNNING:
            self.ports.put("error_code_id", error_code_of(self.last_state))
            if self._on_done is not None:
                self._on_done(self.ports, self.last_state, status)
        return status

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self.status == Status.RUNNING:
            for port in self._clear_on_halt:
                self.ports.put(port, ())
        super().terminate(new_status)


def error_code_of(state: GoalState | None) -> int:
    """What Nav2 writes to ``error_code_id``: the code of a failed goal, else 0."""
    if state is None or state.status not in (GoalStatus.ABORTED, GoalStatus.REJECTED):
        return 0
    return int(state.error_code)


# -- goal makers ---------------------------------------------------------------------------


def _start(p: Ports) -> Pose2D | None:
    """Nav2's start rule: ``use_start`` if given (true needs a ``start``), else a given
    ``start`` is used."""
    start = p.get_pose("start")
    if p.given("use_start") and p.get("use_start") is not None:
        return start if p.get_bool("use_start") else None
    return start


def make_compute_to_pose(p: Ports) -> Goal | None:
    goal = p.get_pose("goal")
    return None if goal is None else ComputePathToPose(goal, _start(p), p.get_str("planner_id"))


def make_compute_through_poses(p: Ports) -> Goal | None:
    goals = p.get_poses("goals")
    return None if goals is None else ComputePathThroughPoses(goals, _start(p), p.get_str("planner_id"))


def make_follow_path(p: Ports) -> Goal | None:
    path = p.get_poses("path")
    if path is None:
        return None
    return FollowPath(path, p.get_str("controller_id"), p.get_str("goal_checker_id"))


def refresh_follow_path(p: Ports, goal: Goal) -> Goal | None:
    """A new FollowPath when ``path`` (or ``controller_id``) changed and is not empty."""
    assert isinstance(goal, FollowPath)
    path = p.get_poses("path")
    controller = p.get_str("controller_id")
    if path and (path != goal.path or controller != goal.controller_id):
        return FollowPath(path, controller, p.get_str("goal_checker_id"))
    return None


def make_smooth_path(p: Ports) -> Goal | None:
    path = p.get_poses("unsmoothed_path")
    if path is None:
        return None
    return SmoothPath(
        path,
        p.get_str("smoother_id"),
        p.get_float("max_smoothing_duration", 3.0),
        p.get_bool("check_for_collisions"),
    )


def make_clear_costmap(p: Ports) -> Goal | None:
    """The costmap a clear service name names (``global_costmap/...``, ``local_costmap/...``;
    anything else clears both)."""
    name = p.get_str("service_name")
    which = Costmap.GLOBAL if "global" in name else Costmap.LOCAL if "local" in name else Costmap.BOTH
    return ClearCostmaps(which)


def make_navigate_to_pose(p: Ports) -> Goal | None:
    goal = p.get_pose("goal")
    return None if goal is None else NavigateToPose(goal, p.get_str("behavior_tree"))


def make_navigate_through_poses(p: Ports) -> Goal | None:
    goals = p.get_poses("goals")
    return None if not goals else NavigateThroughPoses(goals, p.get_str("behavior_tree"))


def make_follow_waypoints(p: Ports) -> Goal | None:
    poses = p.get_poses("waypoints")
    return None if poses is None else FollowWaypoints(poses)


def make_spin(p: Ports) -> Goal | None:
    return Spin(p.get_float("spin_dist", 1.57), p.get_float("time_allowance", 10.0))


def make_backup(p: Ports) -> Goal | None:
    return BackUp(
        abs(p.get_float("backup_dist", 0.15)),
        abs(p.get_float("backup_speed", 0.025)),
        p.get_float("time_allowance", 10.0),
    )


def make_drive_on_heading(p: Ports) -> Goal | None:
    return DriveOnHeading(
        abs(p.get_float("dist_to_travel", 0.15)),
        abs(p.get_float("speed", 0.025)),
        p.get_float("time_allowance", 10.0),
    )


def make_wait(p: Ports) -> Goal | None:
    d = p.get("wait_duration")
    return None if not isinstance(d, (int, float)) else Wait(float(d))


def path_done(p: Ports, state: GoalState | None, status: Status) -> None:
    """The planners' outputs: ``path`` of a success, the empty path otherwise."""
    p.put("path", state.path if state is not None and status == Status.SUCCESS else ())


def smoothing_done(p: Ports, state: GoalState | None, status: Status) -> None:
    ok = state is not None and status == Status.SUCCESS
    p.put("smoothed_path", state.path if ok and state is not None else ())
    p.put("was_completed", ok)
    p.put("smoothing_duration", 0.0)


# -- data leaves -----------------------------------------------------------------------------


class PortedLeaf(py_trees.behaviour.Behaviour):
    """An instant leaf: ``step(ports)`` returns its status (SUCCESS / FAILURE)."""

    def __init__(self, name: str, ports: Ports, step: Callable[[Ports], Status]) -> None:
        super().__init__(name=name)
        self.ports = ports
        self._step = step

    def update(self) -> Status:
        return self._step(self.ports)


def remove_passed_goals(backend: NavigationBackend) -> Callable[[Ports], Status]:
    """Nav2's ``RemovePassedGoals``: drop the leading goals within ``radius`` of the robot
    (the last one is always kept)."""

    def step(p: Ports) -> Status:
        goals = list(p.get_poses("input_goals") or ())
        here = backend.robot_state().pose
        if goals and here is None:
            return Status.FAILURE
        radius = p.get_float("radius", 0.5)
        while len(goals) > 1 and here is not None and here.distance_to(goals[0]) <= radius:
            goals.pop(0)
        p.put("output_goals", tuple(goals))
        return Status.SUCCESS

    return step


def truncate_path(p: Ports) -> Status:
    """Nav2's ``TruncatePath``: the path without its poses closer than ``distance`` to its
    last pose (the last pose is kept)."""
    path = list(p.get_poses("input_path") or ())
    if not path:
        return Status.FAILURE
    end = path[-1]
    d = p.get_float("distance", 1.0)
    kept = [q for q in path[:-1] if q.distance_to(end) >= d]
    p.put("output_path", (*kept, end))
    return Status.SUCCESS


def pose_from_path(p: Ports) -> Status:
    """Nav2's ``GetPoseFromPath``: the pose at ``index`` (negative from the end)."""
    path = p.get_poses("path") or ()
    i = p.get_int("index", 0)
    if not -len(path) <= i < len(path):
        return Status.FAILURE
    p.put("pose", path[i])
    return Status.SUCCESS


def current_pose(backend: NavigationBackend) -> Callable[[Ports], Status]:
    def step(p: Ports) -> Status:
        here = backend.robot_state().pose
        if here is None:
            return Status.FAILURE
        p.put("current_pose", here)
        return Status.SUCCESS

    return step


def selector(default_port: str, out_port: str) -> Callable[[Ports], Status]:
    """A Nav2 ``*Selector``: outputs its default (no selector topic here)."""

    def step(p: Ports) -> Status:
        p.put(out_port, p.get_str(default_port))
        return Status.SUCCESS

    return step


def cancel_running(backend: NavigationBackend, kinds: tuple[str, ...]) -> Callable[[Ports], Status]:
    """A Nav2 ``Cancel*`` node: cancel the robot's running goal if it is one of ``kinds``."""
    active = read_key(backend.namespace, "active_goal")

    def step(p: Ports) -> Status:
        gid = active()
        if gid is not None:
            try:
                state = backend.goal_state(gid)
            except KeyError:
                return Status.SUCCESS
            if state.kind in kinds and not state.status.terminal:
                backend.cancel_goal(gid)
        return Status.SUCCESS

    return step


def path_length(path: Path, start: int = 0) -> float:
    """Length (m) of ``path`` from pose ``start`` to its end."""
    return sum(a.distance_to(b) for a, b in zip(path[start:], path[start + 1 :], strict=False))


def remaining_along(path: Path, here: Pose2D) -> float:
    """Nav2's distance remaining: the path's length from the pose nearest ``here``."""
    if not path:
        return 0.0
    i = min(range(len(path)), key=lambda k: math.hypot(path[k].x - here.x, path[k].y - here.y))
    return path_length(path, i)
