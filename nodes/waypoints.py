"""``NextWaypoint``: the waypoint-by-waypoint walk of a patrol route (the inspection trees)."""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from py_trees.common import Status

from fleet.navigation import NavigationBackend
from fleet.types import Mode, Pose2D
from nodes.blackboard import robot_blackboard


class NextWaypoint(py_trees.behaviour.Behaviour):
    """Choose the robot's next waypoint on its patrol ``route``, for trees that visit a route
    one waypoint at a time and act at each (inspection: drive there, look around, dwell).

    On each tick: with a new ``task_id`` (or no waypoint yet) the waypoint is the route pose
    nearest the robot; once the robot stands within ``tolerance_m`` of the current waypoint,
    the next one (so an interrupted visit, e.g. by charging, resumes at the same waypoint).
    Coming back to the lap's first waypoint counts a lap (``laps += 1``, as
    :class:`nodes.trees.FollowRoute`). Writes ``route_progress`` and ``mode = patrol`` and
    hands the waypoint to ``put``. SUCCESS, or FAILURE without a route (or robot pose).
    Sends no goal; nothing to cancel.
    """

    def __init__(
        self,
        backend: NavigationBackend,
        put: Callable[[Pose2D], None],
        *,
        tolerance_m: float = 0.5,
        name: str = "NextWaypoint",
    ) -> None:
        super().__init__(name=name)
        self.backend = backend
        self.put = put
        self.tolerance_m = tolerance_m
        keys = ("route", "task_id", "laps", "lap_task_id", "route_progress", "mode", "active_leaf")
        self.blackboard = robot_blackboard(backend.namespace, name=name, keys=keys)
        self.blackboards.append(self.blackboard)
        self._task: object = None
        self._index = -1
        self._start = 0

    def update(self) -> Status:
        bb = self.blackboard
        route = tuple(bb.route or ())
        here = self.backend.robot_state().pose
        if len(route) < 1 or here is None:
            self.feedback_message = "no route" if not route else "no robot pose"
            return Status.FAILURE
        if bb.task_id != self._task or not 0 <= self._index < len(route):
            self._task = bb.task_id
            if bb.lap_task_id != bb.task_id:
                bb.laps, bb.lap_task_id = 0, bb.task_id
            self._index = min(range(len(route)), key=lambda i: route[i].distance_to(here))
            self._start = self._index
        elif route[self._index].distance_to(here) <= self.tolerance_m:
            self._index = (self._index + 1) % len(route)
            if self._index == self._start:
                bb.laps = int(bb.laps) + 1
        done = (self._index - self._start) % len(route)
        bb.route_progress = done / len(route)
        bb.mode = Mode.PATROL
        bb.active_leaf = self.name
        self.put(route[self._index])
        self.feedback_message = f"waypoint {self._index} of {len(route)}"
        return Status.SUCCESS
