"""The Nav2 goal semantics every stepped world shares (the simulator and the SUMO world).

One implementation of what a goal *is* on a backend, whatever moves the robots:

* **Ids.** :class:`GoalBook` issues ``"<namespace>#<n>"`` (``n`` counts from 1 per robot) and
  never reuses one. It keeps every live goal and the last :data:`KEEP_FINISHED` finished goals
  of each robot; ``goal_state`` of an older id raises ``KeyError`` like an id never issued.
* **Misuse is an exception, bad input is a value.** An object that is not one of the goal
  types of :mod:`fleet.types` is a programming error: :func:`check_goal` raises
  :class:`fleet.errors.BackendError` before anything changes (no id is spent, the running goal
  keeps running). A goal whose input no server could take is ``REJECTED``
  (:func:`reject_reason`: a NavigateThroughPoses without poses, a non-finite pose). A goal that
  is accepted but cannot start ends ``ABORTED`` at once with its action's code
  (:func:`start_error`: an empty FollowWaypoints ``WAYPOINT_UNKNOWN``, as Nav2's waypoint
  follower terminates an empty list; a non-finite Spin ``SPIN_UNKNOWN``; a non-positive
  BackUp / DriveOnHeading ``*_INVALID_INPUT``; an empty FollowPath ``INVALID_PATH``).
* **Motion and computation.** A robot has one motion goal (:data:`fleet.types.MOTION_GOAL_KINDS`)
  at a time; computation goals (:data:`fleet.types.COMPUTE_GOAL_KINDS`) run beside it
  (:func:`is_computation`) and finish when they are sent (:mod:`sim.computations`).
* **Records.** :class:`GoalRecord` holds the lifecycle of one id: EXECUTING (or REJECTED) to
  exactly one terminal status, the error code and message, the missed waypoints and the
  feedback frozen when the goal ended. :meth:`GoalRecord.snapshot` gives the
  :class:`fleet.types.GoalState` that ``goal_state`` returns.
* **Preemption.** A new motion goal for a robot ends the goal it was executing ``ABORTED`` with code 0
  and the message ``Goal <old> was preempted by goal <new>.`` (:func:`preempt`).
* **Cancel** is idempotent: :meth:`GoalBook.live` finds the record to cancel, ``None`` for an
  unknown or finished id (then cancel does nothing).
* **Codes.** :data:`BEHAVIOR_CODES`: the UNKNOWN / TIMEOUT / COLLISION_AHEAD / INVALID_INPUT
  codes of Spin, BackUp and DriveOnHeading.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import get_args

import numpy as np

from fleet.errors import BackendError
from fleet.types import (
    COMPUTE_GOAL_KINDS,
    BackUp,
    ComputePathThroughPoses,
    ComputePathToPose,
    DriveOnHeading,
    ErrorCode,
    Feedback,
    FollowPath,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Path,
    Pose2D,
    SmoothPath,
    Spin,
)
from sim.snapshots import make_goal_state

#: The goal types a world executes (one per Nav2 action): the members of :data:`fleet.types.Goal`.
GOAL_TYPES: tuple[type, ...] = get_args(Goal)
#: Finished goals kept per robot for ``goal_state`` (older ones are forgotten). A robot on
#: patrol ends about 170 goals an hour: a limit of thousands was never reached in a soak and
#: the book grew for as long as the fleet drove (docs/performance.md, "Soak"). Clients poll
#: the goal they sent until it ends; Nav2's action servers forget results too (after 15 min).
KEEP_FINISHED = 32
#: The goal statuses by their small-integer code (the codes of the batch status arrays:
#: :meth:`GoalBook.status_codes`, ``sim.simulator.Simulator.goal_table``).
STATUS_CODES: tuple[GoalStatus, ...] = tuple(GoalStatus)
#: ``GoalStatus`` -> its code in :data:`STATUS_CODES`.
STATUS_CODE: dict[GoalStatus, int] = {s: i for i, s in enumerate(STATUS_CODES)}
#: ``TERMINAL[code]``: whether the status of that code is terminal (``TERMINAL[-1]``, no goal
#: or an unknown id, is False).
TERMINAL = np.array([*(s.terminal for s in STATUS_CODES), False], dtype=bool)
#: Code of an id that is unknown (never issued or forgotten) in :meth:`GoalBook.status_codes`.
UNKNOWN_CODE = -1


@dataclass(frozen=True)
class BehaviorCodes:
    """Error codes of one Nav2 behavior action (``invalid`` is ``None`` for Spin)."""

    name: str
    unknown: ErrorCode
    timeout: ErrorCode
    collision: ErrorCode
    invalid: ErrorCode | None


#: Goal kind -> the codes of that behavior action.
BEHAVIOR_CODES: dict[str, BehaviorCodes] = {
    "spin": BehaviorCodes(
        "Spin", ErrorCode.SPIN_UNKNOWN, ErrorCode.SPIN_TIMEOUT, ErrorCode.SPIN_COLLISION_AHEAD, None
    ),
    "backup": BehaviorCodes(
        "BackUp",
        ErrorCode.BACKUP_UNKNOWN,
        ErrorCode.BACKUP_TIMEOUT,
        ErrorCode.BACKUP_COLLISION_AHEAD,
        ErrorCode.BACKUP_INVALID_INPUT,
    ),
    "drive_on_heading": BehaviorCodes(
        "DriveOnHeading",
        ErrorCode.DRIVE_UNKNOWN,
        ErrorCode.DRIVE_TIMEOUT,
        ErrorCode.DRIVE_COLLISION_AHEAD,
        ErrorCode.DRIVE_INVALID_INPUT,
    ),
}


def check_goal(goal: object) -> Goal:
    """``goal`` if it is a goal of :mod:`fleet.types`; else raise
    :class:`~fleet.errors.BackendError` (passing another object is a programming error)."""
    if not isinstance(goal, Goal):
        known = ", ".join(t.__name__ for t in GOAL_TYPES)
        raise BackendError(
            f"send_goal: goal: {type(goal).__name__} is not a navigation goal (one of {known})"
        )
    return goal


def goal_poses(goal: Goal) -> tuple[Pose2D, ...]:
    """The poses of a navigation goal in order; ``()`` for a behavior (Spin, Wait, ...)."""
    if isinstance(goal, NavigateToPose):
        return (goal.pose,)
    if isinstance(goal, (NavigateThroughPoses, FollowWaypoints)):
        return tuple(goal.poses)
    return ()


def is_computation(goal: Goal) -> bool:
    """Whether ``goal`` only computes (plans, smooths, clears costmaps) and so runs beside the
    robot's motion goal (:data:`fleet.types.COMPUTE_GOAL_KINDS`)."""
    return goal.kind in COMPUTE_GOAL_KINDS


def input_poses(goal: Goal) -> Path:
    """Every pose a goal carries (navigation poses, a path, a planner's start and goals), for
    validation."""
    if isinstance(goal, (FollowPath, SmoothPath)):
        return tuple(goal.path)
    if isinstance(goal, ComputePathToPose):
        return (goal.goal,) if goal.start is None else (goal.start, goal.goal)
    if isinstance(goal, ComputePathThroughPoses):
        return tuple(goal.goals) if goal.start is None else (goal.start, *goal.goals)
    return goal_poses(goal)


def reject_reason(goal: Goal) -> str | None:
    """Why a server refuses ``goal`` outright (it ends ``REJECTED``), or ``None``."""
    if isinstance(goal, NavigateThroughPoses) and not goal.poses:
        return "NavigateThroughPoses needs at least one pose."
    for i, pose in enumerate(input_poses(goal)):
        if not (math.isfinite(pose.x) and math.isfinite(pose.y) and math.isfinite(pose.theta)):
            return f"Pose {i} ({pose.x}, {pose.y}, {pose.theta}) is not finite."
    return None


def start_error(goal: Goal) -> tuple[ErrorCode, str] | None:
    """``(code, message)`` of an accepted goal that fails at its start (it ends ``ABORTED``
    at once), or ``None`` if it can run."""
    if isinstance(goal, FollowWaypoints) and not goal.poses:
        return ErrorCode.WAYPOINT_UNKNOWN, "FollowWaypoints got an empty list of waypoints."
    if isinstance(goal, FollowPath) and not goal.path:
        return ErrorCode.INVALID_PATH, "FollowPath got an empty path."
    if isinstance(goal, Spin) and not math.isfinite(goal.target_yaw):
        return ErrorCode.SPIN_UNKNOWN, f"Spin target {goal.target_yaw} rad is not a finite angle."
    if isinstance(goal, (BackUp, DriveOnHeading)):
        d, v = float(goal.distance_m), float(goal.speed_mps)
        if not (math.isfinite(d) and math.isfinite(v) and d > 0 and v > 0):
            codes = BEHAVIOR_CODES[goal.kind]
            assert codes.invalid is not None
            msg = f"{codes.name} needs a positive distance and speed, got {goal.distance_m} m at {goal.speed_mps} m/s."
            return codes.invalid, msg
    return None


class GoalRecord:
    """Lifecycle of one goal id. ``status`` moves from EXECUTING (or REJECTED) to exactly one
    terminal status and never changes again (``terminal`` tells which side it is on). A
    terminal record does not change any more, so its snapshot is made once."""

    __slots__ = (
        "goal_id",
        "kind",
        "goal",
        "namespace",
        "status",
        "terminal",
        "error_code",
        "error_msg",
        "missed",
        "feedback",
        "final",
        "path",
        "on_finish",
    )

    def __init__(self, goal_id: str, goal: Goal, namespace: str) -> None:
        self.goal_id = goal_id
        self.kind = goal.kind
        self.goal = goal
        self.namespace = namespace
        self.status = GoalStatus.EXECUTING
        self.terminal = False
        self.error_code = int(ErrorCode.NONE)
        self.error_msg = ""
        self.missed: tuple[int, ...] = ()
        self.feedback = Feedback()
        self.final: GoalState | None = None
        #: The path a computation goal produced (its result).
        self.path: Path = ()
        #: Called once with the record when it ends (the world's status arrays), or ``None``.
        self.on_finish: Callable[[GoalRecord], None] | None = None

    def finish(self, status: GoalStatus, code: int = 0, msg: str = "") -> None:
        """Move to terminal ``status`` once; later calls are ignored."""
        if self.terminal:
            return
        self.status = status
        self.terminal = status.terminal
        self.error_code = int(code)
        self.error_msg = msg
        if self.on_finish is not None:
            self.on_finish(self)

    def snapshot(self, live: Feedback | None = None) -> GoalState:
        """The goal's state with feedback ``live`` (default: the feedback stored when the goal
        ended)."""
        if live is None and self.terminal:
            if self.final is None:
                self.final = self._state(self.feedback)
            return self.final
        return self._state(live if live is not None else self.feedback)

    def _state(self, feedback: Feedback) -> GoalState:
        return make_goal_state(
            goal_id=self.goal_id,
            kind=self.kind,
            status=self.status,
            feedback=feedback,
            error_code=self.error_code,
            error_msg=self.error_msg,
            missed_waypoints=self.missed,
            path=self.path,
        )


class GoalBook:
    """Every goal of a world by id (see the module docstring for the id rules)."""

    def __init__(self, keep_finished: int = KEEP_FINISHED) -> None:
        self._records: dict[str, GoalRecord] = {}
        self._issued: dict[str, deque[str]] = {}
        self._count: dict[str, int] = {}
        self._keep = keep_finished

    def open(self, namespace: str, goal: object) -> GoalRecord:
        """A new EXECUTING record of ``goal`` for robot ``namespace`` with a fresh id. Raises
        :class:`~fleet.errors.BackendError` (and spends no id) if ``goal`` is not a goal."""
        checked = check_goal(goal)
        n = self._count[namespace] = self._count.get(namespace, 0) + 1
        record = GoalRecord(f"{namespace}#{n}", checked, namespace)
        issued = self._issued.setdefault(namespace, deque())
        self._records[record.goal_id] = record
        issued.append(record.goal_id)
        # forget the oldest finished goal beyond the limit; a live goal (the robot's motion
        # goal, however old) is kept in its place
        while len(issued) > self._keep + 1:
            live: list[str] = []
            while issued and not self._records[issued[0]].terminal:
                live.append(issued.popleft())
            found = bool(issued)
            if found:
                del self._records[issued.popleft()]
            issued.extendleft(reversed(live))
            if not found:
                break
        return record

    def get(self, goal_id: str) -> GoalRecord:
        """The record of ``goal_id``; ``KeyError`` for an id never issued (or forgotten)."""
        return self._records[goal_id]

    def live(self, goal_id: str) -> GoalRecord | None:
        """The record of ``goal_id`` if it is still running, else ``None`` (unknown or finished)."""
        record = self._records.get(goal_id)
        return None if record is None or record.terminal else record

    def status_codes(self, goal_ids: Sequence[str]) -> np.ndarray:
        """The status of each of ``goal_ids`` as an ``int8`` code of :data:`STATUS_CODES`
        (:data:`UNKNOWN_CODE` for an id never issued or forgotten): one call for a whole
        fleet's goals, no snapshot objects built."""
        records = self._records
        code = STATUS_CODE
        return np.fromiter(
            (code[r.status] if (r := records.get(g)) is not None else UNKNOWN_CODE for g in goal_ids),
            dtype=np.int8,
            count=len(goal_ids),
        )

    def records(self) -> Iterator[GoalRecord]:
        """Every record kept, oldest first per robot."""
        return iter(list(self._records.values()))


def preempt(old: GoalRecord, new: GoalRecord, feedback: Feedback) -> None:
    """End ``old`` ABORTED (code 0) with its last ``feedback``, naming the goal ``new`` that
    replaced it."""
    old.feedback = feedback
    old.finish(GoalStatus.ABORTED, 0, f"Goal {old.goal_id} was preempted by goal {new.goal_id}.")


def reject_if_invalid(record: GoalRecord) -> bool:
    """End ``record`` REJECTED if :func:`reject_reason` refuses its goal; return whether it did."""
    reason = reject_reason(record.goal)
    if reason is None:
        return False
    record.finish(GoalStatus.REJECTED, 0, reason)
    return True
