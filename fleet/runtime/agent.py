"""One robot's agent: its behavior tree, its blackboard, its orders and its status on the bus.

A :class:`RobotAgent` owns the tree built by :func:`nodes.build_tree` for its namespace and
navigation backend. It does not own a loop (the runner does, see ``docs/architecture.md``):
each :meth:`RobotAgent.tick` applies the orders received since the last tick, ticks the
tree once (``root.tick_once()``) and publishes a status record on ``fleet/<robot>/status``.
While the agent exists its liveliness token ``fleet/<robot>/alive`` is held.

Orders (``fleet/<robot>/task``) are applied to the blackboard keys of
``docs/architecture.md``: a ``patrol`` order sets ``route`` (the lap of poses), ``task_id``
and ``charger``; a ``go_to``, ``inspection``, ``park`` or ``pick`` order sets ``steps``
(the legacy picking tree gets ``pick``); a ``charge`` order sets ``charge_now``; an ``idle``
order clears them all and ``task_id``. An order whose id was already applied under the same
coordinator epoch (a duplicate, or a late copy of an order that has been superseded) is
ignored, so a message can never be applied twice.
Orders are queued by the bus callback thread and applied on the ticking thread only.
With traffic management the agent also takes the robot's traffic grants
(``fleet/<robot>/grant``, newest ``seq`` wins) into the blackboard key ``grant``.

Orders and grants from the bus pass an :class:`~fleet.runtime.order_gate.OrderGate` first
(``docs/protocol.md``): only those of the live coordinator's epoch, in sequence, are applied;
the others are counted (``rejected`` in the status) and ignored. Orders handed over in-process
(:meth:`RobotAgent.deliver`, :meth:`RobotAgent.deliver_grant`, from a coordinator in the same
process) skip the gate. The status acknowledges the last order applied (``epoch``,
``order_seq``) and the last grant (``grant_seq``).

Safety and health: each tick first reads the robot's state and asks the robot's
:class:`fleet.diagnostics.SafetyWatchdog`; while it trips (localization lost or stale, the
navigation server down) the tree is halted at once (its running goal is canceled, so the robot
stops within this one control period), the robot reports ``mode = "safety_stop"`` and the
coordinator takes its task back; when it clears the tree runs again. Every status record
carries the robot's diagnostics (``health``, ``diag``: :func:`fleet.diagnostics.robot_diagnostics`).
Until the backend gave a first pose the robot *waits for state* (no fault, no watchdog trip):
mode ``idle``, leaf ``WaitingForState``, ``localization`` WARN, the tree not ticked.

Status rate: with ``status_hz`` (the config's ``bus.status_hz``) the agent publishes its status
on the bus at most that often (simulated time, from the records' ``t``): a record is published
when at least ``1 / status_hz`` s passed since the last one published; ``None`` publishes every
tick. With ``status_max_period_s`` (the config's ``bus.status_max_period_s``) it publishes *on
change* instead: a record goes out (still at most at ``status_hz``) only if it differs from the
last one published (:func:`~fleet.runtime.status_record.status_changed`: anything but ``t``, ``seq`` and small moves of the
pose, battery, progress and odometry), and at least every ``status_max_period_s`` s whatever
changed. ``on_status`` (an in-process coordinator) still gets every tick's record.

Bus loss: :meth:`RobotAgent.set_link_lost` (called by the runner's bus-loss watchdog, see
:class:`fleet.bus.link.LinkWatch`) stops the tree like a safety stop (the running goal is
canceled, the robot stands, ``mode = "safety_stop"``, ``link_stops`` counts it) until the link
is back; the blackboard keeps the task, so the tree resumes it then.

Pause and emergency stop (``fleet/control/state``, :class:`~fleet.messages.FleetControl`,
or :meth:`RobotAgent.set_control` in-process): while the fleet is paused or its e-stop is
latched the agent stops its tree (the running goal is canceled), does not tick it, and
reports ``mode`` ``paused`` / ``estop``; the blackboard keeps the task, so the tree resumes
it (at the step or lap it reached) when the fleet runs again. Below the tree, the runner's
:class:`~fleet.runtime.latch.LatchedBackend` refuses goals while the e-stop is latched.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

from py_trees.common import Status

from fleet.coordination.views import Observation
from fleet.diagnostics import (
    HealthParams,
    SafetyWatchdog,
)
from fleet.messages import FleetControl, Grant, StatusRecord, TaskMessage
from fleet.runtime.agent_bus import AgentBus, ControlBus, Declared
from fleet.runtime.charger_index import nearest_charger
from fleet.runtime.order_gate import OrderGate
from fleet.runtime.status_record import (
    Held,
    TreeView,
    held_changed,
    observation_of,
    status_record,
    tree_view,
    view_names,
)
from fleet.runtime.watched import WatchedBackend, wake_aware
from fleet.types import Mode, Pose2D, RobotState, TaskKind, TreeKind
from fleet.wake import Wake
from nodes.task_tree import build_agent_tree

if TYPE_CHECKING:
    from fleet.bus.lease import Lease
    from fleet.navigation import Clock, NavigationBackend
    from fleet.robots import BatteryModel

logger = logging.getLogger(__name__)

#: Remember this many applied order ids (older ones are forgotten first).
SEEN_IDS = 256


class RobotAgent:
    """The agent of the robot ``namespace`` (``/robot3``; its bus name is ``robot3``).

    Args:
        namespace: the robot's namespace.
        backend: its :class:`~fleet.navigation.NavigationBackend`.
        clock: the fleet clock (simulated seconds); status timestamps come from it.
        bus: a :class:`~fleet.bus.status_bus.StatusBus` (any :class:`AgentBus`), or ``None``
            for an agent without a network (orders then come only through :meth:`deliver`).
        tree_kind: ``"tasks"`` (the tree that runs every task kind; default), or the
            single-purpose ``"patrol"`` / ``"picking"`` trees
            (:func:`nodes.task_tree.build_robot_tree`).
        tree_file: a BehaviorTree.CPP XML file to run instead of the built-in tree
            (:func:`nodes.xml_tree.load_tree`; ``tree_kind`` should be the file's
            :attr:`~nodes.xml_tree.XmlTree.task_kind`). A bad file raises
            :class:`~fleet.errors.TreeError`.
        battery_model: the battery thresholds the tree's battery guard uses.
        tick_hz: how often the runner should call :meth:`tick` (simulated Hz).
        on_status: called with every tick's status record (e.g. to feed an in-process
            coordinator directly), whatever ``status_hz``.
        traffic: build the traffic-managed tree (``docs/traffic.md``): the robot drives only
            what its traffic grants (``fleet/<robot>/grant``, or :meth:`deliver_grant`) allow.
        status_hz: publish the status on the bus at most this often (simulated Hz, > 0);
            ``None``: every tick. See the module docstring.
        near_chargers: with ``traffic``, ``chargers`` become the blackboard ``charger_sites``:
            the battery guard also measures to the nearest (``traffic.near_charger_trigger``).
        leases: the live coordinator lease (:meth:`fleet.bus.lease.LeaseWatch.current`): orders
            and grants on the bus are then taken through the agent's :class:`OrderGate`.
            ``None``: the agent takes no orders from the bus (its coordinator runs in the same
            process and hands them over with :meth:`deliver` / :meth:`deliver_grant`).
        status_max_period_s: publish on change, and at least this often (simulated s, > 0);
            ``None``: publish at every ``status_hz`` period whether or not anything changed.
        clear_blackboard: clear what an earlier agent of ``namespace`` left on the blackboard;
            ``False``: the caller did (:func:`nodes.blackboard.clear_robot_blackboards`).

    ``published`` counts the records published on the bus.
    """

    # long: one attribute per piece of the agent's state, each set once here
    def __init__(
        self,
        namespace: str,
        backend: NavigationBackend,
        clock: Clock,
        bus: AgentBus | None,
        tree_kind: str = TreeKind.TASKS,
        battery_model: BatteryModel | None = None,
        tick_hz: float = 10.0,
        on_status: Callable[[StatusRecord], None] | None = None,
        traffic: bool = False,
        status_hz: float | None = None,
        tree_file: str | None = None,
        health: HealthParams | None = None,
        chargers: Sequence[Pose2D] = (),
        near_chargers: bool = False,
        leases: Callable[[], Lease | None] | None = None,
        status_max_period_s: float | None = None,
        clear_blackboard: bool = True,
    ) -> None:
        from fleet.robots import BatteryModel
        from nodes.blackboard import clear_robot_blackboard, robot_blackboard

        self.namespace = "/" + namespace.strip("/")
        self.name = self.namespace.lstrip("/")
        self.backend = backend
        self.clock = clock
        self.bus = bus
        self.tick_hz = float(tick_hz)
        self.tree_kind = tree_kind
        self.on_status = on_status
        #: Like ``on_status``, given the record as an in-process coordinator reads it.
        self.on_observation: Callable[[str, Observation], None] | None = None
        #: Instead of ``on_observation``: each period's ``(name, observation)`` is appended here
        #: (the runner hands a whole period's to the coordinator in one call).
        self.observations: list[tuple[str, Observation]] | None = None
        _check_rate("status_hz", status_hz, "Hz")
        _check_rate("status_max_period_s", status_max_period_s, "s")
        #: Least simulated time between two records published on the bus (None: every tick).
        self.status_period_s = None if status_hz is None else 1.0 / status_hz
        #: Publish on change, and at least this often (None: every status period).
        self.status_max_period_s = status_max_period_s
        self._last_published: float | None = None
        self._sent_held: Held | None = None  # the values of the last record published
        self.published = 0
        if clear_blackboard:  # the blackboard is process-global: not what an earlier agent left
            clear_robot_blackboard(self.namespace)
        self.bb = robot_blackboard(self.namespace, name=f"agent{self.namespace}")
        self.traffic = traffic
        battery = battery_model or BatteryModel()
        self.tree_file = tree_file
        #: The tree's view of the backend: it records what the tree polls (``fleet.wake``).
        self.watched = WatchedBackend(backend)
        self._read_state = backend.robot_state  # bound once: read every period
        self.root = build_agent_tree(
            tree_kind, tree_file, self.namespace, self.watched, clock, battery, traffic
        )
        self._init_ticking()
        self.health = health or HealthParams(battery_low=battery.low)
        #: The fleet-side safety stop (see the module docstring); ``watchdog.trips`` counts stops.
        self.watchdog = SafetyWatchdog(self.health)
        #: The config's chargers: until the coordinator names one, the battery guard uses
        #: the one nearest the robot (so a robot never given work still charges).
        self.chargers = tuple(chargers)
        if near_chargers and traffic:  # sent to a free charger near it: the guard measures so
            self.bb.charger_sites = self.chargers  # the same tuple for every agent of a fleet
        self.seq = 0
        self.ticks = 0
        self.charges = 0
        #: The lowest battery fraction this robot reported since the agent started.
        self.min_battery = 1.0
        #: Ticks spent in each tree mode (``Mode`` values) since the agent started.
        self.mode_ticks: dict[str, int] = {}
        self._held: Held | None = None
        self._built: tuple[Held, StatusRecord] | None = None
        self._seen: dict[str, None] = {}
        self._inbox: list[TaskMessage] = []
        self._grant: Grant | None = None
        self._grant_fresh = False
        self._grant_seq = self._grant_epoch = 0
        self.grants_applied = 0
        self.gate = OrderGate(leases) if leases is not None else None  # None: no orders from the bus
        self.ack: tuple[int, int] = (0, 0)  # (epoch, seq) of the last order applied
        self._lock = threading.Lock()
        self._last_mode: str = Mode.IDLE
        self._control: FleetControl | None = None
        #: The tree is stopped: the fleet is paused or its e-stop latched (see the module docstring).
        self.halted: str | None = None
        #: Why the bus-loss watchdog holds the robot (``""``: it does not); see :meth:`set_link_lost`.
        self.link_lost = ""
        #: Times the bus-loss watchdog stopped the robot.
        self.link_stops = 0
        #: No pose came from the backend yet: the robot waits for its first state (not a fault).
        self.waiting_for_state = self._was_waiting = True
        self._token: Declared | None = None
        self._sub: Declared | None = None
        self._grant_sub: Declared | None = None
        self._control_sub: Declared | None = None
        if bus is not None:
            if self.gate is not None:
                self._sub = bus.subscribe_tasks(self.name, self._on_bus_task)
                if traffic:
                    self._grant_sub = bus.subscribe_grants(self.name, self._on_bus_grant)
            if isinstance(bus, ControlBus):
                self._control_sub = bus.subscribe_control(self.set_control)
            self._token = bus.declare_alive(self.name)

    def _init_ticking(self) -> None:
        """The state of event-driven ticking (:mod:`fleet.runtime.scheduler`)."""
        #: Orders, a grant or a control state were delivered since the last tick took them.
        self.touched = False
        #: Every node keeps the ``fleet.wake`` contract: the tree may be ticked on change.
        self.event_driven = wake_aware(self.root)
        #: What the tree waits for since its last tick (``fleet.wake``).
        self.wake: Wake | None = self.watched.wake if self.event_driven else None
        #: Whether the last :meth:`tick` ticked the tree; ``tree_ticks`` counts those ticks.
        self.tree_ticked = False
        self.tree_ticks = 0
        #: The last tree tick changed something: the tree must be ticked again next period.
        self.settling = True
        self._nodes = list(self.root.iterate())
        self._signature: tuple[object, ...] = ()
        #: The status record's view of the tree, kept while neither the tree nor the blackboard
        #: changed (a period without a tree tick, orders or a stop reads nothing new).
        self._view: TreeView | None = None
        self._view_names = view_names(self.namespace)
        self._has_charger = False

    # -- orders ------------------------------------------------------------------------

    def deliver(self, msg: TaskMessage) -> None:
        """Queue an order; thread-safe. It is applied at the start of the next :meth:`tick`."""
        with self._lock:
            self._inbox.append(msg)
            self.touched = True

    def deliver_grant(self, grant: Grant) -> None:
        """Keep a traffic :class:`~fleet.messages.Grant` for the next :meth:`tick`; thread-safe.
        Only the newest (highest ``seq``) of those received counts; older or duplicate copies
        are ignored."""
        if grant.robot != self.name:
            return
        with self._lock:
            if self._grant is None or grant.seq > self._grant.seq:
                self._grant = grant
                self._grant_fresh = True
                self.touched = True

    def _on_bus_task(self, msg: TaskMessage) -> None:
        """An order from the bus: queued if the gate admits it."""
        if msg.robot in (None, self.name) and self.gate is not None and self.gate.admit("task", msg):
            self.deliver(msg)

    def _on_bus_grant(self, grant: Grant) -> None:
        """A grant from the bus: kept if the gate admits it (the gate orders them by ``seq``)."""
        if grant.robot == self.name and self.gate is not None and self.gate.admit("grant", grant):
            with self._lock:
                self._grant = grant
                self._grant_fresh = True
                self.touched = True

    def pending(self) -> bool:
        """Orders, a grant or a control change wait to be applied (thread-safe)."""
        with self._lock:
            ctl = self._control
            halted = ctl is not None and (ctl.estop or ctl.paused)
            return bool(self._inbox) or self._grant_fresh or (halted != (self.halted is not None))

    def set_control(self, ctl: FleetControl) -> None:
        """Keep the fleet's control state for the next :meth:`tick` (newest ``seq`` wins);
        thread-safe."""
        with self._lock:
            if self._control is None or ctl.seq > self._control.seq:
                self._control = ctl
                self.touched = True

    def _apply_orders(self) -> bool:
        """Apply the queued orders and the newest grant; whether there was any. Called when
        ``touched`` (something was delivered since the last time; no lock needed to read it)."""
        with self._lock:
            self.touched = False
            inbox, self._inbox = self._inbox, []
            grant = self._grant if self._grant_fresh else None
            self._grant_fresh = False
        for msg in inbox:
            self.apply(msg)
        if grant is not None:
            self._grant_seq, self._grant_epoch = grant.seq, grant.epoch
            self.bb.grant = grant
            self.grants_applied += 1
            return True
        return bool(inbox)

    def apply(self, msg: TaskMessage) -> bool:
        """Apply one order to the blackboard now; returns False if it was ignored (an id
        already applied, or addressed to another robot)."""
        if msg.robot not in (None, self.name):
            return False
        tid = msg.task_id
        if tid is not None:
            seen = f"{msg.epoch}/{tid}"  # ids are unique per coordinator epoch
            if seen in self._seen:
                return False
            self._seen[seen] = None
            if len(self._seen) > SEEN_IDS:
                self._seen.pop(next(iter(self._seen)))
        self.ack = (msg.epoch, msg.seq)
        if msg.charger is not None:
            self.bb.charger = _pose(msg.charger)
        bb = self.bb
        kind = msg.kind
        bb.route = bb.pick = bb.steps = None
        bb.charge_now = False
        bb.task_kind = None if kind == TaskKind.IDLE else str(kind)
        bb.task_id = None if kind == TaskKind.IDLE else tid
        if kind == TaskKind.PATROL:
            bb.route = tuple(_pose(p) for p in msg.poses)
        elif kind == TaskKind.PICK and (self.tree_kind != TreeKind.TASKS or not msg.steps):
            bb.pick = msg.pick  # the single-purpose picking tree
        elif kind in (TaskKind.PICK, TaskKind.GO_TO, TaskKind.INSPECTION, TaskKind.PARK):
            bb.steps = tuple(msg.steps)
        elif kind == TaskKind.CHARGE:
            bb.charge_now = True
        return True

    def set_link_lost(self, reason: str) -> None:
        """The bus-loss watchdog: ``reason`` (non-empty) stops the tree now (the running goal is
        canceled: the robot stands) and keeps it stopped; ``""`` lets the next :meth:`tick` run
        it again from the blackboard's task. Call from the ticking thread."""
        if reason and not self.link_lost:
            logger.warning("robot %s: stopped: %s", self.name, reason)
            self._stop_tree()
            self.link_stops += 1
            self.bb.mode = Mode.SAFETY_STOP
            self.bb.active_leaf = "BusWatchdog"
        elif not reason and self.link_lost:
            logger.warning("robot %s: bus link back: resuming", self.name)
            self.bb.mode = Mode.IDLE
        self.link_lost = reason

    # -- ticking -----------------------------------------------------------------------

    def tick(self, tree: bool = True) -> StatusRecord:
        """Apply queued orders, check the safety watchdog, tick the tree once (unless the
        watchdog holds the robot), publish (see ``status_hz``) and return the status record.

        ``tree=False`` (the event-driven scheduler, :mod:`fleet.runtime.scheduler`, found nothing
        the tree waits for) does all of that but the tree's tick, unless orders were applied or
        the robot leaves a safety stop or a pause; ``tree_ticked`` says whether it ticked."""
        self.period(tree)
        rec = self.last_status
        assert rec is not None  # a period always holds a record
        return rec

    def period(self, tree: bool = True) -> None:
        """:meth:`tick` without returning the record: the record of a period that publishes
        nothing (and has no ``on_status``) is built only when :attr:`last_status` is read, from
        the values held at the period (the same record; the runner's path, where most periods
        publish nothing)."""
        self.tree_ticked = False
        if self.touched and self._apply_orders():
            tree = True
            self._view = None
        st = self._read_state()
        if not self._has_charger:
            if self.bb.charger is None and self.chargers and st.pose is not None:
                self.bb.charger = nearest_charger(self.chargers, st.pose)  # until one is named
            self._has_charger = self.bb.charger is not None
        was = self.watchdog.reason
        waiting = self.waiting_for_state and self._waiting_for_state(st)
        reason = "" if waiting else self.watchdog.check(st)
        ctl = self._control  # replaced whole under the lock; reading it needs none
        halt = (
            None if ctl is None or not (ctl.estop or ctl.paused) else Mode.ESTOP if ctl.estop else Mode.PAUSED
        )
        was_waiting, self._was_waiting = self._was_waiting, waiting
        if halt is not None or reason or was or was_waiting:
            self._view = None  # the blackboard changes below
        if halt is not None:  # the fleet's pause or e-stop comes before everything
            if self.halted is None:
                self._stop_tree()
            self.halted = halt
            self.bb.mode = halt
        elif self.link_lost:
            self.halted = None
            self.bb.mode = Mode.SAFETY_STOP
            self.bb.active_leaf = "BusWatchdog"
        elif reason:
            self.halted = None
            if not was:
                logger.warning("robot %s: safety stop: %s", self.name, reason)
                self.root.stop(Status.INVALID)  # cancels the running goal: the robot stops
            self.bb.mode = Mode.SAFETY_STOP
            self.bb.active_leaf = "SafetyWatchdog"
        elif waiting:
            self.bb.mode, self.bb.active_leaf = Mode.IDLE, "WaitingForState"
        else:
            if was:
                logger.warning("robot %s: safety stop cleared", self.name)
            if was or was_waiting or self.halted is not None:
                self.halted = None
                self.bb.mode = Mode.IDLE
                tree = True
            if tree:
                self._tick_tree(st)
                self._view = None
        view = self._view
        if view is None:  # the tree or the blackboard may have changed: read them again
            view = self._view = self._tree_view()
        self.ticks += 1
        mode = view.mode
        if mode == Mode.CHARGING and self._last_mode != Mode.CHARGING:
            self.charges += 1
        self._last_mode = mode
        self.mode_ticks[mode] = self.mode_ticks.get(mode, 0) + 1
        self._report(st, view)

    def _report(self, st: RobotState, view: TreeView) -> None:
        """The period's status: held for :attr:`last_status`, published when due, observed."""
        self.seq += 1
        t = float(self.clock.now())
        battery = float(st.battery)
        self.min_battery = min(self.min_battery, battery)
        ack = self.ack
        self._held = (
            st, view, t, self.seq, ack, self._grant_seq if self._grant_epoch == ack[0] else 0,
            int(getattr(self.bus, "malformed", 0)), self.gate.rejected_total if self.gate is not None else 0,
            self.watchdog.reason, self.waiting_for_state,
        )  # fmt: skip
        if self.on_status is not None or self._publish_due(t):
            self._publish(t)
            if self.on_status is not None:
                rec = self.last_status
                assert rec is not None
                self.on_status(rec)
        obs = observation_of(t, st.pose, battery, bool(st.stuck), bool(st.charging), view)
        if self.observations is not None:
            self.observations.append((self.name, obs))
        elif self.on_observation is not None:
            self.on_observation(self.name, obs)

    @property
    def last_status(self) -> StatusRecord | None:
        """The status record of the last period (``None`` before the first), built on first
        read from the values held at that period."""
        held, built = self._held, self._built
        if held is None:
            return None
        if built is not None and built[0] is held:
            return built[1]
        rec = status_record(self.name, self.namespace, held, self.health)
        self._built = (held, rec)
        return rec

    def _publish_due(self, t: float) -> bool:
        """Whether a record of time ``t`` may be published (the ``status_hz`` period passed)."""
        if self.bus is None:
            return False
        last, period = self._last_published, self.status_period_s
        return period is None or last is None or t >= last + period - 1e-9

    def _waiting_for_state(self, st: RobotState) -> bool:
        """Whether the robot still waits for its first state (no pose yet from the backend)."""
        if self.waiting_for_state and st.pose is not None:
            self.waiting_for_state = False
        elif self.waiting_for_state and not self.ticks:
            logger.info("robot %s: waiting for its first state from the navigation backend", self.name)
        return self.waiting_for_state

    def _tick_tree(self, st: RobotState) -> None:
        """Tick the tree once (its state reads answered by ``st``, the period's, until it sends or
        cancels a goal: :class:`WatchedBackend`); note whether it has settled (``settling``: the
        tick changed a node's status or the goals it watches, so the next period ticks it again,
        e.g. a ``Repeat`` restarts its child only at the next tick)."""
        wake = self.watched.wake
        before = dict(wake.goals)
        wake.reset()
        self.watched.held = st
        try:
            self.root.tick_once()
        finally:
            self.watched.held = None
        self.tree_ticked = True
        self.tree_ticks += 1
        if self.wake is not None:
            sig = tuple(n.status for n in self._nodes)
            self.settling = sig != self._signature or wake.goals != before
            self._signature = sig

    def _publish(self, t: float) -> None:
        """Publish the period's record (of time ``t``) when due; on change (``status_max_period_s``)
        it is built only if it says something the last one published did not (:func:`held_changed`)."""
        if self.bus is None or not self._publish_due(t):
            return
        last, longest, sent, held = (
            self._last_published,
            self.status_max_period_s,
            self._sent_held,
            self._held,
        )
        assert held is not None
        if longest is not None and last is not None and sent is not None and t < last + longest - 1e-9:
            if not held_changed(sent, held, self.health):
                return
        rec = self.last_status
        assert rec is not None
        self._last_published = rec.t
        self._sent_held = held
        self.published += 1
        self.bus.publish_status(rec)

    def _tree_view(self) -> TreeView:
        """What the status record reports of the tree and its blackboard (read now)."""
        return tree_view(self.root.status.name, self._view_names)

    def status(self, state: RobotState | None = None, view: TreeView | None = None) -> StatusRecord:
        """The current status record of this robot (each call takes the next ``seq``), from
        ``state`` (default: the backend's now) and ``view`` (default: the tree now)."""
        self.seq += 1
        st = state if state is not None else self.backend.robot_state()
        v = view if view is not None else self._tree_view()
        ack = self.ack
        return status_record(
            self.name,
            self.namespace,
            (
                st, v, float(self.clock.now()), self.seq, ack,
                self._grant_seq if self._grant_epoch == ack[0] else 0, int(getattr(self.bus, "malformed", 0)),
                self.gate.rejected_total if self.gate is not None else 0, self.watchdog.reason,
                self.waiting_for_state,
            ),
            self.health,
        )  # fmt: skip

    def _stop_tree(self) -> None:
        """Interrupt the tree: the running leaf cancels its goal (the robot stops)."""
        try:
            self.root.stop(Status.INVALID)
        except Exception as e:  # noqa: BLE001 - best effort: the latch below still holds
            logger.warning("robot %s: stopping the tree failed: %s", self.name, e)

    def close(self) -> None:
        """Cancel the robot's outstanding goal, drop the liveliness token and the subscriptions."""
        self._stop_tree()
        for handle in (self._token, self._sub, self._grant_sub, self._control_sub):
            if handle is not None:
                try:
                    handle.undeclare()
                except Exception as e:  # noqa: BLE001 - keep releasing the rest
                    logger.debug("robot %s: undeclare failed: %s", self.name, e)
        self._token = self._sub = self._grant_sub = self._control_sub = None


def _check_rate(name: str, value: float | None, unit: str) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number of {unit} or None, got {value}")


def _pose(p: Pose2D | Iterable[float]) -> Pose2D:
    return p if isinstance(p, Pose2D) else Pose2D(*(float(v) for v in p))
