"""The tree's side of event-driven ticking (:mod:`fleet.runtime.scheduler`): which trees keep the
:mod:`fleet.wake` contract, and the backend wrapper that records the goals a tree polls."""

from __future__ import annotations

from typing import TYPE_CHECKING

import py_trees

from fleet.navigation import NavigationBackend
from fleet.types import Goal, GoalState, RobotState
from fleet.wake import SENT, Wake

if TYPE_CHECKING:
    from py_trees.behaviour import Behaviour

#: py_trees classes that read nothing but their children's statuses.
_PY_TREES_NODES: tuple[type, ...] = (
    py_trees.composites.Selector,
    py_trees.composites.Sequence,
    py_trees.decorators.Repeat,
    py_trees.decorators.FailureIsSuccess,
    py_trees.decorators.SuccessIsFailure,
    py_trees.decorators.FailureIsRunning,
    py_trees.decorators.SuccessIsRunning,
    py_trees.decorators.RunningIsFailure,
    py_trees.decorators.RunningIsSuccess,
    py_trees.decorators.Inverter,
    py_trees.decorators.OneShot,
    py_trees.decorators.Retry,
)


def wake_aware(root: Behaviour) -> bool:
    """Whether every node of the tree keeps the :mod:`fleet.wake` contract: its class says
    ``wake_aware = True`` itself (not inherited), or it is one of the py_trees composites and
    decorators that read only their children."""
    for node in root.iterate():
        cls = type(node)
        if cls in _PY_TREES_NODES:
            continue
        if cls.__dict__.get("wake_aware") is not True:
            return False
    return True


class WatchedBackend:
    """The tree's view of its robot's backend: every call goes to ``inner``; the status of every
    goal the tree polls, and every goal it sends, are recorded in ``wake``.

    ``held``: the robot state the agent read this period (set by the agent around a tree tick,
    when the world does not move): :meth:`robot_state` returns it instead of reading the same
    state again, until a goal is sent or canceled (which may change it); ``None``: read."""

    def __init__(self, inner: NavigationBackend) -> None:
        self.inner = inner
        self.wake = Wake()
        self.held: RobotState | None = None

    @property
    def namespace(self) -> str:
        return self.inner.namespace

    def send_goal(self, goal: Goal) -> str:
        self.held = None
        gid = self.inner.send_goal(goal)
        self.wake.saw_goal(gid, SENT)
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        state = self.inner.goal_state(goal_id)
        self.wake.saw_goal(goal_id, state.status)
        return state

    def cancel_goal(self, goal_id: str) -> None:
        self.held = None
        self.inner.cancel_goal(goal_id)

    def robot_state(self) -> RobotState:
        held = self.held
        return held if held is not None else self.inner.robot_state()

    def __getattr__(self, name: str) -> object:
        return getattr(self.inner, name)
