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
order clears them all and ``task_id``. An order whose id was already applied (a duplicate, or a late copy
of an order that has been superseded) is ignored, so a message can never be applied twice.
Orders are queued by the bus callback thread and applied on the ticking thread only.
With traffic management the agent also takes the robot's traffic grants
(``fleet/<robot>/grant``, newest ``seq`` wins) into the blackboard key ``grant``.

Safety and health: each tick first reads the robot's state and asks the robot's
:class:`fleet.diagnostics.SafetyWatchdog`; while it trips (localization lost or stale, the
navigation server down) the tree is halted at once (its running goal is canceled, so the robot
stops within this one control period), the robot reports ``mode = "safety_stop"`` and the
coordinator takes its task back; when it clears the tree runs again. Every status record
carries the robot's diagnostics (``health``, ``diag``: :func:`fleet.diagnostics.robot_diagnostics`).

Status rate: with ``status_hz`` (the config's ``bus.status_hz``) the agent publishes its status
on the bus at most that often (simulated time, from the records' ``t``): a record is published
when at least ``1 / status_hz`` s passed since the last one published; ``None`` publishes every
tick. With ``status_max_period_s`` (the config's ``bus.status_max_period_s``) it publishes *on
change* instead: a record goes out (still at most at ``status_hz``) only if it differs from the
last one published (:func:`status_changed`: anything but ``t``, ``seq`` and small moves of the
pose, battery, progress and odometry), and at least every ``status_max_period_s`` s whatever
changed. ``on_status`` (an in-process coordinator) still gets every tick's record.

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
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from fleet.diagnostics import (
    Diagnostic,
    HealthParams,
    Level,
    SafetyWatchdog,
    problems,
    robot_diagnostics,
    worst,
)
from fleet.messages import FleetControl, Grant, StatusRecord, TaskMessage
from fleet.types import Mode, Pose2D, RobotState, TaskKind, TreeKind

if TYPE_CHECKING:
    from py_trees.behaviour import Behaviour

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


@runtime_checkable
class ControlBus(Protocol):
    """A bus that also carries the fleet's control state (:class:`StatusBus` does); an
    :class:`AgentBus` without it leaves pause and e-stop to in-process delivery."""

    def subscribe_control(self, callback: Callable[[FleetControl], None]) -> Declared: ...


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
        status_max_period_s: publish on change, and at least this often (simulated s, > 0);
            ``None``: publish at every ``status_hz`` period whether or not anything changed.

    ``published`` counts the records published on the bus.
    """

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
        status_max_period_s: float | None = None,
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
        _check_rate("status_hz", status_hz, "Hz")
        _check_rate("status_max_period_s", status_max_period_s, "s")
        #: Least simulated time between two records published on the bus (None: every tick).
        self.status_period_s = None if status_hz is None else 1.0 / status_hz
        #: Publish on change, and at least this often (None: every status period).
        self.status_max_period_s = status_max_period_s
        self._last_published: float | None = None
        self._last_sent: StatusRecord | None = None
        self.published = 0
        # py_trees' blackboard is process-global: start from the defaults, not from what an
        # earlier agent of the same namespace in this process left behind
        clear_robot_blackboard(self.namespace)
        self.bb = robot_blackboard(self.namespace, name=f"agent{self.namespace}")
        self.traffic = traffic
        battery = battery_model or BatteryModel()
        self.tree_file = tree_file
        self.root = _build_root(tree_kind, tree_file, self.namespace, backend, clock, battery, traffic)
        self.health = health or HealthParams(battery_low=battery.low)
        #: The fleet-side safety stop (see the module docstring); ``watchdog.trips`` counts stops.
        self.watchdog = SafetyWatchdog(self.health)
        #: The config's chargers: until the coordinator names one, the battery guard uses
        #: the one nearest the robot (so a robot never given work still charges).
        self.chargers = tuple(chargers)
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
        self._control: FleetControl | None = None
        #: The tree is stopped: the fleet is paused or its e-stop latched (see the module docstring).
        self.halted: str | None = None
        self._token: Declared | None = None
        self._sub: Declared | None = None
        self._grant_sub: Declared | None = None
        self._control_sub: Declared | None = None
        if bus is not None:
            self._sub = bus.subscribe_tasks(self.name, self.deliver)
            if traffic:
                self._grant_sub = bus.subscribe_grants(self.name, self.deliver_grant)
            if isinstance(bus, ControlBus):
                self._control_sub = bus.subscribe_control(self.set_control)
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

    def pending(self) -> bool:
        """Orders, a grant or a control change wait to be applied (thread-safe)."""
        with self._lock:
            ctl = self._control
            halted = ctl is not None and (ctl.estop or ctl.paused)
            return (
                bool(self._inbox)
                or (self._grant is not None and self._grant.seq > self._grant_seq)
                or (halted != (self.halted is not None))
            )

    def set_control(self, ctl: FleetControl) -> None:
        """Keep the fleet's control state for the next :meth:`tick` (newest ``seq`` wins);
        thread-safe."""
        with self._lock:
            if self._control is None or ctl.seq > self._control.seq:
                self._control = ctl

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

    # -- ticking -----------------------------------------------------------------------

    def _default_charger(self, pose: Pose2D | None) -> None:
        """Set the blackboard ``charger`` to the config charger nearest ``pose`` (the robot's)."""
        if pose is not None:
            self.bb.charger = min(
                self.chargers, key=lambda c: (abs(c.x - pose.x) + abs(c.y - pose.y), c.x, c.y)
            )

    def tick(self) -> StatusRecord:
        """Apply queued orders, check the safety watchdog, tick the tree once (unless the
        watchdog holds the robot), publish (see ``status_hz``) and return the status record."""
        from py_trees.common import Status

        self._apply_orders()
        st = self.backend.robot_state()
        if self.bb.charger is None and self.chargers:
            self._default_charger(st.pose)
        was = self.watchdog.reason
        reason = self.watchdog.check(st)
        with self._lock:
            ctl = self._control
        halt = (
            None if ctl is None or not (ctl.estop or ctl.paused) else Mode.ESTOP if ctl.estop else Mode.PAUSED
        )
        if halt is not None:  # the fleet's pause or e-stop comes before everything
            if self.halted is None:
                self._stop_tree()
            self.halted = halt
            self.bb.mode = halt
        elif reason:
            self.halted = None
            if not was:
                logger.warning("robot %s: safety stop: %s", self.name, reason)
                self.root.stop(Status.INVALID)  # cancels the running goal: the robot stops
            self.bb.mode = Mode.SAFETY_STOP
            self.bb.active_leaf = "SafetyWatchdog"
        else:
            if was:
                logger.warning("robot %s: safety stop cleared", self.name)
            if was or self.halted is not None:
                self.halted = None
                self.bb.mode = Mode.IDLE
            self.root.tick_once()
        self.ticks += 1
        mode = str(self.bb.mode)
        if mode == Mode.CHARGING and self._last_mode != Mode.CHARGING:
            self.charges += 1
        self._last_mode = mode
        self.mode_ticks[mode] = self.mode_ticks.get(mode, 0) + 1
        rec = self.status(st)
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
        longest, sent = self.status_max_period_s, self._last_sent
        if (
            longest is not None
            and last is not None
            and sent is not None
            and rec.t < last + longest - 1e-9
            and not status_changed(sent, rec)
        ):
            return
        self._last_published = rec.t
        self._last_sent = rec
        self.published += 1
        self.bus.publish_status(rec)

    def status(self, state: RobotState | None = None) -> StatusRecord:
        """The current status record of this robot (each call takes the next ``seq``), from
        ``state`` (default: the backend's now)."""
        self.seq += 1
        st = state if state is not None else self.backend.robot_state()
        health, diag = self._diagnostics(st)
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
            health=health,
            diag=diag,
            result_id=bb.result_id,
            result=str(bb.result or ""),
            steps_done=int(bb.step_index)
            if bb.steps_task_id is not None and bb.steps_task_id == task_id
            else 0,
        )

    def _diagnostics(self, st: RobotState) -> tuple[int, tuple[tuple[str, int, str], ...]]:
        """``(worst level, the checks that are not OK)`` of ``st``; a healthy robot (the common
        case) costs no check objects."""
        h = self.health
        if (
            st.localized
            and st.navigation_ready
            and st.battery_known
            and not st.stuck
            and not st.safety_stop
            and st.pose is not None
            and st.battery >= h.battery_low
            and st.pose_age_s <= 0.5 * h.localization_timeout_s
        ):
            return 0, ()
        items = robot_diagnostics(st, h)
        if self.watchdog.reason and not st.safety_stop:
            items = (*(d for d in items if d.name != "motion"), _stopped(self.watchdog.reason))
        return int(worst(items)), problems(items)

    def _stop_tree(self) -> None:
        """Interrupt the tree: the running leaf cancels its goal (the robot stops)."""
        from py_trees.common import Status

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


#: Moves smaller than these do not count as a change of the status (m, rad, fraction, m).
POSE_EPS_M = 0.05
THETA_EPS_RAD = 0.05
BATTERY_EPS = 0.005
PROGRESS_EPS = 0.01


def status_changed(old: StatusRecord, new: StatusRecord) -> bool:
    """Whether ``new`` says something ``old`` did not: any field but ``t`` and ``seq`` differs,
    except that the pose must move by :data:`POSE_EPS_M` / :data:`THETA_EPS_RAD`, the battery by
    :data:`BATTERY_EPS`, the lap progress by :data:`PROGRESS_EPS` and the odometer by
    :data:`POSE_EPS_M` to count."""
    p, q = old.pose, new.pose
    if (p is None) != (q is None):
        return True
    if p is not None and q is not None:
        if abs(p[0] - q[0]) > POSE_EPS_M or abs(p[1] - q[1]) > POSE_EPS_M:
            return True
        if abs(math.remainder(p[2] - q[2], math.tau)) > THETA_EPS_RAD:
            return True
    return (
        abs(old.battery - new.battery) > BATTERY_EPS
        or abs(old.progress - new.progress) > PROGRESS_EPS
        or abs(old.distance_m - new.distance_m) > POSE_EPS_M
        or old.mode != new.mode
        or old.task_id != new.task_id
        or old.bt != new.bt
        or old.leaf != new.leaf
        or old.charging != new.charging
        or old.stuck != new.stuck
        or old.laps != new.laps
        or old.collisions != new.collisions
        or old.picks_done != new.picks_done
        or old.health != new.health
        or old.diag != new.diag
        or old.result_id != new.result_id
        or old.result != new.result
        or old.steps_done != new.steps_done
    )


def _build_root(
    tree_kind: str,
    tree_file: str | None,
    namespace: str,
    backend: NavigationBackend,
    clock: Clock,
    battery: BatteryModel,
    traffic: bool,
) -> Behaviour:
    """The robot's tree: the XML file's when one is given, else the built-in tree of ``tree_kind``."""
    if tree_file is not None:
        from nodes.xml_tree import load_tree

        return load_tree(tree_file, namespace, backend, clock, battery).root
    from nodes.task_tree import build_robot_tree

    return build_robot_tree(tree_kind, namespace, backend, clock, battery, traffic=traffic)


def _stopped(reason: str) -> Diagnostic:
    return Diagnostic("motion", Level.ERROR, f"safety stop: {reason}")


def _pose(p: Pose2D | Iterable[float]) -> Pose2D:
    if isinstance(p, Pose2D):
        return p
    return Pose2D(*(float(v) for v in p))
