"""The computation goals of a stepped world: Nav2's planner, smoother and costmap servers.

ComputePathToPose, ComputePathThroughPoses, SmoothPath and ClearCostmaps move nothing, so they
run beside the robot's motion goal (see :mod:`fleet.navigation`) and finish when they are sent:
:func:`compute` ends the goal's :class:`sim.goals.GoalRecord` SUCCEEDED with its result
(``record.path``) or ABORTED with Nav2's code and a message. What a world brings is a
:class:`Planner`: a ``plan(start, goal)`` in the ``map`` frame with ComputePathToPose's codes
(the simulator's :class:`sim.planner.GridPlanner`, the SUMO world's lane router), a
``segment_free`` check for the smoother, and ``clear_costmaps``.

* **ComputePathToPose**: the plan from ``start`` (or the robot's pose) to the goal; each pose
  of the path faces the next one, the last has the goal's yaw. Codes 2xx.
* **ComputePathThroughPoses**: the legs through every goal joined into one path; codes 3xx
  (the leg's 2xx code + 100), ``NO_VIAPOINTS_GIVEN`` without goals.
* **SmoothPath**: corner cutting (Chaikin, :data:`SMOOTHING_ROUNDS` rounds) keeping the first
  and last pose; a cut is kept only where the smoothed segments stay free (``segment_free``),
  so the result never leaves free space the input was in. ``check_for_collisions`` fails a
  path whose own segments are not free with ``SMOOTHED_PATH_IN_COLLISION``; an empty path is
  ``SMOOTHER_INVALID_PATH``.
* **ClearCostmaps**: asks the world to clear the robot's costmaps (``clear_costmaps``);
  SUCCEEDS once done.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

from fleet.types import (
    ClearCostmaps,
    ComputePathThroughPoses,
    ComputePathToPose,
    Costmap,
    ErrorCode,
    GoalStatus,
    Path,
    Pose2D,
    SmoothPath,
)
from sim.goals import GoalRecord

Point = tuple[float, float]
#: Rounds of corner cutting of SmoothPath.
SMOOTHING_ROUNDS = 3
#: ComputePathThroughPoses' codes are ComputePathToPose's + this.
THROUGH_POSES_OFFSET = 100


class PlanOutcome(Protocol):
    """What a planner returns (:class:`sim.planner.PlanResult` has it)."""

    @property
    def path(self) -> tuple[Point, ...]: ...

    @property
    def error_code(self) -> int: ...

    @property
    def error_msg(self) -> str: ...


class Planner(Protocol):
    """What a world offers its computation goals (see the module docstring)."""

    def plan_path(self, namespace: str, start: Point, goal: Point) -> PlanOutcome:
        """A path from ``start`` to ``goal`` for robot ``namespace`` (its costmaps, if it has
        any), with ComputePathToPose's codes."""
        ...

    def segment_free(self, namespace: str, a: Point, b: Point) -> bool:
        """Whether robot ``namespace`` may drive straight from ``a`` to ``b``."""
        ...

    def clear_costmaps(self, namespace: str, which: Costmap) -> None:
        """Clear robot ``namespace``'s ``which`` costmaps (a world without costmaps does
        nothing)."""
        ...


def compute(record: GoalRecord, here: Pose2D | None, world: Planner) -> None:
    """Run the computation goal of ``record`` for the robot at ``here`` (``None``: unknown
    pose) on ``world``; the record ends SUCCEEDED (with ``record.path`` for the planners and
    the smoother) or ABORTED with Nav2's code."""
    goal = record.goal
    ns = record.namespace
    if isinstance(goal, ComputePathToPose):
        _plan(record, world, goal.start or here, (goal.goal,), 0)
    elif isinstance(goal, ComputePathThroughPoses):
        if not goal.goals:
            record.finish(GoalStatus.ABORTED, ErrorCode.NO_VIAPOINTS_GIVEN, "No goals were given.")
            return
        _plan(record, world, goal.start or here, tuple(goal.goals), THROUGH_POSES_OFFSET)
    elif isinstance(goal, SmoothPath):
        _smooth(record, world, goal)
    elif isinstance(goal, ClearCostmaps):
        world.clear_costmaps(ns, Costmap(goal.costmap))
        record.finish(GoalStatus.SUCCEEDED)
    else:  # pragma: no cover - the dispatch sends only computation goals here
        raise TypeError(f"{goal.kind} is not a computation goal")


def _plan(
    record: GoalRecord, world: Planner, start: Pose2D | None, goals: tuple[Pose2D, ...], offset: int
) -> None:
    if start is None:
        record.finish(
            GoalStatus.ABORTED, int(ErrorCode.PLANNER_TF_ERROR) + offset, "The robot's pose is unknown."
        )
        return
    points: list[Point] = [(start.x, start.y)]
    for i, g in enumerate(goals):
        res = world.plan_path(record.namespace, points[-1], (g.x, g.y))
        if res.error_code:
            where = f" (leg to goal {i})" if len(goals) > 1 else ""
            record.finish(GoalStatus.ABORTED, int(res.error_code) + offset, res.error_msg + where)
            return
        points.extend(res.path[1:])
    record.path = path_through(points, goals[-1].theta)
    record.finish(GoalStatus.SUCCEEDED)


def path_through(points: Sequence[Point], final_yaw: float) -> Path:
    """Poses at ``points`` (``map``), each facing the next point, the last one ``final_yaw``
    (a single point is the start and the goal)."""
    out: list[Pose2D] = []
    n = len(points)
    for i, (x, y) in enumerate(points):
        if i + 1 < n:
            nx, ny = points[i + 1]
            yaw = math.atan2(ny - y, nx - x) if (nx, ny) != (x, y) else (out[-1].theta if out else final_yaw)
        else:
            yaw = final_yaw
        out.append(Pose2D(float(x), float(y), float(yaw)))
    return tuple(out)


def _smooth(record: GoalRecord, world: Planner, goal: SmoothPath) -> None:
    path = tuple(goal.path)
    if not path:
        record.finish(GoalStatus.ABORTED, ErrorCode.SMOOTHER_INVALID_PATH, "SmoothPath got an empty path.")
        return
    ns = record.namespace
    points = [(p.x, p.y) for p in path]
    if goal.check_for_collisions:
        for a, b in zip(points, points[1:], strict=False):
            if not world.segment_free(ns, a, b):
                record.finish(
                    GoalStatus.ABORTED,
                    ErrorCode.SMOOTHED_PATH_IN_COLLISION,
                    f"The path crosses an obstacle between ({a[0]:.2f}, {a[1]:.2f}) and ({b[0]:.2f}, {b[1]:.2f}).",
                )
                return
    smoothed = smooth_points(points, lambda a, b: world.segment_free(ns, a, b))
    record.path = path_through(smoothed, path[-1].theta)
    record.finish(GoalStatus.SUCCEEDED)


def smooth_points(
    points: Sequence[Point],
    free: Callable[[Point, Point], bool] | None = None,
    rounds: int = SMOOTHING_ROUNDS,
) -> list[Point]:
    """Chaikin corner cutting of the polyline ``points`` (first and last point kept). ``free``
    (``(a, b) -> bool``) vets each cut: a corner whose cut segment is not free is kept as it
    was (the other new segments lie on the input's)."""
    pts = list(points)
    for _ in range(rounds):
        if len(pts) < 3:
            return pts
        out = [pts[0]]
        for i in range(1, len(pts) - 1):
            (ax, ay), (bx, by), (cx, cy) = pts[i - 1], pts[i], pts[i + 1]
            q = (0.75 * bx + 0.25 * ax, 0.75 * by + 0.25 * ay)
            r = (0.75 * bx + 0.25 * cx, 0.75 * by + 0.25 * cy)
            if free is None or free(q, r):
                out.extend((q, r))
            else:
                out.append((bx, by))
        out.append(pts[-1])
        pts = out
    return pts
