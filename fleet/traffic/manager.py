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

Time is always passed in (seconds); nothing here reads a clock. Units: meters, seconds."""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import networkx as nx
import numpy as np

from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.roadmap.graph import Roadmap
from fleet.errors import TrafficError
from fleet.messages import Grant
from fleet.traffic.params import ONCOMING_NODES, TrafficParams
from fleet.traffic.reservations import ReservationTable, Resource, edge_key


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


#: Why a robot drives, as carried by :attr:`Grant.purpose`.
PURPOSE_PATROL = "patrol"


PURPOSE_CHARGE = "charge"


PURPOSE_CHARGE_WAIT = "charge-wait"


PURPOSE_PARK = "park"


#: Base priority of a robot that needs a charger (times ``2 - battery``): it outranks any
#: waiting robot, so it is not the one asked to yield on the way to the charger.
CHARGE_PRIORITY = 1000.0
