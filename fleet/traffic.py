"""Traffic management on the roadmap: node and edge reservations ahead of every robot.

The :class:`TrafficManager` is the fleet's single owner of the roadmap's right of way. It
sees only the roadmap, each robot's planned node path, the robots' positions
(:class:`~fleet.types.Pose2D`, ``map`` frame) and their liveness; it never talks to a robot.
Each cycle it hands out, per robot, the prefix of its path the robot may drive now (a
:class:`Grant`). :class:`TrafficFollower` turns a grant into ``NavigateThroughPoses`` goals
on any :class:`~fleet.navigation.NavigationBackend`, so the same code drives the
in-process simulator, ROS 2 Nav2 robots and SUMO vehicles. See ``docs/traffic.md``.

Rules (the contract the tests check):

* Resources are roadmap nodes and undirected edges. :class:`ReservationTable` never lets
  two robots hold the same resource.
* A robot holds the node it stands on and the nodes and edges of its granted prefix. It may
  only drive inside what it holds. Nodes behind it are released once it is farther than
  ``clearance_m`` from them; the edge behind it when it reaches the next node.
* Grants grow by *blocks*: the next path node, and if that node is inside a single-lane
  corridor (roadmap degree 2), every following node of the corridor, all or nothing, and
  the node at its far end (the next node of degree other than 2) or the path's end. So two
  robots can never meet head-on inside a corridor. The far end is in the block when it is a
  dead end or the path's end, or when another robot is about to come from it into the
  corridor; otherwise (``TrafficParams.hold_far_end`` off, the default) the junction at the
  far end is taken as a block of its own when the robot gets there, so robots crossing at
  the aisle's end are not held up while it drives through the aisle.
* The remaining waits can form cycles (two robots at both ends of one aisle, four robots
  around an intersection). The manager keeps a wait-for graph (robot -> holders of what it
  waits for), finds its strongly connected components with networkx every
  ``detect_period_s``, and when a cycle has stood still for ``deadlock_detect_s`` makes its
  lowest-priority robot that *can* yield do so: reroute around the others (bounded detour),
  or step aside to a free node nearby and come back after the others have passed.
* Priority ages: a robot's priority grows with its current wait and with every time it
  yielded, grants are handed out oldest-waiter first, and a robot waiting longer than
  ``starve_s`` claims the block it waits for, so younger robots cannot keep taking it.
* A robot declared dead (:meth:`TrafficManager.declare_dead`), or that has had a grant
  ahead but made no progress for ``stall_timeout_s``, or (if ``stale_timeout_s`` is set) sent
  no position for that long, keeps only what it physically occupies (nodes within
  ``clearance_m``, the edge it is on); everything else is released and the robots whose
  paths cross its nodes are rerouted around them when the roadmap allows (a must-visit
  node it holds is skipped). A robot declared dead with ``keep_grant`` (the coordinator
  lost its agent, but the robot may still be driving its last goal) keeps its whole grant.

Time is always passed in (seconds); nothing here reads a clock. Units: meters, seconds.
"""

from __future__ import annotations

import dataclasses
import enum
import heapq
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import networkx as nx
import numpy as np

from fleet.errors import FleetError
from fleet.types import GoalStatus, NavigateThroughPoses, Pose2D

if TYPE_CHECKING:
    from fleet.config import FleetConfig
    from fleet.navigation import NavigationBackend
    from fleet.roadmap import Roadmap

#: A reservable resource: a node name, or an undirected edge as a sorted ``(a, b)`` pair.
Resource = str | tuple[str, str]


class TrafficError(FleetError):
    """The traffic manager was used wrongly (unknown robot or node, bad path, bad parameter)."""


def edge_key(a: str, b: str) -> tuple[str, str]:
    """The resource of the undirected edge between ``a`` and ``b``."""
    return (a, b) if a <= b else (b, a)


# ----------------------------------------------------------------------------- parameters

#: How far ahead (path nodes) the manager looks for a robot coming the other way into a
#: corridor (see ``TrafficParams.hold_far_end``).
ONCOMING_NODES = 8


@dataclass(frozen=True)
class TrafficParams:
    """Tunables of :class:`TrafficManager` (meters, seconds).

    ``clearance_m``: a robot keeps a node until its center is farther than this from it; it
    must exceed two robot radii and be at most the shortest roadmap edge (default: twice
    ``robot_radius`` plus 0.3 m). ``arrive_m``: a robot has reached a path node when it is this
    close (larger than the navigation stack's via-point tolerance). ``horizon_m``: grants are
    extended while less than this much path is granted ahead (at least one block is always
    asked for). ``stall_timeout_s``: a robot with a grant ahead that moved less than
    ``progress_m`` for this long is treated as dead; ``stale_timeout_s`` (``None`` = off):
    likewise for a robot whose position was not updated for this long.
    ``deadlock_detect_s``: a wait-for cycle whose robots all waited this long is resolved;
    ``detect_period_s``: how often the wait-for graph is examined. ``starve_s``: a robot
    waiting longer claims the block it waits for. ``reroute_after_s``: a robot blocked this
    long by a dead or idle robot is rerouted (or the idle robot is nudged aside).
    ``reroute_factor`` / ``reroute_slack_m``: a yield-by-reroute is accepted only if the new
    way is at most ``factor * old + slack`` long. ``sidestep_depth``: how many edges away a
    robot may step aside. ``yield_timeout_s``: how long a robot that stepped aside lets the
    robots it yielded to go first. ``yield_bonus`` and ``aging_per_s`` weigh priority (see
    :meth:`TrafficManager.priority`). ``loop_min_nodes``: looped paths are kept at least this
    many nodes ahead of the grant. ``max_resolutions``: at most this many deadlocks and
    blocked robots are handled per detection pass (bounds the cost of one cycle).
    ``hold_far_end``: a robot entering a single-lane corridor also takes the junction at its
    far end, for the whole way through (the strict rule). Off (the default), it takes the far
    junction as a block of its own when it gets there, unless another robot's next
    :data:`ONCOMING_NODES` path nodes come from that junction into the corridor: then the
    strict rule applies, so robots meeting at a corridor's end stay rare while crossing
    traffic is not held up at every aisle end.
    """

    robot_radius: float = 0.3
    clearance_m: float | None = None
    arrive_m: float = 0.5
    horizon_m: float = 6.0
    progress_m: float = 0.1
    stall_timeout_s: float = 20.0
    stale_timeout_s: float | None = None
    deadlock_detect_s: float = 2.0
    detect_period_s: float = 0.5
    starve_s: float = 20.0
    reroute_after_s: float = 5.0
    reroute_factor: float = 2.0
    reroute_slack_m: float = 10.0
    sidestep_depth: int = 4
    yield_timeout_s: float = 30.0
    yield_bonus: float = 30.0
    aging_per_s: float = 1.0
    loop_min_nodes: int = 40
    max_resolutions: int = 8
    hold_far_end: bool = False

    @property
    def clearance(self) -> float:
        return self.clearance_m if self.clearance_m is not None else 2.0 * self.robot_radius + 0.3


# ----------------------------------------------------------------------------- reservation table


class ReservationTable:
    """Exclusive holds of resources by robots. Pure bookkeeping, no geometry.

    Invariant: every resource has at most one holder, and ``held(robot)`` is exactly the set
    of resources whose holder is ``robot``.
    """

    def __init__(self) -> None:
        self._holder: dict[Resource, str] = {}
        self._held: dict[str, set[Resource]] = {}

    def holder(self, res: Resource) -> str | None:
        """The robot holding ``res``, or ``None``."""
        return self._holder.get(res)

    def held(self, robot: str) -> frozenset[Resource]:
        """The resources ``robot`` holds (a copy)."""
        return frozenset(self._held.get(robot, ()))

    def conflicts(self, robot: str, resources: Iterable[Resource]) -> list[Resource]:
        """The resources among ``resources`` that another robot holds."""
        h = self._holder
        return [r for r in resources if h.get(r, robot) != robot]

    def try_acquire(self, robot: str, resources: Sequence[Resource]) -> list[Resource]:
        """Acquire all of ``resources`` for ``robot`` or none: returns the conflicting ones
        (empty list = acquired). Acquiring a resource already held by ``robot`` is a no-op."""
        bad = self.conflicts(robot, resources)
        if bad:
            return bad
        mine = self._held.setdefault(robot, set())
        for r in resources:
            self._holder[r] = robot
            mine.add(r)
        return []

    def release(self, robot: str, resources: Iterable[Resource]) -> list[Resource]:
        """Release those of ``resources`` that ``robot`` holds; returns the released ones."""
        mine = self._held.get(robot)
        if not mine:
            return []
        out = []
        for r in resources:
            if r in mine:
                mine.discard(r)
                del self._holder[r]
                out.append(r)
        return out

    def release_all(self, robot: str, keep: Iterable[Resource] = ()) -> list[Resource]:
        """Release everything ``robot`` holds except ``keep``; returns the released ones."""
        mine = self._held.get(robot)
        if not mine:
            return []
        k = set(keep)
        return self.release(robot, [r for r in list(mine) if r not in k])

    def __len__(self) -> int:
        return len(self._holder)

    def check(self) -> None:
        """Raise ``AssertionError`` if the invariant is broken (for tests)."""
        n = 0
        for robot, mine in self._held.items():
            for r in mine:
                assert self._holder.get(r) == robot, (
                    f"{r!r} in held({robot}) but holder is {self._holder.get(r)}"
                )
            n += len(mine)
        assert n == len(self._holder), "holder table and per-robot sets disagree"


# ----------------------------------------------------------------------------- grants


@dataclass(frozen=True)
class Grant:
    """What one robot may drive now.

    ``nodes`` / ``poses``: the granted path nodes ahead of the node the robot last reached
    (``current``), in driving order, with poses facing along the path (``map`` frame). Empty
    while the robot must wait (or has no path). ``horizon`` is the absolute index in path
    ``path_id`` of the last granted node: a follower resends a goal when ``(path_id,
    horizon)`` changes. ``final``: the grant reaches the end of the path. ``alive``: false
    once the manager treats the robot as dead (it must not move). ``done``: the robot has
    reached the end of its path. Set by :class:`ReservationTraffic` (the manager leaves the
    defaults): ``task_id`` the coordinator assignment the path serves, ``purpose`` why the
    robot drives (``patrol``, ``charge``, ``charge-wait``, ``park`` or ``""``), ``laps``
    loops completed on the path for ``task_id``, ``seq`` a per-robot counter (a receiver
    ignores a grant whose ``seq`` is not newer than the last one it applied).
    ``JSON``: :meth:`to_dict` / :meth:`from_dict`.
    """

    robot: str
    path_id: int
    horizon: int
    current: str | None
    nodes: tuple[str, ...]
    poses: tuple[Pose2D, ...]
    final: bool = False
    waiting: bool = False
    done: bool = False
    alive: bool = True
    task_id: str | None = None
    purpose: str = ""
    laps: int = 0
    seq: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "v": 1,
            "robot": self.robot,
            "path_id": self.path_id,
            "horizon": self.horizon,
            "current": self.current,
            "nodes": list(self.nodes),
            "poses": [list(p.as_tuple()) for p in self.poses],
            "final": self.final,
            "waiting": self.waiting,
            "done": self.done,
            "alive": self.alive,
            "task_id": self.task_id,
            "purpose": self.purpose,
            "laps": self.laps,
            "seq": self.seq,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Grant:
        return cls(
            robot=str(d["robot"]),
            path_id=int(d["path_id"]),
            horizon=int(d["horizon"]),
            current=None if d.get("current") is None else str(d["current"]),
            nodes=tuple(str(n) for n in d["nodes"]),
            poses=tuple(Pose2D(float(p[0]), float(p[1]), float(p[2])) for p in d["poses"]),
            final=bool(d.get("final", False)),
            waiting=bool(d.get("waiting", False)),
            done=bool(d.get("done", False)),
            alive=bool(d.get("alive", True)),
            task_id=None if d.get("task_id") is None else str(d["task_id"]),
            purpose=str(d.get("purpose", "")),
            laps=int(d.get("laps", 0)),
            seq=int(d.get("seq", 0)),
        )


@dataclass
class TrafficMetrics:
    """Counters of the manager (fleet totals). Per-robot waits: :meth:`TrafficManager.wait_stats`."""

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


# ----------------------------------------------------------------------------- manager state


class _Robot:
    __slots__ = (
        "name",
        "rank",
        "base_priority",
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
        "alive",
        "x",
        "y",
        "has_pose",
        "last_update",
        "prog_x",
        "prog_y",
        "prog_t",
        "wait_since",
        "wait_total",
        "wait_events",
        "blockers",
        "blocked_on",
        "claims",
        "yields",
        "yield_to",
        "dirty_t",
        "occupied",
        "next_reroute",
        "blocked_since",
    )

    def __init__(self, name: str, rank: int, now: float) -> None:
        self.name = name
        self.rank = rank
        self.base_priority = 0.0
        self.path: list[str] = []
        self.must: list[bool] = []
        self.cum: list[float] = []
        self.offset = 0  # absolute index of path[0] within this path_id
        self.cur = 0
        self.g = 0
        self.path_id = 0
        self.loop: tuple[list[str], list[bool]] | None = None
        self.must_passed = 0
        self.passed = 0
        self.back: set[str] = set()  # held nodes that may be behind the robot
        self.alive = True
        self.x = 0.0
        self.y = 0.0
        self.has_pose = False
        self.last_update = now
        self.prog_x = 0.0
        self.prog_y = 0.0
        self.prog_t = now
        self.wait_since: float | None = None
        self.wait_total = 0.0
        self.wait_events = 0
        self.blockers: set[str] = set()
        self.blocked_on: set[Resource] = set()
        self.claims: set[Resource] = set()
        self.yields = 0
        self.yield_to: dict[str, tuple[frozenset[Resource], float]] = {}
        self.dirty_t = -math.inf
        self.occupied: frozenset[Resource] = frozenset()
        self.next_reroute = -math.inf
        self.blocked_since = now

    @property
    def parked(self) -> bool:
        """Alive, standing at the end of its path (no grant ahead, nothing left to drive)."""
        return self.alive and self.cur == self.g and self.cur >= len(self.path) - 1

    @property
    def waiting(self) -> bool:
        return self.alive and self.g == self.cur and self.cur < len(self.path) - 1


class TrafficManager:
    """Reservation-based traffic management on a roadmap (see the module docstring).

    Typical use, once per coordinator cycle::

        tm.update(robot, pose, now)          # for every robot with a fresh position
        changed = tm.cycle(now)              # robots whose grant changed
        for r in changed: deliver(r, tm.grant(r))

    Paths are given with :meth:`set_path` (``loop=True`` for a patrol loop that repeats
    forever) and dropped with :meth:`clear_path`. The manager may replace the part of a path
    between the robot and its next must-visit node (reroutes, side steps); the robot learns
    it through the grant. ``roadmap`` is a :class:`fleet.roadmap.Roadmap` or a
    ``networkx.Graph`` with node attribute ``pos`` and (optional) edge attribute ``length``.
    """

    def __init__(self, roadmap: Roadmap | nx.Graph, params: TrafficParams | None = None) -> None:
        g = roadmap if isinstance(roadmap, nx.Graph) else roadmap.graph
        self.params = params or TrafficParams()
        p = self.params
        if p.clearance <= 2.0 * p.robot_radius:
            raise TrafficError(f"TrafficParams.clearance_m ({p.clearance}) must exceed two robot radii")
        self.graph: nx.Graph = g
        self._pos: dict[str, tuple[float, float]] = {
            str(n): (float(d["pos"][0]), float(d["pos"][1])) for n, d in g.nodes(data=True)
        }
        self._names = list(self._pos)
        self._xy = np.array([self._pos[n] for n in self._names], dtype=float).reshape(-1, 2)
        self._adj: dict[str, list[str]] = {str(n): [str(m) for m in g.neighbors(n)] for n in g.nodes}
        self._deg: dict[str, int] = {n: len(a) for n, a in self._adj.items()}
        self._len: dict[tuple[str, str], float] = {}
        for a, b, d in g.edges(data=True):
            pa, pb = self._pos[str(a)], self._pos[str(b)]
            self._len[edge_key(str(a), str(b))] = float(d.get("length", math.dist(pa, pb)))
        self.table = ReservationTable()
        self.metrics = TrafficMetrics()
        self._robots: dict[str, _Robot] = {}
        self._waiters: dict[Resource, set[str]] = {}
        self._claims: dict[Resource, str] = {}
        self._dirty: set[str] = set()
        self._changed: set[str] = set()
        self._waiting: set[str] = set()
        self._dead_nodes: dict[str, str] = {}  # node -> dead robot occupying it
        self._next_detect = -math.inf
        self._now = 0.0
        self._dir_index: dict[tuple[str, str], set[str]] | None = None

    # ------------------------------------------------------------------ robots

    @property
    def robots(self) -> list[str]:
        return list(self._robots)

    def add_robot(self, robot: str, pose: Pose2D, now: float, priority: float = 0.0) -> str:
        """Register ``robot`` standing at ``pose``; it holds its nearest roadmap node, which is
        returned. Raises :class:`TrafficError` if the robot is known or the node is held by
        another robot (two robots cannot start on one node)."""
        if robot in self._robots:
            raise TrafficError(f"robot {robot!r} is already registered")
        node = self.nearest_node(pose.x, pose.y)
        other = self.table.holder(node)
        if other is not None:
            raise TrafficError(f"robot {robot!r} starts at node {node!r}, which {other!r} holds")
        r = _Robot(robot, len(self._robots), now)
        r.base_priority = float(priority)
        r.x, r.y, r.has_pose = pose.x, pose.y, True
        r.prog_x, r.prog_y = pose.x, pose.y
        r.path, r.must, r.cum = [node], [True], [0.0]
        self._robots[robot] = r
        self.table.try_acquire(robot, [node])
        r.back.add(node)
        return node

    def remove_robot(self, robot: str) -> None:
        """Forget ``robot`` and release everything it holds (it left the floor)."""
        r = self._get(robot)
        self._drop_claims(r)
        self._release(r, list(self.table.held(robot)))
        for n in r.occupied:
            if isinstance(n, str) and self._dead_nodes.get(n) == robot:
                del self._dead_nodes[n]
        self._waiting.discard(robot)
        del self._robots[robot]
        self._dirty.discard(robot)

    def update(self, robot: str, pose: Pose2D, now: float) -> None:
        """The latest position of ``robot`` (``map`` frame). Cheap: geometry runs in :meth:`cycle`."""
        r = self._robots.get(robot)
        if r is None:
            raise TrafficError(f"unknown robot {robot!r}")
        r.x = pose.x
        r.y = pose.y
        r.has_pose = True
        r.last_update = now
        if not r.alive and math.hypot(r.x - r.prog_x, r.y - r.prog_y) > 2.0 * self.params.clearance:
            self._revive(r, now)

    def set_priority(self, robot: str, priority: float) -> None:
        """Base priority of ``robot`` (higher goes first and yields last; default 0)."""
        self._get(robot).base_priority = float(priority)

    def declare_dead(
        self, robot: str, now: float, reason: str = "declared dead", keep_grant: bool = False
    ) -> None:
        """``robot`` is dead (or stopped for good): release all it holds except what it
        physically occupies, drop its path, reroute others around its nodes. With
        ``keep_grant`` it keeps everything it holds: for a robot whose controller is gone
        but which may still be driving its last goal, to the end of its grant."""
        r = self._get(robot)
        if r.alive:
            self._kill(r, now, reason, keep_all=keep_grant)

    def declare_alive(self, robot: str, now: float) -> None:
        """``robot`` is back: it keeps what it occupies and must be given a path again."""
        r = self._get(robot)
        if not r.alive:
            self._revive(r, now)

    def is_alive(self, robot: str) -> bool:
        return self._get(robot).alive

    # ------------------------------------------------------------------ paths

    def set_path(
        self,
        robot: str,
        nodes: Sequence[str],
        now: float,
        must_visit: Iterable[int] | None = None,
        loop: bool = False,
    ) -> int:
        """Give ``robot`` the node path ``nodes`` (consecutive nodes must be roadmap edges).

        The robot first finishes its current grant; the new path is joined from there
        (where it crosses the grant, or by a shortest path to ``nodes[0]``). ``must_visit``
        are indices into ``nodes`` that detours must keep (default: the last node; with
        ``loop`` every node). With ``loop=True`` the path repeats forever (``nodes[-1]`` must
        be adjacent to ``nodes[0]`` or equal to it); :meth:`laps` counts completed loops.
        Returns the new ``path_id``. Raises :class:`TrafficError` for an unknown node, a
        missing edge or an empty path.
        """
        r = self._get(robot)
        seq = [str(n) for n in nodes]
        if not seq:
            raise TrafficError(f"set_path({robot!r}): empty path")
        for n in seq:
            if n not in self._pos:
                raise TrafficError(f"set_path({robot!r}): unknown roadmap node {n!r}")
        for a, b in zip(seq, seq[1:], strict=False):
            if a != b and edge_key(a, b) not in self._len:
                raise TrafficError(f"set_path({robot!r}): no roadmap edge between {a!r} and {b!r}")
        if must_visit is None:
            must = [loop] * len(seq)
            must[-1] = True
        else:
            must = [False] * len(seq)
            for i in must_visit:
                if not -len(seq) <= i < len(seq):
                    raise TrafficError(f"set_path({robot!r}): must_visit index {i} outside the path")
                must[i] = True
        if loop and len(seq) > 1 and seq[-1] == seq[0]:
            seq, must = seq[:-1], [must[0] or must[-1]] + must[1:-1]
        if loop and (len(seq) < 2 or edge_key(seq[-1], seq[0]) not in self._len):
            raise TrafficError(f"set_path({robot!r}): a loop needs 2+ nodes, its end adjacent to its start")
        self._now = now
        if not r.alive:
            return r.path_id
        prefix = r.path[r.cur : r.g + 1]
        pm = [False] * len(prefix) if loop else r.must[r.cur : r.g + 1]
        new_nodes, new_must = self._join(prefix, seq, must)
        r.loop = (list(seq), list(must)) if loop else None
        r.must_passed = 0
        self._install(r, prefix + new_nodes, pm + new_must)
        if loop:
            self._extend_loop(r)
        self._avoid_dead(r)
        return r.path_id

    def clear_path(self, robot: str, now: float) -> None:
        """Drop ``robot``'s path: it stops at the end of its current grant and keeps holding
        what it needs to get there and stand there."""
        r = self._get(robot)
        if not r.alive:
            return
        self._now = now
        r.loop = None
        self._install(r, r.path[r.cur : r.g + 1], r.must[r.cur : r.g + 1])

    def path(self, robot: str) -> list[str]:
        """The robot's remaining path, starting at the node it last reached."""
        r = self._get(robot)
        return r.path[r.cur :]

    def laps(self, robot: str) -> int:
        """Completed loops of a looped path since the last :meth:`set_path`: must-visit nodes
        reached divided by the must-visit nodes of one loop (0 for other paths)."""
        r = self._get(robot)
        if r.loop is None:
            return 0
        return r.must_passed // max(1, sum(r.loop[1]))

    def nodes_passed(self, robot: str) -> int:
        """Path nodes the robot reached since it was added."""
        return self._get(robot).passed

    def done(self, robot: str) -> bool:
        """True when the robot has reached the end of its (non-looped) path."""
        r = self._get(robot)
        return r.alive and r.cur >= len(r.path) - 1

    # ------------------------------------------------------------------ queries

    def nearest_node(self, x: float, y: float) -> str:
        if not self._names:
            raise TrafficError("the roadmap has no nodes")
        d = (self._xy[:, 0] - x) ** 2 + (self._xy[:, 1] - y) ** 2
        return self._names[int(np.argmin(d))]

    def holder(self, res: Resource) -> str | None:
        return self.table.holder(res)

    def held(self, robot: str) -> frozenset[Resource]:
        return self.table.held(robot)

    def claimant(self, res: Resource) -> str | None:
        """The starving robot that claimed ``res`` (younger robots may not take it), or ``None``."""
        return self._claims.get(res)

    def node_pos(self, node: str) -> tuple[float, float]:
        """``(x, y)`` of roadmap node ``node`` in meters."""
        return self._pos[node]

    def waiting(self) -> set[str]:
        """Robots that have a path left but no grant beyond the node they stand on."""
        return set(self._waiting)

    def blockers(self, robot: str) -> set[str]:
        """Robots ``robot`` waits for (holders or claimants of what it needs next)."""
        return set(self._get(robot).blockers)

    def priority(self, robot: str, now: float) -> float:
        """``base + yields * yield_bonus + aging_per_s * seconds waiting`` (higher goes first)."""
        r = self._get(robot)
        return self._prio(r, now)

    def grant(self, robot: str) -> Grant:
        """The robot's current grant (see :class:`Grant`)."""
        r = self._get(robot)
        path = r.path
        nodes = tuple(path[r.cur + 1 : r.g + 1]) if r.alive else ()
        poses = tuple(self._pose_at(r, j) for j in range(r.cur + 1, r.cur + 1 + len(nodes)))
        return Grant(
            robot=robot,
            path_id=r.path_id,
            horizon=r.offset + (r.g if r.alive else r.cur),
            current=path[r.cur] if path else None,
            nodes=nodes,
            poses=poses,
            final=r.g >= len(path) - 1,
            waiting=r.name in self._waiting,
            done=r.alive and r.cur >= len(path) - 1,
            alive=r.alive,
        )

    def wait_stats(self, robot: str, now: float) -> tuple[float, int]:
        """``(total seconds waited, wait events)`` of ``robot`` (the current wait included)."""
        r = self._get(robot)
        t = r.wait_total + (now - r.wait_since if r.wait_since is not None else 0.0)
        return (t, r.wait_events + (1 if r.wait_since is not None else 0))

    def mean_wait_s(self, now: float) -> float:
        """Mean over robots of their total wait time (s)."""
        if not self._robots:
            return 0.0
        return sum(self.wait_stats(n, now)[0] for n in self._robots) / len(self._robots)

    def wait_for_graph(self) -> nx.DiGraph:
        """Directed graph robot -> robots it waits for, over the waiting robots."""
        g = nx.DiGraph()
        for name in self._waiting:
            r = self._robots[name]
            g.add_node(name)
            for b in r.blockers:
                g.add_edge(name, b)
        return g

    def deadlocked(self, now: float, limit_s: float) -> list[frozenset[str]]:
        """Sets of robots waiting on each other (a cycle of the wait-for graph, dead robots
        excluded) in which every robot has been waiting, on the same robots, for more than
        ``limit_s`` seconds: the fleet report's deadlocks."""
        return [frozenset(c) for c in self._cycles(now, limit_s + 1e-9)]

    def longest_wait(self, now: float) -> tuple[str | None, float]:
        """The robot that has been waiting longest right now and for how long (s); catches
        robots that never deadlock for long but never get through either."""
        best: tuple[str | None, float] = (None, 0.0)
        for n in self._waiting:
            w = self._robots[n].wait_since
            if w is not None and now - w > best[1]:
                best = (n, now - w)
        return best

    def blocked_by_dead(self) -> set[str]:
        """Waiting robots whose blockers include a dead robot (they cannot be rerouted)."""
        return {
            n
            for n in self._waiting
            if any(not self._robots[b].alive for b in self._robots[n].blockers if b in self._robots)
        }

    def check(self) -> None:
        """Raise ``AssertionError`` if a reservation invariant is broken (for tests)."""
        self.table.check()
        for r in self._robots.values():
            if not r.alive or not r.path:
                continue
            held = self.table.held(r.name)
            for j in range(r.cur + 1, r.g + 1):
                assert r.path[j] in held, f"{r.name} granted {r.path[j]} without holding it"
                a, b = r.path[j - 1], r.path[j]
                if a != b:
                    assert edge_key(a, b) in held, f"{r.name} granted edge {a}-{b} without holding it"

    # ------------------------------------------------------------------ the cycle

    def cycle(self, now: float) -> set[str]:
        """One manager cycle at ``now``: track progress (release behind, count laps, detect
        stalls), extend grants oldest-waiter first, account waits, detect and resolve
        deadlocks. Returns the robots whose :meth:`grant` changed since the last cycle (its
        horizon, path, ``current`` node, ``waiting`` or ``alive``): deliver those."""
        p = self.params
        self._now = now
        self._dir_index = None
        tol2 = p.arrive_m * p.arrive_m
        clear2 = p.clearance * p.clearance
        prog2 = p.progress_m * p.progress_m
        pos = self._pos
        dirty = self._dirty
        stale = p.stale_timeout_s
        dead: list[_Robot] = []
        for r in self._robots.values():
            if not r.alive:
                continue
            x, y = r.x, r.y
            if stale is not None and now - r.last_update > stale:
                dead.append(r)
                continue
            path = r.path
            cur0 = r.cur
            while r.cur < r.g:
                nx_, ny_ = pos[path[r.cur + 1]]
                if (x - nx_) * (x - nx_) + (y - ny_) * (y - ny_) > tol2:
                    break
                r.cur += 1
            if r.cur != cur0:
                self._advanced(r, cur0, now)
            if r.back:
                rel = None
                for n in r.back:
                    bx, by = pos[n]
                    if (x - bx) * (x - bx) + (y - by) * (y - by) > clear2:
                        rel = [n] if rel is None else rel + [n]
                if rel is not None:
                    fwd = path[r.cur + 1 : r.g + 1]
                    for n in rel:
                        if n not in fwd and (r.cur < r.g or n != path[r.cur]):
                            r.back.discard(n)
                            self._release(r, [n])
            if r.g > r.cur:
                if (x - r.prog_x) * (x - r.prog_x) + (y - r.prog_y) * (y - r.prog_y) > prog2:
                    r.prog_x, r.prog_y, r.prog_t = x, y, now
                elif now - r.prog_t > p.stall_timeout_s:
                    dead.append(r)
            else:
                r.prog_x, r.prog_y, r.prog_t = x, y, now
                if r.g < len(path) - 1 and r.name not in dirty and now - r.dirty_t > p.detect_period_s:
                    dirty.add(r.name)
        for r in dead:
            self._kill(r, now, "stalled" if r.g > r.cur else "no position updates")
        if dirty:
            order = sorted(
                (self._robots[n] for n in dirty if n in self._robots),
                key=lambda r: (-self._prio(r, now), r.rank),
            )
            dirty.clear()
            for r in order:
                r.dirty_t = now
                self._extend(r, now)
        if self._waiting and now >= self._next_detect:
            self._next_detect = now + p.detect_period_s
            self._detect_and_resolve(now)
        out = self._changed
        self._changed = set()
        return out

    # ------------------------------------------------------------------ internals: progress

    def _advanced(self, r: _Robot, cur0: int, now: float) -> None:
        path = r.path
        rel: list[Resource] = []
        for j in range(cur0, r.cur):
            a, b = path[j], path[j + 1]
            r.back.add(a)
            if a != b:
                rel.append(edge_key(a, b))
        r.back.add(path[r.cur])
        r.passed += r.cur - cur0
        for j in range(cur0 + 1, r.cur + 1):
            if r.must[j]:
                r.must_passed += 1
        fwd_edges = {edge_key(path[j], path[j + 1]) for j in range(r.cur, r.g)}
        self._release(r, [e for e in rel if e not in fwd_edges])
        if r.loop is not None:
            self._extend_loop(r)
        if r.cur > 256:
            self._trim(r)
        self._dirty.add(r.name)
        self._changed.add(r.name)  # ``current`` and ``nodes`` of its grant moved on
        self._update_waiting(r, now)

    def _trim(self, r: _Robot) -> None:
        k = r.cur - 1
        del r.path[:k]
        del r.must[:k]
        del r.cum[:k]
        r.offset += k
        r.cur -= k
        r.g -= k

    def _extend_loop(self, r: _Robot) -> None:
        assert r.loop is not None
        seq, must = r.loop
        # invariant: the path of a looped robot ends at seq[-1], so a whole lap follows it
        while len(r.path) - r.g < self.params.loop_min_nodes:
            base = len(r.path)
            self._append(r, list(seq), list(must))
            if self._dead_nodes:
                self._avoid_dead(r, start=base - 1)

    # ------------------------------------------------------------------ internals: paths

    def _join(self, prefix: list[str], seq: list[str], must: list[bool]) -> tuple[list[str], list[bool]]:
        """Nodes (and must flags) to append after ``prefix`` to continue on ``seq``."""
        if not prefix:
            return list(seq), list(must)
        last = prefix[-1]
        for i, n in enumerate(seq):
            if n == last:
                return seq[i + 1 :], must[i + 1 :]
        link = self._shortest(last, seq[0], frozenset())
        if link is None:
            raise TrafficError(f"no roadmap path from {last!r} to {seq[0]!r}")
        return link[1:] + seq[1:], [False] * (len(link) - 2) + must

    def _install(self, r: _Robot, nodes: list[str], must: list[bool], granted: int | None = None) -> None:
        """Replace the robot's path by ``nodes`` whose first ``g - cur + 1`` entries are its
        current grant (kept, so nothing granted is taken back); ``granted`` overrides the
        index of the last granted node (the caller holds those resources)."""
        now = self._now
        keep = r.g - r.cur if granted is None else granted
        assert len(nodes) == len(must)
        self._drop_claims(r)
        r.offset += r.cur
        r.path = []
        r.must = []
        r.cum = [0.0]
        self._append(r, nodes, must, first=True)
        r.cur = 0
        r.g = keep
        r.path_id += 1
        r.blockers = set()
        r.blocked_on = set()
        self._changed.add(r.name)
        self._dirty.add(r.name)
        self._update_waiting(r, now)

    def _append(self, r: _Robot, nodes: list[str], must: list[bool], first: bool = False) -> None:
        path, cum = r.path, r.cum
        for n, m in zip(nodes, must, strict=True):
            if path:
                a = path[-1]
                cum.append(cum[-1] + (self._len.get(edge_key(a, n), 0.0) if a != n else 0.0))
            elif not first:
                cum.append(0.0)
            path.append(n)
            r.must.append(m)
        if len(cum) > len(path):
            del cum[len(path) :]

    def _pose_at(self, r: _Robot, j: int) -> Pose2D:
        path = r.path
        x, y = self._pos[path[j]]
        k = j + 1
        while k < len(path) and path[k] == path[j]:
            k += 1
        if k < len(path):
            nx_, ny_ = self._pos[path[k]]
            return Pose2D(x, y, math.atan2(ny_ - y, nx_ - x))
        k = j - 1
        while k >= 0 and path[k] == path[j]:
            k -= 1
        if k >= 0:
            px, py = self._pos[path[k]]
            return Pose2D(x, y, math.atan2(y - py, x - px))
        return Pose2D(x, y, 0.0)

    def _shortest(
        self, a: str, b: str, avoid: frozenset[str] | set[str], limit: float = math.inf
    ) -> list[str] | None:
        """A* from ``a`` to ``b`` by edge length (straight-line heuristic), not entering nodes
        in ``avoid``; ``None`` if there is no such path of length at most ``limit``."""
        if a == b:
            return [a]
        if b in avoid:
            return None
        pos = self._pos
        bx, by = pos[b]
        dist = {a: 0.0}
        prev: dict[str, str] = {}
        heap = [(math.dist(pos[a], (bx, by)), 0.0, a)]
        adj, lens = self._adj, self._len
        closed: set[str] = set()
        while heap:
            f, d, u = heapq.heappop(heap)
            if f > limit:
                return None
            if u == b:
                out = [b]
                while out[-1] != a:
                    out.append(prev[out[-1]])
                return out[::-1]
            if u in closed:
                continue
            closed.add(u)
            for v in adj[u]:
                if v in avoid or v in closed:
                    continue
                nd = d + lens[edge_key(u, v)]
                if nd < dist.get(v, math.inf):
                    dist[v] = nd
                    prev[v] = u
                    vx, vy = pos[v]
                    heapq.heappush(heap, (nd + math.hypot(vx - bx, vy - by), nd, v))
        return None

    def _next_must(self, r: _Robot, after: int) -> int:
        for k in range(after + 1, len(r.path)):
            if r.must[k]:
                return k
        return len(r.path) - 1

    def _splice(self, r: _Robot, a: int, b: int, seg: list[str]) -> None:
        """Replace ``path[a..b]`` by ``seg`` (``seg[0] == path[a]``, ``seg[-1] == path[b]``)."""
        nodes = r.path[r.cur : a] + seg + r.path[b + 1 :]
        if len(seg) == 1:
            mid = [r.must[a] or r.must[b]]
        else:
            mid = [r.must[a]] + [False] * (len(seg) - 2) + [r.must[b]]
        self._install(r, nodes, r.must[r.cur : a] + mid + r.must[b + 1 :])

    # ------------------------------------------------------------------ internals: grants

    def _block(self, r: _Robot) -> list[int]:
        path, deg = r.path, self._deg
        n = len(path)
        j = r.g + 1
        out = []
        while j < n:
            out.append(j)
            node = path[j]
            if deg[node] != 2 or j == n - 1 or path[j + 1] == path[j - 1] or path[j + 1] == node:
                break
            j += 1
        if (
            not self.params.hold_far_end
            and len(out) > 1
            and deg[path[out[-1]]] > 2
            and out[-1] < n - 1
            and not self._oncoming(r, path[out[-1]], path[out[-2]])
        ):
            out.pop()  # nobody comes the other way: the far junction is taken when reached
        return out

    def _oncoming(self, r: _Robot, far: str, last: str) -> bool:
        """Whether another live robot's next :data:`ONCOMING_NODES` path nodes go from the
        junction ``far`` into the corridor node ``last`` (the opposite way to ``r``)."""
        idx = self._dir_index
        if idx is None:
            idx = {}
            for o in self._robots.values():
                if not o.alive:
                    continue
                seg = o.path[o.cur : o.cur + ONCOMING_NODES]
                for a, b in zip(seg, seg[1:], strict=False):
                    idx.setdefault((a, b), set()).add(o.name)
            self._dir_index = idx
        who = idx.get((far, last))
        return who is not None and (len(who) > 1 or r.name not in who)

    def _extend(self, r: _Robot, now: float) -> None:
        if not r.alive or not r.path:
            return
        p = self.params
        changed = False
        if r.yield_to:
            self._expire_yields(r, now)
        while r.g < len(r.path) - 1:
            if r.g > r.cur and r.cum[r.g] - r.cum[r.cur] >= p.horizon_m:
                break
            idx = self._block(r)
            path = r.path
            res: list[Resource] = []
            for j in idx:
                a, b = path[j - 1], path[j]
                res.append(b)
                if a != b:
                    res.append(edge_key(a, b))
            bad = self.table.conflicts(r.name, res)
            blockers: set[str] = set()
            for x in bad:
                h = self.table.holder(x)
                if h is not None:
                    blockers.add(h)
            for x in res:
                c = self._claims.get(x)
                if c is not None and c != r.name and c in self._robots and self._robots[c].alive:
                    bad.append(x)
                    blockers.add(c)
            for w, (conf, _) in r.yield_to.items():
                wr = self._robots.get(w)
                if wr is None:
                    continue
                for x in res:
                    if x in conf and x in wr.blocked_on:
                        bad.append(x)
                        blockers.add(w)
            if bad:
                if blockers != r.blockers:
                    r.blocked_since = now
                r.blockers = blockers
                r.blocked_on = set(res)
                for x in bad:
                    self._waiters.setdefault(x, set()).add(r.name)
                if r.wait_since is not None and now - r.wait_since > p.starve_s:
                    self._claim(r, res)
                break
            self.table.try_acquire(r.name, res)
            r.g = idx[-1]
            changed = True
            r.blockers = set()
            r.blocked_on = set()
            self._drop_claims(r)
        if changed:
            self._changed.add(r.name)
            r.prog_t = now
        self._update_waiting(r, now)

    def _expire_yields(self, r: _Robot, now: float) -> None:
        for w in list(r.yield_to):
            conf, until = r.yield_to[w]
            wr = self._robots.get(w)
            if (
                wr is None
                or not wr.alive
                or now > until
                or (not (conf & wr.blocked_on) and not any(self.table.holder(x) == w for x in conf))
            ):
                del r.yield_to[w]

    def _claim(self, r: _Robot, res: list[Resource]) -> None:
        for x in res:
            c = self._claims.get(x)
            if c is None or c not in self._robots or not self._robots[c].alive:
                self._claims[x] = r.name
                r.claims.add(x)

    def _drop_claims(self, r: _Robot) -> None:
        if not r.claims:
            return
        for x in r.claims:
            if self._claims.get(x) == r.name:
                del self._claims[x]
                self._wake(x)
        r.claims = set()

    def _wake(self, x: Resource) -> None:
        ws = self._waiters.pop(x, None)
        if ws:
            self._dirty.update(ws)

    def _release(self, r: _Robot, res: Iterable[Resource]) -> None:
        for x in self.table.release(r.name, res):
            self._wake(x)

    def _update_waiting(self, r: _Robot, now: float) -> None:
        w = r.waiting
        if w and r.wait_since is None:
            r.wait_since = now
            self._waiting.add(r.name)
            self._changed.add(r.name)
        elif not w and r.wait_since is not None:
            self._changed.add(r.name)
            r.wait_total += now - r.wait_since
            r.wait_events += 1
            self.metrics.wait_events += 1
            self.metrics.wait_time_s += now - r.wait_since
            r.wait_since = None
            self._waiting.discard(r.name)

    def _prio(self, r: _Robot, now: float) -> float:
        p = self.params
        age = now - r.wait_since if r.wait_since is not None else 0.0
        return r.base_priority + r.yields * p.yield_bonus + p.aging_per_s * age

    # ------------------------------------------------------------------ internals: deadlocks

    def _cycles(self, now: float = math.inf, min_wait: float = -math.inf) -> list[set[str]]:
        """Strongly connected components (2+ robots) of the wait-for graph restricted to the
        robots that have been waiting, on the same robots, for at least ``min_wait`` s."""
        robots = self._robots
        long = set()
        for n in self._waiting:
            r = robots[n]
            if r.wait_since is not None and now - max(r.wait_since, r.blocked_since) >= min_wait:
                long.add(n)
        edges = [(n, b) for n in long for b in robots[n].blockers if b in long]
        if not edges:
            return []
        g = nx.DiGraph()
        g.add_edges_from(edges)
        return [c for c in nx.strongly_connected_components(g) if len(c) > 1]

    def _detect_and_resolve(self, now: float) -> None:
        p = self.params
        budget = p.max_resolutions
        for comp in self._cycles(now, p.deadlock_detect_s):
            if budget <= 0:
                break
            budget -= 1
            self.metrics.deadlocks_detected += 1
            self._log(now, f"deadlock {sorted(comp)}")
            if self._resolve(comp, now):
                self.metrics.deadlocks_resolved += 1
            else:
                self.metrics.deadlocks_unresolved += 1
        # robots blocked by dead or idle robots
        for name in sorted(self._waiting):
            if budget <= 0:
                break
            r = self._robots.get(name)
            if r is None or r.wait_since is None or now - r.wait_since < p.reroute_after_s:
                continue
            if now < r.next_reroute:
                continue
            stuck_on = [self._robots[b] for b in r.blockers if b in self._robots]
            if not stuck_on or not all(not b.alive or b.parked for b in stuck_on):
                continue
            budget -= 1
            r.next_reroute = now + p.reroute_after_s
            avoid = {x for b in stuck_on for x in self.table.held(b.name) if isinstance(x, str)}
            if self._reroute(r, avoid, now, bounded=False):
                self.metrics.dead_reroutes += 1
                continue
            for b in stuck_on:
                if b.parked and self._sidestep(b, {name}, now, back=False):
                    self.metrics.nudges += 1
                    break

    def _resolve(self, comp: set[str], now: float) -> bool:
        members = sorted((self._robots[n] for n in comp), key=lambda r: (self._prio(r, now), -r.rank))
        for v in members:
            others = [m for m in members if m is not v]
            avoid = {x for m in others for x in self.table.held(m.name) if isinstance(x, str)}
            if self._reroute(v, avoid, now, bounded=True):
                self.metrics.reroutes += 1
                self._log(now, f"{v.name} rerouted to break a deadlock")
                self._after_yield(v, others, now)
                return True
            if self._sidestep(v, {m.name for m in others}, now, back=True):
                self.metrics.sidesteps += 1
                self._log(now, f"{v.name} stepped aside to {v.path[v.g]} to break a deadlock")
                return True
        # no member can move: make room, i.e. move a robot that waits on the cycle and stands
        # next to it (it frees a node a member can step aside to at the next detection)
        near = {u for m in members for u in self._adj[m.path[m.cur]]}
        outside = sorted(
            (
                self._robots[n]
                for n in self._waiting
                if n not in comp
                and self._robots[n].blockers & comp
                and self._robots[n].path[self._robots[n].cur] in near
            ),
            key=lambda r: (self._prio(r, now), -r.rank),
        )
        avoid = {x for m in members for x in self.table.held(m.name) if isinstance(x, str)}
        for o in outside:
            if self._reroute(o, avoid, now, bounded=True) or self._sidestep(o, set(comp), now, back=True):
                self.metrics.sidesteps += 1
                self._log(now, f"{o.name} made room for deadlock {sorted(comp)}")
                return False
        return False

    def _after_yield(self, v: _Robot, others: list[_Robot], now: float) -> None:
        v.yields += 1
        mine = self.table.held(v.name)
        for m in others:
            if v.name in m.blockers:
                v.yield_to[m.name] = (frozenset(mine | m.blocked_on), now + self.params.yield_timeout_s)
                self._dirty.add(m.name)

    def _reroute(self, r: _Robot, avoid: set[str], now: float, bounded: bool) -> bool:
        """Replace the path between the robot's grant end and its next must-visit node by one
        that avoids ``avoid`` (and dead robots' nodes). False if impossible or too long."""
        if not r.alive or r.g >= len(r.path) - 1:
            return False
        a = r.g
        b = self._next_must(r, a)
        bad = set(avoid) | set(self._dead_nodes)
        bad.discard(r.path[a])
        if r.path[b] in bad:
            return False
        old = r.cum[b] - r.cum[a]
        limit = self.params.reroute_factor * old + self.params.reroute_slack_m
        seg = self._shortest(r.path[a], r.path[b], bad, limit if bounded else 2.0 * limit)
        if seg is None or seg == r.path[a : b + 1]:
            return False
        self._splice(r, a, b, seg)
        return True

    def _sidestep(self, r: _Robot, others: set[str], now: float, back: bool) -> bool:
        """Move ``r`` to a free node a few edges away that is not on the next part of the
        paths of ``others``, then (``back``) continue its path from there."""
        if not r.alive or not r.path:
            return False
        start = r.path[r.g]
        avoid: set[str] = set()
        for o in others:
            orr = self._robots.get(o)
            if orr is not None:
                avoid.update(orr.path[orr.cur : orr.cur + 12])
        holder = self.table.holder
        parent: dict[str, str] = {start: start}
        frontier = [start]
        target = None
        for _ in range(self.params.sidestep_depth):
            nxt: list[str] = []
            for u in frontier:
                for v in self._adj[u]:
                    if v in parent:
                        continue
                    if holder(v) not in (None, r.name) or holder(edge_key(u, v)) not in (None, r.name):
                        continue
                    if v in self._dead_nodes or (v in self._claims and self._claims[v] != r.name):
                        continue
                    parent[v] = u
                    nxt.append(v)
                    if v not in avoid and target is None:
                        target = v
            if target is not None or not nxt:
                break
            frontier = nxt
        if target is None:
            return False
        seg = [target]
        while seg[-1] != start:
            seg.append(parent[seg[-1]])
        seg.reverse()
        res: list[Resource] = []
        for u, v in zip(seg, seg[1:], strict=False):
            res += [v, edge_key(u, v)]
        old_members = [self._robots[o] for o in others if o in self._robots]
        g_new = r.g - r.cur + len(seg) - 1
        nodes = r.path[r.cur : r.g] + seg
        must = r.must[r.cur : r.g] + [r.must[r.g]] + [False] * (len(seg) - 1)
        ret: list[str] | None = None
        if back and r.g < len(r.path) - 1:
            b = self._next_must(r, r.g)
            ret = self._shortest(target, r.path[b], set(self._dead_nodes))
            if ret is None:
                return False
        if self.table.try_acquire(r.name, res):
            return False
        if ret is not None:
            if len(ret) > 1:
                nodes += ret[1:]
                must += [False] * (len(ret) - 2) + [r.must[b]]
            else:
                must[-1] = r.must[b]
            nodes += r.path[b + 1 :]
            must += r.must[b + 1 :]
        else:
            must[-1] = True
            r.loop = None
        self._install(r, nodes, must, granted=g_new)
        self._update_waiting(r, now)
        self._after_yield(r, old_members, now)
        return True

    def _log(self, now: float, msg: str) -> None:
        ev = self.metrics.events
        ev.append((now, msg))
        if len(ev) > 2000:
            del ev[:1000]

    # ------------------------------------------------------------------ internals: death

    def _occupied(self, r: _Robot) -> set[Resource]:
        c2 = self.params.clearance**2
        out: set[Resource] = set()
        held = self.table.held(r.name)
        for x in held:
            if isinstance(x, str):
                px, py = self._pos[x]
                if (px - r.x) ** 2 + (py - r.y) ** 2 <= c2:
                    out.add(x)
        if not out and r.cur < r.g:  # mid-edge, far from both ends: the edge is what it blocks
            a, b = r.path[r.cur], r.path[r.cur + 1]
            e = edge_key(a, b)
            if e in held:
                ax, ay = self._pos[a]
                bx, by = self._pos[b]
                dx, dy = bx - ax, by - ay
                L2 = dx * dx + dy * dy
                t = ((r.x - ax) * dx + (r.y - ay) * dy) / L2 if L2 > 0 else 0.0
                if 0.0 < t < 1.0:
                    out.add(e)
        if not out and r.path:
            n = r.path[r.cur]
            if n in held:
                out.add(n)
        return out

    def _kill(self, r: _Robot, now: float, reason: str, keep_all: bool = False) -> None:
        occ = set(self.table.held(r.name)) if keep_all else self._occupied(r)
        r.alive = False
        r.occupied = frozenset(occ)
        self.metrics.deaths += 1
        self._log(now, f"{r.name} dead ({reason}); keeps {sorted(map(str, occ))}")
        self._drop_claims(r)
        for x in self.table.release_all(r.name, keep=occ):
            self._wake(x)
        for x in occ:
            if isinstance(x, str):
                self._dead_nodes[x] = r.name
        if r.wait_since is not None:
            r.wait_total += now - r.wait_since
            r.wait_events += 1
            r.wait_since = None
        self._waiting.discard(r.name)
        r.back = {x for x in occ if isinstance(x, str)}
        r.loop = None
        r.path = [r.path[r.cur]] if r.path else []
        r.must = [True] * len(r.path)
        r.cum = [0.0] * len(r.path)
        r.offset += r.cur
        r.cur = r.g = 0
        r.path_id += 1
        r.yield_to = {}
        r.blockers = set()
        r.blocked_on = set()
        r.prog_x, r.prog_y = r.x, r.y
        self._changed.add(r.name)
        for o in self._robots.values():
            if o.alive and o is not r:
                self._avoid_dead(o)

    def _revive(self, r: _Robot, now: float) -> None:
        r.alive = True
        for x in r.occupied:
            if isinstance(x, str) and self._dead_nodes.get(x) == r.name:
                del self._dead_nodes[x]
        r.occupied = frozenset()
        node = self.nearest_node(r.x, r.y)
        if not self.table.try_acquire(r.name, [node]):
            r.back.add(node)
            r.offset += 1
            r.path, r.must, r.cum = [node], [True], [0.0]
            r.cur = r.g = 0
            r.path_id += 1
        r.prog_x, r.prog_y, r.prog_t = r.x, r.y, now
        self._log(now, f"{r.name} alive again")
        self._changed.add(r.name)
        self._dirty.add(r.name)

    def _avoid_dead(self, r: _Robot, start: int | None = None) -> None:
        """Reroute the not-yet-granted part of ``r``'s path around dead robots' nodes; a
        must-visit node held by a dead robot is skipped."""
        if not self._dead_nodes or not r.alive:
            return
        dead = self._dead_nodes
        i = max(r.g, start if start is not None else r.g) + 1
        guard = 0
        while i < len(r.path) and guard < 64:
            guard += 1
            if r.path[i] not in dead:
                i += 1
                continue
            a = i - 1
            b = i
            while b < len(r.path) and (r.path[b] in dead or not r.must[b]) and b < len(r.path) - 1:
                b += 1
            if r.path[b] in dead:
                return  # the path ends on a dead robot: nothing to do but wait
            seg = self._shortest(r.path[a], r.path[b], set(dead))
            if seg is None:
                return
            self._splice(r, a, b, seg)
            self.metrics.dead_reroutes += 1
            i = a + len(seg)

    def _get(self, robot: str) -> _Robot:
        r = self._robots.get(robot)
        if r is None:
            raise TrafficError(f"unknown robot {robot!r}")
        return r


# ----------------------------------------------------------------------------- robot side


class FollowerStatus(enum.Enum):
    """What a :class:`TrafficFollower` is doing."""

    IDLE = "idle"  # no grant, or no path
    DRIVING = "driving"  # a goal to the granted horizon is executing
    WAITING = "waiting"  # standing at the end of its grant, waiting for more
    ARRIVED = "arrived"  # the grant was final and the robot reached it
    STOPPED = "stopped"  # the manager treats the robot as dead: goals canceled


class TrafficFollower:
    """Drives one robot through :class:`Grant` s on any :class:`NavigationBackend`.

    Call :meth:`apply` with the robot's latest grant every tick (it is idempotent). It sends
    ``NavigateThroughPoses`` through the granted poses only, extends the goal (by preempting
    it with a longer one) once the robot is within ``refresh_m`` of the goal's end or stopped,
    sends a shorter goal at once if the grant shrank (a new path), and cancels the goal when
    the manager declares the robot dead. Leading poses the robot already stands within
    ``skip_m`` of are dropped so that a resent goal does not make it turn back. A goal that
    ends ABORTED is resent after ``retry_s`` (``now`` is passed in).
    """

    def __init__(
        self, backend: NavigationBackend, refresh_m: float = 2.5, skip_m: float = 0.35, retry_s: float = 1.0
    ) -> None:
        self.backend = backend
        self.refresh_m = refresh_m
        self.skip_m = skip_m
        self.retry_s = retry_s
        self.goal_id: str | None = None
        self.sent: tuple[int, int] | None = None  # (path_id, horizon) of the goal sent
        self.sent_end: Pose2D | None = None
        self.goals_sent = 0
        self._last_send = -math.inf
        self.status = FollowerStatus.IDLE

    def apply(self, grant: Grant | None, now: float = 0.0) -> FollowerStatus:
        """Act on ``grant`` (see the class docstring); returns the follower's status."""
        b = self.backend
        if grant is None or not grant.alive:
            self._cancel()
            self.status = FollowerStatus.STOPPED if grant is not None else FollowerStatus.IDLE
            return self.status
        state = b.goal_state(self.goal_id) if self.goal_id is not None else None
        active = state is not None and not state.status.terminal
        if not grant.nodes:
            if self.sent is not None and self.sent[0] != grant.path_id and active:
                self._cancel()  # a new path that starts where the robot stands
                active = False
            if active:
                self.status = FollowerStatus.DRIVING
            elif grant.done:
                self.status = FollowerStatus.ARRIVED
            else:
                self.status = FollowerStatus.WAITING if grant.waiting else FollowerStatus.IDLE
            return self.status
        n = self._leg_length(grant)
        key = (grant.path_id, grant.horizon - len(grant.nodes) + n)
        if key == self.sent:
            if active:
                self.status = FollowerStatus.DRIVING
                return self.status
            if state is not None and state.status is GoalStatus.SUCCEEDED:
                self.status = (
                    FollowerStatus.ARRIVED
                    if grant.final and n == len(grant.nodes)
                    else FollowerStatus.WAITING
                )
                return self.status
            if now - self._last_send < self.retry_s:
                self.status = FollowerStatus.WAITING
                return self.status
            # aborted or canceled under us: send again
        elif active and self.sent is not None and self.sent[0] == grant.path_id and key[1] > self.sent[1]:
            pose = b.robot_state().pose
            end = self.sent_end
            if (
                pose is not None
                and end is not None
                and pose.distance_to(end) > self.refresh_m
                and self._ahead_ok(state)
            ):
                self.status = FollowerStatus.DRIVING
                return self.status
        self._send(grant, n, key, now)
        self.status = FollowerStatus.DRIVING
        return self.status

    @staticmethod
    def _leg_length(grant: Grant) -> int:
        """How many of the granted poses one goal may take: up to the first turn-back (a pose
        where the path reverses onto where it came from), because a navigation stack checks
        only the final pose and would call a goal that ends where it started reached."""
        nodes = (grant.current,) + grant.nodes if grant.current is not None else grant.nodes
        off = 1 if grant.current is not None else 0
        for k in range(1, len(nodes) - 1):
            if nodes[k + 1] == nodes[k - 1] or nodes[k + 1] == nodes[k]:
                return k + 1 - off if k + 1 - off > 0 else 1
        return len(grant.nodes)

    def _ahead_ok(self, state: Any) -> bool:
        # keep driving the old goal only while the robot still has some way to go in it
        fb = getattr(state, "feedback", None)
        rem = getattr(fb, "distance_remaining_m", None)
        return rem is None or rem > self.refresh_m

    def _send(self, grant: Grant, n: int, key: tuple[int, int], now: float) -> None:
        poses = list(grant.poses[:n])
        pose = self.backend.robot_state().pose
        if pose is not None:
            while len(poses) > 1 and pose.distance_to(poses[0]) <= self.skip_m:
                poses.pop(0)
        self.goal_id = self.backend.send_goal(NavigateThroughPoses(tuple(poses)))
        self.sent = key
        self.sent_end = poses[-1]
        self.goals_sent += 1
        self._last_send = now

    def _cancel(self) -> None:
        if self.goal_id is not None:
            self.backend.cancel_goal(self.goal_id)
        self.sent = None


# ----------------------------------------------------------------------------- coordinator glue


#: Why a robot drives, as carried by :attr:`Grant.purpose`.
PURPOSE_PATROL = "patrol"
PURPOSE_CHARGE = "charge"
PURPOSE_CHARGE_WAIT = "charge-wait"
PURPOSE_PARK = "park"
#: Base priority of a robot that needs a charger (times ``2 - battery``): it outranks any
#: waiting robot, so it is not the one asked to yield on the way to the charger.
CHARGE_PRIORITY = 1000.0


class ReservationTraffic:
    """A ``fleet.coordinator.TrafficPolicy`` backed by a :class:`TrafficManager`.

    It decides *where* each robot drives; the manager decides *when*:

    * ``on_assign`` gives the robot its patrol loop (the route's waypoint nodes joined by
      shortest roadmap paths, every waypoint must-visit); ``on_release`` drops it.
    * A robot whose status mode is ``charging`` is sent to the nearest charger dock that
      nobody holds or heads for, lowest battery first; if every charger is taken it waits
      at a free parking dock near the chargers (purpose ``charge-wait``) and is sent on when
      a charger frees.
    * A robot idle (no route, mode ``idle``) for ``park_idle_s`` that does not stand on a
      parking or charger dock is sent to the nearest free parking dock, so idle robots do
      not stand in aisles. A robot on a charger dock that has finished charging is moved
      to parking only when another robot waits for a charger.
    * ``cycle`` feeds every robot view's pose and liveness into the manager, runs one manager
      cycle and hands every changed grant, stamped with the robot's task id, purpose, lap
      count and a per-robot ``seq``, to ``deliver(robot, grant)``. Robots are registered the
      first time their pose is seen (a robot whose node another robot holds waits,
      unregistered and standing still, until it is free).
    * Deadlocks for the fleet report: a set of robots waiting on each other (a wait-for
      cycle) for more than ``deadlock_s``; each such set counts once while it lasts
      (:attr:`deadlocks`, episodes in :attr:`deadlock_events`).

    ``roadmap`` is the traffic roadmap (with docks, see :func:`traffic_from_config`);
    ``chargers`` / ``parking`` are its dock node names.
    """

    def __init__(
        self,
        roadmap: Roadmap,
        params: TrafficParams | None = None,
        deliver: Callable[[str, Grant], None] | None = None,
        *,
        chargers: Sequence[str] = (),
        parking: Sequence[str] = (),
        deadlock_s: float = 30.0,
        park_idle_s: float = 5.0,
    ) -> None:
        self.roadmap = roadmap
        self.manager = TrafficManager(roadmap, params)
        self.deliver = deliver
        self.chargers = list(dict.fromkeys(chargers))
        self.parking = [n for n in dict.fromkeys(parking) if n not in set(self.chargers)]
        self._parking_set = set(self.parking)
        self._charger_set = set(self.chargers)
        self.deadlock_s = float(deadlock_s)
        self.park_idle_s = float(park_idle_s)
        self.deadlocks = 0
        self.deadlock_events: list[tuple[float, tuple[str, ...]]] = []
        self._open_deadlocks: set[frozenset[str]] = set()
        self._now = 0.0
        self._pending: dict[str, list[str]] = {}
        self._task: dict[str, str | None] = {}
        self._purpose: dict[str, str] = {}
        self._target: dict[str, str] = {}
        self._idle_since: dict[str, float] = {}
        self._seq: dict[str, int] = {}
        self._coord_dead: set[str] = set()
        self._charge_wait: set[str] = set()
        self._last_dl = -math.inf
        self._charger_dist: dict[str, float] | None = None
        # grants of a later policy (a restarted coordinator) must outrank older ones at the
        # robots: seq counts up from the wall time this policy was made, in microseconds
        self._seq_base = time.time_ns() // 1000

    # -- TrafficPolicy -----------------------------------------------------------------

    def on_assign(
        self, robot: str, route: Any, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]:
        nodes = [str(n) for n in getattr(route, "nodes", ())]
        if nodes:
            self._pending[robot] = nodes
            self._task[robot] = task_id
            self._apply_pending(robot)
        return poses

    def on_release(self, robot: str) -> None:
        self._pending.pop(robot, None)
        self._task[robot] = None
        if self._purpose.get(robot) == PURPOSE_PATROL:
            self._purpose.pop(robot, None)
        if robot in self.manager.robots and self.manager.is_alive(robot):
            self.manager.clear_path(robot, self._now)

    def waiting(self, robot: str) -> bool:
        """True while ``robot`` stands still because the manager has not granted it more
        path, for a live robot ahead (so the coordinator must not call it stuck). A robot
        held up by a dead robot is not "waiting": the coordinator's stuck rule then gives its
        route to a robot that can reach it."""
        m = self.manager
        if robot not in m.robots:
            return robot in self._pending or robot in self._task and self._task[robot] is not None
        if robot not in m.waiting():
            return False
        return not any(b in m.robots and not m.is_alive(b) for b in m.blockers(robot))

    def cycle(self, now: float, robots: Mapping[str, Any]) -> Sequence[Any]:
        self._now = now
        m = self.manager
        requests: list[tuple[float, str]] = []
        for name, v in robots.items():
            obs = getattr(v, "obs", None)
            pose = getattr(obs, "pose", None) if obs is not None else None
            alive = bool(getattr(v, "alive", True))
            if name not in m.robots:
                if pose is None or not alive:
                    continue
                try:
                    m.add_robot(name, pose, now)
                except TrafficError:
                    continue  # its node is held: it stays put, unregistered, until it is free
            if not alive:
                if m.is_alive(name):
                    # its agent is gone but the robot may still drive its last goal: it
                    # keeps its whole grant
                    m.declare_dead(name, now, "coordinator: dead", keep_grant=True)
                self._coord_dead.add(name)
                self._purpose.pop(name, None)
                continue
            if name in self._coord_dead:
                self._coord_dead.discard(name)
                m.declare_alive(name, now)
            if pose is not None:
                m.update(name, pose, now)
            if name in self._pending:
                self._apply_pending(name)
            self._errands(name, v, obs, now, requests)
        self._serve_chargers(requests)
        changed = m.cycle(now)
        self._count_deadlocks(now)
        if self.deliver is not None:
            for name in sorted(changed):
                self.deliver(name, self.grant(name))
        return ()

    # -- queries -----------------------------------------------------------------------

    def grant(self, robot: str) -> Grant:
        """The robot's current grant, stamped with its task, purpose, laps and a new ``seq``."""
        g = self.manager.grant(robot)
        seq = self._seq.get(robot, self._seq_base) + 1
        self._seq[robot] = seq
        purpose = self._purpose.get(robot, "")
        task = self._task.get(robot) if purpose == PURPOSE_PATROL else None
        laps = self.manager.laps(robot) if purpose == PURPOSE_PATROL else 0
        return dataclasses.replace(g, task_id=task, purpose=purpose, laps=laps, seq=seq)

    def purpose(self, robot: str) -> str:
        return self._purpose.get(robot, "")

    def mean_wait_s(self, now: float) -> float:
        return self.manager.mean_wait_s(now)

    # -- internals ---------------------------------------------------------------------

    def _set_path(
        self, robot: str, nodes: list[str], purpose: str, must: list[int] | None = None, loop: bool = False
    ) -> None:
        m = self.manager
        if not m.is_alive(robot):
            m.declare_alive(robot, self._now)  # e.g. stalled earlier: a new errand revives it
        m.set_path(robot, nodes, self._now, must_visit=must, loop=loop)
        self._purpose[robot] = purpose

    def _apply_pending(self, robot: str) -> None:
        m = self.manager
        if robot in m.robots:
            m.set_priority(robot, 0.0)
        nodes = self._pending.get(robot)
        if nodes is None or robot not in m.robots or robot in self._coord_dead:
            return
        del self._pending[robot]
        self._target.pop(robot, None)
        self._charge_wait.discard(robot)
        loop = self.roadmap.expand_route(nodes, closed=True)
        wps = set(nodes)
        if len(loop) < 2:
            self._set_path(robot, loop, PURPOSE_PATROL)
        else:
            self._set_path(
                robot, loop, PURPOSE_PATROL, must=[i for i, n in enumerate(loop) if n in wps], loop=True
            )

    def _errands(self, name: str, v: Any, obs: Any, now: float, requests: list[tuple[float, str]]) -> None:
        """Charging and parking trips (see the class docstring). Robots that need a charger
        are collected in ``requests`` as ``(battery, robot)``: :meth:`_serve_chargers`."""
        mode = getattr(obs, "mode", None) if obs is not None else None
        purpose = self._purpose.get(name, "")
        target = self._target.get(name)
        if target is not None and self.manager.holder(target) not in (None, name):
            # another robot stepped onto the dock this robot heads for (e.g. to let a third
            # pass): choose another dock rather than wait for it, head-on on a dead-end spur
            self._target.pop(name, None)
            if purpose in (PURPOSE_CHARGE, PURPOSE_CHARGE_WAIT):
                self._purpose.pop(name, None)
                self._charge_wait.discard(name)
                purpose = ""
            elif purpose == PURPOSE_PARK:
                self._go(name, self._free_dock(name, self.parking), PURPOSE_PARK)
                return
        if mode == "charging":
            self._idle_since.pop(name, None)
            if purpose != PURPOSE_CHARGE:
                requests.append((float(getattr(obs, "battery", 0.0)), name))
            return
        if mode != "idle" or getattr(v, "assignment", None) is not None or name in self._pending:
            self._idle_since.pop(name, None)
            return
        if purpose in (PURPOSE_CHARGE, PURPOSE_CHARGE_WAIT):
            self.manager.set_priority(name, 0.0)
            self._purpose.pop(name, None)  # charged: now simply idle where it stands
            self._target.pop(name, None)
            self._charge_wait.discard(name)
            purpose = ""
        since = self._idle_since.setdefault(name, now)
        if purpose == PURPOSE_PARK or now - since < self.park_idle_s:
            return
        path = self.manager.path(name)
        here = path[0] if path else None
        if here in self._parking_set:
            return
        if here in self._charger_set and not self._charge_wait:
            return
        self._go(name, self._free_dock(name, self.parking), PURPOSE_PARK)

    def _serve_chargers(self, requests: list[tuple[float, str]]) -> None:
        """Free chargers go to the robots with the lowest battery first; the others wait on a
        free parking dock near the chargers (once; they stay there until a charger frees)."""
        if not requests:
            return
        for battery, name in sorted(requests):
            # a robot short of energy goes first at intersections and is never the one to yield
            self.manager.set_priority(name, CHARGE_PRIORITY * (2.0 - battery))
            node = self._free_dock(name, self.chargers)
            if node is not None:
                self._go(name, node, PURPOSE_CHARGE)
            elif self._purpose.get(name) != PURPOSE_CHARGE_WAIT:
                self._go(name, self._free_dock(name, self.parking, self._to_charger()), PURPOSE_CHARGE_WAIT)

    def _to_charger(self) -> dict[str, float]:
        """Roadmap distance (m) from every node to its nearest charger dock (cached)."""
        if self._charger_dist is None:
            self._charger_dist = (
                dict(
                    nx.multi_source_dijkstra_path_length(
                        self.roadmap.graph, set(self.chargers), weight="length"
                    )
                )
                if self.chargers
                else {}
            )
        return self._charger_dist

    def _go(self, name: str, node: str | None, purpose: str) -> bool:
        if node is None:
            return False
        self._target[name] = node
        if purpose == PURPOSE_CHARGE_WAIT:
            self._charge_wait.add(name)
        else:
            self._charge_wait.discard(name)
        self._set_path(name, [node], purpose)
        return True

    def _free_dock(
        self, robot: str, docks: Sequence[str], first: Mapping[str, float] | None = None
    ) -> str | None:
        """The dock nearest ``robot`` (roadmap distance; with ``first``, the dock of least
        ``first[dock]``, then nearest) that nobody else holds or heads for."""
        m = self.manager
        taken = {n for r, n in self._target.items() if r != robot}
        free = [d for d in docks if m.holder(d) in (None, robot) and d not in taken]
        if not free:
            return None
        path = m.path(robot)
        here = path[0] if path else self.roadmap.nearest_node(*m.node_pos(free[0]))
        dist = nx.single_source_dijkstra_path_length(self.roadmap.graph, here, weight="length")
        if first is None:
            return min(free, key=lambda d: (dist.get(d, math.inf), d))
        return min(free, key=lambda d: (round(first.get(d, math.inf), 1), dist.get(d, math.inf), d))

    def _count_deadlocks(self, now: float) -> None:
        if now - self._last_dl < self.manager.params.detect_period_s:
            return
        self._last_dl = now
        current = set(self.manager.deadlocked(now, self.deadlock_s))
        for c in current - self._open_deadlocks:
            self.deadlocks += 1
            self.deadlock_events.append((now, tuple(sorted(c))))
        self._open_deadlocks = current


def traffic_from_config(
    config: FleetConfig, deliver: Callable[[str, Grant], None] | None = None
) -> ReservationTraffic:
    """The :class:`ReservationTraffic` of a fleet config: its roadmap with the chargers,
    parking spots and robot start poses joined as docks (:func:`fleet.docks.add_docks`),
    :class:`TrafficParams` from ``robot_model.radius`` and the ``traffic`` section. Raises
    :class:`~fleet.errors.ConfigError` (field ``traffic``) if a dock cannot be joined."""
    from fleet.docks import DockError, add_docks
    from fleet.errors import ConfigError
    from fleet.roadmap import Roadmap

    ts = config.traffic
    params = TrafficParams(
        robot_radius=config.sim.model.radius,
        horizon_m=ts.horizon_m,
        stall_timeout_s=ts.stall_timeout_s,
    )
    docks: list[tuple[str, Pose2D]] = [(f"charger:{c.name}", c.pose) for c in config.chargers]
    docks += [(f"park:{i}", p) for i, p in enumerate(config.parking)]
    docks += [(f"start:{r.name}", r.start) for r in config.robots]
    try:
        g, node_of = add_docks(
            config.roadmap.graph, docks, params.clearance, config.grid, params.robot_radius
        )
    except DockError as e:
        raise ConfigError(str(config.path), "traffic", str(e)) from None
    chargers = [node_of[f"charger:{c.name}"] for c in config.chargers]
    # idle robots park only on docks (a start pose on a roadmap node is no parking spot)
    parking = [
        node_of[label]
        for label, _ in docks
        if not label.startswith("charger:") and g.nodes[node_of[label]].get("dock")
    ]
    return ReservationTraffic(
        Roadmap.from_graph(g),
        params,
        deliver,
        chargers=chargers,
        parking=parking,
        deadlock_s=ts.deadlock_s,
        park_idle_s=ts.park_idle_s,
    )
