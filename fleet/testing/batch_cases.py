"""Conformance case of the batch query (:func:`fleet.navigation.query_batch`): its rows agree
with the per-goal queries of the same backend."""

from __future__ import annotations

import math

from fleet.navigation import GOAL_CODES, NO_GOAL, NavBatch, query_batch
from fleet.testing.harness import Case, ConformanceHarness, case_registry, expect, finish
from fleet.types import GoalState, GoalStatus, NavigateToPose, RobotState, Wait

_CASES, _case = case_registry()

#: Attempts at reading a backend that answers from live messages in a quiet moment.
_ATTEMPTS = 50


@_case()
def batch_query_agrees_with_per_goal_queries(h: ConformanceHarness) -> None:
    """query_batch over rows of a running navigation goal, a finished goal, no goal and an
    unknown id gives, row by row, what robot_state and goal_state give (status, error code,
    distance remaining, pose, battery, flags); an unknown id is NO_GOAL, not an error."""
    b = h.backend
    done = b.send_goal(Wait(0.3))
    state = finish(h, done, 5.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"Wait(0.3) ended {state.status.value}")
    nav = b.send_goal(NavigateToPose(h.world.reachable))
    h.advance(2.0)
    ids = [nav, done, None, "/nobody#424242"]
    reason = ""
    for _ in range(_ATTEMPTS):  # a live backend may change between two reads: find a quiet one
        before = _reads(h, nav, done)
        batch = query_batch([b] * len(ids), ids)
        if before != _reads(h, nav, done):
            continue
        reason = _disagreement(batch, *before)
        if not reason:
            return
    expect(False, reason or f"the backend never stood still for one batch in {_ATTEMPTS} attempts")


def _reads(h: ConformanceHarness, nav: str, done: str) -> tuple[RobotState, GoalState, GoalState]:
    b = h.backend
    return b.robot_state(), b.goal_state(nav), b.goal_state(done)


def _disagreement(batch: NavBatch, robot: RobotState, nav: GoalState, done: GoalState) -> str:
    """What in ``batch`` differs from the per-goal reads (``""``: nothing)."""
    if len(batch) != 4:
        return f"the batch has {len(batch)} rows, not 4"
    for row, goal in ((0, nav), (1, done)):
        if batch.status(row) is not goal.status or int(batch.goal_status[row]) != GOAL_CODES[goal.status]:
            return f"row {row}: status {batch.status(row)} but goal_state says {goal.status}"
        if int(batch.goal_error[row]) != goal.error_code:
            return f"row {row}: error code {batch.goal_error[row]} but goal_state says {goal.error_code}"
        rem = goal.feedback.distance_remaining_m
        if not _same(float(batch.distance_remaining[row]), rem):
            return f"row {row}: distance remaining {batch.distance_remaining[row]} but feedback says {rem}"
    for row in (2, 3):
        if int(batch.goal_status[row]) != NO_GOAL:
            return f"row {row} (no goal / unknown id): status code {batch.goal_status[row]}, not NO_GOAL"
    p = robot.pose
    for row in range(4):
        pose = (batch.x[row], batch.y[row], batch.theta[row])
        want = (p.x, p.y, p.theta) if p is not None else (None, None, None)
        if not all(_same(float(a), w) for a, w in zip(pose, want, strict=True)):
            return f"row {row}: pose {pose} but robot_state says {want}"
        flags = (batch.charging[row], batch.stuck[row], batch.localized[row], batch.navigation_ready[row])
        if tuple(bool(f) for f in flags) != (
            robot.charging,
            robot.stuck,
            robot.localized,
            robot.navigation_ready,
        ):
            return f"row {row}: flags (charging, stuck, localized, navigation_ready) {flags} differ from robot_state"
        for name in ("battery", "distance_m"):
            if not _same(float(getattr(batch, name)[row]), getattr(robot, name)):
                return f"row {row}: {name} {getattr(batch, name)[row]} but robot_state says {getattr(robot, name)}"
        if int(batch.collisions[row]) != robot.collisions:
            return f"row {row}: collisions {batch.collisions[row]} but robot_state says {robot.collisions}"
    return ""


def _same(a: float, b: float | None) -> bool:
    """``a`` is ``b`` (NaN standing for ``None``), to 1e-6."""
    if b is None:
        return math.isnan(a)
    return not math.isnan(a) and abs(a - b) <= 1e-6 * max(1.0, abs(b))


#: The batch cases (:data:`fleet.testing.conformance.CASES` includes them).
BATCH_CASES: tuple[Case, ...] = tuple(_CASES)

__all__ = ["BATCH_CASES"]
