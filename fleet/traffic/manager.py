"""Traffic management on the roadmap: node and edge reservations ahead of every robot.

The :class:`TrafficManager` is the fleet's single owner of the roadmap's right of way. It
sees only the roadmap, each robot's planned node path, the robots' positions
(:class:`~fleet.types.Pose2D`, ``map`` frame) and their liveness; it never talks to a robot.
Each cycle it hands out, per robot, the prefix of its path the robot may drive now (a
:class:`~fleet.messages.Grant`). :class:`~fleet.traffic.follower.TrafficFollower` turns a
grant into ``NavigateThroughPoses`` goals on any :class:`~fleet.navigation.NavigationBackend`,
so the same code drives the in-process simulator, ROS 2 Nav2 robots and SUMO vehicles. See
``docs/traffic.md``.

Rules (the contract the tests check):

* Resources are roadmap nodes and undirected edges. A
  :class:`~fleet.traffic.reservations.ReservationTable` never lets two robots hold the same
  resource.
* A robot holds the node it stands on and the nodes and edges of its granted prefix. It may
  only drive inside what it holds. Nodes behind it are released once it is farther than
  ``clearance_m`` from them; the edge behind it when it reaches the next node
  (:mod:`fleet.traffic.tracking`).
* Grants grow by *blocks*: the next path node, and if that node is inside a single-lane
  corridor (roadmap degree 2), every following node of the corridor, all or nothing, and
  the node at its far end (the next node of degree other than 2) or the path's end. So two
  robots can never meet head-on inside a corridor. The far end is in the block when it is a
  dead end or the path's end, or when another robot is about to come from it into the
  corridor; otherwise (``TrafficParams.hold_far_end`` off, the default) the junction at the
  far end is taken as a block of its own when the robot gets there, so robots crossing at
  the aisle's end are not held up while it drives through the aisle (:mod:`fleet.traffic.grants`).
* The remaining waits can form cycles (two robots at both ends of one aisle, four robots
  around an intersection). The manager keeps a wait-for graph (robot -> holders of what it
  waits for), finds its strongly connected components with networkx every
  ``detect_period_s``, and when a cycle has stood still for ``deadlock_detect_s`` makes its
  lowest-priority robot that *can* yield do so: reroute around the others (bounded detour),
  or step aside to a free node nearby and come back after the others have passed
  (:mod:`fleet.traffic.deadlocks`).
* Priority ages: a robot's priority grows with its current wait and with every time it
  yielded, grants are handed out oldest-waiter first, and a robot waiting longer than
  ``starve_s`` claims the block it waits for, so younger robots cannot keep taking it.
* A robot declared dead (:meth:`TrafficManager.declare_dead`), or that has had a grant
  ahead but made no progress for ``stall_timeout_s``, or (if ``stale_timeout_s`` is set) sent
  no position for that long, keeps only what it physically occupies (nodes within
  ``clearance_m``, the edge it is on); everything else is released and the robots whose
  paths cross its nodes are rerouted around them when the roadmap allows (a must-visit
  node it holds is skipped). A robot declared dead with ``keep_grant`` (the coordinator
  lost its agent, but the robot may still be driving its last goal) keeps its whole grant
  (:mod:`fleet.traffic.failures`).

Time is always passed in (seconds); nothing here reads a clock. Units: meters, seconds."""

from __future__ import annotations

import math
from collections.abc import Container, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, cast

import networkx as nx

from fleet.errors import TrafficError
from fleet.messages import Grant
from fleet.traffic.contraflow import CONTRAFLOW_GAIN_M, reserve
from fleet.traffic.deadlocks import cycles, detect_and_resolve
from fleet.traffic.failures import avoid_dead, kill, revive, shrink
from fleet.traffic.grants import extend
from fleet.traffic.params import TrafficParams
from fleet.traffic.paths import checked_path, errand_way, install, join, pose_at
from fleet.traffic.reservations import ReservationTable, Resource, edge_key
from fleet.traffic.roads import RoadIndex
from fleet.traffic.state import TrackedRobot, TrafficMetrics, TrafficState
from fleet.traffic.tracking import extend_loop, track
from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.roadmap.graph import Roadmap


class TrafficManager:
    """Reservation-based traffic management on a roadmap (see the module docstring).

    Typical use, once per coordinator cycle::

        tm.update(robot, pose, now)          # for every robot with a fresh position
        changed = tm.cycle(now)              # robots whose grant changed
        for r in changed: deliver(r, tm.grant(r))

    Paths are given with :meth:`set_path` (``loop=True`` for a patrol loop that repeats
    forever) and dropped with :meth:`clear_path`. The manager may replace the part of a path
    between the robot and its next must-visit node (reroutes, side steps); the robot learns
    it through the grant. ``roadmap`` is a :class:`fleet.roadmap.graph.Roadmap` or a
    ``networkx.Graph`` with node attribute ``pos`` and (optional) edge attribute ``length``.
    Raises :class:`TrafficError` if ``params.clearance`` does not exceed two robot radii.

    Attributes: ``params``, ``graph`` (the roadmap graph), ``table`` (the reservations),
    ``metrics`` (:class:`~fleet.traffic.state.TrafficMetrics`, fleet totals).
    """

    def __init__(self, roadmap: Roadmap | nx.Graph[str], params: TrafficParams | None = None) -> None:
        g = roadmap if isinstance(roadmap, nx.Graph) else roadmap.graph
        self.params = params or TrafficParams()
        p = self.params
        if p.clearance <= 2.0 * p.robot_radius:
            raise TrafficError(f"TrafficParams.clearance_m ({p.clearance}) must exceed two robot radii")
        self.graph: nx.Graph[str] = g
        self._st = TrafficState(RoadIndex(g), p)
        self.table: ReservationTable = self._st.table
        self.metrics: TrafficMetrics = self._st.metrics
        self._recheck: dict[str, float] = {}  # robot -> when shorten_errand may look again

    # ------------------------------------------------------------------ robots

    @property
    def robots(self) -> list[str]:
        """Every registered robot, in registration order."""
        return list(self._st.robots)

    def knows(self, robot: str) -> bool:
        """Whether ``robot`` is registered (``robot in robots`` without copying the list)."""
        return robot in self._st.robots

    def add_robot(self, robot: str, pose: Pose2D, now: float, priority: float = 0.0) -> str:
        """Register ``robot`` standing at ``pose``; it holds its nearest roadmap node, which is
        returned. Raises :class:`TrafficError` if the robot is known or the node is held by
        another robot (two robots cannot start on one node)."""
        st = self._st
        if robot in st.robots:
            raise TrafficError(f"robot {robot!r} is already registered")
        node = st.roads.nearest_node(pose.x, pose.y)
        other = st.table.holder(node)
        if other is not None:
            raise TrafficError(f"robot {robot!r} starts at node {node!r}, which {other!r} holds")
        r = TrackedRobot(robot, len(st.robots), now)
        r.base_priority = float(priority)
        r.x, r.y = pose.x, pose.y
        r.prog_x, r.prog_y = pose.x, pose.y
        r.path, r.must, r.cum = [node], [True], [0.0]
        st.robots[robot] = r
        st.table.try_acquire(robot, [node])
        r.back.add(node)
        return node

    def update(self, robot: str, pose: Pose2D, now: float) -> None:
        """The latest position of ``robot`` (``map`` frame). Cheap: geometry runs in
        :meth:`cycle`. A dead robot that moved more than ``2 * clearance_m`` is revived."""
        r = self._st.robots.get(robot)
        if r is None:
            raise TrafficError(f"unknown robot {robot!r}")
        r.x = pose.x
        r.y = pose.y
        r.last_update = now
        if not r.alive and math.hypot(r.x - r.prog_x, r.y - r.prog_y) > 2.0 * self.params.clearance:
            revive(self._st, r, now)

    def set_flow(self, moves: Iterable[tuple[str, str]]) -> None:
        """The directed edges the fleet drives (e.g. the steps of its patrol loops): paths the
        manager plans from now on avoid driving against them
        (``TrafficParams.flow_penalty``, :meth:`RoadIndex.set_flow`)."""
        self._st.roads.set_flow(moves, self._st.params.flow_penalty)

    def costs_from(self, node: str) -> Mapping[str, float]:
        """Cost (m, against-the-flow edges weighted) of the cheapest path from ``node`` to every
        node, as the manager plans its own paths (:meth:`RoadIndex.costs_from`)."""
        return self._st.roads.costs_from(node)

    def route(self, stops: Sequence[str]) -> list[str]:
        """``stops`` joined by the paths the manager plans itself (shortest with the fleet's
        flow, :meth:`costs_from`), visited in order. Raises :class:`TrafficError` when a leg
        cannot be driven."""
        roads = self._st.roads
        out = list(stops[:1])
        for a, b in zip(stops, stops[1:], strict=False):
            leg = roads.shortest(a, b, ())
            if leg is None:
                raise TrafficError(f"no roadmap path from {a!r} to {b!r}")
            out += leg[1:]  # a shortest leg never comes back to its start
        return out

    def costs_near(self, node: str, targets: Iterable[str], reach: float = math.inf) -> dict[str, float]:
        """:meth:`costs_from` ``node`` of the ``targets`` at most ``reach`` (m) beyond the
        nearest of them, from a search that stops there (:meth:`RoadIndex.costs_near`)."""
        return self._st.roads.costs_near(node, targets, reach)

    def nearest(self, node: str, candidates: Iterable[str]) -> str | None:
        """The candidate node of least :meth:`costs_from` ``node`` (ties: the least name);
        ``None`` for none (:meth:`RoadIndex.nearest`: stops at the nearest)."""
        return self._st.roads.nearest(node, candidates)

    def set_priority(self, robot: str, priority: float) -> None:
        """Base priority of ``robot`` (higher goes first and yields last; default 0)."""
        self._st.get(robot).base_priority = float(priority)

    def set_detour_limit(self, robot: str, meters: float | None) -> None:
        """How much longer (m) than its way a detour around a dead robot may be for ``robot``
        (``None``, the default: any). Set it for a robot that cannot afford a long way round
        (short of energy, on its way to a charger): it then waits before a dead robot rather
        than drive far round it, and only after ``dead_wait_s`` of waiting is it rerouted."""
        self._st.get(robot).detour_m = None if meters is None else float(meters)

    def detour_limit(self, robot: str) -> float | None:
        """``robot``'s detour limit (m; see :meth:`set_detour_limit`), ``None`` for none."""
        return self._st.get(robot).detour_m

    def declare_dead(
        self, robot: str, now: float, reason: str = "declared dead", keep_grant: bool = False
    ) -> None:
        """``robot`` is dead (or stopped for good): release all it holds except what it
        physically occupies, drop its path, reroute others around its nodes. With
        ``keep_grant`` it keeps everything it holds: for a robot whose controller is gone
        but which may still be driving its last goal, to the end of its grant."""
        r = self._st.get(robot)
        if r.alive:
            kill(self._st, r, now, reason, keep_all=keep_grant)

    def release_dead(self, robot: str, now: float) -> None:
        """The dead ``robot`` (declared with ``keep_grant``) keeps only what it physically
        occupies; the rest is released and routes across its old grant are replanned."""
        r = self._st.get(robot)
        if not r.alive:
            shrink(self._st, r, now)

    def declare_alive(self, robot: str, now: float) -> None:
        """``robot`` is back: it keeps what it occupies and must be given a path again."""
        r = self._st.get(robot)
        if not r.alive:
            revive(self._st, r, now)

    def is_alive(self, robot: str) -> bool:
        """False while the manager treats ``robot`` as dead."""
        return self._st.get(robot).alive

    # ------------------------------------------------------------------ paths

    def set_path(
        self,
        robot: str,
        nodes: Sequence[str],
        now: float,
        must_visit: Iterable[int] | None = None,
        loop: bool = False,
        turn_back: bool = False,
    ) -> int:
        """Give ``robot`` the node path ``nodes`` (consecutive nodes must be roadmap edges).

        The robot first finishes its current grant; the new path is joined from there
        (where it crosses the grant, or by a shortest path to ``nodes[0]``). With
        ``turn_back`` (errands) the robot may turn back, from its grant's end or from a node
        before it (the grant is then cut back there), and drive against the fleet's flow
        where nobody comes, when that way is shorter (:func:`fleet.traffic.paths.errand_way`). ``must_visit``
        are indices into ``nodes`` that detours must keep (default: the last node; with
        ``loop`` every node). With ``loop=True`` the path repeats forever (``nodes[-1]`` must
        be adjacent to ``nodes[0]`` or equal to it); :meth:`laps` counts completed loops.
        Returns the new ``path_id`` (the old one for a dead robot, whose path is ignored).
        Raises :class:`TrafficError` for an unknown node, a missing edge or an empty path.
        """
        st = self._st
        r = st.get(robot)
        seq, must = checked_path(st.roads, robot, nodes, must_visit, loop)
        st.now = now
        if not r.alive:
            return r.path_id
        way = errand_way(st, r, seq[0]) if turn_back and not loop else None
        prefix = r.path[r.cur : r.g + 1]
        pm = [False] * len(prefix) if loop else r.must[r.cur : r.g + 1]
        if way is not None and len(way) > 1:
            new_nodes, new_must = way[1:] + seq[1:], [False] * (len(way) - 2) + must
        else:
            new_nodes, new_must = join(st.roads, prefix, seq, must, loop)
        r.loop = (list(seq), list(must)) if loop else None
        r.must_passed = 0
        install(st, r, prefix + new_nodes, pm + new_must)
        if way is not None and len(way) > 1 and self.params.contraflow_m > 0.0:
            reserve(st, r, way)
        if loop:
            extend_loop(st, r)
        avoid_dead(st, r)
        return r.path_id

    def shorten_errand(self, robot: str, now: float) -> bool:
        """With ``TrafficParams.contraflow_m``: look again (at most every ``detect_period_s``)
        for a way for ``robot``, on an errand path (driven once, to the dock at its end), that
        is at least :data:`~fleet.traffic.contraflow.CONTRAFLOW_GAIN_M` shorter than the rest
        of its path, turning back or driving against the flow where the stretch is free
        (:func:`fleet.traffic.paths.errand_way`); take it, reserving that stretch end to end
        (:func:`fleet.traffic.contraflow.reserve`). Whether it did. The caller says which
        robots are on errands (the policy: charging and parking trips)."""
        p = self.params
        st = self._st
        r = st.get(robot)
        if p.contraflow_m <= 0.0 or not r.alive or r.loop is not None or r.cur >= len(r.path) - 1:
            return False
        if now < self._recheck.get(robot, -math.inf):
            return False
        self._recheck[robot] = now + p.detect_period_s
        target = r.path[-1]
        beat = r.cum[-1] - r.cum[r.cur] - CONTRAFLOW_GAIN_M
        tx, ty = st.roads.pos[target]
        if math.hypot(tx - r.x, ty - r.y) >= beat:
            return False  # no way can be that much shorter
        st.now = now
        way = errand_way(st, r, target, baseline=beat)
        if way is None or len(way) < 2:
            return False
        prefix = r.path[r.cur : r.g + 1]
        must = r.must[r.cur : r.g + 1] + [False] * (len(way) - 2) + [True]
        install(st, r, prefix + way[1:], must)
        reserve(st, r, way)
        return True

    def clear_path(self, robot: str, now: float) -> None:
        """Drop ``robot``'s path: it stops at the end of its current grant and keeps holding
        what it needs to get there and stand there."""
        r = self._st.get(robot)
        if not r.alive:
            return
        self._st.now = now
        r.loop = None
        install(self._st, r, r.path[r.cur : r.g + 1], r.must[r.cur : r.g + 1])

    def path(self, robot: str) -> list[str]:
        """The robot's remaining path, starting at the node it last reached."""
        r = self._st.get(robot)
        return r.path[r.cur :]

    def laps(self, robot: str) -> int:
        """Completed loops of a looped path since the last :meth:`set_path`: must-visit nodes
        reached divided by the must-visit nodes of one loop (0 for other paths)."""
        r = self._st.get(robot)
        if r.loop is None:
            return 0
        return r.must_passed // max(1, sum(r.loop[1]))

    def nodes_passed(self, robot: str) -> int:
        """Path nodes the robot reached since it was added."""
        return self._st.get(robot).passed

    def done(self, robot: str) -> bool:
        """True when the robot has reached the end of its (non-looped) path."""
        r = self._st.get(robot)
        return r.alive and r.cur >= len(r.path) - 1

    # ------------------------------------------------------------------ the cycle

    def cycle(self, now: float) -> set[str]:
        """One manager cycle at ``now``: track progress (release behind, count laps, detect
        stalls), extend grants oldest-waiter first, account waits, detect and resolve
        deadlocks. Returns the robots whose :meth:`grant` changed since the last cycle (its
        horizon, path, ``current`` node, ``waiting`` or ``alive``): deliver those."""
        st = self._st
        st.now = now
        st.dir_index = None
        track(st, now)
        dirty = st.dirty
        if dirty:
            robots = st.robots
            order = sorted(
                (robots[n] for n in dirty if n in robots),
                key=lambda r: (-st.priority(r, now), r.rank),
            )
            dirty.clear()
            for r in order:
                r.tried_t = now
                extend(st, r, now)
        if st.waiting and now >= st.next_detect:
            st.next_detect = now + self.params.detect_period_s
            detect_and_resolve(st, now)
        out = st.changed
        st.changed = set()
        return out

    def grant(self, robot: str) -> Grant:
        """The robot's current grant (see :class:`~fleet.messages.Grant`); ``task_id``,
        ``purpose``, ``laps`` and ``seq`` keep their defaults (the policy stamps them)."""
        st = self._st
        r = st.get(robot)
        path = r.path
        nodes = tuple(path[r.cur + 1 : r.g + 1]) if r.alive else ()
        poses = tuple(pose_at(st.roads, r, j) for j in range(r.cur + 1, r.cur + 1 + len(nodes)))
        return Grant(
            robot=robot,
            path_id=r.path_id,
            horizon=r.offset + (r.g if r.alive else r.cur),
            current=path[r.cur] if path else None,
            nodes=nodes,
            poses=poses,
            final=r.g >= len(path) - 1,
            waiting=r.name in st.waiting,
            done=r.alive and r.cur >= len(path) - 1,
            alive=r.alive,
        )

    # ------------------------------------------------------------------ queries

    def nearest_node(self, x: float, y: float) -> str:
        """The roadmap node nearest ``(x, y)`` (m, ``map`` frame)."""
        return self._st.roads.nearest_node(x, y)

    def holder(self, res: Resource) -> str | None:
        """The robot holding node or edge ``res``, or ``None``."""
        return self._st.table.holder(res)

    def free_docks(self, robot: str | None, docks: Sequence[str], skip: Container[str] = ()) -> list[str]:
        """The nodes of ``docks`` (in order) that nobody or ``robot`` holds and that are not in
        ``skip`` (:meth:`ReservationTable.free_for <fleet.traffic.reservations.ReservationTable.free_for>`)."""
        return cast("list[str]", self._st.table.free_for(robot, docks, skip))

    def held(self, robot: str) -> frozenset[Resource]:
        """The nodes and edges ``robot`` holds."""
        return self._st.table.held(robot)

    def claimant(self, res: Resource) -> str | None:
        """The starving robot that claimed ``res`` (younger robots may not take it), or ``None``."""
        return self._st.claims.get(res)

    def node_pos(self, node: str) -> tuple[float, float]:
        """``(x, y)`` of roadmap node ``node`` in meters."""
        return self._st.roads.pos[node]

    def waiting(self) -> set[str]:
        """Robots that have a path left but no grant beyond the node they stand on."""
        return set(self._st.waiting)

    def is_waiting(self, robot: str) -> bool:
        """Whether ``robot`` is in :meth:`waiting` (without copying the set)."""
        return robot in self._st.waiting

    def blockers(self, robot: str) -> set[str]:
        """Robots ``robot`` waits for (holders or claimants of what it needs next)."""
        return set(self._st.get(robot).blockers)

    def priority(self, robot: str, now: float) -> float:
        """``base + yields * yield_bonus + aging_per_s * seconds waiting`` (higher goes first)."""
        return self._st.priority(self._st.get(robot), now)

    def wait_stats(self, robot: str, now: float) -> tuple[float, int]:
        """``(total seconds waited, wait events)`` of ``robot`` (the current wait included)."""
        r = self._st.get(robot)
        t = r.wait_total + (now - r.wait_since if r.wait_since is not None else 0.0)
        return (t, r.wait_events + (1 if r.wait_since is not None else 0))

    def mean_wait_s(self, now: float) -> float:
        """Mean over robots of their total wait time (s)."""
        robots = self._st.robots
        if not robots:
            return 0.0
        return sum(self.wait_stats(n, now)[0] for n in robots) / len(robots)

    def wait_for_graph(self) -> nx.DiGraph[str]:
        """Directed graph robot -> robots it waits for, over the waiting robots."""
        g: nx.DiGraph[str] = nx.DiGraph()
        for name in self._st.waiting:
            g.add_node(name)
            for b in self._st.robots[name].blockers:
                g.add_edge(name, b)
        return g

    def deadlocked(self, now: float, limit_s: float) -> list[frozenset[str]]:
        """Sets of robots waiting on each other (a cycle of the wait-for graph, dead robots
        excluded) in which every robot has been waiting, on the same robots, for more than
        ``limit_s`` seconds: the fleet report's deadlocks."""
        return [frozenset(c) for c in cycles(self._st, now, limit_s + 1e-9)]

    def longest_wait(self, now: float) -> tuple[str | None, float]:
        """The robot that has been waiting longest right now and for how long (s); catches
        robots that never deadlock for long but never get through either."""
        best: tuple[str | None, float] = (None, 0.0)
        for n in self._st.waiting:
            w = self._st.robots[n].wait_since
            if w is not None and now - w > best[1]:
                best = (n, now - w)
        return best

    def check(self) -> None:
        """Raise ``AssertionError`` if a reservation invariant is broken (for tests)."""
        self.table.check()
        for r in self._st.robots.values():
            if not r.alive or not r.path:
                continue
            held = self.table.held(r.name)
            for j in range(r.cur + 1, r.g + 1):
                assert r.path[j] in held, f"{r.name} granted {r.path[j]} without holding it"
                a, b = r.path[j - 1], r.path[j]
                if a != b:
                    assert edge_key(a, b) in held, f"{r.name} granted edge {a}-{b} without holding it"
