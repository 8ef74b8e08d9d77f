"""The task service's records: one :class:`TaskRecord` per task (what ``GET /api/tasks/{id}``
returns) and one :class:`TaskEvent` per change of it (what ``/api/ws`` and the Zenoh
``fleet/service/events/<id>`` publications carry).

Times: ``*_at`` fields are Unix wall time (s) of the coordinator's machine, written as ISO
8601 in JSON; ``t`` is the fleet clock (simulated seconds, restarting at 0 with every run).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from typing import Any

from fleet.coordination.lifecycle import TaskState

#: Where a task came from: the fleet config, or submitted at runtime (API, CLI, bus, client).
SOURCES = ("config", "submitted")


def iso(t: float | None) -> str | None:
    """``2026-11-24T07:00:11.123Z`` for a Unix time, ``None`` for ``None``."""
    if t is None:
        return None
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass
class TaskRecord:
    """One task as the service keeps it (mirrored in the durable store).

    ``id`` (``t-0001``, never reused, across restarts too); ``name`` its name in the
    coordinator's task book (a config route's or pick's name, else the id); ``kind``;
    ``source`` (:data:`SOURCES`); ``spec`` the task as submitted (JSON values); ``priority``;
    ``only`` the one robot allowed (``None``: any); ``state``; ``robot`` the robot holding
    it, or the last one that did; ``assignment`` the id of that hand-over (the wire's
    ``task_id``); ``attempts`` hand-overs so far; ``laps`` laps driven (patrols);
    ``steps_done`` / ``steps_total`` of the current hand-over; ``message`` why it failed or
    who canceled it; ``submitted_by``; times (see the module docstring).
    """

    id: str
    name: str
    kind: str
    source: str
    spec: dict[str, Any]
    priority: int = 0
    only: str | None = None
    state: TaskState = TaskState.QUEUED
    robot: str | None = None
    assignment: str | None = None
    attempts: int = 0
    laps: int = 0
    steps_done: int = 0
    steps_total: int = 0
    message: str = ""
    submitted_by: str = ""
    created_at: float = 0.0
    assigned_at: float | None = None
    started_at: float | None = None
    ended_at: float | None = None
    updated_at: float = 0.0
    cancel_requested: bool = field(default=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The JSON of the HTTP API (``docs/service.md``)."""
        return {
            "id": self.id,
            "kind": self.kind,
            "state": self.state.value,
            "robot": self.robot,
            "name": self.name,
            "source": self.source,
            "priority": self.priority,
            "only_robot": self.only,
            "assignment": self.assignment,
            "attempts": self.attempts,
            "laps": self.laps,
            "steps_done": self.steps_done,
            "steps_total": self.steps_total,
            "message": self.message,
            "submitted_by": self.submitted_by,
            "created_at": iso(self.created_at),
            "assigned_at": iso(self.assigned_at),
            "started_at": iso(self.started_at),
            "ended_at": iso(self.ended_at),
            "updated_at": iso(self.updated_at),
            "cancel_requested": self.cancel_requested,
            "spec": self.spec,
        }


@dataclass(frozen=True)
class TaskEvent:
    """One change of a task: ``event`` is ``queued``, ``assigned``, ``active``, ``progress``,
    ``requeued``, ``completed``, ``failed``, ``canceled`` or ``restored``; ``text`` says more;
    ``seq`` orders every event of the service; ``wall`` Unix time, ``t`` fleet time."""

    seq: int
    task_id: str
    event: str
    state: str
    robot: str | None
    assignment: str | None
    text: str
    wall: float
    t: float

    def to_dict(self) -> dict[str, Any]:
        return {
            "seq": self.seq,
            "task_id": self.task_id,
            "event": self.event,
            "state": self.state,
            "robot": self.robot,
            "assignment": self.assignment,
            "text": self.text,
            "at": iso(self.wall),
            "t": self.t,
        }
