"""Action leaves: one py_trees behaviour per navigation action, talking only to a
:class:`~fleet.navigation.NavigationBackend`.

Every action leaf follows one contract (:class:`GoalAction`):

* ``initialise`` builds the goal (a static value, or a callable evaluated now, e.g. the
  route or the charger pose from the blackboard), cancels the goal another leaf of the same
  robot left outstanding (blackboard ``active_goal``), sends the goal with
  ``backend.send_goal`` and keeps its id. If the goal cannot be built (the callable
  returned ``None``) nothing is sent and the next ``update`` returns FAILURE.
* ``update`` polls ``backend.goal_state(id)``: PENDING / EXECUTING / CANCELING -> RUNNING,
  SUCCEEDED -> SUCCESS, ABORTED / REJECTED / CANCELED -> FAILURE with ``feedback_message``
  carrying the status, the error code and the error message.
* ``terminate`` cancels the goal only when the leaf was RUNNING and is being interrupted
  (``terminate(INVALID)``). py_trees also calls ``terminate(INVALID)`` on leaves that have
  already finished; those goals are left alone.

Each leaf keeps the last :class:`~fleet.types.GoalState` it saw (``last_state``), its goal id
(``goal_id``) and writes its name to the robot's blackboard key ``active_leaf`` (and its
``mode``, if given) when it starts; a failure message also goes to ``last_error``.

Leaves never read the wall clock; time-outs are the backend's (``time_allowance_s``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TypeAlias, TypeVar, cast

import py_trees
from py_trees.common import Status

from fleet.navigation import Clock, NavigationBackend
from fleet.types import (
    COMPUTE_GOAL_KINDS,
    BackUp,
    ClearCostmaps,
    Costmap,
    DriveOnHeading,
    ErrorCode,
    FollowWaypoints,
    Goal,
    GoalState,
    GoalStatus,
    Mode,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
)
from fleet.wake import wake_of
from nodes.blackboard import robot_blackboard

T = TypeVar("T")
#: A value given statically or computed when the leaf starts (``None`` = not available).
Source: TypeAlias = T | Callable[[], T | None]

_RUNNING_STATES = (GoalStatus.PENDING, GoalStatus.EXECUTING, GoalStatus.CANCELING)


def resolve(source: Source[T]) -> T | None:
    """The value of ``source``: call it if it is callable, else return it."""
    if callable(source):
        value: T | None = source()
        return value
    return source


def describe_failure(state: GoalState) -> str:
    """``"ABORTED code=105 (FAILED_TO_MAKE_PROGRESS): <error_msg>"`` for a failed goal."""
    try:
        code_name = ErrorCode(state.error_code).name
    except ValueError:
        code_name = "UNKNOWN"
    msg = f"{state.status.name} code={state.error_code} ({code_name})"
    return f"{msg}: {state.error_msg}" if state.error_msg else msg


class GoalAction(py_trees.behaviour.Behaviour):
    """Send one navigation goal, poll it, cancel it when interrupted.

    Args:
        name: behaviour name (also written to the blackboard ``active_leaf``).
        backend: the robot's navigation backend; its ``namespace`` is the blackboard
            namespace of the leaf.
        goal: the goal, or a callable returning it (or ``None``) evaluated in ``initialise``.
        mode: if given, written to the blackboard ``mode`` when the leaf starts
            (:class:`fleet.types.Mode`).

    Returns (from ``update``): RUNNING while the goal is PENDING / EXECUTING / CANCELING;
    SUCCESS when it SUCCEEDED; FAILURE when it was ABORTED, REJECTED or CANCELED, when the
    backend does not know the id, or when no goal could be built. ``feedback_message``
    carries the reason.

    Cancel: ``terminate(INVALID)`` while RUNNING calls ``backend.cancel_goal(goal_id)``; the
    goal ends CANCELED and the robot stops.

    Event-driven ticking (:mod:`fleet.wake`): the leaf reads only its goal's state, which the
    scheduler watches; each subclass that keeps it so says ``wake_aware = True`` itself (the
    scheduler does not inherit the mark).
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        name: str,
        backend: NavigationBackend,
        goal: Source[Goal] | None = None,
        *,
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name=name)
        self.backend = backend
        self.namespace = backend.namespace
        self._goal_source = goal
        self.mode = mode
        self.blackboard = robot_blackboard(
            backend.namespace, name=name, keys=("active_leaf", "active_goal", "last_error", "mode")
        )
        self.blackboards.append(self.blackboard)
        #: Id of the goal sent by the last ``initialise`` (``None`` if none was sent).
        self.goal_id: str | None = None
        #: The goal sent by the last ``initialise``.
        self.goal: Goal | None = None
        #: The last goal state polled (feedback, error code and message).
        self.last_state: GoalState | None = None
        #: Number of goals this leaf has sent.
        self.goals_sent = 0
        #: Number of goals this leaf has canceled on interruption.
        self.cancels = 0
        self._no_goal_reason = ""

    # -- hooks for subclasses -------------------------------------------------------------

    def make_goal(self) -> Goal | None:
        """Build the goal to send (default: evaluate the ``goal`` argument)."""
        if self._goal_source is None:
            return None
        return cast("Goal | None", resolve(self._goal_source))

    def on_state(self, state: GoalState) -> None:
        """Called with every polled state (before the status is decided)."""

    def on_success(self, state: GoalState) -> Status:
        """Called when the goal SUCCEEDED; returns the leaf's status (default SUCCESS)."""
        return Status.SUCCESS

    # -- py_trees lifecycle -----------------------------------------------------------

    def initialise(self) -> None:
        self.goal_id = None
        self.goal = None
        self.last_state = None
        self._no_goal_reason = ""
        bb = self.blackboard
        bb.active_leaf = self.name
        if self.mode is not None:
            bb.mode = self.mode
        try:
            goal = self.make_goal()
        except KeyError as exc:  # a blackboard key that does not exist (yet)
            goal = None
            self._no_goal_reason = f"cannot build the goal: {exc}"
        if goal is None:
            self._no_goal_reason = self._no_goal_reason or "no goal available"
            return
        self.send(goal)

    def send(self, goal: Goal) -> str:
        """Cancel the robot's outstanding motion goal (if another leaf left one), send ``goal``
        and make it this leaf's goal. Returns the new id. A computation goal (a plan, a
        smoothing, a costmap clearing: :data:`fleet.types.COMPUTE_GOAL_KINDS`) runs beside
        the robot's motion goal: it cancels nothing and is not the ``active_goal``."""
        bb = self.blackboard
        motion = goal.kind not in COMPUTE_GOAL_KINDS
        previous = bb.active_goal
        if motion and previous is not None and previous != self.goal_id:
            self.backend.cancel_goal(previous)
        self.goal = goal
        self.goal_id = self.backend.send_goal(goal)
        self.last_state = None
        self.goals_sent += 1
        if motion:
            bb.active_goal = self.goal_id
        self.feedback_message = f"sent {goal.kind} {self.goal_id}"
        return self.goal_id

    def update(self) -> Status:
        if self.goal_id is None:
            return self._fail(self._no_goal_reason or "no goal sent")
        try:
            state = self.backend.goal_state(self.goal_id)
        except KeyError:
            return self._fail(f"backend does not know goal {self.goal_id}")
        self.last_state = state
        self.on_state(state)
        if state.status in _RUNNING_STATES:
            self.feedback_message = f"{state.status.name.lower()} {self.goal_id}"
            return Status.RUNNING
        if state.status is GoalStatus.SUCCEEDED:
            self.feedback_message = f"succeeded {self.goal_id}"
            return self.on_success(state)
        return self._fail(describe_failure(state))

    def _fail(self, message: str) -> Status:
        self.feedback_message = message
        self.blackboard.last_error = f"{self.name}: {message}"
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        # self.status is still the status of the previous tick here: RUNNING means a goal
        # of ours is outstanding; anything else (SUCCESS, FAILURE, INVALID) means it is not.
        if new_status is Status.INVALID and self.status is Status.RUNNING and self.goal_id is not None:
            self.backend.cancel_goal(self.goal_id)
            self.cancels += 1
            self.feedback_message = f"canceled {self.goal_id}"
        if self.goal_id is not None and self.blackboard.active_goal == self.goal_id:
            self.blackboard.active_goal = None


class NavigateToPoseAction(GoalAction):
    """Drive to a pose (Nav2 ``navigate_to_pose``).

    Goal: ``NavigateToPose(pose)`` with ``pose`` (``map`` frame) given statically or by a
    callable evaluated when the leaf starts (e.g. ``read_key(ns, "charger")``); ``None`` means
    no goal and the leaf fails. Statuses and cancel as :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        pose: Source[Pose2D],
        *,
        name: str = "NavigateToPose",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._pose = pose

    def make_goal(self) -> Goal | None:
        pose = resolve(self._pose)
        return None if pose is None else NavigateToPose(pose)


class NavigateThroughPosesAction(GoalAction):
    """Drive through poses in order (Nav2 ``navigate_through_poses``).

    Goal: ``NavigateThroughPoses(poses)``, static or from a callable evaluated when the leaf
    starts; ``None`` or an empty sequence means no goal and the leaf fails. Statuses and
    cancel as :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        poses: Source[Sequence[Pose2D]],
        *,
        name: str = "NavigateThroughPoses",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._poses = poses

    def make_poses(self) -> Sequence[Pose2D] | None:
        """The poses to drive through (default: evaluate the ``poses`` argument)."""
        return resolve(self._poses)

    def make_goal(self) -> Goal | None:
        poses = self.make_poses()
        if not poses:
            return None
        return NavigateThroughPoses(tuple(poses))


class FollowWaypointsAction(GoalAction):
    """Visit waypoints in order (Nav2 ``follow_waypoints``).

    Goal: ``FollowWaypoints(poses)``, static or from a callable. The backend skips a waypoint
    it cannot reach and still SUCCEEDS; the missed indices are in
    ``last_state.missed_waypoints`` and in ``feedback_message``. Statuses and cancel as
    :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        poses: Source[Sequence[Pose2D]],
        *,
        name: str = "FollowWaypoints",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._poses = poses

    def make_goal(self) -> Goal | None:
        poses = resolve(self._poses)
        if poses is None:
            return None
        return FollowWaypoints(tuple(poses))

    def on_success(self, state: GoalState) -> Status:
        if state.missed_waypoints:
            self.feedback_message = (
                f"succeeded {self.goal_id}, missed waypoints {list(state.missed_waypoints)}"
            )
        return Status.SUCCESS


class SpinAction(GoalAction):
    """Rotate in place (Nav2 ``spin``).

    Goal: ``Spin(target_yaw, time_allowance_s)``; ``target_yaw`` in radians, signed
    (counter-clockwise positive). FAILURE with ``SPIN_TIMEOUT`` if it takes longer than the
    allowance. Statuses and cancel as :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        target_yaw: Source[float] = math.pi / 2,
        *,
        time_allowance_s: float = 10.0,
        name: str = "Spin",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._yaw = target_yaw
        self.time_allowance_s = time_allowance_s

    def make_goal(self) -> Goal | None:
        yaw = resolve(self._yaw)
        return None if yaw is None else Spin(float(yaw), self.time_allowance_s)


class BackUpAction(GoalAction):
    """Drive straight backwards (Nav2 ``backup``).

    Goal: ``BackUp(distance_m, speed_mps, time_allowance_s)`` (both positive). FAILURE with
    ``BACKUP_COLLISION_AHEAD`` when something is behind the robot, ``BACKUP_TIMEOUT`` or
    ``BACKUP_INVALID_INPUT``. Statuses and cancel as :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        distance_m: Source[float] = 0.3,
        speed_mps: float = 0.15,
        *,
        time_allowance_s: float = 10.0,
        name: str = "BackUp",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._distance = distance_m
        self.speed_mps = speed_mps
        self.time_allowance_s = time_allowance_s

    def make_goal(self) -> Goal | None:
        d = resolve(self._distance)
        return None if d is None else BackUp(float(d), self.speed_mps, self.time_allowance_s)


class DriveOnHeadingAction(GoalAction):
    """Drive straight forwards (Nav2 ``drive_on_heading``).

    Goal: ``DriveOnHeading(distance_m, speed_mps, time_allowance_s)``. FAILURE with
    ``DRIVE_COLLISION_AHEAD``, ``DRIVE_TIMEOUT`` or ``DRIVE_INVALID_INPUT``. Statuses and
    cancel as :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        distance_m: Source[float],
        speed_mps: float = 0.1,
        *,
        time_allowance_s: float = 10.0,
        name: str = "DriveOnHeading",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._distance = distance_m
        self.speed_mps = speed_mps
        self.time_allowance_s = time_allowance_s

    def make_goal(self) -> Goal | None:
        d = resolve(self._distance)
        return None if d is None else DriveOnHeading(float(d), self.speed_mps, self.time_allowance_s)


class ClearCostmapsAction(GoalAction):
    """Clear the robot's learned obstacles (Nav2's ``ClearEntireCostmap`` services, as the
    ClearingActions of Nav2's navigator trees do before their recoveries).

    Goal: ``ClearCostmaps(which)`` (``global``, ``local`` or ``both``; the static map stays).
    SUCCESS once cleared; FAILURE where the backend has no costmaps to clear (SUMO rejects
    the goal). Statuses and cancel as :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        which: Costmap = Costmap.BOTH,
        *,
        name: str = "ClearCostmaps",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._which = which

    def make_goal(self) -> Goal | None:
        return ClearCostmaps(self._which)


class WaitAction(GoalAction):
    """Stand still (Nav2 ``wait``).

    Goal: ``Wait(duration_s)``, static or from a callable (e.g. a pick's dwell time). The
    backend times the wait on its own clock, never the wall clock. Statuses and cancel as
    :class:`GoalAction`.
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(
        self,
        backend: NavigationBackend,
        duration_s: Source[float] = 5.0,
        *,
        name: str = "Wait",
        mode: Mode | None = None,
    ) -> None:
        super().__init__(name, backend, mode=mode)
        self._duration = duration_s

    def make_goal(self) -> Goal | None:
        d = resolve(self._duration)
        return None if d is None else Wait(float(d))


class Charge(py_trees.behaviour.Behaviour):
    """Stand on a charger until the battery reaches ``resume``.

    Sends no goal. Returns RUNNING while the robot is charging (``robot_state().charging``)
    and the battery is below ``resume``, and during the first ``grace_s`` seconds (of the
    injected ``clock``) of any period in which it is not charging (the robot may still be
    settling on the charger); SUCCESS once the battery is at or above ``resume``; FAILURE
    when it has not been charging for more than ``grace_s`` seconds (not on a charger).
    Writes ``mode = Mode.CHARGING`` and ``active_leaf`` when it starts. Cancel: nothing to
    cancel; the robot simply stays where it is.
    """

    def __init__(
        self,
        backend: NavigationBackend,
        clock: Clock,
        resume: float,
        *,
        grace_s: float = 3.0,
        name: str = "Charge",
    ) -> None:
        super().__init__(name=name)
        self.backend = backend
        self.clock = clock
        self.resume = resume
        self.grace_s = grace_s
        self.blackboard = robot_blackboard(
            backend.namespace, name=name, keys=("active_leaf", "mode", "last_error")
        )
        self.blackboards.append(self.blackboard)
        self._not_charging_since: float | None = None

    def initialise(self) -> None:
        self._not_charging_since = None
        self.blackboard.active_leaf = self.name
        self.blackboard.mode = Mode.CHARGING

    wake_aware = True

    def update(self) -> Status:
        state = self.backend.robot_state()
        if state.battery >= self.resume:
            self.feedback_message = f"charged to {state.battery:.2f}"
            return Status.SUCCESS
        now = self.clock.now()
        wake = wake_of(self.backend)
        if wake is not None:  # the charging flag is watched for every robot
            wake.battery_at_least(self.resume)
        if state.charging:
            self._not_charging_since = None
            self.feedback_message = f"charging {state.battery:.2f} -> {self.resume:.2f}"
            return Status.RUNNING
        if self._not_charging_since is None:
            self._not_charging_since = now
        if wake is not None:
            wake.at(self._not_charging_since + self.grace_s)
        waited = now - self._not_charging_since
        if waited > self.grace_s:
            self.feedback_message = f"not charging for {waited:.1f} s (not on a charger?)"
            self.blackboard.last_error = f"{self.name}: {self.feedback_message}"
            return Status.FAILURE
        self.feedback_message = f"waiting for the charger ({waited:.1f} s)"
        return Status.RUNNING


class Idle(py_trees.behaviour.Behaviour):
    """The lowest-priority branch: nothing to do.

    Sends no goal; always RUNNING. Writes ``mode = Mode.IDLE``, ``active_leaf`` and
    ``route_progress = 0`` when it starts. Cancel: nothing to cancel.
    """

    def __init__(self, namespace: str, *, name: str = "Idle") -> None:
        super().__init__(name=name)
        self.blackboard = robot_blackboard(
            namespace, name=name, keys=("active_leaf", "mode", "route_progress")
        )
        self.blackboards.append(self.blackboard)

    def initialise(self) -> None:
        self.blackboard.active_leaf = self.name
        self.blackboard.mode = Mode.IDLE
        self.blackboard.route_progress = 0.0

    wake_aware = True

    def update(self) -> Status:
        self.feedback_message = "idle"
        return Status.RUNNING


class CompletePick(py_trees.behaviour.Behaviour):
    """Mark the current pick done: ``picks_done += 1`` and ``pick = None``.

    Sends no goal; SUCCESS at once. Cancel: nothing to cancel.
    """

    def __init__(self, namespace: str, *, name: str = "CompletePick") -> None:
        super().__init__(name=name)
        self.blackboard = robot_blackboard(namespace, name=name, keys=("pick", "picks_done", "active_leaf"))
        self.blackboards.append(self.blackboard)

    def update(self) -> Status:
        bb = self.blackboard
        bb.picks_done = int(bb.picks_done) + 1
        bb.pick = None
        bb.active_leaf = self.name
        self.feedback_message = f"picks done: {bb.picks_done}"
        return Status.SUCCESS
