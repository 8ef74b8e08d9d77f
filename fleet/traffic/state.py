"""What the traffic manager knows: one :class:`TrackedRobot` per robot (its pose and
liveness, its course along its path, its wait for right of way) and the fleet-wide
bookkeeping every part of the manager shares (:class:`TrafficState`), with the few
operations they all use: release and wake, drop claims, wait accounting, priority.

The parts of the manager (:mod:`~fleet.traffic.paths`, :mod:`~fleet.traffic.grants`,
:mod:`~fleet.traffic.tracking`, :mod:`~fleet.traffic.failures`,
:mod:`~fleet.traffic.deadlocks`) are functions over a :class:`TrafficState`;
:class:`~fleet.traffic.manager.TrafficManager` is the public face. Time is passed in (s)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from fleet.errors import TrafficError
from fleet.traffic.params import TrafficParams
from fleet.traffic.reservations import ReservationTable, Resource
from fleet.traffic.roads import RoadIndex

#: At most this many entries stay in :attr:`TrafficMetrics.events`; the older half is dropped
#: when it is exceeded.
MAX_EVENTS = 2000


@dataclass
class TrafficMetrics:
    """Counters of the manager (fleet totals). Per-robot waits: ``TrafficManager.wait_stats``.

    ``events``: ``(time s, message)`` of deadlocks, resolutions and deaths, bounded by
    :data:`MAX_EVENTS`."""

    wait_events: int = 0
    wait_time_s: float = 0.0
    deadlocks_detected: int = 0
    deadlocks_resolved: int = 0
    deadlocks_unresolved: int = 0
    reroutes: int = 0
    sidesteps: int = 0
    nudges: int = 0
    deaths: int = 0
    dead_reroutes: int = 0
    events: list[tuple[float, str]] = field(default_factory=list)


class TrackedRobot:
    """One robot as the manager sees it. One flat record on purpose: the manager reads
    several of its parts for every robot every cycle, and one object per robot keeps that
    loop measurably cheaper than three (``bench/bench_traffic.py``). Its slots, by part:

    *Pose and liveness.* ``x, y``: latest position (m, ``map`` frame), ``last_update``:
    when it came (s); ``alive``; ``prog_x, prog_y, prog_t``: where and
    when it last made progress; ``occupied``: what it keeps while dead. ``name``; ``rank``:
    registration order (breaks priority ties).

    *Course: its path and how far it is driven and granted.* ``path``: node names from the
    node it last reached onwards (older nodes are trimmed); ``must``: per node, whether
    detours must keep it; ``cum``: cumulative length (m) along ``path``. ``cur``: index of
    the node last reached; ``g``: index of the last granted node (``g >= cur``).
    ``offset``: absolute index of ``path[0]`` within path ``path_id``. ``loop``: ``(nodes,
    must)`` of a looped path (appended lap by lap), else ``None``. ``must_passed`` /
    ``passed``: must-visit nodes reached (laps) and nodes reached. ``back``: held nodes that
    may be behind the robot (released by distance). ``tried_t``: when the manager last tried
    to extend its grant.

    *Wait: for right of way, and priority.* ``wait_since``: when the current wait began
    (``None``: not waiting); ``wait_total`` / ``wait_events``: finished waits (s, count).
    ``blockers``: robots it waits for; ``blocked_on``: the resources of the block it asked
    for; ``blocked_since``: since when ``blockers`` are the same. ``claims``: resources it
    claimed after starving. ``yields``: times it gave way; ``yield_to``: robot -> (resources
    it leaves to that robot, until when). ``base_priority``: set by the caller (higher goes
    first). ``next_reroute``: not before this time is it rerouted around a dead or parked
    robot again. ``detour_m``: set by the caller for a robot that cannot afford a long way
    round (one short of energy on its way to a charger): a detour around a dead robot may
    then be at most this much (m) longer than its way, else it waits, and after stepping
    aside it comes back the shortest way, against the flow if need be (``None``: any detour,
    with the flow).
    """

    __slots__ = (
        # pose and liveness
        "name",
        "rank",
        "alive",
        "x",
        "y",
        "last_update",
        "prog_x",
        "prog_y",
        "prog_t",
        "occupied",
        # course
        "path",
        "must",
        "cum",
        "offset",
        "cur",
        "g",
        "path_id",
        "loop",
        "must_passed",
        "passed",
        "back",
        "tried_t",
        # wait
        "wait_since",
        "wait_total",
        "wait_events",
        "blockers",
        "blocked_on",
        "blocked_since",
        "claims",
        "yields",
        "yield_to",
        "base_priority",
        "next_reroute",
        "detour_m",
    )

    def __init__(self, name: str, rank: int, now: float) -> None:
        self.name = name
        self.rank = rank
        self.alive = True
        self.x = 0.0
        self.y = 0.0
        self.last_update = now
        self.prog_x = 0.0
        self.prog_y = 0.0
        self.prog_t = now
        self.occupied: frozenset[Resource] = frozenset()
        self.path: list[str] = []
        self.must: list[bool] = []
        self.cum: list[float] = []
        self.offset = 0
        self.cur = 0
        self.g = 0
        self.path_id = 0
        self.loop: tuple[list[str], list[bool]] | None = None
        self.must_passed = 0
        self.passed = 0
        self.back: set[str] = set()
        self.tried_t = -math.inf
        self.wait_since: float | None = None
        self.wait_total = 0.0
        self.wait_events = 0
        self.blockers: set[str] = set()
        self.blocked_on: set[Resource] = set()
        self.blocked_since = now
        self.claims: set[Resource] = set()
        self.yields = 0
        self.yield_to: dict[str, tuple[frozenset[Resource], float]] = {}
        self.base_priority = 0.0
        self.next_reroute = -math.inf
        self.detour_m: float | None = None

    @property
    def parked(self) -> bool:
        """Alive, standing at the end of its path (no grant ahead, nothing left to drive)."""
        return self.alive and self.cur == self.g and self.cur >= len(self.path) - 1


class TrafficState:
    """The manager's shared bookkeeping (all attributes are read and written by its parts).

    ``robots``: every registered robot by name; ``table``: who holds which resource;
    ``waiters``: resource -> robots to wake when it is released; ``claims``: resource -> the
    starving robot that claimed it; ``dirty``: robots whose grant must be tried this cycle;
    ``changed``: robots whose grant changed since the last cycle; ``waiting``: robots
    waiting for right of way; ``dead_nodes``: node -> the dead robot standing on it;
    ``dir_index``: per cycle, ``(a, b)`` -> robots about to drive from node ``a`` to ``b``
    (built on first use); ``next_detect``: time of the next deadlock detection pass;
    ``now``: time of the latest call (s).
    """

    def __init__(self, roads: RoadIndex, params: TrafficParams) -> None:
        self.roads = roads
        self.params = params
        self.robots: dict[str, TrackedRobot] = {}
        self.table = ReservationTable()
        self.metrics = TrafficMetrics()
        self.waiters: dict[Resource, set[str]] = {}
        self.claims: dict[Resource, str] = {}
        self.dirty: set[str] = set()
        self.changed: set[str] = set()
        self.waiting: set[str] = set()
        self.dead_nodes: dict[str, str] = {}
        self.dir_index: dict[tuple[str, str], set[str]] | None = None
        #: What ``dir_index`` is made current from: the index kept between cycles and the
        #: next path nodes each live robot was indexed with (:func:`~fleet.traffic.grants.moves_ahead`).
        self.dir_moves: dict[tuple[str, str], set[str]] = {}
        self.dir_segs: dict[str, tuple[str, ...]] = {}
        self.next_detect = -math.inf
        self.now = 0.0

    def get(self, robot: str) -> TrackedRobot:
        """The record of ``robot``; raises :class:`TrafficError` for an unknown robot."""
        r = self.robots.get(robot)
        if r is None:
            raise TrafficError(f"unknown robot {robot!r}")
        return r

    def wake(self, x: Resource) -> None:
        """``x`` was released (or unclaimed): the robots waiting for it try again this cycle."""
        ws = self.waiters.pop(x, None)
        if ws:
            self.dirty.update(ws)

    def release(self, r: TrackedRobot, res: Iterable[Resource]) -> None:
        """Release those of ``res`` that ``r`` holds and wake their waiters."""
        for x in self.table.release(r.name, res):
            self.wake(x)

    def drop_claims(self, r: TrackedRobot) -> None:
        """Withdraw every claim of ``r`` (waking the robots that waited for the resources)."""
        if not r.claims:
            return
        for x in r.claims:
            if self.claims.get(x) == r.name:
                del self.claims[x]
                self.wake(x)
        r.claims = set()

    def update_waiting(self, r: TrackedRobot, now: float) -> None:
        """Start or end ``r``'s wait: a robot waits while it is alive, has path left and no
        grant beyond the node it last reached. An ended wait is added to the robot's and the
        fleet's totals."""
        waiting = r.alive and r.g == r.cur and r.cur < len(r.path) - 1
        if waiting and r.wait_since is None:
            r.wait_since = now
            self.waiting.add(r.name)
            self.changed.add(r.name)
        elif not waiting and r.wait_since is not None:
            self.changed.add(r.name)
            r.wait_total += now - r.wait_since
            r.wait_events += 1
            self.metrics.wait_events += 1
            self.metrics.wait_time_s += now - r.wait_since
            r.wait_since = None
            self.waiting.discard(r.name)

    def priority(self, r: TrackedRobot, now: float) -> float:
        """``base + yields * yield_bonus + aging_per_s * seconds waiting`` (higher goes first)."""
        p = self.params
        age = now - r.wait_since if r.wait_since is not None else 0.0
        return r.base_priority + r.yields * p.yield_bonus + p.aging_per_s * age

    def log(self, now: float, msg: str) -> None:
        """Append ``(now, msg)`` to the bounded event log."""
        ev = self.metrics.events
        ev.append((now, msg))
        if len(ev) > MAX_EVENTS:
            del ev[: MAX_EVENTS // 2]
