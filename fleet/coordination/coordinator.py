"""The fleet coordinator: who patrols which route, and what happens when a robot drops out.

Two layers, so the decisions can be tested without a network:

* :class:`CoordinatorState` is the pure decision logic. It is fed robot observations
  (:meth:`~CoordinatorState.observe`, :meth:`~CoordinatorState.robot_joined`,
  :meth:`~CoordinatorState.robot_left`) and, once per cycle, :meth:`~CoordinatorState.step`
  returns the :class:`TaskOrder` messages to send. It never reads a clock: every call takes
  ``now`` (seconds of the fleet clock, simulated time in a simulated run).
* :class:`Coordinator` is the thin bus-facing wrapper: it subscribes to ``fleet/*/status`` and
  the liveliness tokens on the :class:`~fleet.bus.status_bus.StatusBus`, feeds the state, and
  publishes the orders on ``fleet/<robot>/task``.

Rules (all times in seconds of the fleet clock):

* Patrols are the config's routes. Each route is held by at most one robot at a time; robots
  without a route idle as spares; routes without a robot wait.
* Assignment is a global greedy min-cost matching on roadmap travel cost (the robot's pose to
  the route's nearest waypoint, along the roadmap): the cheapest (robot, route) pair is
  matched first, then the next cheapest among the rest. Distances come from one Dijkstra per
  distinct start node (cached; the roadmap is read-only), and the cost matrix is built with
  numpy, so a cycle with 1000 idle robots and 1000 waiting routes stays well under a second.
* Every assignment has a fresh id ``p-0001``, ``p-0002``, ... (one counter for every order
  kind, so ids also order idle orders ``i-0003``). Ids are never reused.
* A route is taken back from its robot (a :class:`Reassignment` is recorded with the time and
  the reason) when the robot dies (its liveliness token disappears, or no status arrived for
  ``status_timeout_s``), is stuck (no progress of :data:`PROGRESS_M` for
  ``stuck_reassign_s`` while it should be driving), or goes to charge (its status reports
  ``mode == "charging"``). The robot gets an idle order, the route goes to the best available
  idle robot. A robot that was taken off a route for being stuck is not given a new route for
  ``stuck_reassign_s``; a charging robot becomes available again when it reports ``idle``.
* Laps: a status counts only for the assignment whose id it carries and only from that
  assignment's robot, and a lap count never decreases, so a late or duplicate status cannot
  complete (or un-complete) the wrong assignment. A patrol assignment is *completed* when it
  has at least one lap.
* Reconciliation: if a robot reports a task id other than the one the coordinator last gave it
  (a lost, late or never-received order: Zenoh publications are not stored), the current order
  is sent again, at most once per :data:`RESEND_S`.
* Idle robots standing on a charger are matched first (their cost is lowered by
  :data:`CHARGER_BONUS_M`), so that a charged spare leaves the charger to robots that need it.
* Chargers: every order carries a charger pose. Each robot is given a charger when first seen:
  the least-loaded charger, nearest first among equally loaded ones, so two robots share a
  charger only when there are more robots than chargers.

Picking (a fleet whose robots run picking trees, ``task_kind="picking"``; see
:func:`state_from_config`): the config's ``tasks`` are assigned instead of its routes, by the
same rules where not said otherwise.

* The picks form a queue in config order; each pick is done once. Every cycle, each eligible
  robot (alive, ``mode == "idle"``, no assignment, battery at least ``low``
  + :data:`BATTERY_MARGIN`) gets the nearest waiting pick: travel cost from the robot to the
  pick's shelf along the roadmap, matched globally greedily like routes (same charger bonus,
  stuck cooldown, preferred robot ``PickTask.robot``; config order breaks ties). The order is a
  :class:`TaskOrder` of kind ``"pick"`` with a fresh id ``k-0007`` from the same counter.
* Completion: status records carry the robot's cumulative ``picks_done`` (the tree's
  ``CompletePick`` increments it). A pick assignment takes as its baseline the ``picks_done``
  of the first record from its robot that carries its id, and is *completed* by a later record
  from that robot, with that id, with a higher ``picks_done``. Only an active assignment can
  complete, so a late status of a robot the pick was taken from cannot complete it.
* A pick is taken back (a :class:`Reassignment` whose ``route`` is the pick's name) when its
  robot dies, goes to charge, or is stuck (no progress for ``stuck_reassign_s`` plus the pick's
  ``dwell_s`` in mode ``picking`` / ``recovery``); it waits for the next eligible robot and
  starts again from the shelf. Unacknowledged pick orders are resent like patrols.

Traffic management plugs in through :class:`TrafficPolicy` (the default, :class:`NoTraffic`,
does nothing): it sees every assignment and release and runs once per cycle.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import networkx as nx
import numpy as np

from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig, PickTask
    from fleet.navigation import Clock
    from fleet.roadmap.graph import Roadmap

#: A robot has made progress when it moved this far (m) from where it last made progress.
PROGRESS_M = 0.5
#: An order the robot does not acknowledge (its status carries another id) is resent this often (s).
RESEND_S = 1.0
#: Robots whose battery is below ``low + BATTERY_MARGIN`` are not given a new patrol.
BATTERY_MARGIN = 0.05
#: Two robots closer than this (m) when one of them becomes stuck count as a deadlock.
DEADLOCK_RADIUS_M = 1.5
#: Modes in which a robot is expected to drive (used by the stuck check).
DRIVING_MODES = ("patrol", "recovery")
#: Modes in which a robot with a pick is expected to drive (or dwell at the shelf).
PICK_DRIVING_MODES = ("picking", "recovery")
#: Kinds of fleet the coordinator serves: robots running patrol trees, or picking trees.
TASK_KINDS = ("patrol", "picking")

#: Added to the travel cost (m) of a robot recently taken off a route for being stuck.
COOLDOWN_PENALTY = 1e6
#: Idle robots standing within ON_CHARGER_M (m) of a charger look this much (m) closer to
#: every route, so that they leave the charger to robots that need it.
CHARGER_BONUS_M = 20.0
ON_CHARGER_M = 0.5
#: The rank (m) of a task's preferred robot: below any travel cost, so it is matched first.
PREFERRED_RANK = -1e9
#: A robot stuck this close (m) to a waypoint of its lap marks the waypoint blocked ...
BLOCKED_RADIUS_M = 1.5
#: ... and new assignments skip it for this long (s).
BLOCKED_WAYPOINT_S = 300.0

REASON_DEAD = "dead"
REASON_STUCK = "stuck"
REASON_CHARGING = "charging"


# ----------------------------------------------------------------------------- values


@dataclass(frozen=True)
class PatrolRoute:
    """A patrol route as the coordinator holds it: one lap of ``poses`` (map frame), the
    roadmap node at each pose (``nodes[i]`` for ``poses[i]``), and an optional preferred robot."""

    name: str
    poses: tuple[Pose2D, ...]
    nodes: tuple[str, ...]
    robot: str | None = None


@dataclass(frozen=True)
class Observation:
    """What one status record tells the coordinator about a robot.

    ``t``: the record's timestamp (s); ``pose``: map frame or ``None``; ``battery`` in [0, 1];
    ``mode``: the tree's mode (``idle``, ``patrol``, ``charging``, ``recovery``, ``picking``);
    ``task_id``: the assignment the robot is executing; ``laps``: laps completed for that id;
    ``picks_done``: picks the robot completed since its agent started (cumulative).
    """

    t: float
    pose: Pose2D | None
    battery: float = 1.0
    mode: str = "idle"
    stuck: bool = False
    task_id: str | None = None
    laps: int = 0
    charging: bool = False
    picks_done: int = 0


@dataclass(frozen=True)
class TaskOrder:
    """A message for one robot (published on ``fleet/<robot>/task``).

    ``kind`` is ``"patrol"`` (``route`` and ``poses`` set), ``"pick"`` (``pick`` set: a
    :class:`fleet.config.PickTask`) or ``"idle"`` (drop any route or pick).
    ``charger`` is the charger pose the robot should use when its battery runs low.
    """

    robot: str
    task_id: str
    kind: str
    route: str | None
    poses: tuple[Pose2D, ...]
    charger: Pose2D | None
    pick: PickTask | None = None


@dataclass
class Assignment:
    """One patrol assignment: ``route`` given to ``robot`` at ``t_assigned`` under ``task_id``.

    ``laps`` is the highest lap count the robot reported for this id; ``t_first_lap`` when the
    first lap was reported; ``ended`` / ``end_reason`` when the route was taken back (``None``
    while active).
    """

    task_id: str
    route: str
    robot: str
    t_assigned: float
    poses: tuple[Pose2D, ...]
    laps: int = 0
    t_first_lap: float | None = None
    ended: float | None = None
    end_reason: str | None = None

    @property
    def completed(self) -> bool:
        return self.laps >= 1


@dataclass
class PickAssignment:
    """One pick assignment: the config's pick ``task`` (named ``pick``) given to ``robot`` at
    ``t_assigned`` under ``task_id``.

    ``base`` is the robot's ``picks_done`` in the first status carrying ``task_id`` (``None``
    until then); ``t_done`` when a later status showed the pick done; ``ended`` /
    ``end_reason`` when the pick was taken back (``None`` otherwise).
    """

    task_id: str
    pick: str
    robot: str
    t_assigned: float
    task: PickTask
    base: int | None = None
    t_done: float | None = None
    ended: float | None = None
    end_reason: str | None = None

    @property
    def completed(self) -> bool:
        return self.t_done is not None


@dataclass
class Reassignment:
    """A route (or a pick: ``route`` is then the pick's name) taken from ``from_robot`` at ``t``
    for ``reason`` (``dead``, ``stuck``, ``charging``). ``to_robot`` / ``new_task_id`` /
    ``t_reassigned`` are filled when it is given to another robot (``None`` while it waits)."""

    t: float
    route: str
    from_robot: str
    reason: str
    old_task_id: str
    to_robot: str | None = None
    new_task_id: str | None = None
    t_reassigned: float | None = None


@dataclass
class RobotView:
    """Everything the coordinator knows about one robot (mutable; owned by the state)."""

    name: str
    alive: bool = True
    last_seen: float | None = None
    obs: Observation | None = None
    assignment: Assignment | None = None
    charger: int | None = None
    progress_pose: Pose2D | None = None
    progress_t: float = 0.0
    cooldown_until: float = -math.inf
    last_order: TaskOrder | None = None
    last_sent: float = -math.inf
    was_stuck: bool = False
    pick: PickAssignment | None = None


class TrafficPolicy(Protocol):
    """Extension point for traffic management (e.g. roadmap segment reservations).

    The coordinator calls :meth:`on_assign` when it gives a route to a robot (the policy may
    return different poses, e.g. with waiting points), :meth:`on_release` when a robot loses
    its route or dies, and :meth:`cycle` once per coordinator cycle with every robot's view;
    :meth:`cycle` returns extra orders to send (usually none). Policies must keep
    :meth:`cycle` roughly linear in the number of robots.
    """

    def on_assign(
        self, robot: str, route: PatrolRoute, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]: ...

    def on_release(self, robot: str) -> None: ...

    def waiting(self, robot: str) -> bool:
        """True while the policy holds ``robot`` back (it is then not stuck, only waiting)."""
        ...

    def cycle(self, now: float, robots: Mapping[str, RobotView]) -> Sequence[TaskOrder]: ...


class NoTraffic:
    """The default :class:`TrafficPolicy`: robots rely on their own reactive safety layer."""

    def on_assign(
        self, robot: str, route: PatrolRoute, poses: tuple[Pose2D, ...], task_id: str | None = None
    ) -> tuple[Pose2D, ...]:
        return poses

    def on_release(self, robot: str) -> None:
        return None

    def waiting(self, robot: str) -> bool:
        return False

    def cycle(self, now: float, robots: Mapping[str, RobotView]) -> Sequence[TaskOrder]:
        return ()


@dataclass
class CoordinatorParams:
    """Thresholds (seconds) and the battery level below which robots go to charge."""

    stuck_reassign_s: float = 30.0
    status_timeout_s: float = 3.0
    battery_low: float = 0.25


# ----------------------------------------------------------------------------- state


class _Distances:
    """Roadmap shortest-path distances from a node to every node, one Dijkstra per source node
    (LRU-cached), as numpy rows indexed like :attr:`index`."""

    def __init__(self, roadmap: Roadmap, cache_rows: int = 4096) -> None:
        self.roadmap = roadmap
        self.names = roadmap.nodes
        self.index = {n: i for i, n in enumerate(self.names)}
        self._rows: OrderedDict[str, np.ndarray] = OrderedDict()
        self._cap = cache_rows

    def row(self, source: str) -> np.ndarray:
        r = self._rows.get(source)
        if r is not None:
            self._rows.move_to_end(source)
            return r
        lengths = nx.single_source_dijkstra_path_length(self.roadmap.graph, source, weight="length")
        r = np.full(len(self.names), np.inf)
        for n, d in lengths.items():
            r[self.index[str(n)]] = d
        self._rows[source] = r
        if len(self._rows) > self._cap:
            self._rows.popitem(last=False)
        return r


class CoordinatorState:
    """The coordinator's decisions, free of I/O. See the module docstring for the rules.

    Args:
        routes: the patrols to keep covered.
        chargers: charger poses (map frame).
        roadmap: the roadmap used for travel costs.
        params: thresholds.
        traffic: the traffic policy (default :class:`NoTraffic`).
        picks: the picks to do once each (:class:`fleet.config.PickTask`, unique names), in
            queue order. A robot runs one tree kind, so give routes (patrol trees) or picks
            (picking trees), not both: :func:`state_from_config` chooses by ``task_kind``.

    Raises:
        ValueError: both routes and picks were given, or two picks share a name.
    """

    def __init__(
        self,
        routes: Sequence[PatrolRoute],
        chargers: Sequence[Pose2D],
        roadmap: Roadmap,
        params: CoordinatorParams | None = None,
        traffic: TrafficPolicy | None = None,
        picks: Sequence[PickTask] = (),
    ) -> None:
        if routes and picks:
            raise ValueError(
                "CoordinatorState: give routes (patrol fleet) or picks (picking fleet), not both"
            )
        self.routes: dict[str, PatrolRoute] = {r.name: r for r in routes}
        self.chargers = list(chargers)
        self.roadmap = roadmap
        self.params = params or CoordinatorParams()
        self.traffic: TrafficPolicy = traffic or NoTraffic()
        self.robots: dict[str, RobotView] = {}
        self.assignments: list[Assignment] = []
        self.by_id: dict[str, Assignment] = {}
        self.reassignments: list[Reassignment] = []
        self.holder: dict[str, str | None] = {r.name: None for r in routes}
        self.deadlocks = 0
        self.events: list[tuple[float, str]] = []
        self._counter = 0
        self._charger_load = [0] * len(self.chargers)
        self._dist = _Distances(roadmap)
        self._route_idx = self._route_index_matrix(routes)
        self._pending_reassign: dict[str, Reassignment] = {}
        self.blocked: list[tuple[float, float, float]] = []
        self.expected: set[str] = set()
        self.settle_s = 0.0
        self._t_start: float | None = None
        self.picks: dict[str, PickTask] = {}
        for t in picks:
            if t.name in self.picks:
                raise ValueError(f"CoordinatorState: duplicate pick name {t.name!r}")
            self.picks[t.name] = t
        #: pick name -> robot holding it (``None``: waiting or done)
        self.pick_holder: dict[str, str | None] = {n: None for n in self.picks}
        self.done_picks: set[str] = set()
        self.pick_assignments: list[PickAssignment] = []
        self.picks_by_id: dict[str, PickAssignment] = {}
        self._pending_pick_reassign: dict[str, Reassignment] = {}
        nodes: list[int] = []
        offsets: list[float] = []
        for t in self.picks.values():  # each shelf's roadmap node and its distance to the shelf
            node = roadmap.nearest_node(t.shelf.x, t.shelf.y)
            px, py = roadmap.pos(node)
            nodes.append(self._dist.index[node])
            offsets.append(math.hypot(t.shelf.x - px, t.shelf.y - py))
        self._pick_node = np.array(nodes, dtype=np.int64)
        self._pick_offset = np.array(offsets, dtype=float)
        self._pick_col = {n: j for j, n in enumerate(self.picks)}

    def expect(self, robots: Iterable[str], settle_s: float) -> None:
        """Hold the first assignment until every robot in ``robots`` has reported or
        ``settle_s`` seconds passed since the first cycle, so that robots starting in other
        processes a moment later are matched too (and get their preferred routes)."""
        self.expected = set(robots)
        self.settle_s = float(settle_s)

    # -- inputs ------------------------------------------------------------------------

    def robot_joined(self, robot: str, now: float) -> None:
        """The robot's liveliness token appeared (or it was seen again after being dead)."""
        v = self._view(robot, now)
        if not v.alive:
            v.alive = True
            v.last_seen = now
            self._log(now, f"{robot} joined")

    def robot_left(self, robot: str, now: float) -> None:
        """The robot's liveliness token disappeared: it is dead at once."""
        v = self.robots.get(robot)
        if v is not None and v.alive:
            self._die(v, now, "liveliness token dropped")

    def observe(self, robot: str, now: float, obs: Observation) -> None:
        """A status record from ``robot`` arrived at ``now``."""
        v = self._view(robot, now)
        if not v.alive:
            v.alive = True
            self._log(now, f"{robot} is back")
        v.last_seen = now
        v.obs = obs
        if obs.task_id is not None:
            a = self.by_id.get(obs.task_id)
            if a is not None and a.robot == robot and obs.laps > a.laps:
                if a.t_first_lap is None:
                    a.t_first_lap = now
                a.laps = obs.laps
            pa = self.picks_by_id.get(obs.task_id)
            if pa is not None and pa.robot == robot and v.pick is pa:
                if pa.base is None:
                    pa.base = obs.picks_done
                elif obs.picks_done > pa.base:
                    self._complete_pick(v, now)
        if obs.pose is not None:
            if v.progress_pose is None or v.progress_pose.distance_to(obs.pose) > PROGRESS_M:
                v.progress_pose = obs.pose
                v.progress_t = now
        if obs.stuck and not v.was_stuck and obs.pose is not None and self._someone_near(v, obs.pose):
            self.deadlocks += 1
            self._log(now, f"{robot} blocked by another robot")
        v.was_stuck = obs.stuck

    # -- the cycle ---------------------------------------------------------------------

    def step(self, now: float) -> list[TaskOrder]:
        """Run one cycle at ``now``: detect dead, stuck and charging robots, take their routes
        back, assign waiting routes, resend unacknowledged orders. Returns the orders to send."""
        p = self.params
        out: list[TaskOrder] = []
        for v in self.robots.values():
            if v.alive and v.last_seen is not None and now - v.last_seen > p.status_timeout_s:
                self._die(v, now, f"no status for {now - v.last_seen:.1f} s")
                continue
            if v.pick is not None and v.alive and v.obs is not None:
                out.extend(self._check_pick(v, now))
            a = v.assignment
            if a is None or not v.alive or v.obs is None:
                continue
            if v.obs.mode == "charging":
                out.append(self._release(v, now, REASON_CHARGING))
            elif self.traffic.waiting(v.name):
                v.progress_t = now  # held back by traffic management: waiting, not stuck
            elif (
                v.obs.task_id == a.task_id
                and v.obs.mode in DRIVING_MODES
                and now - max(v.progress_t, a.t_assigned) > p.stuck_reassign_s
            ):
                v.cooldown_until = now + p.stuck_reassign_s
                self._block_waypoint_near(a, v.obs.pose, now)
                out.append(self._release(v, now, REASON_STUCK))
        if self._t_start is None:
            self._t_start = now
        settled = now - self._t_start >= self.settle_s or all(
            r in self.robots and self.robots[r].obs is not None for r in self.expected
        )
        if settled:
            out.extend(self._assign(now))
            out.extend(self._assign_picks(now))
        out.extend(self.traffic.cycle(now, self.robots))
        sent = {o.robot for o in out}
        for v in self.robots.values():
            if v.name in sent or not v.alive or v.obs is None or now - v.last_sent < RESEND_S:
                continue
            last = v.last_order
            if v.assignment is not None:
                if v.obs.task_id != v.assignment.task_id:
                    out.append(
                        last
                        if last is not None and last.task_id == v.assignment.task_id
                        else self._patrol_order(v)
                    )
            elif v.pick is not None:
                if v.obs.task_id != v.pick.task_id:
                    out.append(
                        last if last is not None and last.task_id == v.pick.task_id else self._pick_order(v)
                    )
            elif v.obs.task_id is not None and (last is None or v.obs.task_id != last.task_id):
                out.append(last if last is not None and last.kind == "idle" else self._idle_order(v))
        for o in out:
            rv = self.robots.get(o.robot)
            if rv is not None:
                rv.last_order = o
                rv.last_sent = now
        return out

    # -- queries -----------------------------------------------------------------------

    @property
    def waiting_routes(self) -> list[str]:
        """Routes without a robot, in config order."""
        return [r for r, h in self.holder.items() if h is None]

    def active_assignment(self, route: str) -> Assignment | None:
        holder = self.holder.get(route)
        if holder is None:
            return None
        return self.robots[holder].assignment

    def laps_completed(self) -> int:
        return sum(a.laps for a in self.assignments)

    def patrols_completed(self) -> int:
        return sum(1 for a in self.assignments if a.completed)

    def laps_by_route(self) -> dict[str, int]:
        out = {r: 0 for r in self.routes}
        for a in self.assignments:
            out[a.route] += a.laps
        return out

    def laps_by_robot(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for a in self.assignments:
            out[a.robot] = out.get(a.robot, 0) + a.laps
        return out

    @property
    def waiting_picks(self) -> list[str]:
        """Picks neither held by a robot nor done, in config order."""
        return [n for n, h in self.pick_holder.items() if h is None and n not in self.done_picks]

    def picks_completed(self) -> int:
        return sum(1 for a in self.pick_assignments if a.completed)

    def picks_by_robot(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for a in self.pick_assignments:
            if a.completed:
                out[a.robot] = out.get(a.robot, 0) + 1
        return out

    # -- internals ---------------------------------------------------------------------

    def _view(self, robot: str, now: float) -> RobotView:
        v = self.robots.get(robot)
        if v is None:
            v = RobotView(name=robot, last_seen=now, progress_t=now)
            self.robots[robot] = v
            self._log(now, f"{robot} joined")
        return v

    def _log(self, now: float, text: str) -> None:
        self.events.append((now, text))

    def _next_id(self, prefix: str) -> str:
        self._counter += 1
        return f"{prefix}-{self._counter:04d}"

    def _die(self, v: RobotView, now: float, why: str) -> None:
        v.alive = False
        self._log(now, f"{v.name} dead ({why})")
        if v.assignment is not None:
            self._release(v, now, REASON_DEAD)
        if v.pick is not None:
            self._release_pick(v, now, REASON_DEAD)
        if v.charger is not None:
            self._charger_load[v.charger] -= 1
            v.charger = None
        v.last_order = None
        v.obs = None
        v.progress_pose = None

    def _release(self, v: RobotView, now: float, reason: str) -> TaskOrder:
        a = v.assignment
        assert a is not None
        a.ended = now
        a.end_reason = reason
        v.assignment = None
        self.holder[a.route] = None
        self.traffic.on_release(v.name)
        r = Reassignment(t=now, route=a.route, from_robot=v.name, reason=reason, old_task_id=a.task_id)
        self.reassignments.append(r)
        self._pending_reassign[a.route] = r
        self._log(now, f"{a.route} taken from {v.name} ({reason})")
        return self._idle_order(v)

    def _charger_for(self, v: RobotView) -> Pose2D | None:
        if not self.chargers:
            return None
        if v.charger is None:
            pose = v.obs.pose if v.obs is not None else None
            best: tuple[int, float, int] | None = None
            for i, c in enumerate(self.chargers):
                d = pose.distance_to(c) if pose is not None else 0.0
                key = (self._charger_load[i], d, i)
                if best is None or key < best:
                    best = key
            assert best is not None
            v.charger = best[2]
            self._charger_load[v.charger] += 1
        return self.chargers[v.charger]

    def _idle_order(self, v: RobotView) -> TaskOrder:
        return TaskOrder(v.name, self._next_id("i"), "idle", None, (), self._charger_for(v))

    def _eligible(self, v: RobotView, now: float) -> bool:
        o = v.obs
        return (
            v.alive
            and v.assignment is None
            and v.pick is None
            and o is not None
            and o.pose is not None
            and o.mode == "idle"
            and o.battery >= self.params.battery_low + BATTERY_MARGIN
        )

    def _route_index_matrix(self, routes: Sequence[PatrolRoute]) -> np.ndarray:
        idx = self._dist.index
        width = max((len(r.nodes) for r in routes), default=1)
        m = np.zeros((len(routes), max(width, 1)), dtype=np.int64)
        for i, r in enumerate(routes):
            ids = [idx[n] for n in r.nodes] or [0]
            m[i, :] = ids[-1]
            m[i, : len(ids)] = ids
        return m

    def cost_matrix(
        self, robots: Sequence[RobotView], routes: Sequence[str]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Travel costs (m) ``[robot, route]`` and the lap index each robot would enter at."""
        order = {r: i for i, r in enumerate(self.routes)}
        ridx = np.array([order[r] for r in routes], dtype=np.int64) if routes else np.zeros(0, np.int64)
        sub = self._route_idx[ridx] if len(ridx) else np.zeros((0, 1), np.int64)
        costs = np.full((len(robots), len(routes)), np.inf)
        entry = np.zeros((len(robots), len(routes)), dtype=np.int64)
        for i, v in enumerate(robots):
            assert v.obs is not None and v.obs.pose is not None
            pose = v.obs.pose
            start = self.roadmap.nearest_node(pose.x, pose.y)
            sx, sy = self.roadmap.pos(start)
            row = self._dist.row(start)
            d = row[sub]
            k = np.argmin(d, axis=1)
            costs[i] = math.hypot(sx - pose.x, sy - pose.y) + d[np.arange(len(routes)), k]
            entry[i] = k
        return costs, entry

    def _assign(self, now: float) -> list[TaskOrder]:
        waiting = self.waiting_routes
        if not waiting:
            return []
        idle = [v for v in self.robots.values() if self._eligible(v, now)]
        if not idle:
            return []
        costs, entry = self.cost_matrix(idle, waiting)
        pairs = self._match(idle, costs, [self.routes[r].robot for r in waiting], now)
        return [self._give(idle[i], waiting[j], int(entry[i, j]), now) for i, j in pairs]

    def _match(
        self, idle: Sequence[RobotView], costs: np.ndarray, preferred: Sequence[str | None], now: float
    ) -> list[tuple[int, int]]:
        """Greedy min-cost matching of ``idle`` robots (rows of ``costs``) to tasks (columns):
        the cheapest pair first, then the next among the rest. Robots idling on a charger look
        :data:`CHARGER_BONUS_M` closer (it frees the charger), robots just taken off a task for
        being stuck :data:`COOLDOWN_PENALTY` farther, and a task's ``preferred[j]`` robot comes
        first. Infinite costs (unreachable) never match."""
        rank = costs.copy()
        for i, v in enumerate(idle):
            if self._on_charger(v):
                rank[i] -= CHARGER_BONUS_M
            if now < v.cooldown_until:
                rank[i] += COOLDOWN_PENALTY
        names = {v.name: i for i, v in enumerate(idle)}
        for j, pref in enumerate(preferred):
            if pref is not None and pref in names and math.isfinite(rank[names[pref], j]):
                rank[names[pref], j] = PREFERRED_RANK
        pairs: list[tuple[int, int]] = []
        used_r: set[int] = set()
        used_c: set[int] = set()
        n = min(len(idle), len(preferred))
        for f in np.argsort(rank, axis=None, kind="stable"):
            i, j = divmod(int(f), len(preferred))
            if i in used_r or j in used_c or not math.isfinite(rank[i, j]):
                continue
            used_r.add(i)
            used_c.add(j)
            pairs.append((i, j))
            if len(pairs) == n:
                break
        return pairs

    def _handed_over(
        self, pending: dict[str, Reassignment], name: str, robot: str, tid: str, now: float
    ) -> None:
        """Log a new assignment of ``name``; complete its pending :class:`Reassignment`, if any."""
        r = pending.pop(name, None)
        if r is not None:
            r.to_robot, r.new_task_id, r.t_reassigned = robot, tid, now
            self._log(now, f"{name} reassigned to {robot} as {tid}")
        else:
            self._log(now, f"{name} assigned to {robot} as {tid}")

    def _give(self, v: RobotView, route_name: str, k: int, now: float) -> TaskOrder:
        route = self.routes[route_name]
        poses = route.poses[k:] + route.poses[:k]
        self.blocked = [b for b in self.blocked if b[2] > now]
        if self.blocked:
            kept = tuple(
                p
                for p in poses
                if not any(math.hypot(p.x - bx, p.y - by) < 1e-6 for bx, by, _ in self.blocked)
            )
            if len(kept) >= 2 and len(kept) < len(poses):
                self._log(now, f"{route_name}: skipping {len(poses) - len(kept)} blocked waypoint(s)")
                poses = kept
        tid = self._next_id("p")
        poses = self.traffic.on_assign(v.name, route, poses, tid)
        a = Assignment(task_id=tid, route=route_name, robot=v.name, t_assigned=now, poses=poses)
        self.assignments.append(a)
        self.by_id[tid] = a
        v.assignment = a
        v.progress_t = now
        self.holder[route_name] = v.name
        self._handed_over(self._pending_reassign, route_name, v.name, tid, now)
        return self._patrol_order(v)

    def _patrol_order(self, v: RobotView) -> TaskOrder:
        a = v.assignment
        assert a is not None
        return TaskOrder(v.name, a.task_id, "patrol", a.route, a.poses, self._charger_for(v))

    def _on_charger(self, v: RobotView) -> bool:
        pose = v.obs.pose if v.obs is not None else None
        return pose is not None and any(pose.distance_to(c) <= ON_CHARGER_M for c in self.chargers)

    def _block_waypoint_near(self, a: Assignment, pose: Pose2D | None, now: float) -> None:
        """The robot of ``a`` got stuck at ``pose``: if that is next to a waypoint of its lap
        (something sits on it, e.g. a dead robot), skip that waypoint in new assignments for
        :data:`BLOCKED_WAYPOINT_S`."""
        if pose is None or not a.poses:
            return
        wp = min(a.poses, key=pose.distance_to)
        if wp.distance_to(pose) <= BLOCKED_RADIUS_M:
            self.blocked.append((wp.x, wp.y, now + BLOCKED_WAYPOINT_S))
            self._log(now, f"waypoint ({wp.x:.1f}, {wp.y:.1f}) of {a.route} blocked")

    def _someone_near(self, v: RobotView, pose: Pose2D) -> bool:
        for other in self.robots.values():
            if other is v or not other.alive or other.obs is None or other.obs.pose is None:
                continue
            if other.obs.pose.distance_to(pose) < DEADLOCK_RADIUS_M:
                return True
        return False

    # -- picking -----------------------------------------------------------------------

    def pick_cost_matrix(self, robots: Sequence[RobotView], picks: Sequence[str]) -> np.ndarray:
        """Travel costs (m) ``[robot, pick]``: robot pose -> nearest roadmap node -> along the
        roadmap -> the node nearest the pick's shelf -> the shelf (``inf`` if unreachable)."""
        cols = np.array([self._pick_col[n] for n in picks], dtype=np.int64)
        nodes, offsets = self._pick_node[cols], self._pick_offset[cols]
        costs = np.full((len(robots), len(picks)), np.inf)
        for i, v in enumerate(robots):
            assert v.obs is not None and v.obs.pose is not None
            pose = v.obs.pose
            start = self.roadmap.nearest_node(pose.x, pose.y)
            sx, sy = self.roadmap.pos(start)
            costs[i] = math.hypot(sx - pose.x, sy - pose.y) + self._dist.row(start)[nodes] + offsets
        return costs

    def _assign_picks(self, now: float) -> list[TaskOrder]:
        waiting = self.waiting_picks
        if not waiting:
            return []
        idle = [v for v in self.robots.values() if self._eligible(v, now)]
        if not idle:
            return []
        costs = self.pick_cost_matrix(idle, waiting)
        pairs = self._match(idle, costs, [self.picks[p].robot for p in waiting], now)
        return [self._give_pick(idle[i], waiting[j], now) for i, j in pairs]

    def _give_pick(self, v: RobotView, name: str, now: float) -> TaskOrder:
        tid = self._next_id("k")
        pa = PickAssignment(task_id=tid, pick=name, robot=v.name, t_assigned=now, task=self.picks[name])
        self.pick_assignments.append(pa)
        self.picks_by_id[tid] = pa
        v.pick = pa
        v.progress_t = now
        self.pick_holder[name] = v.name
        self._handed_over(self._pending_pick_reassign, name, v.name, tid, now)
        return self._pick_order(v)

    def _pick_order(self, v: RobotView) -> TaskOrder:
        pa = v.pick
        assert pa is not None
        return TaskOrder(v.name, pa.task_id, "pick", None, (), self._charger_for(v), pick=pa.task)

    def _complete_pick(self, v: RobotView, now: float) -> None:
        pa = v.pick
        assert pa is not None
        pa.t_done = now
        v.pick = None
        self.pick_holder[pa.pick] = None
        self.done_picks.add(pa.pick)
        self._log(now, f"{pa.pick} done by {v.name} ({pa.task_id})")

    def _check_pick(self, v: RobotView, now: float) -> list[TaskOrder]:
        """Take the pick back from a robot that went to charge or is stuck."""
        pa, obs = v.pick, v.obs
        assert pa is not None and obs is not None
        if obs.mode == "charging":
            return [self._release_pick(v, now, REASON_CHARGING)]
        allowed = self.params.stuck_reassign_s + pa.task.dwell_s  # standing at the shelf is no stall
        if (
            obs.task_id == pa.task_id
            and obs.mode in PICK_DRIVING_MODES
            and now - max(v.progress_t, pa.t_assigned) > allowed
        ):
            v.cooldown_until = now + self.params.stuck_reassign_s
            return [self._release_pick(v, now, REASON_STUCK)]
        return []

    def _release_pick(self, v: RobotView, now: float, reason: str) -> TaskOrder:
        pa = v.pick
        assert pa is not None
        pa.ended = now
        pa.end_reason = reason
        v.pick = None
        self.pick_holder[pa.pick] = None
        r = Reassignment(t=now, route=pa.pick, from_robot=v.name, reason=reason, old_task_id=pa.task_id)
        self.reassignments.append(r)
        self._pending_pick_reassign[pa.pick] = r
        self._log(now, f"{pa.pick} taken from {v.name} ({reason})")
        return self._idle_order(v)


def patrol_routes(config: FleetConfig) -> list[PatrolRoute]:
    """The config's routes as :class:`PatrolRoute` values (one lap each, roadmap node per pose)."""
    out = []
    for r in config.routes:
        poses = config.route_poses(r)
        nodes = tuple(config.roadmap.nearest_node(p.x, p.y) for p in poses)
        out.append(PatrolRoute(r.name, poses, nodes, r.robot))
    return out


def state_from_config(
    config: FleetConfig, traffic: TrafficPolicy | None = None, task_kind: str = "patrol"
) -> CoordinatorState:
    """A :class:`CoordinatorState` for the chargers and thresholds of ``config``, and its routes
    (``task_kind="patrol"``: the robots run patrol trees) or its picking ``tasks``
    (``task_kind="picking"``: picking trees). Raises ``ValueError`` for another kind."""
    if task_kind not in TASK_KINDS:
        raise ValueError(f"task_kind {task_kind!r}: expected one of {', '.join(TASK_KINDS)}")
    params = CoordinatorParams(
        stuck_reassign_s=config.coordinator.stuck_reassign_s,
        status_timeout_s=config.coordinator.status_timeout_s,
        battery_low=config.sim.battery.low,
    )
    picking = task_kind == "picking"
    return CoordinatorState(
        [] if picking else patrol_routes(config),
        [c.pose for c in config.chargers],
        config.roadmap,
        params,
        traffic,
        picks=list(config.tasks) if picking else (),
    )


# ----------------------------------------------------------------------------- bus wrapper


class Coordinator:
    """The coordinator on the status bus.

    Subscribes to every robot's status and liveliness token on ``bus`` and publishes orders on
    ``fleet/<robot>/task``. Call :meth:`cycle` once per agent tick (the runner does); it
    returns the orders it sent. ``clock`` gives the fleet time (simulated seconds).

    Robots in ``local_robots`` run in the same process: their statuses are fed directly with
    :meth:`feed_local` (their bus copies and liveliness events are ignored) and their orders
    are also handed to ``local_deliver[robot]`` at once, so an in-process run does not depend
    on network timing. Their orders are still published, for observers and for robustness.

    ``task_kind`` is the tree kind the fleet's robots run: ``"patrol"`` (the config's routes
    are assigned) or ``"picking"`` (its tasks are); see :func:`state_from_config`.
    """

    def __init__(
        self,
        config: FleetConfig,
        bus: Any,
        clock: Clock,
        traffic: TrafficPolicy | None = None,
        local_robots: set[str] | None = None,
        task_kind: str = "patrol",
    ) -> None:
        self.config = config
        self.bus = bus
        self.clock = clock
        self.state = state_from_config(config, traffic, task_kind)
        self.state.expect([r.name for r in config.robots], config.coordinator.status_timeout_s)
        self.local_robots = set(local_robots or ())
        self.local_deliver: dict[str, Callable[[Any], None]] = {}
        #: In-process agents' ``deliver_grant`` by robot (traffic grants skip the bus for them).
        self.local_grant_deliver: dict[str, Callable[[Any], None]] = {}
        self._grants: dict[str, tuple[Any, float]] = {}  # remote robot -> (latest grant, last sent)
        if traffic is not None and getattr(traffic, "deliver", False) is None:
            traffic.deliver = self._deliver_grant  # type: ignore[attr-defined]
        self._inbox: list[tuple[str, Any]] = []
        self._lock = threading.Lock()
        if bus is not None:
            bus.subscribe_statuses(self._on_status)
            bus.watch_alive(self._on_join, self._on_leave)

    def _on_status(self, rec: Any) -> None:
        if rec.robot not in self.local_robots:
            self.feed("status", rec)

    def _on_join(self, robot: str) -> None:
        if robot not in self.local_robots:
            self.feed("join", robot)

    def _on_leave(self, robot: str) -> None:
        if robot not in self.local_robots:
            self.feed("leave", robot)

    def feed(self, kind: str, payload: Any) -> None:
        """Queue an input (``status`` record, ``join`` / ``leave`` robot name); thread-safe."""
        with self._lock:
            self._inbox.append((kind, payload))

    def feed_local(self, rec: Any) -> None:
        """A status record of an in-process robot."""
        self.feed("status", rec)

    def cycle(self) -> list[TaskOrder]:
        """Apply everything received since the last cycle, decide, publish. Returns the orders."""
        now = self.clock.now()
        with self._lock:
            inbox, self._inbox = self._inbox, []
        for kind, payload in inbox:
            if kind == "status":
                self.state.observe(payload.robot, now, observation_from_record(payload))
            elif kind == "join":
                self.state.robot_joined(payload, now)
            elif kind == "leave":
                self.state.robot_left(payload, now)
        orders = self.state.step(now)
        self._resend_grants(now)
        for o in orders:
            msg = task_message(o)
            deliver = self.local_deliver.get(o.robot)
            if deliver is not None:
                deliver(msg)
            if self.bus is not None:
                self.bus.publish_task(msg)
        return orders

    def _deliver_grant(self, robot: str, grant: Any) -> None:
        """A traffic grant changed: hand it to the in-process agent, or publish it on
        ``fleet/<robot>/grant`` (and again every :data:`RESEND_S`, as Zenoh keeps nothing)."""
        deliver = self.local_grant_deliver.get(robot)
        if deliver is not None:
            deliver(grant)
            return
        self._grants[robot] = (grant, self.clock.now())
        if self.bus is not None:
            self.bus.publish_grant(grant)

    def _resend_grants(self, now: float) -> None:
        if self.bus is None:
            return
        for robot, (grant, sent) in list(self._grants.items()):
            if now - sent >= RESEND_S:
                self._grants[robot] = (grant, now)
                self.bus.publish_grant(grant)


def observation_from_record(rec: Any) -> Observation:
    """Convert a :class:`fleet.bus.status_bus.StatusRecord` to an :class:`Observation`."""
    pose = getattr(rec, "pose", None)
    if pose is not None and not isinstance(pose, Pose2D):
        pose = Pose2D(*pose)
    return Observation(
        t=float(getattr(rec, "t", 0.0)),
        pose=pose,
        battery=float(getattr(rec, "battery", 1.0)),
        mode=str(getattr(rec, "mode", "idle")),
        stuck=bool(getattr(rec, "stuck", False)),
        task_id=getattr(rec, "task_id", None),
        laps=int(getattr(rec, "laps", 0) or 0),
        charging=bool(getattr(rec, "charging", False)),
        picks_done=int(getattr(rec, "picks_done", 0) or 0),
    )


def task_message(order: TaskOrder) -> Any:
    """Convert a :class:`TaskOrder` to the bus's :class:`fleet.bus.status_bus.TaskMessage`."""
    from fleet.messages import TaskMessage

    return TaskMessage(
        robot=order.robot,
        task_id=order.task_id,
        kind=order.kind,
        route=order.route,
        poses=order.poses,
        charger=order.charger,
        pick=order.pick,
    )
