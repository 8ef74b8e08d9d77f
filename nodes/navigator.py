"""Nav2's bt_navigator for one robot, over a navigation backend: NavigateToPose and
NavigateThroughPoses goals run a navigator tree (BehaviorTree.CPP XML) whose leaves plan
(``ComputePathToPose``), drive (``FollowPath``) and recover (``ClearEntireCostmap``, ``Spin``,
``Wait``, ``BackUp``) on the backend.

:class:`BtNavigator` is itself a :class:`~fleet.navigation.NavigationBackend` wrapping the
robot's backend (``inner``): navigation goals run a tree, every other goal passes through.
Call :meth:`BtNavigator.tick` once per step of the world (``fleet sim-ros`` does, after each
simulator step; bt_navigator ticks every ``bt_loop_duration``).

What it does, as Nav2 Jazzy's bt_navigator:

* **Which tree.** A goal's ``behavior_tree`` (a path to an XML file) picks the tree; empty
  means the default of its action (an empty default in :attr:`BtNavigator.defaults`: no
  tree, the goal goes to the inner backend's own navigation) (``nav_to_pose_xml`` / ``nav_through_poses_xml``, by default
  this project's ``nodes/trees/navigate_to_pose.xml`` / ``navigate_through_poses.xml``). A
  tree is loaded once and kept (and its blackboard with it) for the next goals naming the same
  file. A tree that cannot be loaded ends the goal ABORTED (its message says why) at once.
* **Blackboard.** Under ``<namespace>/navigator``: ``goal`` (NavigateToPose) or ``goals``
  (NavigateThroughPoses), ``path`` (written by the tree), ``number_recoveries`` (counted by
  the recovery leaves), the error codes of ``error_code_names`` (``follow_path_error_code``,
  ``compute_path_error_code``), ``initial_pose_received`` (true).
* **Feedback**: current pose, navigation time, distance remaining along ``path`` from the pose
  on it nearest the robot, estimated time remaining (distance / current speed, when moving),
  number of recoveries, poses remaining (the tree's ``goals``).
* **Result.** The tree's SUCCESS / FAILURE ends the goal SUCCEEDED / ABORTED; the error code is
  the lowest non-zero of the ``error_code_names`` keys (Nav2's ``populateErrorCode``) and the
  message names it and the last failure the robot's leaves reported. The tree is then halted
  (a running leaf cancels its goal) and the error codes reset.
* **Preemption.** A new navigation goal of the running action with the same tree (or an empty
  ``behavior_tree`` while the default runs) replaces the goal on the blackboard: the running
  goal ends ABORTED and the tree continues with the new one (``GoalUpdated`` fires). With
  another tree, Nav2 refuses the preemption: the new goal ends ABORTED and the old one keeps
  running. A navigation goal of the other action, or any other motion goal, halts the tree
  and ends the running goal ABORTED (the backend contract: the newest motion goal wins).
* **Cancel** halts the tree; the goal ends CANCELED.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field
from pathlib import Path

from py_trees.blackboard import Blackboard
from py_trees.common import Status

from fleet.errors import FleetError
from fleet.navigation import Clock, NavigationBackend
from fleet.robots import BatteryModel
from fleet.types import (
    MOTION_GOAL_KINDS,
    ErrorCode,
    Feedback,
    Goal,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    RobotState,
)
from nodes.blackboard import key_path, normalize_namespace
from nodes.nav2_leaves import remaining_along
from nodes.registry import NodeRegistry, TreeParams
from nodes.xml_tree import XmlTree, load_tree

logger = logging.getLogger(__name__)

#: The folder of the navigator trees shipped with the project.
TREES_DIR = Path(__file__).resolve().parent / "trees"
#: The default tree of NavigateToPose (replanning at 1 Hz, recoveries).
DEFAULT_NAV_TO_POSE_XML = TREES_DIR / "navigate_to_pose.xml"
#: The default tree of NavigateThroughPoses.
DEFAULT_NAV_THROUGH_POSES_XML = TREES_DIR / "navigate_through_poses.xml"
#: Nav2's default ``error_code_names``.
ERROR_CODE_NAMES = ("follow_path_error_code", "compute_path_error_code")
NAVIGATION_KINDS = ("navigate_to_pose", "navigate_through_poses")


@dataclass
class _NavGoal:
    goal_id: str
    goal: NavigateToPose | NavigateThroughPoses
    tree_file: str
    started: float
    status: GoalStatus = GoalStatus.EXECUTING
    feedback: Feedback = field(default_factory=Feedback)
    error_code: int = 0
    error_msg: str = ""

    def snapshot(self) -> GoalState:
        return GoalState(
            self.goal_id, self.goal.kind, self.status, self.feedback, self.error_code, self.error_msg
        )

    def finish(self, status: GoalStatus, code: int = 0, msg: str = "") -> None:
        if not self.status.terminal:
            self.status, self.error_code, self.error_msg = status, int(code), msg


class BtNavigator:
    """bt_navigator for the robot of ``inner`` (see the module docstring).

    Args:
        inner: the robot's backend (it must execute ComputePathToPose / FollowPath ...).
        clock: the backend's clock (navigation time, RateController ...).
        nav_to_pose_xml / nav_through_poses_xml: default trees (``None``: the project's).
        registry, params, battery: passed to :func:`nodes.xml_tree.load_tree`.
        keep_finished: finished navigation goals kept for ``goal_state``.
    """

    def __init__(
        self,
        inner: NavigationBackend,
        clock: Clock,
        *,
        nav_to_pose_xml: str | Path | None = None,
        nav_through_poses_xml: str | Path | None = None,
        registry: NodeRegistry | None = None,
        params: TreeParams | None = None,
        battery: BatteryModel | None = None,
        keep_finished: int = 256,
    ) -> None:
        self.inner = inner
        self.clock = clock
        self.defaults = {
            "navigate_to_pose": str(nav_to_pose_xml or DEFAULT_NAV_TO_POSE_XML),
            "navigate_through_poses": str(nav_through_poses_xml or DEFAULT_NAV_THROUGH_POSES_XML),
        }
        self._registry = registry
        self._params = params or TreeParams()
        self._battery = battery
        self._ns = normalize_namespace(inner.namespace)
        self.prefix = key_path(self._ns, "navigator")
        self._trees: dict[str, XmlTree] = {}
        self._goals: dict[str, _NavGoal] = {}
        self._keep = keep_finished
        self._ids = itertools.count(1)
        self._active: _NavGoal | None = None
        self._tree: XmlTree | None = None
        self._last_error: object = ""
        #: Ticks of navigator trees so far.
        self.ticks = 0

    # -- NavigationBackend ------------------------------------------------------------------

    @property
    def namespace(self) -> str:
        return self.inner.namespace

    def send_goal(self, goal: Goal) -> str:
        """Start a navigation goal on its tree (others pass through to ``inner``)."""
        if not isinstance(goal, (NavigateToPose, NavigateThroughPoses)):
            if getattr(goal, "kind", None) in MOTION_GOAL_KINDS and self._active is not None:
                self._end(GoalStatus.ABORTED, 0, f"preempted by a {goal.kind} goal")
            return self.inner.send_goal(goal)
        tree_file = goal.behavior_tree or self.defaults[goal.kind]
        if not tree_file:  # no tree: the inner backend's own navigation
            if self._active is not None:
                self._end(GoalStatus.ABORTED, 0, f"preempted by a {goal.kind} goal")
            return self.inner.send_goal(goal)
        gid = f"{self._ns}#n{next(self._ids)}"
        rec = _NavGoal(gid, goal, tree_file, self.clock.now())
        self._remember(rec)
        active = self._active
        if active is not None and active.goal.kind == goal.kind:
            if tree_file != active.tree_file:
                rec.finish(
                    GoalStatus.ABORTED,
                    0,
                    f"Preemption with another behavior tree ({tree_file}) is refused while {active.tree_file} runs; "
                    "cancel the running goal first.",
                )
                return gid
            active.finish(GoalStatus.ABORTED, 0, f"Goal {active.goal_id} was preempted by goal {gid}.")
            self._active = rec
            self._set_goal(goal)
            return gid
        if active is not None:
            self._end(GoalStatus.ABORTED, 0, f"Goal {active.goal_id} was preempted by goal {gid}.")
        try:
            tree = self._load(tree_file)
        except FleetError as e:
            rec.finish(GoalStatus.ABORTED, 0, f"Cannot load the behavior tree: {e}")
            return gid
        if self.inner.robot_state().pose is None:
            rec.finish(GoalStatus.ABORTED, 0, "The robot's pose is not available.")
            return gid
        self._tree, self._active = tree, rec
        self._clean()
        Blackboard.storage[f"{self.prefix}/{self._params.recoveries_key}"] = 0
        Blackboard.storage[f"{self.prefix}/initial_pose_received"] = True
        Blackboard.storage[f"{self.prefix}/path"] = ()  # no stale path for the feedback
        self._last_error = Blackboard.storage.get(key_path(self._ns, "last_error"), "")
        self._set_goal(goal)
        rec.feedback = self._feedback(rec)
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        rec = self._goals.get(goal_id)
        if rec is None:
            return self.inner.goal_state(goal_id)
        return rec.snapshot()

    def cancel_goal(self, goal_id: str) -> None:
        rec = self._goals.get(goal_id)
        if rec is None:
            self.inner.cancel_goal(goal_id)
        elif rec is self._active:
            self._end(GoalStatus.CANCELED)

    def robot_state(self) -> RobotState:
        return self.inner.robot_state()

    # -- running ---------------------------------------------------------------------------

    @property
    def active(self) -> str | None:
        """The id of the navigation goal whose tree runs (``None``: none)."""
        return None if self._active is None else self._active.goal_id

    def tick(self) -> None:
        """Tick the running tree once, refresh the feedback, end the goal when the tree ends."""
        rec, tree = self._active, self._tree
        if rec is None or tree is None:
            return
        tree.root.tick_once()
        self.ticks += 1
        rec.feedback = self._feedback(rec)
        status = tree.root.status
        if status == Status.SUCCESS:
            self._end(GoalStatus.SUCCEEDED)
        elif status == Status.FAILURE:
            code = self._error_code()
            name = _code_name(code)
            last = Blackboard.storage.get(key_path(self._ns, "last_error"), "")
            last = str(last) if last and last != self._last_error else ""
            msg = f"The navigator tree {Path(rec.tree_file).name} failed" + (f" ({name})" if code else "")
            self._end(GoalStatus.ABORTED, code, f"{msg}: {last}" if last else msg + ".")

    def close(self) -> None:
        """Halt the running tree (its goal ends ABORTED)."""
        if self._active is not None:
            self._end(GoalStatus.ABORTED, int(ErrorCode.SERVER_UNAVAILABLE), "The navigator was closed.")

    # -- internals -------------------------------------------------------------------------

    def _load(self, tree_file: str) -> XmlTree:
        tree = self._trees.get(tree_file)
        if tree is None:
            tree = load_tree(
                tree_file,
                self._ns,
                self.inner,
                self.clock,
                self._battery,
                registry=self._registry,
                blackboard=self.prefix,
                params=self._params,
            )
            self._trees[tree_file] = tree
            logger.info("%s: loaded navigator tree %s", self._ns, tree_file)
        return tree

    def _set_goal(self, goal: NavigateToPose | NavigateThroughPoses) -> None:
        st = Blackboard.storage
        if isinstance(goal, NavigateToPose):
            st[f"{self.prefix}/goal"] = goal.pose
        else:
            st[f"{self.prefix}/goals"] = tuple(goal.poses)

    def _end(self, status: GoalStatus, code: int = 0, msg: str = "") -> None:
        rec, tree = self._active, self._tree
        self._active = None
        if tree is not None:
            tree.root.stop(Status.INVALID)
        if rec is not None:
            rec.feedback = self._feedback(rec)
            rec.finish(status, code, msg)
        self._clean()

    def _clean(self) -> None:
        for name in ERROR_CODE_NAMES:
            Blackboard.storage[f"{self.prefix}/{name}"] = 0

    def _error_code(self) -> int:
        codes = [Blackboard.storage.get(f"{self.prefix}/{n}", 0) for n in ERROR_CODE_NAMES]
        nonzero = [int(c) for c in codes if isinstance(c, int) and c]
        return min(nonzero, default=0)

    def _feedback(self, rec: _NavGoal) -> Feedback:
        st = Blackboard.storage
        state = self.inner.robot_state()
        here = state.pose
        path = st.get(f"{self.prefix}/path")
        remaining: float | None = None
        if here is not None and isinstance(path, tuple) and path:
            remaining = remaining_along(path, here)
        speed = abs(state.linear_velocity)
        eta = remaining / speed if remaining is not None and speed > 0.01 and remaining > 0.1 else 0.0
        goals = st.get(f"{self.prefix}/goals")
        return Feedback(
            current_pose=here,
            navigation_time_s=self.clock.now() - rec.started,
            estimated_time_remaining_s=eta,
            distance_remaining_m=remaining if remaining is not None else _straight(here, rec.goal),
            number_of_recoveries=int(st.get(f"{self.prefix}/{self._params.recoveries_key}", 0) or 0),
            number_of_poses_remaining=len(goals)
            if isinstance(rec.goal, NavigateThroughPoses) and isinstance(goals, tuple)
            else None,
        )

    def _remember(self, rec: _NavGoal) -> None:
        self._goals[rec.goal_id] = rec
        if len(self._goals) > self._keep:
            for gid in list(self._goals):
                if len(self._goals) <= self._keep:
                    break
                if self._goals[gid].status.terminal:
                    del self._goals[gid]


def _straight(here: Pose2D | None, goal: NavigateToPose | NavigateThroughPoses) -> float | None:
    """The straight-line distance to the goal's last pose (before a path exists)."""
    if here is None:
        return None
    last = goal.pose if isinstance(goal, NavigateToPose) else (goal.poses[-1] if goal.poses else None)
    return None if last is None else here.distance_to(last)


def _code_name(code: int) -> str:
    try:
        return f"{ErrorCode(code).name} {code}"
    except ValueError:
        return str(code)
