"""One robot's agent: its behavior tree, its blackboard, its orders and its status on the bus.

A :class:`RobotAgent` owns the tree built by :func:`nodes.build_tree` for its namespace and
navigation backend. It does not own a loop (the runner does, see ``docs/architecture.md``):
each :meth:`RobotAgent.tick` applies the orders received since the last tick, ticks the
tree once (``root.tick_once()``) and publishes a status record on ``fleet/<robot>/status``.
While the agent exists its liveliness token ``fleet/<robot>/alive`` is held.

Orders (``fleet/<robot>/task``) are applied to the blackboard keys of
``docs/architecture.md``: a ``patrol`` order sets ``route`` (the lap of poses), ``task_id``
and ``charger``; a ``pick`` order sets ``pick``; an ``idle`` order clears ``route``,
``pick`` and ``task_id``. An order whose id was already applied (a duplicate, or a late copy
of an order that has been superseded) is ignored, so a message can never be applied twice.
Orders are queued by the bus callback thread and applied on the ticking thread only.
With traffic management the agent also takes the robot's traffic grants
(``fleet/<robot>/grant``, newest ``seq`` wins) into the blackboard key ``grant``.

Status rate: with ``status_hz`` (the config's ``bus.status_hz``) the agent publishes its status
on the bus at most that often (simulated time, from the records' ``t``): a record is published
when at least ``1 / status_hz`` s passed since the last one published; ``None`` publishes every
tick. ``on_status`` (an in-process coordinator) still gets every tick's record.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Protocol

from fleet.messages import Grant, StatusRecord, TaskMessage
from fleet.types import Mode, Pose2D, TaskKind, TreeKind

if TYPE_CHECKING:
    from fleet.navigation import Clock, NavigationBackend
    from fleet.robots import BatteryModel

logger = logging.getLogger(__name__)

#: Remember this many applied order ids (older ones are forgotten first).
SEEN_IDS = 256


class Declared(Protocol):
    """Something declared on the bus (a subscription, a liveliness token)."""

    def undeclare(self) -> None: ...


class AgentBus(Protocol):
    """What an agent needs of the bus (:class:`fleet.bus.status_bus.StatusBus` has it)."""

    def publish_status(self, rec: StatusRecord) -> None: ...

    def subscribe_tasks(self, robot: str, callback: Callable[[TaskMessage], None]) -> Declared: ...

    def subscribe_grants(self, robot: str, callback: Callable[[Grant], None]) -> Declared: ...

    def declare_alive(self, robot: str) -> Declared: ...


class RobotAgent:
    """The agent of the robot ``namespace`` (``/robot3``; its bus name is ``robot3``).

    Args:
        namespace: the robot's namespace.
        backend: its :class:`~fleet.navigation.NavigationBackend`.
        clock: the fleet clock (simulated seconds); status timestamps come from it.
        bus: a :class:`~fleet.bus.status_bus.StatusBus` (any :class:`AgentBus`), or ``None``
            for an agent without a network (orders then come only through :meth:`deliver`).
        tree_kind: ``"patrol"`` or ``"picking"`` (see :func:`nodes.build_tree`).
        battery_model: the battery thresholds the tree's battery guard uses.
        tick_hz: how often the runner should call :meth:`tick` (simulated Hz).
        on_status: called with every tick's status record (e.g. to feed an in-process
            coordinator directly), whatever ``status_hz``.
        traffic: build the traffic-managed tree (``docs/traffic.md``): the robot drives only
            what its traffic grants (``fleet/<robot>/grant``, or :meth:`deliver_grant`) allow.
        status_hz: publish the status on the bus at most this often (simulated Hz, > 0);
            ``None``: every tick. See the module docstring.

    ``published`` counts the records published on the bus.
    """

    def __init__(
        self,
        namespace: str,
        backend: NavigationBackend,
        clock: Clock,
        bus: AgentBus | None,
        tree_kind: str = TreeKind.PATROL,
        battery_model: BatteryModel | None = None,
        tick_hz: float = 10.0,
        on_status: Callable[[StatusRecord], None] | None = None,
        traffic: bool = False,
        status_hz: float | None = None,
        chargers: Sequence[Pose2D] = (),
    ) -> None:
        from fleet.robots import BatteryModel
        from nodes import build_tree
        from nodes.blackboard import clear_robot_blackboard, robot_blackboard

        self.namespace = "/" + namespace.strip("/")
        self.name = self.namespace.lstrip("/")
        self.backend = backend
        self.clock = clock
        self.bus = bus
        self.tick_hz = float(tick_hz)
        self.tree_kind = tree_kind
        self.on_status = on_status
        if status_hz is not None and not (math.isfinite(status_hz) and status_hz > 0):
            raise ValueError(f"status_hz must be a positive number of Hz or None, got {status_hz}")
        #: Least simulated time between two records published on the bus (None: every tick).
        self.status_period_s = None if status_hz is None else 1.0 / status_hz
        self._last_published: float | None = None
        self.published = 0
        # py_trees' blackboard is process-global: start from the defaults, not from what an
        # earlier agent of the same namespace in this process left behind
        clear_robot_blackboard(self.namespace)
        self.bb = robot_blackboard(self.namespace, name=f"agent{self.namespace}")
        self.traffic = traffic
        #: The config's chargers: until the coordinator names one, the battery guard uses
        #: the one nearest the robot (so a robot never given work still charges).
        self.chargers = tuple(chargers)
        self.root = build_tree(
            tree_kind, self.namespace, backend, clock, battery_model or BatteryModel(), traffic=traffic
        )
        self.seq = 0
        self.ticks = 0
        self.charges = 0
        #: The lowest battery fraction this robot reported since the agent started.
        self.min_battery = 1.0
        #: Ticks spent in each tree mode (``Mode`` values) since the agent started.
        self.mode_ticks: dict[str, int] = {}
        self.last_status: StatusRecord | None = None
        self._seen: dict[str, None] = {}
        self._inbox: list[TaskMessage] = []
        self._grant: Grant | None = None
        self._grant_seq = 0
        self.grants_applied = 0
        self._lock = threading.Lock()
        self._last_mode: str = Mode.IDLE
        self._token: Declared | None = None
        self._sub: Declared | None = None
        self._grant_sub: Declared | None = None
        if bus is not None:
            self._sub = bus.subscribe_tasks(self.name, self.deliver)
            if traffic:
                self._grant_sub = bus.subscribe_grants(self.name, self.deliver_grant)
            self._token = bus.declare_alive(self.name)

    # -- orders ------------------------------------------------------------------------

    def deliver(self, msg: TaskMessage) -> None:
        """Queue an order; thread-safe. It is applied at the start of the next :meth:`tick`."""
        with self._lock:
            self._inbox.append(msg)

    def deliver_grant(self, grant: Grant) -> None:
        """Keep a traffic :class:`~fleet.messages.Grant` for the next :meth:`tick`; thread-safe.
        Only the newest (highest ``seq``) of those received counts; older or duplicate copies
        (the bus copy of a grant also handed over in-process) are ignored."""
        if grant.robot != self.name:
            return
        with self._lock:
            if self._grant is None or grant.seq > self._grant.seq:
                self._grant = grant

    def _apply_orders(self) -> None:
        with self._lock:
            inbox, self._inbox = self._inbox, []
            grant = self._grant
        for msg in inbox:
            self.apply(msg)
        if grant is not None and grant.seq > self._grant_seq:
            self._grant_seq = grant.seq
            self.bb.grant = grant
            self.grants_applied += 1

    def apply(self, msg: TaskMessage) -> bool:
        """Apply one order to the blackboard now; returns False if it was ignored (an id
        already applied, or addressed to another robot)."""
        if msg.robot not in (None, self.name):
            return False
        tid = msg.task_id
        if tid is not None:
            if tid in self._seen:
                return False
            self._seen[tid] = None
            if len(self._seen) > SEEN_IDS:
                self._seen.pop(next(iter(self._seen)))
        if msg.charger is not None:
            self.bb.charger = _pose(msg.charger)
        if msg.kind == TaskKind.PATROL:
            self.bb.pick = None
            self.bb.route = tuple(_pose(p) for p in msg.poses)
            self.bb.task_id = tid
        elif msg.kind == TaskKind.PICK:
            self.bb.route = None
            self.bb.pick = msg.pick
            self.bb.task_id = tid
        else:
            self.bb.route = None
            self.bb.pick = None
            self.bb.task_id = None
        return True

    # -- ticking -----------------------------------------------------------------------

    def _default_charger(self) -> None:
        """Set the blackboard ``charger`` to the config charger nearest the robot."""
        pose = self.backend.robot_state().pose
        if pose is not None:
            self.bb.charger = min(
                self.chargers, key=lambda c: (abs(c.x - pose.x) + abs(c.y - pose.y), c.x, c.y)
            )

    def tick(self) -> StatusRecord:
        """Apply queued orders, tick the tree once, publish (see ``status_hz``) and return
        the status record."""
        self._apply_orders()
        if self.bb.charger is None and self.chargers:
            self._default_charger()
        self.root.tick_once()
        self.ticks += 1
        mode = str(self.bb.mode)
        if mode == Mode.CHARGING and self._last_mode != Mode.CHARGING:
            self.charges += 1
        self._last_mode = mode
        self.mode_ticks[mode] = self.mode_ticks.get(mode, 0) + 1
        rec = self.status()
        self.min_battery = min(self.min_battery, float(rec.battery))
        self.last_status = rec
        self._publish(rec)
        if self.on_status is not None:
            self.on_status(rec)
        return rec

    def _publish(self, rec: StatusRecord) -> None:
        if self.bus is None:
            return
        last, period = self._last_published, self.status_period_s
        if period is not None and last is not None and rec.t < last + period - 1e-9:
            return
        self._last_published = rec.t
        self.published += 1
        self.bus.publish_status(rec)

    def status(self) -> StatusRecord:
        """The current status record of this robot (each call takes the next ``seq``)."""
        self.seq += 1
        st = self.backend.robot_state()
        bb = self.bb
        task_id = bb.task_id
        laps = int(bb.laps) if bb.lap_task_id is not None and bb.lap_task_id == task_id else 0
        pose = st.pose.as_tuple() if st.pose is not None else None
        return StatusRecord(
            robot=self.name,
            ns=self.namespace,
            t=float(self.clock.now()),
            pose=pose,
            battery=float(st.battery),
            charging=bool(st.charging),
            stuck=bool(st.stuck),
            bt=self.root.status.name,
            leaf=str(bb.active_leaf or ""),
            mode=str(bb.mode),
            task_id=task_id,
            laps=laps,
            progress=float(bb.route_progress or 0.0),
            distance_m=float(st.distance_m),
            collisions=int(st.collisions),
            seq=self.seq,
            picks_done=int(bb.picks_done or 0),
        )

    def close(self) -> None:
        """Cancel the robot's outstanding goal, drop the liveliness token and the subscription."""
        from py_trees.common import Status

        try:
            self.root.stop(Status.INVALID)
        except Exception as e:  # noqa: BLE001 - best effort on shutdown
            logger.debug("robot %s: stopping the tree failed: %s", self.name, e)
        for handle in (self._token, self._sub, self._grant_sub):
            if handle is not None:
                try:
                    handle.undeclare()
                except Exception as e:  # noqa: BLE001 - keep releasing the rest
                    logger.debug("robot %s: undeclare failed: %s", self.name, e)
        self._token = self._sub = self._grant_sub = None


def _pose(p: Pose2D | Iterable[float]) -> Pose2D:
    if isinstance(p, Pose2D):
        return p
    return Pose2D(*(float(v) for v in p))
