"""A task's lifecycle as users see it, and how the task book reports every change of it.

States (:class:`TaskState`)::

    queued -> assigned -> active -> completed | failed | canceled
       ^         |           |
       +---------+-----------+   taken back (robot dead, stuck, charging): queued again

* ``queued``: waiting for a robot (also after it was taken back from one);
* ``assigned``: handed to a robot under a fresh assignment id; the robot has not yet
  reported executing it;
* ``active``: the robot's status carries the assignment id;
* ``completed``: done (a pick dropped, a go_to reached, every inspection step done, the
  laps of an N-lap patrol driven, a charge to ``battery.resume``);
* ``failed``: the robot gave the task up (its tree failed after every recovery), or a
  restored task no longer fits the config;
* ``canceled``: canceled by a user (queued or held).

The last three are terminal: a task in one of them is never handed out again. The
:class:`~fleet.coordination.tasks.TaskBook` tells a :class:`TaskListener` (the task service,
which keeps the durable store) about every transition, on the coordinator's thread.
"""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from fleet.coordination.views import Assignment


class TaskState(enum.StrEnum):
    """Where a task is in its lifecycle (see the module docstring)."""

    QUEUED = "queued"
    ASSIGNED = "assigned"
    ACTIVE = "active"
    COMPLETED = "completed"
    FAILED = "failed"
    CANCELED = "canceled"

    @property
    def terminal(self) -> bool:
        return self in TERMINAL


#: States a task never leaves.
TERMINAL = frozenset({TaskState.COMPLETED, TaskState.FAILED, TaskState.CANCELED})


class TaskListener(Protocol):
    """Told about every transition of a task (``name`` is its name in the book); times are
    seconds of the fleet clock. Called on the coordinator's thread; keep it quick."""

    def assigned(self, name: str, a: Assignment, now: float) -> None:
        """queued -> assigned: ``a`` is the new assignment (fresh id, robot)."""
        ...

    def started(self, name: str, a: Assignment, now: float) -> None:
        """assigned -> active: the robot reported executing ``a``."""
        ...

    def progressed(self, name: str, a: Assignment, now: float, laps: int, note: str) -> None:
        """The held task moved on: ``laps`` in total over its assignments, ``a.steps_done``
        steps of this assignment, ``note`` what happened (a capture, a lap) or ``""``."""
        ...

    def released(self, name: str, a: Assignment, now: float, reason: str) -> None:
        """assigned/active -> queued: taken back from ``a.robot`` for ``reason``."""
        ...

    def finished(self, name: str, a: Assignment | None, now: float, state: TaskState, message: str) -> None:
        """-> completed / failed / canceled (``a`` the last assignment, ``None`` if the task
        was never handed out)."""
        ...
