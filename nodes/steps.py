"""Leaves that run a task's steps (:class:`fleet.messages.Step`: drive, wait, spin, capture),
with and without traffic management, and the decorator that reports how a task ended.

The robot's blackboard ``steps`` holds the steps of its current go_to, pick, inspection or
park task (``task_id``, ``task_kind``). Progress is kept on the blackboard, so an interrupted
task (battery guard, pause, recovery) resumes at the step it reached: ``step_index`` steps
of task ``steps_task_id`` are done. When the last step is done the leaf writes
``result_id = task_id``, ``result = "succeeded"`` (a pick also counts ``picks_done``) and
clears ``steps``; :class:`ReportFailure` writes ``result = "failed: <why>"`` when the branch
gives up. The agent reports both in its status; the coordinator completes or fails the task.

A ``capture`` step takes no time: the leaf logs it (logger ``nodes.steps``) and moves on; the
coordinator records it in the task's events when ``step_index`` passes it.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import msgspec
import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status

from fleet.messages import Action, Grant, Step
from fleet.navigation import Clock, NavigationBackend
from fleet.traffic.follower import FollowerStatus, TrafficFollower
from fleet.types import Goal, GoalState, GoalStatus, Mode, NavigateToPose, Spin, TaskKind, Wait
from nodes.blackboard import robot_blackboard
from nodes.leaves import GoalAction, describe_failure

logger = logging.getLogger(__name__)

#: Blackboard keys the step leaves use.
STEP_KEYS = (
    "steps",
    "task_id",
    "task_kind",
    "step_index",
    "steps_task_id",
    "result_id",
    "result",
    "picks_done",
    "mode",
    "active_leaf",
    "active_goal",
    "last_error",
)

#: Seconds allowed per radian of a spin step (at least :data:`SPIN_MIN_S`).
SPIN_S_PER_RAD = 3.0
SPIN_MIN_S = 10.0


def step_mode(task_kind: str | None) -> Mode:
    """The mode a robot reports while running steps: ``picking`` for a pick, else ``task``."""
    return Mode.PICKING if task_kind == TaskKind.PICK else Mode.TASK


def action_goal(step: Step) -> Goal | None:
    """The navigation goal of a ``wait`` or ``spin`` step (``None`` for other actions)."""
    if step.action == Action.WAIT:
        return Wait(float(step.duration_s))
    if step.action == Action.SPIN:
        return Spin(float(step.yaw), max(SPIN_MIN_S, abs(step.yaw) * SPIN_S_PER_RAD))
    return None


class _StepProgress:
    """Shared blackboard bookkeeping of the step leaves."""

    def __init__(self, namespace: str, name: str) -> None:
        self.namespace = namespace
        self.bb = robot_blackboard(namespace, name=name, keys=STEP_KEYS)

    def steps(self) -> Sequence[Step]:
        """The current task's steps; resets ``step_index`` when the task changed."""
        bb = self.bb
        if bb.steps_task_id != bb.task_id:
            bb.step_index = 0
            bb.steps_task_id = bb.task_id
        return tuple(bb.steps or ())

    def capture(self, step: Step, backend: NavigationBackend) -> None:
        pose = backend.robot_state().pose
        where = "unknown pose" if pose is None else f"({pose.x:.2f}, {pose.y:.2f}, {pose.theta:.2f})"
        logger.info("%s: capture %r at %s for task %s", self.namespace, step.name, where, self.bb.task_id)

    def advance(self) -> None:
        self.bb.step_index = int(self.bb.step_index) + 1

    def finish(self) -> None:
        """Every step done: report success (a pick also counts ``picks_done``) and clear ``steps``."""
        bb = self.bb
        if bb.task_kind == TaskKind.PICK:
            bb.picks_done = int(bb.picks_done) + 1
        bb.result_id = bb.task_id
        bb.result = "succeeded"
        bb.steps = None


class FollowSteps(GoalAction):
    """Run the blackboard ``steps`` in order on the robot's backend (no traffic management).

    ``drive`` sends ``NavigateToPose(pose)``, ``wait`` ``Wait(duration_s)``, ``spin``
    ``Spin(yaw)``; ``capture`` is logged at once. Starts (or resumes) at ``step_index`` of
    the current task and writes ``mode`` (``picking`` for a pick, else ``task``).

    Returns RUNNING while a step runs (the next step's goal is sent in the tick the previous
    one succeeds), SUCCESS when every step is done (``result`` ``succeeded``, ``steps``
    cleared, see the module docstring), FAILURE when a goal fails (``feedback_message`` says
    why) or there are no steps. Cancel: as :class:`~nodes.leaves.GoalAction` (the executing
    goal is canceled; ``step_index`` stays, so the task resumes at the same step).
    """

    #: Reads only its goal's state (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(self, backend: NavigationBackend, *, name: str = "FollowSteps") -> None:
        super().__init__(name, backend)
        self.progress = _StepProgress(backend.namespace, f"{name}-steps")
        self.blackboards.append(self.progress.bb)
        self._complete = False

    def make_goal(self) -> Goal | None:
        self._complete = False
        bb = self.progress.bb
        if bb.steps is None:
            return None
        bb.mode = step_mode(bb.task_kind)
        return self._next_goal()

    def _next_goal(self) -> Goal | None:
        """The goal of the first step not done (captures on the way are taken); ``None``
        and ``_complete`` set when every step is done."""
        p = self.progress
        steps = p.steps()
        while int(p.bb.step_index) < len(steps):
            step = steps[int(p.bb.step_index)]
            if step.action == Action.CAPTURE:
                p.capture(step, self.backend)
                p.advance()
                continue
            if step.action == Action.DRIVE and step.pose is not None:
                return NavigateToPose(step.pose)
            goal = action_goal(step)
            if goal is not None:
                return goal
            p.advance()  # a step this robot cannot do (a drive without a pose): skipped
        self._complete = True
        return None

    def on_success(self, state: GoalState) -> Status:
        self.progress.advance()
        goal = self._next_goal()
        if goal is not None:
            self.send(goal)
            return Status.RUNNING
        self.progress.finish()
        self.feedback_message = f"steps done ({self.progress.bb.task_id})"
        return Status.SUCCESS

    def update(self) -> Status:
        if self.goal_id is None and self._complete:
            self.progress.finish()
            self.feedback_message = f"steps done ({self.progress.bb.task_id})"
            return Status.SUCCESS
        return super().update()


def cut_grant(grant: Grant, stop: str) -> Grant | None:
    """``grant`` ending at the stop node ``stop``: its nodes up to the first ``stop``
    (``final``), or an empty ``done`` grant if the robot stands on ``stop``; ``None`` if
    ``stop`` is neither in the grant nor its current node (the robot drives the grant as it
    is and the stop lies further on)."""
    if stop in grant.nodes:
        k = grant.nodes.index(stop) + 1
        return msgspec.structs.replace(
            grant,
            nodes=grant.nodes[:k],
            poses=grant.poses[:k],
            horizon=grant.horizon - (len(grant.nodes) - k),
            final=True,
            done=False,
        )
    if grant.current == stop:
        return msgspec.structs.replace(grant, nodes=(), poses=(), final=True, done=True)
    return None


class FollowGrantSteps(Behaviour):
    """Run the blackboard ``steps`` under traffic management.

    A ``drive`` step's target is its traffic roadmap ``node``: the robot follows its grants
    (only those stamped with its ``task_id``) with a
    :class:`~fleet.traffic.follower.TrafficFollower`, stopping at the node even when the
    grant reaches further; ``wait`` and ``spin`` run on the backend where the robot stands
    (it keeps its reservation); ``capture`` is logged. Progress and the result as
    :class:`FollowSteps`.

    Returns RUNNING while driving, waiting for a grant or acting; SUCCESS when every step is
    done; FAILURE when a wait or spin goal fails, or there are no steps. ``terminate`` while
    RUNNING cancels the executing goal.
    """

    #: Its goals are watched; the follower declares the rest (:mod:`fleet.wake`).
    wake_aware = True

    def __init__(self, backend: NavigationBackend, clock: Clock, *, name: str = "FollowGrantSteps") -> None:
        super().__init__(name=name)
        self.backend = backend
        self.clock = clock
        self.progress = _StepProgress(backend.namespace, f"{name}-steps")
        self.grant_bb = robot_blackboard(backend.namespace, name=f"{name}-grant", keys=("grant",))
        self.blackboards += [self.progress.bb, self.grant_bb]
        self.follower = TrafficFollower(backend)
        self._action_id: str | None = None

    def initialise(self) -> None:
        bb = self.progress.bb
        other = bb.active_goal
        if other is not None:
            self.backend.cancel_goal(other)
            bb.active_goal = None
        self.follower = TrafficFollower(self.backend)
        self._action_id = None
        bb.mode = step_mode(bb.task_kind)
        bb.active_leaf = self.name

    def update(self) -> Status:
        p = self.progress
        if p.bb.steps is None:
            self.feedback_message = "no steps"
            return Status.FAILURE
        steps = p.steps()
        while int(p.bb.step_index) < len(steps):
            step = steps[int(p.bb.step_index)]
            if step.action == Action.CAPTURE:
                p.capture(step, self.backend)
                p.advance()
                continue
            status = self._drive(step) if step.action == Action.DRIVE else self._act(step)
            if status is not Status.SUCCESS:
                return status
            p.advance()
        p.bb.active_goal = None
        p.finish()
        self.feedback_message = f"steps done ({p.bb.task_id})"
        return Status.SUCCESS

    def _drive(self, step: Step) -> Status:
        """SUCCESS once the robot stands on the step's node; RUNNING on the way."""
        bb = self.progress.bb
        g: Grant | None = self.grant_bb.grant
        if step.node is None:
            return Status.SUCCESS  # nothing to drive to under traffic management
        if g is None or g.task_id != bb.task_id:
            self.follower.apply(None)  # no grant for this task yet: stand still
            bb.active_goal = None
            self.feedback_message = "waiting for a grant"
            return Status.RUNNING
        cut = cut_grant(g, step.node)
        st = self.follower.apply(cut if cut is not None else g, self.clock.now())
        bb.active_goal = self.follower.goal_id if st is FollowerStatus.DRIVING else None
        self.feedback_message = f"to {step.node}: {st.value}"
        if cut is not None and st is FollowerStatus.ARRIVED:
            self.follower = TrafficFollower(self.backend)
            return Status.SUCCESS
        return Status.RUNNING

    def _act(self, step: Step) -> Status:
        """Run a wait or spin step's goal where the robot stands."""
        bb = self.progress.bb
        if self._action_id is None:
            goal = action_goal(step)
            if goal is None:
                return Status.SUCCESS
            self.follower.apply(None)
            self._action_id = self.backend.send_goal(goal)
            bb.active_goal = self._action_id
        try:
            state = self.backend.goal_state(self._action_id)
        except KeyError:
            state = None
        if state is not None and not state.status.terminal:
            self.feedback_message = f"{step.action} {self._action_id}"
            return Status.RUNNING
        self._action_id = None
        bb.active_goal = None
        if state is not None and state.status is GoalStatus.SUCCEEDED:
            return Status.SUCCESS
        why = "goal lost" if state is None else describe_failure(state)
        self.feedback_message = f"{step.action} failed: {why}"
        bb.last_error = f"{self.name}: {self.feedback_message}"
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        if self.status == Status.RUNNING and new_status == Status.INVALID:
            self.follower.apply(None)
            if self._action_id is not None:
                self.backend.cancel_goal(self._action_id)
                self._action_id = None
            self.progress.bb.active_goal = None


class ReportFailure(py_trees.decorators.Decorator):
    """Pass the child's status through; when it FAILS, give the task up: ``result_id =
    task_id``, ``result = "failed: <last_error>"``, ``steps`` and ``charge_now`` cleared (so
    the branch does not start again), and the agent reports the failure."""

    wake_aware = True  # reads its child's status and the blackboard

    def __init__(self, child: Behaviour, namespace: str, *, name: str = "ReportFailure") -> None:
        super().__init__(name=name, child=child)
        self.bb = robot_blackboard(
            namespace,
            name=name,
            keys=("task_id", "result_id", "result", "steps", "charge_now", "last_error"),
        )
        self.blackboards.append(self.bb)

    def update(self) -> Status:
        status = self.decorated.status
        if status == Status.FAILURE:
            bb = self.bb
            why = str(bb.last_error or self.decorated.feedback_message or "gave up")
            bb.result_id = bb.task_id
            bb.result = f"failed: {why}"
            bb.steps = None
            bb.charge_now = False
            self.feedback_message = str(bb.result)
        return status
