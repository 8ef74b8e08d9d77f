"""Goal-level metrics of a run: a :class:`GoalLog` wraps one robot's navigation backend and
counts what happened to the navigation goals its tree sent; :class:`GoalMetrics` adds the
robots up for the report.

What counts as one *goal*: a navigation goal (NavigateToPose, NavigateThroughPoses,
FollowWaypoints) to a new target. A goal the tree sends again to the same final pose (within
:data:`SAME_TARGET_M`) after the previous attempt failed is a retry of the same goal, not a
new one; the recovery behaviors sent between a failure and its retry (Spin, BackUp,
DriveOnHeading, Wait, ClearCostmaps) are that goal's *recoveries*. A goal ends:

* **succeeded** when an attempt succeeds (its time is from the first attempt to the success);
* **failed** with the last attempt's error code when the tree gives up: it sends a goal to
  another target (or the run ends) after a failure;
* **canceled** when the tree cancels it, or preempts it with another goal, while it runs
  (e.g. a low battery sends the robot to charge).

Time against the optimum, over succeeded goals: the time taken divided by the time to drive
the straight line from where the goal started through its poses at the robot's top speed
(``time_over_straight``), and the same through the roadmap (``time_over_roadmap``: from the
roadmap node nearest each point, along the shortest roadmap path). Memory is bounded: only
counters and sums are kept.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from fleet.navigation import state_reader
from fleet.types import NAV_GOAL_KINDS, ErrorCode, Goal, GoalState, GoalStatus, Pose2D, RobotState

if TYPE_CHECKING:
    from fleet.navigation import Clock, NavigationBackend
    from fleet.roadmap import Roadmap

#: Goals whose final poses are this close (m) are the same target.
SAME_TARGET_M = 0.3
#: Goals that count as recoveries when sent between a failed attempt and its retry.
RECOVERY_KINDS = ("spin", "backup", "drive_on_heading", "wait", "clear_costmaps")


@dataclass
class GoalMetrics:
    """Goal counters of one robot or of the fleet (see the module docstring).

    ``failed_by_code`` maps an error code name (``FAILED_TO_MAKE_PROGRESS``, or the number for
    a code without a name) to the goals that failed with it; ``recoveries`` is the total over
    goals, ``max_recoveries`` the most any one goal needed; times in simulated seconds."""

    sent: int = 0
    succeeded: int = 0
    failed: int = 0
    canceled: int = 0
    failed_by_code: Counter[str] = field(default_factory=Counter)
    recoveries: int = 0
    max_recoveries: int = 0
    time_s: float = 0.0
    straight_s: float = 0.0
    roadmap_s: float = 0.0

    @property
    def success_rate(self) -> float | None:
        """Succeeded / (succeeded + failed); ``None`` before any goal ended either way."""
        done = self.succeeded + self.failed
        return None if done == 0 else self.succeeded / done

    @property
    def recoveries_per_goal(self) -> float | None:
        """Mean recoveries per ended goal (``None``: none ended)."""
        ended = self.succeeded + self.failed + self.canceled
        return None if ended == 0 else self.recoveries / ended

    def add(self, other: GoalMetrics) -> None:
        """Add ``other``'s counts to these."""
        self.sent += other.sent
        self.succeeded += other.succeeded
        self.failed += other.failed
        self.canceled += other.canceled
        self.failed_by_code.update(other.failed_by_code)
        self.recoveries += other.recoveries
        self.max_recoveries = max(self.max_recoveries, other.max_recoveries)
        self.time_s += other.time_s
        self.straight_s += other.straight_s
        self.roadmap_s += other.roadmap_s

    def to_dict(self) -> dict[str, Any]:
        """The report's ``goals`` entry (ratios rounded, ``None`` when undefined)."""

        def ratio(a: float, b: float) -> float | None:
            return round(a / b, 3) if b > 0 else None

        rate = self.success_rate
        per_goal = self.recoveries_per_goal
        return {
            "sent": self.sent,
            "succeeded": self.succeeded,
            "failed": self.failed,
            "canceled": self.canceled,
            "failed_by_code": dict(sorted(self.failed_by_code.items())),
            "success_rate": None if rate is None else round(rate, 4),
            "recoveries": self.recoveries,
            "recoveries_per_goal": None if per_goal is None else round(per_goal, 3),
            "max_recoveries": self.max_recoveries,
            "time_over_straight": ratio(self.time_s, self.straight_s),
            "time_over_roadmap": ratio(self.time_s, self.roadmap_s),
        }


@dataclass
class _Open:
    target: Pose2D
    started: float
    #: where the robot stood when the goal was sent, then the goal's poses: the optimum's
    #: (straight-line and roadmap) lengths are computed from them only if the goal succeeds
    #: (most goals a traffic follower sends are replaced by the next before they end)
    way: tuple[Pose2D, ...]
    attempt: str
    failed_code: int | None = None
    recoveries: int = 0


class GoalLog:
    """A :class:`~fleet.navigation.NavigationBackend` that passes everything to ``inner`` and
    keeps :attr:`metrics` of the navigation goals sent through it.

    Args:
        inner: the robot's backend.
        clock: the run's clock (goal times).
        max_speed_mps: the robot's top speed (the optimum's time).
        roadmap: the fleet's roadmap for ``time_over_roadmap`` (``None``: not measured).

    Outcomes are seen when the tree polls ``goal_state`` (it always does); call
    :meth:`close` at the end of the run (a goal whose last attempt failed counts as failed,
    one still running is not counted as ended).
    """

    def __init__(
        self, inner: NavigationBackend, clock: Clock, max_speed_mps: float, roadmap: Roadmap | None = None
    ) -> None:
        self.inner = inner
        self.clock = clock
        self.max_speed = max(1e-6, float(max_speed_mps))
        self.roadmap = roadmap
        self.metrics = GoalMetrics()
        self._open: _Open | None = None

    @property
    def namespace(self) -> str:
        return self.inner.namespace

    def send_goal(self, goal: Goal) -> str:
        kind = getattr(goal, "kind", "")
        if kind in NAV_GOAL_KINDS:
            return self._send_nav(goal)
        gid = self.inner.send_goal(goal)
        cur = self._open
        if cur is not None and cur.failed_code is not None and kind in RECOVERY_KINDS:
            cur.recoveries += 1
        return gid

    def _send_nav(self, goal: Goal) -> str:
        poses = _poses(goal)
        here = self.inner.robot_state().pose
        cur = self._open
        if (
            cur is not None
            and poses
            and cur.failed_code is not None
            and poses[-1].distance_to(cur.target) <= SAME_TARGET_M
        ):
            cur.attempt = self.inner.send_goal(goal)  # a retry of the same goal
            cur.failed_code = None
            return cur.attempt
        if cur is not None:
            self._finish(cur, None)
        gid = self.inner.send_goal(goal)
        self.metrics.sent += 1
        if not poses or here is None:
            self._open = None
            return gid
        self._open = _Open(poses[-1], self.clock.now(), (here, *poses), attempt=gid)
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        state = self.inner.goal_state(goal_id)
        cur = self._open
        if cur is not None and goal_id == cur.attempt and state.status.terminal and cur.failed_code is None:
            if state.status is GoalStatus.SUCCEEDED:
                self._finish(cur, state)
            elif state.status is GoalStatus.CANCELED:
                self._finish(cur, None)
            else:
                cur.failed_code = int(state.error_code)
        return state

    def cancel_goal(self, goal_id: str) -> None:
        self.inner.cancel_goal(goal_id)

    def robot_state(self) -> RobotState:
        return self.inner.robot_state()

    @property
    def state_reader(self) -> Callable[[], RobotState]:
        """What :meth:`robot_state` calls (it adds nothing): a wrapper above reads the state
        through it, one call less per read."""
        return state_reader(self.inner)

    def close(self) -> None:
        """End of the run: a goal whose last attempt failed counts as failed."""
        cur = self._open
        if cur is not None and cur.failed_code is not None:
            self._finish(cur, None)
        self._open = None

    def _finish(self, cur: _Open, success: GoalState | None) -> None:
        m = self.metrics
        m.recoveries += cur.recoveries
        m.max_recoveries = max(m.max_recoveries, cur.recoveries)
        if success is not None:
            m.succeeded += 1
            m.time_s += self.clock.now() - cur.started
            straight_m, roadmap_m = self._optimum(cur.way)
            m.straight_s += straight_m / self.max_speed
            m.roadmap_s += roadmap_m / self.max_speed
        elif cur.failed_code is not None:
            m.failed += 1
            m.failed_by_code[_code_name(cur.failed_code)] += 1
        else:
            m.canceled += 1
        self._open = None

    def _optimum(self, pts: tuple[Pose2D, ...]) -> tuple[float, float]:
        """(straight-line, roadmap) lengths in m from the start ``pts[0]`` through the rest."""
        straight = sum(a.distance_to(b) for a, b in zip(pts, pts[1:], strict=False))
        rm = self.roadmap
        if rm is None or len(rm) == 0:
            return straight, straight
        total = 0.0
        for a, b in zip(pts, pts[1:], strict=False):
            na, nb = rm.nearest_node(a.x, a.y), rm.nearest_node(b.x, b.y)
            ax, ay = rm.pos(na)
            bx, by = rm.pos(nb)
            via = math.hypot(a.x - ax, a.y - ay) + rm.distance(na, nb) + math.hypot(b.x - bx, b.y - by)
            total += via if math.isfinite(via) else a.distance_to(b)
        return straight, max(straight, total)


def _poses(goal: Goal) -> tuple[Pose2D, ...]:
    pose = getattr(goal, "pose", None)
    if isinstance(pose, Pose2D):
        return (pose,)
    poses = getattr(goal, "poses", ())
    return tuple(p for p in poses if isinstance(p, Pose2D))


def _code_name(code: int) -> str:
    try:
        return ErrorCode(code).name
    except ValueError:
        return str(code)
