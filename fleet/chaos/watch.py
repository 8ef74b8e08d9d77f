"""What a chaos run sees: the robots' statuses on the bus (:class:`Watch`) and the coordinator's
durable task book (:func:`book_checks`)."""

from __future__ import annotations

import sqlite3
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from fleet.messages import StatusRecord

#: A status older than this (wall s) is not "live" for the done-twice check.
FRESH_S = 1.0
#: A status this many simulated seconds behind the fleet's time comes from a restarted fleet
#: (``fleet run`` starts its clock at 0 again): the elapsed time goes on from there.
RESTART_BACK_S = 5.0
#: Simulated seconds (of the fleet time summed over restarts) between two battery samples.
TIMELINE_EVERY_S = 10.0
#: Battery samples kept per robot (about 3 hours at one every 10 s).
TIMELINE_MAX = 1200
#: The lowest battery fraction a chaos run accepts: below it a robot ran (nearly) flat and the
#: run fails (issue 13's target for a fleet that manages its charging).
MIN_BATTERY = 0.05


class Sample(NamedTuple):
    """One robot at one moment: fleet time elapsed (s), battery (fraction), the agent's mode,
    whether the simulator charges it, its pose (m, ``map``) and the tree's active leaf."""

    t: float
    battery: float
    mode: str
    charging: bool
    x: float
    y: float
    leaf: str


@dataclass
class Watch:
    """What the bus shows: every robot's latest status (and the wall time it came), collisions
    summed across simulator restarts, simulated time elapsed summed across restarts, the
    moments robots drove and the coordinator spoke, the assignments seen on two live robots
    at once, and the batteries (lowest, a timeline, and where and doing what a robot went
    below :data:`MIN_BATTERY`). Callbacks run on Zenoh's thread; readers take the lock."""

    latest: dict[str, tuple[float, StatusRecord]] = field(default_factory=dict)
    collisions: dict[str, int] = field(default_factory=dict)
    collisions_seen: dict[str, int] = field(default_factory=dict)
    last_drive: float = 0.0
    last_control: float = 0.0
    #: (assignment, robot, robot, ...) seen live on two or more robots at the same moment
    shared: set[tuple[str, ...]] = field(default_factory=set)
    #: Simulated seconds the fleet ran, summed over restarts of its clock.
    elapsed: float = 0.0
    #: The lowest battery fraction any robot reported, and which robot.
    min_battery: tuple[float, str] = (1.0, "")
    #: Per robot, a :class:`Sample` every :data:`TIMELINE_EVERY_S` simulated seconds, the
    #: newest :data:`TIMELINE_MAX`.
    timeline: dict[str, deque[Sample]] = field(default_factory=dict)
    #: Per robot whose battery went below :data:`MIN_BATTERY`: where it was and what it did at
    #: its first status below it, and at the last status on which it went into charging mode
    #: before that (``None``: it was not in charging mode then).
    crossed: dict[str, tuple[Sample, Sample | None]] = field(default_factory=dict)
    #: Per robot, the status (as a sample) on which it last went into charging mode.
    _charge_began: dict[str, Sample] = field(default_factory=dict)
    _last_t: float | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_status(self, rec: StatusRecord) -> None:
        now = time.monotonic()
        with self.lock:
            prev = self.latest.get(rec.robot)
            if prev is not None and rec.task_id and rec.distance_m > prev[1].distance_m + 0.05:
                self.last_drive = now
            seen = self.collisions_seen.get(rec.robot, 0)
            if rec.collisions < seen:  # a restarted simulator counts from 0 again
                seen = 0
            self.collisions[rec.robot] = self.collisions.get(rec.robot, 0) + rec.collisions - seen
            self.collisions_seen[rec.robot] = rec.collisions
            self._advance(rec.t)
            if rec.pose is not None:  # before its robot's first state an agent knows no battery
                self._battery(rec)
            self.latest[rec.robot] = (now, rec)
            live: dict[str, list[str]] = {}
            for name, (w, r) in self.latest.items():
                if now - w <= FRESH_S and r.task_id and r.mode not in ("idle", "charging"):
                    live.setdefault(r.task_id, []).append(name)
            for assignment, robots in live.items():
                if len(robots) > 1:
                    self.shared.add((assignment, *sorted(robots)))

    def _advance(self, t: float) -> None:
        # caller holds the lock
        if self._last_t is None or t < self._last_t - RESTART_BACK_S:
            self._last_t = t  # the first status, or a fleet whose clock started again
        elif t > self._last_t:
            self.elapsed += t - self._last_t
            self._last_t = t

    def _battery(self, rec: StatusRecord) -> None:
        # caller holds the lock
        self.min_battery = min(self.min_battery, (rec.battery, rec.robot))
        assert rec.pose is not None
        now = Sample(self.elapsed, rec.battery, rec.mode, rec.charging, rec.pose[0], rec.pose[1], rec.leaf)
        if rec.mode != "charging":
            self._charge_began.pop(rec.robot, None)
        elif rec.robot not in self._charge_began:
            self._charge_began[rec.robot] = now
        if rec.battery < MIN_BATTERY and rec.robot not in self.crossed:
            self.crossed[rec.robot] = (now, self._charge_began.get(rec.robot))
        line = self.timeline.setdefault(rec.robot, deque(maxlen=TIMELINE_MAX))
        if not line or self.elapsed >= line[-1][0] + TIMELINE_EVERY_S:
            line.append(now)

    def on_control(self, _sample: object) -> None:
        with self.lock:
            self.last_control = time.monotonic()

    def forget(self, robot: str) -> None:
        """Drop ``robot``'s latest status (its agent was killed: it is no live robot's)."""
        with self.lock:
            self.latest.pop(robot, None)

    def fleet_elapsed(self) -> float:
        with self.lock:
            return self.elapsed

    def status_since(self, robots: list[str], wall: float) -> bool:
        """Whether every one of ``robots`` reported after the wall time ``wall``."""
        with self.lock:
            return all(r in self.latest and self.latest[r][0] > wall for r in robots)

    def holding(self, wall: float) -> tuple[dict[str, str], set[str]]:
        """Live robots' assignments (robot -> assignment id) and the live robots with none
        that are not charging, at ``wall``."""
        with self.lock:
            live = [(n, r) for n, (w, r) in self.latest.items() if wall - w <= FRESH_S]
        held = {n: r.task_id for n, r in live if r.task_id}
        return held, {n for n, r in live if not r.task_id and r.mode == "idle" and not r.charging}

    def driving(self, wall: float) -> dict[str, str]:
        """Robots with a fresh status on a task at ``wall`` (robot -> assignment)."""
        with self.lock:
            return {
                n: r.task_id
                for n, (w, r) in self.latest.items()
                if wall - w <= FRESH_S and r.task_id and r.mode == "patrol"
            }


def book_checks(
    book: Path, routes: list[str], shared: set[tuple[str, ...]], holding: dict[str, str], idle: set[str]
) -> tuple[list[str], list[str]]:
    """Lost and done-twice tasks, from the task book ``book`` (``tasks.sqlite3``, read only) and
    what the bus shows: ``holding`` the live robots' assignments (robot -> assignment id on its
    status), ``idle`` the live robots with nothing to do, ``shared`` the assignments seen on two
    live robots at once.

    Lost: a config route missing from the book, a task that ended failed or canceled, a task the
    book has on a robot whose status does not carry its assignment, a task queued while a live
    robot stands idle. Done twice: an assignment id used for two tasks, a task completed twice,
    an assignment driven by two live robots at once."""
    db = sqlite3.connect(f"file:{book}?mode=ro", uri=True)
    try:
        tasks = db.execute("SELECT id, name, state, source, robot, assignment FROM tasks").fetchall()
        pairs = db.execute(
            "SELECT DISTINCT assignment, task_id FROM events WHERE assignment IS NOT NULL"
        ).fetchall()
        completed = db.execute(
            "SELECT task_id, COUNT(*) FROM events WHERE event = 'completed' GROUP BY task_id HAVING COUNT(*) > 1"
        ).fetchall()
    finally:
        db.close()
    task_of: dict[str, set[str]] = {}
    for assignment, task_id in pairs:
        task_of.setdefault(assignment, set()).add(task_id)
    twice = [f"assignment {a} used for {sorted(ts)}" for a, ts in task_of.items() if len(ts) > 1]
    twice += [f"{t} completed {n} times" for t, n in completed]
    for a, *robots in shared:
        twice.append(f"{next(iter(task_of.get(a, {a})))} ({a}) driven by {robots} at once")
    names = {name for _, name, _, source, _, _ in tasks if source == "config"}
    lost = [f"route {r} missing from the task book" for r in routes if r not in names]
    for i, name, state, _, robot, assignment in tasks:
        if state in ("failed", "canceled"):
            lost.append(f"{i} ({name}) {state}")
        elif state in ("assigned", "active") and holding.get(robot) != assignment:
            lost.append(f"{i} ({name}) {state} on {robot} ({assignment}), which does not hold it")
        elif state == "queued" and idle:
            lost.append(f"{i} ({name}) queued while {sorted(idle)} stand idle")
    return lost, twice


def crossing_lines(crossed: dict[str, tuple[Sample, Sample | None]]) -> list[str]:
    """One line per robot that went below :data:`MIN_BATTERY` (:attr:`Watch.crossed`): when,
    where and doing what, and since when and where it was in charging mode."""
    out = []
    for robot in sorted(crossed):
        at, began = crossed[robot]
        dock = "on a charger" if at.charging else "not on a charger"
        line = (
            f"{robot} below {MIN_BATTERY:.0%} at t={at.t:.0f} s at ({at.x:.1f}, {at.y:.1f}) m: "
            f"mode {at.mode}, leaf {at.leaf}, {dock}"
        )
        if began is not None:
            line += (
                f"; in charging mode since t={began.t:.0f} s ({at.t - began.t:.0f} s), which began at "
                f"{began.battery:.0%} at ({began.x:.1f}, {began.y:.1f}) m"
            )
        out.append(line)
    return out
