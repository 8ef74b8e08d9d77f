"""Robots as the task service shows them (``GET /api/robots``, ``/api/ws``): one JSON object
per robot from its latest status record and the coordinator's view of its health.

``health`` is ``alive`` (reporting), ``silent`` (no status for more than :data:`SILENT_S`
fleet seconds, not yet declared dead), ``stuck`` (its status says so) or ``dead`` (its
liveliness token is gone, or it was silent for the coordinator's ``status_timeout_s``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from fleet.messages import StatusRecord

if TYPE_CHECKING:
    from fleet.coordination.state import CoordinatorState

#: A robot with no status for this long (fleet s) is ``silent``.
SILENT_S = 1.0


def health_of(rec: StatusRecord, state: CoordinatorState | None, now: float | None) -> str:
    """See the module docstring."""
    v = state.robots.get(rec.robot) if state is not None else None
    if v is not None and not v.alive:
        return "dead"
    if v is not None and v.last_seen is not None and now is not None and now - v.last_seen > SILENT_S:
        return "silent"
    return "stuck" if rec.stuck else "alive"


def robot_dict(rec: StatusRecord, health: str, task: str | None) -> dict[str, Any]:
    """One robot: ``name``, ``state`` (its mode, or ``dead``), ``health``, ``battery`` in [0, 1],
    ``charging``, ``pose`` ``{x, y, theta}`` (``map`` frame, m, rad) or ``None``, ``heading``
    (rad), ``task`` (the task id it works on), ``assignment`` (the wire id), ``leaf``, ``laps``,
    ``distance_m``, ``stuck``, ``t`` (fleet time of the status)."""
    p = rec.pose
    return {
        "name": rec.robot,
        "state": "dead" if health == "dead" else str(rec.mode),
        "mode": str(rec.mode),
        "health": health,
        "battery": round(float(rec.battery), 4),
        "charging": bool(rec.charging),
        "pose": None if p is None else {"x": round(p[0], 3), "y": round(p[1], 3), "theta": round(p[2], 3)},
        "heading": None if p is None else round(p[2], 3),
        "task": task,
        "assignment": rec.task_id,
        "leaf": rec.leaf,
        "laps": int(rec.laps),
        "distance_m": round(float(rec.distance_m), 2),
        "stuck": bool(rec.stuck),
        "t": round(float(rec.t), 3),
    }


def robot_dicts(
    records: Sequence[StatusRecord], state: CoordinatorState | None, tasks: Mapping[str, str]
) -> list[dict[str, Any]]:
    """Every robot's :func:`robot_dict`; ``tasks`` maps assignment ids to task ids."""
    now = max((float(r.t) for r in records), default=None)
    return [
        robot_dict(r, health_of(r, state, now), tasks.get(r.task_id) if r.task_id else None) for r in records
    ]
