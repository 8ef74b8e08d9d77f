"""The coordinator's decisions, free of I/O: :class:`CoordinatorState` runs one cycle at a time
over the task book, the robots' health and the matcher. The rules are in
:mod:`fleet.coordination.coordinator`'s docstring."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

from fleet.coordination import health
from fleet.coordination.lifecycle import TaskState
from fleet.coordination.matching import ChargerAllocation, greedy_match, rank, travel_costs
from fleet.coordination.policy import NoTraffic, TrafficPolicy
from fleet.coordination.tasks import (
    IDLE_PREFIX,
    PatrolRoute,
    Pick,
    Task,
    TaskBook,
    only_of,
    patrol_routes,
    priority_of,
)
from fleet.coordination.views import (
    Assignment,
    CoordinatorParams,
    Observation,
    Reason,
    Reassignment,
    RobotView,
    TaskOrder,
)
from fleet.roadmap.distances import Distances
from fleet.types import DRIVING_MODES, Mode, Pose2D, TaskKind, TreeKind

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig, PickTask
    from fleet.coordination.tasks import FloatMatrix, IndexMatrix
    from fleet.roadmap.graph import Roadmap

logger = logging.getLogger(__name__)

#: An order the robot does not acknowledge (its status carries another id) is resent this often (s).
RESEND_S = 1.0
#: Robots whose battery is below ``low + BATTERY_MARGIN`` are not given a new task.
BATTERY_MARGIN = 0.05
#: :attr:`CoordinatorState.events` keeps the latest this many ``(t, text)`` entries.
MAX_EVENTS = 10_000


class CoordinatorState:
    """The coordinator's decisions, free of I/O. See :mod:`fleet.coordination.coordinator`
    for the rules.

    Args:
        routes: the patrols to keep covered.
        chargers: charger poses (map frame).
        roadmap: the roadmap used for travel costs.
        params: thresholds.
        traffic: the traffic policy (default :class:`NoTraffic`).
        picks: the picks to do once each (:class:`fleet.config.model.PickTask`, unique
            names), in queue order. Robots running the task tree take both; a fleet of
            single-purpose trees gets one kind (:func:`state_from_config` chooses).
        first_id: the first assignment id to hand out (a restarted coordinator continues
            its durable book's counter, so ids are never reused).

    Raises:
        ValueError: two tasks share a name.

    Runtime: :meth:`add_task` adds a task, :meth:`cancel` cancels one, :meth:`restore`
    re-reads a lease of a durable book; ``halted`` (paused or e-stopped) suspends the
    cycle's health checks, assignment and traffic cycle (:meth:`step` only reconciles
    nothing: robots stand); ``hooks`` run at the start of every cycle (the task service
    applies its submissions and cancels there, on the coordinator's thread).

    ``book`` is the :class:`TaskBook`; ``events`` the latest :data:`MAX_EVENTS` ``(t, text)``
    log entries (also logged at DEBUG); ``deadlocks`` how often a robot turned stuck next to
    another one.
    """

    def __init__(
        self,
        routes: Sequence[PatrolRoute],
        chargers: Sequence[Pose2D],
        roadmap: Roadmap,
        params: CoordinatorParams | None = None,
        traffic: TrafficPolicy | None = None,
        picks: Sequence[PickTask] = (),
        first_id: int = 1,
    ) -> None:
        self.roadmap = roadmap
        self.params = params or CoordinatorParams()
        self.traffic: TrafficPolicy = traffic or NoTraffic()
        self.robots: dict[str, RobotView] = {}
        self.deadlocks = 0
        self.events: deque[tuple[float, str]] = deque(maxlen=MAX_EVENTS)
        self.book = TaskBook(Distances(roadmap), first_id)
        self.chargers = ChargerAllocation(chargers, self.book.distances)
        self.blocked = health.BlockedWaypoints()
        tasks: list[Task] = [*routes, *(pick_task(p, roadmap) for p in picks)]
        for t in tasks:
            self.book.add(t)
        self.expected: set[str] = set()
        self.settle_s = 0.0
        self._t_start: float | None = None
        #: Paused or e-stopped: no health checks, assignments or traffic cycle.
        self.halted = False
        #: Called as ``hook(self, now)`` at the start of every :meth:`step`.
        self.hooks: list[Callable[[CoordinatorState, float], None]] = []
        self._pending_orders: list[TaskOrder] = []

    def expect(self, robots: Iterable[str], settle_s: float) -> None:
        """Hold the first assignment and the first traffic cycle until every robot in
        ``robots`` has reported or ``settle_s`` seconds passed since the first cycle, so that
        robots starting in other processes a moment later are matched too (and get their
        preferred routes), and a restarted coordinator's charger queue counts the robots
        already on chargers."""
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
        """A status record from ``robot`` arrived at ``now``: count its laps or picks for the
        assignment whose id it carries, note its progress, count deadlocks."""
        v = self.robots.get(robot) or self._view(robot, now)
        if not v.alive:
            v.alive = True
            self._log(now, f"{robot} is back")
        v.last_seen = now
        v.obs = obs
        if v.assignment is not None and v.assignment.restored:
            self._confirm(v, obs, now)
        finished = self.book.record(robot, obs, now, v.assignment)
        if finished is not None:
            v.assignment = None
            if self.book.tasks[finished.name].traffic_route() is not None:
                self.traffic.on_release(robot)
            how = "failed" if finished.t_completed is None else "done"
            self._log(now, f"{finished.name} {how} by {robot} ({finished.task_id})")
        if obs.pose is not None:
            health.note_progress(v, obs.pose, now)
        if (
            obs.stuck
            and not v.was_stuck
            and obs.pose is not None
            and health.someone_near(self.robots.values(), v, obs.pose)
        ):
            self.deadlocks += 1
            self._log(now, f"{robot} blocked by another robot")
        v.was_stuck = obs.stuck

    def _confirm(self, v: RobotView, obs: Observation, now: float) -> None:
        """A restored lease (:meth:`restore`) is kept if the robot's status carries its id
        (traffic management is told again), else the task goes back to the queue."""
        a = v.assignment
        if a is None or not a.restored:
            return
        if obs.task_id == a.task_id:
            a.restored = False
            v.progress_t = now
            task = self.book.tasks[a.name]
            route = task.traffic_route()
            if route is not None:
                self.traffic.on_assign(v.name, route, a.poses, a.task_id)
            self._log(now, f"{a.name} kept by {v.name} after a restart ({a.task_id})")
        else:
            v.assignment = None
            self.book.release(a, now, Reason.RESTART)
            self._log(now, f"{a.name} back in the queue: {v.name} no longer runs {a.task_id}")

    # -- runtime tasks -----------------------------------------------------------------

    def add_task(self, task: Task, now: float) -> None:
        """Add a task at runtime (queued). Raises ``ValueError`` for a taken name or an entry
        off the roadmap."""
        self.book.add(task)
        self._log(now, f"{task.name} queued ({task.kind})")

    def cancel(self, name: str, now: float) -> TaskOrder | None:
        """Cancel task ``name``: a queued task ends at once; a held one is taken from its
        robot (the returned idle order stops it). ``None`` if nothing is to be sent. Raises
        ``KeyError`` for a task that is not in the book or already finished."""
        if name not in self.book.tasks or name in self.book.done:
            raise KeyError(name)
        robot = self.book.holder.get(name)
        v = self.robots.get(robot) if robot is not None else None
        a = v.assignment if v is not None and v.assignment is not None and v.assignment.name == name else None
        order = None
        if v is not None and a is not None:
            v.assignment = None
            if self.book.tasks[name].traffic_route() is not None:
                self.traffic.on_release(v.name)
            order = self._idle_order(v)
        self.book.finish(name, a, now, TaskState.CANCELED, "canceled")
        self._log(now, f"{name} canceled")
        return order

    def restore(self, name: str, robot: str, task_id: str, now: float, started: bool) -> None:
        """Re-read a lease of a durable task book after a restart: ``robot`` holds task
        ``name`` under ``task_id`` until its first status says otherwise (:meth:`_confirm`).
        The robot counts as just seen (a silent one dies after ``status_timeout_s`` and the
        task goes back to the queue)."""
        v = self._view(robot, now)
        v.assignment = self.book.restore(name, robot, task_id, now, started)
        v.progress_t = now

    # -- the cycle ---------------------------------------------------------------------

    def step(self, now: float) -> list[TaskOrder]:
        """Run one cycle at ``now``: run the hooks, detect dead, stuck and charging robots,
        take their tasks back, assign waiting tasks, resend unacknowledged orders. Returns
        the orders to send. While :attr:`halted` only the hooks run (robots stand still and
        keep their tasks; nothing is judged stuck)."""
        for hook in list(self.hooks):
            hook(self, now)
        out = self._pending_orders
        self._pending_orders = []
        if self.halted:
            for v in self.robots.values():
                v.progress_t = now  # standing still on purpose is no stall
            return self._sent(out, now)
        out.extend(self._check_health(now))
        if self._t_start is None:
            self._t_start = now
        settled = now - self._t_start >= self.settle_s or all(
            r in self.robots and self.robots[r].obs is not None for r in self.expected
        )
        if settled:
            # the traffic cycle waits too: its charger queue, built from scratch by a restarted
            # coordinator, must know where every robot stands (a charger taken by a robot that
            # has not reported yet is not free)
            out.extend(self._assign(now))
            out.extend(self.traffic.cycle(now, self.robots))
        out.extend(self._reconcile(now, {o.robot for o in out}))
        return self._sent(out, now)

    def send(self, order: TaskOrder) -> None:
        """Queue an order to go out with the next :meth:`step` (e.g. a cancel's idle order)."""
        self._pending_orders.append(order)

    def _sent(self, out: list[TaskOrder], now: float) -> list[TaskOrder]:
        for o in out:
            rv = self.robots.get(o.robot)
            if rv is not None:
                rv.last_order = o
                rv.last_sent = now
        return out

    def _check_health(self, now: float) -> list[TaskOrder]:
        """Silent robots die; a robot that goes to charge or is stuck loses its task."""
        p = self.params
        out: list[TaskOrder] = []
        for v in self.robots.values():
            if health.silent(v, now, p.status_timeout_s):
                assert v.last_seen is not None
                self._die(v, now, f"no status for {now - v.last_seen:.1f} s")
                continue
            a = v.assignment
            if a is None or not v.alive or v.obs is None:
                continue
            if health.charging(v) and a.kind is not TaskKind.CHARGE:
                out.append(self._release(v, now, Reason.CHARGING))
            elif a.t_started is None and not a.restored and now - a.t_assigned >= p.ack_timeout_s:
                out.append(self._release(v, now, Reason.NO_ACK))  # matched again, under a new id
            elif v.obs.mode == Mode.SAFETY_STOP:
                out.append(self._release(v, now, Reason.SAFETY_STOP))
            elif self.traffic.waiting(v.name):
                v.progress_t = now  # held back by traffic management: waiting, not stuck
            elif health.stalled(v, a, now, p.stuck_reassign_s + self.book.tasks[a.name].stall_grace_s):
                v.cooldown_until = now + p.stuck_reassign_s
                wp = self.blocked.mark_near(a.poses, v.obs.pose, now)
                if wp is not None:
                    self._log(now, f"waypoint ({wp.x:.1f}, {wp.y:.1f}) of {a.name} blocked")
                out.append(self._release(v, now, Reason.STUCK))
        return out

    def _reconcile(self, now: float, sent: set[str]) -> list[TaskOrder]:
        """Resend the current order to robots whose status carries another id (at most once
        per :data:`RESEND_S`); tell robots executing an id they no longer hold to idle."""
        out: list[TaskOrder] = []
        for v in self.robots.values():
            if v.name in sent or not v.alive or v.obs is None or now - v.last_sent < RESEND_S:
                continue
            last, a = v.last_order, v.assignment
            if a is not None:
                if v.obs.task_id != a.task_id:
                    out.append(last if last is not None and last.task_id == a.task_id else self._order(v, a))
            elif v.obs.task_id is not None and (
                last is None
                or v.obs.task_id != last.task_id
                or (last.kind != TaskKind.IDLE and v.obs.mode in DRIVING_MODES)
            ):  # e.g. an N-lap patrol done: the robot would keep looping
                out.append(last if last is not None and last.kind == TaskKind.IDLE else self._idle_order(v))
            elif last is None and not self._eligible(v):
                # never ordered and not about to get a task (a low battery, for one): an idle
                # order tells it its charger, so its battery guard can send it to charge
                out.append(self._idle_order(v))
        return out

    # -- queries -----------------------------------------------------------------------

    @property
    def routes(self) -> dict[str, PatrolRoute]:
        """The patrol routes by name, in config order."""
        return {t.name: t for t in self.book.tasks.values() if isinstance(t, PatrolRoute)}

    @property
    def picks(self) -> dict[str, PickTask]:
        """The config picks by name, in queue order."""
        return {t.name: t.spec for t in self.book.tasks.values() if isinstance(t, Pick)}

    @property
    def holder(self) -> dict[str, str | None]:
        """Task name -> the robot holding it (``None``: waiting or done)."""
        return self.book.holder

    @property
    def by_id(self) -> dict[str, Assignment]:
        """The assignments kept (patrols and picks) by task id (old ones are archived:
        :mod:`fleet.coordination.archive`)."""
        return self.book.by_id

    @property
    def reassignments(self) -> list[Reassignment]:
        """The tasks taken back from a robot, in order (the newest kept; all of them:
        :meth:`reassignment_count`)."""
        return self.book.reassignments

    @property
    def assignments(self) -> list[Assignment]:
        """The patrol assignments kept, in the order made (all of them: :meth:`assigned`)."""
        return self._records(TaskKind.PATROL)

    @property
    def pick_assignments(self) -> list[Assignment]:
        """The pick assignments kept, in the order made (all of them: :meth:`assigned`)."""
        return self._records(TaskKind.PICK)

    def assigned(self, kind: TaskKind) -> int:
        """Assignments of ``kind`` made over the run (those archived included)."""
        return self.book.archive.assigned[kind] + sum(1 for a in self.book.records if a.kind is kind)

    def reassignment_count(self) -> int:
        """Tasks taken back from a robot over the run (those archived included)."""
        return self.book.archive.reassignments + len(self.book.reassignments)

    @property
    def waiting_routes(self) -> list[str]:
        """Routes without a robot, in config order."""
        return self.book.waiting(TaskKind.PATROL)

    @property
    def waiting_picks(self) -> list[str]:
        """Picks neither held by a robot nor done, in config order."""
        return self.book.waiting(TaskKind.PICK)

    @property
    def done_picks(self) -> set[str]:
        """Names of the picks done."""
        return {n for n in self.book.done if self.book.tasks[n].kind is TaskKind.PICK}

    def laps_completed(self) -> int:
        """Laps over every patrol assignment."""
        return self.book.archive.laps + sum(a.laps for a in self.assignments)

    def patrols_completed(self) -> int:
        """Patrol assignments with at least one lap."""
        done = self.book.archive.completed[TaskKind.PATROL]
        return done + sum(1 for a in self.assignments if a.completed)

    def laps_by_route(self) -> dict[str, int]:
        """Laps per route (every route, 0 if none)."""
        out = dict.fromkeys(self.routes, 0)
        out.update(self.book.archive.laps_by_route)
        for a in self.assignments:
            out[a.name] = out.get(a.name, 0) + a.laps
        return out

    def laps_by_robot(self) -> dict[str, int]:
        """Laps per robot that held a patrol."""
        out: dict[str, int] = dict(self.book.archive.laps_by_robot)
        for a in self.assignments:
            out[a.robot] = out.get(a.robot, 0) + a.laps
        return out

    def picks_completed(self) -> int:
        """Picks done."""
        done = self.book.archive.completed[TaskKind.PICK]
        return done + sum(1 for a in self.pick_assignments if a.completed)

    def picks_by_robot(self) -> dict[str, int]:
        """Picks done per robot that did any."""
        out: dict[str, int] = dict(self.book.archive.picks_by_robot)
        for a in self.pick_assignments:
            if a.completed:
                out[a.robot] = out.get(a.robot, 0) + 1
        return out

    def cost_matrix(
        self, robots: Sequence[RobotView], tasks: Sequence[str]
    ) -> tuple[FloatMatrix, IndexMatrix]:
        """Travel costs (m) ``[robot, task]`` and the entry (for a route: the lap index) each
        robot would start at. Every robot must have a pose."""
        poses: list[Pose2D] = []
        for v in robots:
            assert v.obs is not None and v.obs.pose is not None
            poses.append(v.obs.pose)
        idx, off, offsets = self.book.entry_matrix(tasks)
        return travel_costs(self.book.distances, poses, idx, off, offsets)

    # -- internals ---------------------------------------------------------------------

    def _records(self, kind: TaskKind) -> list[Assignment]:
        return [a for a in self.book.records if a.kind is kind]

    def _view(self, robot: str, now: float) -> RobotView:
        v = self.robots.get(robot)
        if v is None:
            v = RobotView(name=robot, last_seen=now, progress_t=now)
            self.robots[robot] = v
            self._log(now, f"{robot} joined")
        return v

    def _log(self, now: float, text: str) -> None:
        self.events.append((now, text))
        logger.debug("t=%.2f %s", now, text)

    def _die(self, v: RobotView, now: float, why: str) -> None:
        v.alive = False
        self._log(now, f"{v.name} dead ({why})")
        if v.assignment is not None:
            self._release(v, now, Reason.DEAD)
        self.chargers.free(v)
        v.last_order = None
        v.obs = None
        v.progress_pose = None

    def _release(self, v: RobotView, now: float, reason: Reason) -> TaskOrder:
        """Take ``v``'s task back for ``reason``; returns the idle order for ``v``."""
        a = v.assignment
        assert a is not None
        v.assignment = None
        self.book.release(a, now, reason)
        if self.book.tasks[a.name].traffic_route() is not None:
            self.traffic.on_release(v.name)
        self._log(now, f"{a.name} taken from {v.name} ({reason})")
        return self._idle_order(v)

    def _eligible(self, v: RobotView) -> bool:
        o = v.obs
        return (
            v.alive
            and v.assignment is None
            and o is not None
            and o.pose is not None
            and o.mode == Mode.IDLE
            and o.battery >= self.params.battery_low + BATTERY_MARGIN
        )

    def _assign(self, now: float) -> list[TaskOrder]:
        """Match waiting tasks to eligible robots (greedy min-cost) and hand them over."""
        waiting = self.book.waiting()
        if not waiting:
            return []
        idle = [v for v in self.robots.values() if self._eligible(v)]
        if not idle:
            return []
        costs, entry = self.cost_matrix(idle, waiting)
        tasks = [self.book.tasks[n] for n in waiting]
        ranks = rank(
            costs,
            idle,
            [t.robot for t in tasks],
            self.chargers,
            now,
            priorities=[priority_of(t) for t in tasks],
            only=[only_of(t) for t in tasks],
        )
        return [self._give(idle[i], waiting[j], int(entry[i, j]), now) for i, j in greedy_match(ranks)]

    def _give(self, v: RobotView, name: str, entry: int, now: float) -> TaskOrder:
        """Hand task ``name`` to ``v``, starting at ``entry``; returns its order."""
        task = self.book.tasks[name]
        poses = task.poses_from(entry)
        kept = self.blocked.skip(poses, now)
        if len(kept) < len(poses):
            self._log(now, f"{name}: skipping {len(poses) - len(kept)} blocked waypoint(s)")
        tid = self.book.next_id(task.id_prefix)
        route = task.traffic_route()
        if route is not None:
            kept = self.traffic.on_assign(v.name, route, kept, tid)
        a, handed = self.book.assign(name, v.name, tid, kept, now)
        v.assignment = a
        v.progress_t = now
        if handed is not None:
            self._log(now, f"{name} reassigned to {v.name} as {tid}")
        else:
            self._log(now, f"{name} assigned to {v.name} as {tid}")
        return self._order(v, a)

    def _order(self, v: RobotView, a: Assignment) -> TaskOrder:
        task = self.book.tasks[a.name]
        work = [n for n, _ in task.entries(self.roadmap)]
        return task.order(v.name, a, self.chargers.charger_for(v, work))

    def _idle_order(self, v: RobotView) -> TaskOrder:
        return TaskOrder(
            v.name, self.book.next_id(IDLE_PREFIX), TaskKind.IDLE, None, (), self.chargers.charger_for(v)
        )


def state_from_config(
    config: FleetConfig,
    traffic: TrafficPolicy | None = None,
    task_kind: TreeKind | str = TreeKind.PATROL,
    first_id: int = 1,
) -> CoordinatorState:
    """A :class:`CoordinatorState` for the chargers and thresholds of ``config``, and its
    initial tasks: its routes (``task_kind`` :attr:`TreeKind.PATROL`), its picks
    (:attr:`TreeKind.PICKING`) or both (:attr:`TreeKind.TASKS`). ``first_id``: see
    :class:`CoordinatorState`. Raises ``ValueError`` for another kind."""
    try:
        tree = TreeKind(task_kind)
    except ValueError:
        raise ValueError(
            f"task_kind {task_kind!r}: expected one of {', '.join(k.value for k in TreeKind)}"
        ) from None
    params = CoordinatorParams(
        stuck_reassign_s=config.coordinator.stuck_reassign_s,
        status_timeout_s=config.coordinator.status_timeout_s,
        ack_timeout_s=config.coordinator.ack_timeout_s,
        battery_low=config.sim.battery.low,
    )
    routes = tree in (TreeKind.PATROL, TreeKind.TASKS)
    picks = tree in (TreeKind.PICKING, TreeKind.TASKS)
    return CoordinatorState(
        patrol_routes(config) if routes else [],
        [c.pose for c in config.chargers],
        config.roadmap,
        params,
        traffic,
        picks=list(config.tasks) if picks else (),
        first_id=first_id,
    )


def pick_task(spec: PickTask, roadmap: Roadmap, priority: int = 0, only: str | None = None) -> Pick:
    """A :class:`Pick` of ``spec`` with the roadmap nodes nearest its shelf and drop (its
    stops under traffic management)."""
    nodes = (roadmap.nearest_node(spec.shelf.x, spec.shelf.y), roadmap.nearest_node(spec.drop.x, spec.drop.y))
    return Pick(spec, nodes, priority, only)
