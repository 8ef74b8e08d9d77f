"""The fleet coordinator: who does which task, and what happens when a robot drops out.

Two layers, so the decisions can be tested without a network:

* :class:`~fleet.coordination.state.CoordinatorState` is the pure decision logic. It is fed
  robot observations (``observe``, ``robot_joined``, ``robot_left``) and, once per cycle,
  ``step`` returns the :class:`~fleet.coordination.views.TaskOrder` messages to send. It never
  reads a clock: every call takes ``now`` (seconds of the fleet clock, simulated time in a
  simulated run). It is built from parts: the task book (:mod:`~fleet.coordination.tasks`),
  the matcher (:mod:`~fleet.coordination.matching`), robot health
  (:mod:`~fleet.coordination.health`) and the traffic policy (:mod:`~fleet.coordination.policy`).
* :class:`Coordinator` is the thin bus-facing wrapper: it subscribes to ``fleet/*/status`` and
  the liveliness tokens on a :class:`CoordinatorBus` (the
  :class:`~fleet.bus.status_bus.StatusBus`), feeds the state, and publishes the orders on
  ``fleet/<robot>/task``.

Rules (all times in seconds of the fleet clock):

* Tasks: one task book holds every task; each task is held by at most one robot at a time.
  A patrol fleet's tasks are the config's routes (:class:`~fleet.coordination.tasks.PatrolRoute`,
  kept covered, counted in laps); robots without a task idle as spares; tasks without a robot
  wait.
* Assignment is a global greedy min-cost matching on roadmap travel cost (the robot's pose to
  the task's nearest entry, for a route its nearest waypoint, along the roadmap): the cheapest
  (robot, task) pair is matched first, then the next cheapest among the rest. Distances come
  from one Dijkstra per distinct start node (cached; the roadmap is read-only), and the cost
  matrix is built with numpy, so a cycle with 1000 idle robots and 1000 waiting routes is one
  matrix (figures: ``bench/bench_coordinator.py``). A robot is eligible when alive, in mode
  ``idle``, without a task, and its battery is at least ``low`` + :data:`BATTERY_MARGIN`.
  A task's preferred robot (``robot`` in the config) is matched first when eligible.
* Every assignment has a fresh id ``p-0001`` (patrol), ``k-0002`` (pick), ... (one counter for
  every order kind, so ids also order idle orders ``i-0003``). Ids are never reused.
* A task is taken back from its robot (a :class:`~fleet.coordination.views.Reassignment` is
  recorded with the time and the reason) when the robot dies (its liveliness token
  disappears, or no status arrived for ``status_timeout_s``), is stuck (no progress of
  :data:`~fleet.coordination.health.PROGRESS_M` for ``stuck_reassign_s``, plus the task's
  stall grace, while it should be driving: its status carries the task's id and a mode of
  :data:`fleet.types.DRIVING_MODES`), or goes to charge (its status reports ``mode ==
  "charging"``), or its safety watchdog stopped it (``mode == "safety_stop"``: localization
  lost, navigation server down). A robot the traffic policy holds back is waiting, not stuck. The robot gets
  an idle order, the task goes to the best available idle robot. A robot that was taken off a
  task for being stuck is ranked after every other robot for ``stuck_reassign_s``; a charging
  robot becomes available again when it reports ``idle``.
* A robot stuck within :data:`~fleet.coordination.health.BLOCKED_RADIUS_M` of a waypoint of
  its lap marks that waypoint blocked: new assignments skip it for
  :data:`~fleet.coordination.health.BLOCKED_WAYPOINT_S` (if at least 2 waypoints remain).
* Laps: a status counts only for the assignment whose id it carries and only from that
  assignment's robot, and a lap count never decreases, so a late or duplicate status cannot
  complete (or un-complete) the wrong assignment. A patrol assignment is *completed* when it
  has at least one lap.
* Reconciliation: if a robot reports a task id other than the one the coordinator last gave it
  (a lost, late or never-received order: Zenoh publications are not stored), the current order
  is sent again, at most once per :data:`RESEND_S`. A robot without a task that still reports
  an id it was not last sent is told to idle. A robot never sent an order that cannot take a
  task (its battery is below ``battery_low`` + margin, say, left low by an earlier run) gets
  an idle order, which tells it its charger: its battery guard then sends it to charge.
* Idle robots standing on a charger are matched first (their cost is lowered by
  :data:`~fleet.coordination.matching.CHARGER_BONUS_M`), so that a charged spare leaves the
  charger to robots that need it.
* Chargers: every order carries a charger pose. Each robot is given the charger near its task
  (least roadmap travel distance from the task's nodes, plus a penalty per robot already given
  that charger; :class:`~fleet.coordination.matching.ChargerAllocation`), chosen again when its
  task changes; a robot without a task, the charger near where it stands.
* Deadlocks: a robot whose status turns ``stuck`` with another live robot within
  :data:`~fleet.coordination.health.DEADLOCK_RADIUS_M` counts one deadlock.

Picking (a fleet whose robots run picking trees, ``task_kind="picking"``; see
:func:`~fleet.coordination.state.state_from_config`): the config's ``tasks`` are the tasks
(:class:`~fleet.coordination.tasks.Pick`) instead of its routes, by the same rules where not
said otherwise.

* The picks form a queue in config order; each pick is done once. Every cycle, each eligible
  robot gets the nearest waiting pick: travel cost from the robot to the pick's shelf along
  the roadmap (to the node nearest the shelf, then straight to the shelf), matched globally
  greedily like routes (same charger bonus, stuck cooldown, preferred robot
  ``PickTask.robot``; config order breaks ties). The order is a ``TaskOrder`` of kind
  ``"pick"`` with a fresh id ``k-0007`` from the same counter.
* Completion: status records carry the robot's cumulative ``picks_done`` (the tree's
  ``CompletePick`` increments it). A pick assignment takes as its baseline the ``picks_done``
  of the first record from its robot that carries its id, and is *completed* by a later record
  from that robot, with that id, with a higher ``picks_done``. Only an active assignment can
  complete, so a late status of a robot the pick was taken from cannot complete it.
* A pick is taken back (a ``Reassignment`` whose ``route`` is the pick's name) when its robot
  dies, goes to charge, or is stuck (its stall grace is the pick's ``dwell_s``: no progress
  for ``stuck_reassign_s`` + ``dwell_s`` in mode ``picking`` / ``recovery``); it waits for
  the next eligible robot and starts again from the shelf. Unacknowledged pick orders are
  resent like patrols.

Orders on the bus (``docs/protocol.md``): every order and grant the coordinator sends carries
its ``epoch`` (the epoch of the coordinator lease this process holds) and a per-robot ``seq``
(orders and grants counted apart, from 1). Agents apply only the live lease's epoch, in
sequence. A robot's status acknowledges the last order and grant it applied; if that
acknowledgement is ahead of the coordinator's own count (something else wrote that robot an
order with this epoch), the count continues above it, so the robot takes the next real order.

Traffic management plugs in through :class:`~fleet.coordination.policy.TrafficPolicy` (the
default, :class:`~fleet.coordination.policy.NoTraffic`, does nothing): it sees every route
assignment and release and runs once per cycle.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal, Protocol

import msgspec

from fleet.coordination.health import PROGRESS_M
from fleet.coordination.matching import CHARGER_BONUS_M
from fleet.coordination.policy import GrantSender, NoTraffic, TrafficPolicy
from fleet.coordination.state import BATTERY_MARGIN, RESEND_S, CoordinatorState, state_from_config
from fleet.coordination.tasks import PatrolRoute, Pick, Task, TaskBook, patrol_routes
from fleet.coordination.views import (
    REASON_CHARGING,
    REASON_DEAD,
    REASON_STUCK,
    Assignment,
    CoordinatorParams,
    Observation,
    Reason,
    Reassignment,
    RobotView,
    TaskOrder,
    make_observation,
)
from fleet.messages import Grant, StatusRecord, TaskMessage
from fleet.types import TreeKind, make_pose

if TYPE_CHECKING:
    from fleet.config.model import FleetConfig
    from fleet.navigation import Clock


logger = logging.getLogger(__name__)


class CoordinatorBus(Protocol):
    """What the :class:`Coordinator` needs from the bus (:class:`fleet.bus.status_bus.StatusBus`
    provides it): status records and liveliness in, orders and grants out. Callbacks may run
    on the bus's own thread."""

    def subscribe_statuses(self, callback: Callable[[StatusRecord], None], /) -> object:
        """Call ``callback(record)`` for every valid status record (``fleet/*/status``)."""
        ...

    def watch_alive(self, on_join: Callable[[str], None], on_leave: Callable[[str], None], /) -> object:
        """Call ``on_join(robot)`` / ``on_leave(robot)`` as liveliness tokens come and go."""
        ...

    def publish_task(self, msg: TaskMessage, /) -> None:
        """Publish an order on ``fleet/<msg.robot>/task``."""
        ...

    def publish_grant(self, grant: Grant, /) -> None:
        """Publish a traffic grant on ``fleet/<grant.robot>/grant``."""
        ...


#: An input of the coordinator: a status record, or a robot whose token appeared / went away.
Input = (
    tuple[Literal["status"], StatusRecord]
    | tuple[Literal["join", "leave"], str]
    | tuple[Literal["observation"], tuple[str, Observation]]
)


class Coordinator:
    """The coordinator on the status bus.

    Subscribes to every robot's status and liveliness token on ``bus`` and publishes orders on
    ``fleet/<robot>/task``. Call :meth:`cycle` once per agent tick (the runner does); it
    returns the orders it sent. ``clock`` gives the fleet time (simulated seconds). ``bus`` may
    be ``None`` (nothing is received or published but what :meth:`feed` and the local
    deliveries carry).

    Robots in ``local_robots`` run in the same process: their statuses are fed directly with
    :meth:`feed_local` (their bus copies and liveliness events are ignored) and their orders
    are also handed to ``local_deliver[robot]`` at once, so an in-process run does not depend
    on network timing. Their orders are still published, for observers and for robustness.

    ``task_kind`` chooses the config's initial tasks: ``"patrol"`` (its routes),
    ``"picking"`` (its picks) or ``"tasks"`` (both); see :func:`state_from_config`.
    ``first_id``: the first assignment id to hand out (a restarted coordinator continues its
    durable book's counter). ``epoch``: the epoch of the coordinator lease this process holds
    (``0`` without one), stamped on every order and grant with a per-robot ``seq``. A
    ``traffic`` policy that sends grants (:class:`~fleet.coordination.policy.GrantSender`,
    ``deliver`` unset) has them delivered by :meth:`_deliver_grant`.

    ``link_losses`` (set by the runner of a coordinator that connects to the bus) counts the
    times this process lost its router: a liveliness token that disappears and is applied
    after another loss of the link is not a robot leaving but this process losing its router
    (Zenoh drops every token it saw then), so it is ignored; a robot that really died meanwhile
    is still found by its silence (``coordinator.status_timeout_s``).
    """

    link_losses: Callable[[], int] | None = None

    def __init__(
        self,
        config: FleetConfig,
        bus: CoordinatorBus | None,
        clock: Clock,
        traffic: TrafficPolicy | None = None,
        local_robots: set[str] | None = None,
        task_kind: TreeKind | str = TreeKind.PATROL,
        first_id: int = 1,
        epoch: int = 0,
    ) -> None:
        self.config = config
        self.epoch = int(epoch)
        #: Last ``seq`` sent (or acknowledged) per robot, for orders and for bus grants.
        self.task_seq: dict[str, int] = {}
        self.grant_seq: dict[str, int] = {}
        self.bus = bus
        self.clock = clock
        self.state = state_from_config(config, traffic, task_kind, first_id)
        self.state.expect([r.name for r in config.robots], config.coordinator.status_timeout_s)
        self.local_robots = set(local_robots or ())
        #: In-process agents' ``deliver`` by robot (their orders skip the bus).
        self.local_deliver: dict[str, Callable[[TaskMessage], None]] = {}
        #: In-process agents' ``deliver_grant`` by robot (traffic grants skip the bus for them).
        self.local_grant_deliver: dict[str, Callable[[Grant], None]] = {}
        self._grants: dict[str, tuple[Grant, float]] = {}  # remote robot -> (latest grant, last sent)
        self._adopt_grants(traffic)
        self._inbox: list[Input] = []
        self._left_at: dict[str, int] = {}  # robot -> link losses when its token vanished
        self._lock = threading.Lock()
        if bus is not None:
            bus.subscribe_statuses(self._on_status)
            bus.watch_alive(self._on_join, self._on_leave)

    def _adopt_grants(self, traffic: object) -> None:
        """Deliver the grants of a policy that sends some and has nobody to send them to."""
        if isinstance(traffic, GrantSender) and traffic.deliver is None:
            traffic.deliver = self._deliver_grant

    def _on_status(self, rec: StatusRecord) -> None:
        if rec.robot not in self.local_robots:
            self._put(("status", rec))

    def _on_join(self, robot: str) -> None:
        if robot not in self.local_robots:
            self._put(("join", robot))

    def _on_leave(self, robot: str) -> None:
        if robot not in self.local_robots:
            if self.link_losses is not None:
                self._left_at[robot] = self.link_losses()
            self._put(("leave", robot))

    def _left_with_link(self, robot: str) -> bool:
        """The token of ``robot`` vanished when this process lost its router (see the class)."""
        if self.link_losses is None:
            return False
        if self._left_at.pop(robot, -1) == self.link_losses():
            return False
        logger.info("robot %s's token went with this process's bus link: not a leave", robot)
        return True

    def _put(self, item: Input) -> None:
        with self._lock:
            self._inbox.append(item)

    def feed(self, kind: str, payload: StatusRecord | str) -> None:
        """Queue an input (``status`` record, ``join`` / ``leave`` robot name); thread-safe.
        Raises ``ValueError`` for another kind or a payload of the wrong type."""
        if kind == "status" and isinstance(payload, StatusRecord):
            self._put(("status", payload))
        elif kind in ("join", "leave") and isinstance(payload, str):
            self._put(("join", payload) if kind == "join" else ("leave", payload))
        else:
            raise ValueError(f"Coordinator.feed: no input of kind {kind!r} with a {type(payload).__name__}")

    def feed_local(self, rec: StatusRecord) -> None:
        """A status record of an in-process robot."""
        with self._lock:  # _put, without the call: every robot, every period
            self._inbox.append(("status", rec))

    def feed_observation(self, robot: str, obs: Observation) -> None:
        """What an in-process robot's status record says, handed over as the
        :class:`Observation` :func:`observation_from_record` would make of it (its agent builds
        it from the state and tree it just read: no record to take apart)."""
        with self._lock:
            self._inbox.append(("observation", (robot, obs)))

    def feed_observations(self, items: list[tuple[str, Observation]]) -> None:
        """:meth:`feed_observation` of each ``(robot, observation)`` in order, in one call (a
        whole period of in-process agents)."""
        with self._lock:
            self._inbox.extend([("observation", item) for item in items])

    def cycle(self) -> list[TaskOrder]:
        """Apply everything received since the last cycle, decide, publish. Returns the orders."""
        now = self.clock.now()
        with self._lock:
            inbox, self._inbox = self._inbox, []
        observe, local = self.state.observe, self.local_robots
        for item in inbox:
            if item[0] == "status":
                rec = item[1]
                if rec.robot not in local:  # _heal leaves local robots alone
                    self._heal(rec)
                observe(rec.robot, now, observation_from_record(rec))
            elif item[0] == "observation":
                observe(item[1][0], now, item[1][1])
            elif item[0] == "join":
                self.state.robot_joined(item[1], now)
            elif not self._left_with_link(item[1]):
                self.state.robot_left(item[1], now)
        orders = self.state.step(now)
        self._resend_grants(now)
        for o in orders:
            seq = self.task_seq[o.robot] = self.task_seq.get(o.robot, 0) + 1
            msg = msgspec.structs.replace(task_message(o), epoch=self.epoch, seq=seq)
            deliver = self.local_deliver.get(o.robot)
            if deliver is not None:
                deliver(msg)
            if self.bus is not None:
                self.bus.publish_task(msg)
        return orders

    def _deliver_grant(self, robot: str, grant: Grant) -> None:
        """A traffic grant changed: hand it to the in-process agent, or publish it on
        ``fleet/<robot>/grant`` (and again every :data:`RESEND_S`, as Zenoh keeps nothing)."""
        deliver = self.local_grant_deliver.get(robot)
        if deliver is not None:
            deliver(grant)
            return
        seq = self.grant_seq[robot] = self.grant_seq.get(robot, 0) + 1
        grant = msgspec.structs.replace(grant, epoch=self.epoch, seq=seq)
        self._grants[robot] = (grant, self.clock.now())
        if self.bus is not None:
            self.bus.publish_grant(grant)

    def _heal(self, rec: StatusRecord) -> None:
        """Continue a robot's sequences above what its status acknowledges for this epoch."""
        if rec.epoch != self.epoch or rec.robot in self.local_robots:
            return
        r = rec.robot
        if rec.order_seq > self.task_seq.get(r, 0):
            self.task_seq[r] = rec.order_seq
        if rec.grant_seq > self.grant_seq.get(r, 0):
            self.grant_seq[r] = rec.grant_seq

    def _resend_grants(self, now: float) -> None:
        if self.bus is None:
            return
        for robot, (grant, sent) in list(self._grants.items()):
            if now - sent >= RESEND_S:
                self._grants[robot] = (grant, now)
                self.bus.publish_grant(grant)


def observation_from_record(rec: StatusRecord) -> Observation:
    """Convert a :class:`fleet.messages.StatusRecord` to an :class:`Observation`."""
    pose = rec.pose
    return make_observation(
        t=float(rec.t),
        pose=None if pose is None else make_pose(*pose),
        battery=float(rec.battery),
        mode=str(rec.mode),
        stuck=bool(rec.stuck),
        task_id=rec.task_id,
        laps=int(rec.laps),
        charging=bool(rec.charging),
        picks_done=int(rec.picks_done),
        result_id=rec.result_id,
        result=str(rec.result),
        steps_done=int(rec.steps_done),
    )


def task_message(order: TaskOrder) -> TaskMessage:
    """Convert a :class:`TaskOrder` to the bus's :class:`fleet.messages.TaskMessage`."""
    return TaskMessage(
        robot=order.robot,
        task_id=order.task_id,
        kind=order.kind,
        route=order.route,
        poses=order.poses,
        charger=order.charger,
        pick=order.pick,
        steps=order.steps,
    )


__all__ = [
    "BATTERY_MARGIN",
    "CHARGER_BONUS_M",
    "PROGRESS_M",
    "REASON_CHARGING",
    "REASON_DEAD",
    "REASON_STUCK",
    "RESEND_S",
    "Assignment",
    "Coordinator",
    "CoordinatorBus",
    "CoordinatorParams",
    "CoordinatorState",
    "NoTraffic",
    "Observation",
    "PatrolRoute",
    "Pick",
    "Reason",
    "Reassignment",
    "RobotView",
    "Task",
    "TaskBook",
    "TaskOrder",
    "TrafficPolicy",
    "observation_from_record",
    "patrol_routes",
    "state_from_config",
    "task_message",
]
