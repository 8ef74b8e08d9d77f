"""The planner, smoother and costmap goals on a SUMO network, and the goal kinds SUMO rejects.

What applies on SUMO:

* **ComputePathToPose / ComputePathThroughPoses** plan on the road network: start and goals
  are snapped to their nearest lane points (beyond ``max_snap_m``: ``START_OUTSIDE_MAP`` /
  ``GOAL_OUTSIDE_MAP``), SUMO's ``findRoute`` joins their edges (none: ``NO_VALID_PATH``) and
  the path runs along the lanes (the snapped start, the lane ends, the snapped goal); the
  through-poses codes are the 3xx ones (:mod:`sim.computations`).
* **SmoothPath** rounds the corners of any path (there is no occupancy map, so every cut is
  allowed and ``check_for_collisions`` finds nothing).

What does not, and is ``REJECTED`` with the reason (:data:`REJECTED_KINDS`):

* **FollowPath**: SUMO vehicles drive their lanes, they cannot follow a free path;
* **ClearCostmaps**: SUMO keeps no costmaps.
"""

from __future__ import annotations

from collections.abc import Callable

from fleet.types import Costmap, ErrorCode, GoalStatus, Pose2D
from sim.computations import Point, compute
from sim.goals import GoalRecord, is_computation, reject_if_invalid
from sim.planner import PlanResult
from sim.sumo.lanes import LaneIndex
from sim.sumo.launch import ROBOT_TYPE, Libsumo

#: Goal kinds SUMO cannot execute -> why (they end REJECTED).
REJECTED_KINDS: dict[str, str] = {
    "follow_path": "SUMO vehicles drive along lanes and cannot follow a free path; send a navigation goal",
    "clear_costmaps": "SUMO keeps no costmaps to clear",
}
#: Curved lanes are sampled this often (m) along their shape.
SAMPLE_M = 1.0


class SumoPlanning:
    """The computation goals of a SUMO world (see the module docstring)."""

    def __init__(self, ls: Libsumo, lanes: LaneIndex, max_snap_m: float) -> None:
        self.ls = ls
        self.lanes = lanes
        self.max_snap_m = max_snap_m

    def take(self, record: GoalRecord, pose: Callable[[], Pose2D | None]) -> bool:
        """Finish ``record`` here if it is a computation goal (run at once, beside the robot's
        motion goal) or a kind SUMO rejects; return whether it did. ``pose`` gives the robot's
        pose."""
        why = REJECTED_KINDS.get(record.kind)
        if why is not None:
            record.finish(GoalStatus.REJECTED, 0, why)
            return True
        if not is_computation(record.goal):
            return False
        if not reject_if_invalid(record):
            compute(record, pose(), self)
        return True

    def plan_path(self, namespace: str, start: Point, goal: Point) -> PlanResult:
        """A path along the lanes from the lane point of ``start`` to that of ``goal``."""
        lanes = self.lanes
        a, b = lanes.nearest(*start), lanes.nearest(*goal)
        for lp, code, what in (
            (a, ErrorCode.START_OUTSIDE_MAP, "Start"),
            (b, ErrorCode.GOAL_OUTSIDE_MAP, "Goal"),
        ):
            if lp.dist > self.max_snap_m:
                p = start if lp is a else goal
                msg = f"{what} ({p[0]:.2f}, {p[1]:.2f}) is {lp.dist:.1f} m from the nearest SUMO lane."
                return PlanResult((), code, msg)
        if a.edge == b.edge and b.pos >= a.pos:
            edges = [a.edge]
        else:
            route = self.ls.simulation.findRoute(a.edge, b.edge, ROBOT_TYPE)
            edges = list(route.edges)
            if not edges:
                return PlanResult(
                    (),
                    ErrorCode.NO_VALID_PATH,
                    f"No route on the SUMO network from ({start[0]:.2f}, {start[1]:.2f}) to ({goal[0]:.2f}, {goal[1]:.2f}).",
                )
        points: list[Point] = [(a.x, a.y)]
        for i, edge in enumerate(edges):
            lane = a.lane if i == 0 else (b.lane if i == len(edges) - 1 else 0)
            p0 = a.pos if i == 0 else 0.0
            p1 = b.pos if i == len(edges) - 1 else lanes.edge_length[edge]
            points.extend(self._along(edge, lane, p0, p1))
        points.append((b.x, b.y))
        out = [points[0]]
        for p in points[1:]:
            if p != out[-1]:
                out.append(p)
        if len(out) == 1:
            out.append(out[0])
        return PlanResult(tuple(out))

    def _along(self, edge: str, lane: int, p0: float, p1: float) -> list[Point]:
        """Points of lane ``lane`` of ``edge`` from lane position ``p0`` to ``p1`` (m)."""
        ends = (self.lanes.point(edge, lane, p0), self.lanes.point(edge, lane, p1))
        if ends[0] is not None and ends[1] is not None:
            return [ends[0], ends[1]]
        n = max(1, int((p1 - p0) / SAMPLE_M))
        out: list[Point] = []
        for k in range(n + 1):
            x, y = self.ls.simulation.convert2D(edge, p0 + (p1 - p0) * k / n, lane)[:2]
            out.append((float(x), float(y)))
        return out

    def segment_free(self, namespace: str, a: Point, b: Point) -> bool:
        """Always: SUMO has no occupancy map."""
        return True

    def clear_costmaps(self, namespace: str, which: Costmap) -> None:
        """Never called: ClearCostmaps is rejected on SUMO."""
