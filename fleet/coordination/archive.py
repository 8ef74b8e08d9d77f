"""What a long run's old assignments add up to, once they are no longer kept one by one.

The task book (:class:`fleet.coordination.tasks.TaskBook`) records every assignment and every
reassignment. A fleet that keeps driving makes about one of each per simulated second at 200
robots (robots going to charge hand their routes over), so over hours these logs grew without
bound. The book keeps the newest :data:`KEEP_RECORDS` of each; an older assignment is
*archived* once it ended at least :data:`ARCHIVE_AFTER_S` simulated seconds ago (until then
a robot may still report laps under its id: a lap driven is a lap driven). An archived
assignment is gone from ``records`` and ``by_id`` (a status carrying its id is ignored, as an
unknown id) and its counts are added to an :class:`Archive`, so that every total the
coordinator reports (laps, laps by route and by robot, patrols and picks assigned and
completed, reassignments) stays the same as if nothing had been forgotten.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from fleet.coordination.views import Assignment
from fleet.types import TaskKind

#: Newest assignments (and reassignments) kept one by one in the task book.
KEEP_RECORDS = 2048
#: An ended assignment is archived no sooner than this (simulated s) after it ended.
ARCHIVE_AFTER_S = 600.0


@dataclass
class Archive:
    """Totals of the archived assignments (see the module docstring); ``reassignments``
    counts the reassignment records dropped from the book's log."""

    assigned: Counter[TaskKind] = field(default_factory=Counter)
    completed: Counter[TaskKind] = field(default_factory=Counter)
    laps: int = 0
    laps_by_route: Counter[str] = field(default_factory=Counter)
    laps_by_robot: Counter[str] = field(default_factory=Counter)
    picks_by_robot: Counter[str] = field(default_factory=Counter)
    reassignments: int = 0

    def add(self, a: Assignment) -> None:
        """Count the ended assignment ``a`` in."""
        self.assigned[a.kind] += 1
        if a.completed:
            self.completed[a.kind] += 1
            if a.kind is TaskKind.PICK:
                self.picks_by_robot[a.robot] += 1
        if a.kind is TaskKind.PATROL:
            self.laps += a.laps
            self.laps_by_route[a.name] += a.laps
            self.laps_by_robot[a.robot] += a.laps


def split_old(records: list[Assignment], now: float) -> tuple[list[Assignment], list[Assignment]]:
    """``(kept, archived)``: of ``records`` (oldest first) beyond the newest
    :data:`KEEP_RECORDS`, those that ended :data:`ARCHIVE_AFTER_S` or more before ``now`` are
    archived; the rest are kept in order."""
    cut = len(records) - KEEP_RECORDS
    kept: list[Assignment] = []
    old: list[Assignment] = []
    for i, a in enumerate(records):
        if i < cut and a.ended is not None and now - a.ended >= ARCHIVE_AFTER_S:
            old.append(a)
        else:
            kept.append(a)
    return kept, old
