"""The Zenoh status bus: status records, orders, traffic grants and liveliness.

Topics (JSON, UTF-8; see ``docs/status_bus.md`` for schemas and examples):

* ``fleet/<robot>/status``: a :class:`~fleet.messages.StatusRecord`, robot -> everyone;
* ``fleet/batch/<source>/status``: many robots' records from one process
  (:mod:`fleet.messages.status_batch`, MessagePack), when the bus batches (``batch_source``);
  :meth:`StatusBus.subscribe_statuses` takes both forms, so receivers see the same records;
* ``fleet/<robot>/task``: a :class:`~fleet.messages.TaskMessage`, coordinator -> robot;
* ``fleet/<robot>/grant``: a :class:`~fleet.messages.Grant`, coordinator -> robot;
* ``fleet/<robot>/alive``: a liveliness token held by the robot's agent session;
* ``fleet/control/state``: the fleet's :class:`~fleet.messages.FleetControl` (pause, e-stop),
  coordinator -> everyone.

Threading: Zenoh runs callbacks on its own threads (one per callback subscriber).
:class:`StatusBus` callbacks parse and validate the payload, update the latest-record table,
append a :class:`BusEvent` to a bounded queue (:meth:`StatusBus.drain_events`) and call the
user callbacks, which must be cheap and thread-safe. A malformed payload is counted
(:attr:`StatusBus.malformed`, :attr:`StatusBus.last_malformed`) and dropped; an exception
raised by a user callback is counted (:attr:`StatusBus.callback_errors`); nothing ever raises
out of a Zenoh callback."""

from __future__ import annotations

import os
import re
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Literal, TypeVar

import msgspec
import zenoh

from fleet.bus.keys import (
    ALIVE_KEYS,
    CONTROL_KEY,
    GRANT,
    STATUS_BATCH_KEYS,
    STATUS_KEYS,
    TASK,
    alive_key,
    grant_key,
    robot_of_key,
    status_batch_key,
    status_key,
    task_key,
)
from fleet.bus.session import Declaration, close_session, undeclare_all
from fleet.messages import FleetControl, Grant, StatusRecord, TaskMessage
from fleet.messages.status_batch import MAX_BATCH_RECORDS, check_status, decode_batch, encode_batch

#: At most this many events wait in :meth:`StatusBus.drain_events` (oldest dropped first).
MAX_EVENTS = 10000

#: A queued status record waits at most this long (wall s) for its batch to fill (agents ticking
#: in turn filled one over tens of ms: most of the latency, docs/performance.md "Target 4").
MAX_BATCH_DELAY_S = 0.005

T = TypeVar("T")

#: What one robot's subscription delivers (:meth:`StatusBus.subscribe_tasks`, ``_grants``).
Order = TypeVar("Order", TaskMessage, Grant)

EventKind = Literal["status", "task", "grant", "join", "leave"]


@dataclass(frozen=True)
class BusEvent:
    """What :meth:`StatusBus.drain_events` returns: ``kind`` ``status``, ``task``, ``grant``
    (``payload`` the record, order or grant), ``join`` or ``leave`` (``payload`` ``None``)."""

    kind: EventKind
    robot: str
    payload: StatusRecord | TaskMessage | Grant | None = None


class BusHandle:
    """A declaration on the bus (subscription, token); :meth:`undeclare` is idempotent."""

    def __init__(self, undeclare: Callable[[], None]) -> None:
        self._undeclare: Callable[[], None] | None = undeclare
        self._lock = threading.Lock()

    def undeclare(self) -> None:
        with self._lock:
            fn, self._undeclare = self._undeclare, None
        if fn is not None:
            try:
                fn()
            except Exception:  # noqa: BLE001 - the session may already be closed
                pass

    @property
    def active(self) -> bool:
        return self._undeclare is not None


StatusCallback = Callable[[StatusRecord], None]
TaskCallback = Callable[[TaskMessage], None]
GrantCallback = Callable[[Grant], None]
RobotCallback = Callable[[str], None]


def _is_delete(sample: zenoh.Sample) -> bool:
    return sample.kind == zenoh.SampleKind.DELETE


class StatusBus:
    """Status records, task messages, grants and liveliness on one Zenoh ``session``.

    The session belongs to the caller: :meth:`close` undeclares what the bus declared;
    :meth:`shutdown` does that and closes the session. ``robot`` is this process's robot (for
    logs only). See the module docstring for threading and malformed-message handling.

    Batching: with ``batch_source`` (this process's name, one key chunk, e.g. ``loadtest-w2``)
    :meth:`publish_status` queues the record; batches of up to :data:`MAX_BATCH_RECORDS` go out
    on ``fleet/batch/<batch_source>/status`` when full, when the oldest record has waited
    ``batch_delay_s`` (wall s, checked as a record is queued; ``None``: never) and at
    :meth:`flush_statuses` (the runner's, after each round of agent ticks). Without it every
    record is its own put on ``fleet/<robot>/status``.

    Counters (read at any time): ``received`` valid status, task and grant messages,
    ``malformed`` dropped payloads (``last_malformed`` says why: ``<key>: <field>: <reason>``),
    ``callback_errors`` exceptions raised by user callbacks, ``events_dropped`` events pushed
    out of the bounded event queue, ``early`` valid orders that arrived before their agent
    subscribed (:meth:`guard_orders`)."""

    def __init__(
        self,
        session: zenoh.Session,
        *,
        robot: str | None = None,
        max_events: int = MAX_EVENTS,
        batch_source: str | None = None,
        batch_delay_s: float | None = MAX_BATCH_DELAY_S,
    ) -> None:
        self.session = session
        self.robot = robot
        #: Status records are queued and sent as batches under this name (see above).
        self.batch_source = batch_source
        self._batch_key = None if batch_source is None else status_batch_key(batch_source)
        self._queued: list[StatusRecord] = []
        self._batch_delay_s = float("inf") if batch_delay_s is None else float(batch_delay_s)
        self._queued_since = 0.0  # time.monotonic() of the oldest queued record
        #: Status puts sent (one per record, or one per batch when batching).
        self.status_puts = 0
        self.received = 0
        self.malformed = 0
        self.last_malformed: str | None = None
        self.callback_errors = 0
        self.last_callback_error: str | None = None
        self.events_dropped = 0
        self.early = 0
        self._lock = threading.Lock()
        self._latest: dict[str, StatusRecord] = {}
        self._alive: set[str] = set()
        self._events: deque[BusEvent] = deque()
        self._max_events = max_events
        self._status_cbs: list[StatusCallback] = []
        self._join_cbs: list[RobotCallback] = []
        self._leave_cbs: list[RobotCallback] = []
        self._control_cbs: list[Callable[[FleetControl], None]] = []
        self._control_sub: zenoh.Subscriber[None] | None = None
        self._status_sub: zenoh.Subscriber[None] | None = None
        self._batch_sub: zenoh.Subscriber[None] | None = None
        self._alive_sub: zenoh.Subscriber[None] | None = None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._status_pubs: dict[str, zenoh.Publisher] = {}  # by robot name: the hot path
        self._handles: list[BusHandle] = []
        self._closed = False

    # -- publishing ------------------------------------------------------------------

    def _publisher(self, key: str, block: bool, encoding: zenoh.Encoding | None = None) -> zenoh.Publisher:
        pub = self._publishers.get(key)
        if pub is None:
            cc = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
            enc = encoding or zenoh.Encoding.APPLICATION_JSON
            pub = self._publishers[key] = self.session.declare_publisher(
                key, encoding=enc, congestion_control=cc
            )
        return pub

    def publish_status(self, rec: StatusRecord) -> None:
        """Publish ``rec`` on ``fleet/<rec.robot>/status`` (congestion: drop, the next record
        replaces a lost one), or queue it when batching (see the class). ValueError for a robot
        name that cannot be a key chunk or a non-finite number; the record's types are not
        checked again here (receivers do)."""
        if self._batch_key is not None:
            queued = self._queued
            now = time.monotonic()
            if not queued:
                self._queued_since = now
            queued.append(check_status(rec))
            # a full batch waits for nothing, an old one no longer
            if len(queued) >= MAX_BATCH_RECORDS or now - self._queued_since >= self._batch_delay_s:
                self.flush_statuses()
            return
        pub = self._status_pubs.get(rec.robot)
        if pub is None:
            pub = self._status_pubs[rec.robot] = self._publisher(status_key(rec.robot), False)
        pub.put(rec.to_json())
        self.status_puts += 1

    def flush_statuses(self) -> int:
        """Send the queued records as batches (congestion: block); returns how many records
        went out. Does nothing without ``batch_source``. (A batch is also sent as soon as
        :data:`MAX_BATCH_RECORDS` records are queued, so none waits for more than that.)"""
        queued, self._queued = self._queued, []
        if self._batch_key is None or not queued or self.batch_source is None:
            return 0
        # congestion: block. A lost batch would lose hundreds of robots' records at once, and
        # a sender that outruns the router should slow down rather than lose them
        pub = self._publisher(self._batch_key, True, zenoh.Encoding("application/msgpack"))
        for i in range(0, len(queued), MAX_BATCH_RECORDS):
            pub.put(encode_batch(self.batch_source, queued[i : i + MAX_BATCH_RECORDS]))
            self.status_puts += 1
        return len(queued)

    def publish_task(self, robot: str | TaskMessage, msg: TaskMessage | None = None) -> None:
        """Publish an order on ``fleet/<robot>/task``: ``publish_task(robot, msg)`` or
        ``publish_task(msg)`` with ``msg.robot`` set. Sent reliably (congestion: block).
        ValueError naming the field for an inconsistent order."""
        if isinstance(robot, TaskMessage):
            msg, name = robot, robot.robot
        else:
            name = robot
        if msg is None or name is None:
            raise ValueError("publish_task needs a robot name and a TaskMessage")
        if msg.robot is None:
            msg = msgspec.structs.replace(msg, robot=name)
        elif msg.robot != name:
            raise ValueError(f"task for {msg.robot!r} published to robot {name!r}")
        self._publisher(task_key(name), True).put(msg.to_json())

    def declare_task_publishers(self, robots: Iterable[str]) -> None:
        """Declare each robot's order publisher now (set-up), not at its first order."""
        for name in robots:
            self._publisher(task_key(name), True)

    def publish_grant(self, grant: Grant) -> None:
        """Publish a traffic :class:`Grant` on ``fleet/<grant.robot>/grant`` (congestion:
        block, like orders)."""
        self._publisher(grant_key(grant.robot), True).put(grant.to_json())

    def publish_control(self, ctl: FleetControl) -> None:
        """Publish the fleet's control state on ``fleet/control/state`` (congestion: block)."""
        self._publisher(CONTROL_KEY, True).put(ctl.to_json())

    # -- receiving -------------------------------------------------------------------

    def _bad(self, key: str, reason: str) -> None:
        with self._lock:
            self.malformed += 1
            self.last_malformed = f"{key}: {reason}"

    def _push(self, ev: BusEvent) -> None:
        # caller holds self._lock
        if self._max_events <= 0:
            return
        if len(self._events) >= self._max_events:
            self._events.popleft()
            self.events_dropped += 1
        self._events.append(ev)

    def _call(self, cbs: list[Callable[[T], None]], arg: T) -> None:
        for cb in cbs:
            try:
                cb(arg)
            except Exception as e:  # noqa: BLE001 - never raise into Zenoh's thread
                self._callback_failed(cb, e)

    def _callback_failed(self, cb: object, e: Exception) -> None:
        with self._lock:
            self.callback_errors += 1
            self.last_callback_error = f"{getattr(cb, '__qualname__', cb)}: {e!r}"

    def _on_status_sample(self, sample: zenoh.Sample) -> None:
        key = "?"
        try:
            key = str(sample.key_expr)
            if _is_delete(sample):
                return
            robot = robot_of_key(key)
            rec = StatusRecord.from_json(sample.payload.to_bytes())
            if rec.robot != robot:
                raise ValueError(f"status.robot: {rec.robot!r} does not match the key's robot {robot!r}")
        except Exception as e:  # noqa: BLE001 - count and drop
            self._bad(key, str(e))
            return
        self._take(key, [rec])

    def _on_batch_sample(self, sample: zenoh.Sample) -> None:
        key = "?"
        try:
            key = str(sample.key_expr)
            if _is_delete(sample):
                return
            batch = decode_batch(sample.payload.to_bytes())
        except Exception as e:  # noqa: BLE001 - count and drop
            self._bad(key, str(e))
            return
        for err in batch.errors:  # the bad records only; the rest of the batch counts
            self._bad(key, err)
        self._take(key, batch.records)

    def _take(self, key: str, recs: list[StatusRecord]) -> None:
        """Valid records: the latest table, the event queue, then the callbacks."""
        try:
            with self._lock:
                self.received += len(recs)
                latest = self._latest
                for rec in recs:
                    latest[rec.robot] = rec
                if self._max_events > 0:  # no event built for a bus that keeps none
                    for rec in recs:
                        self._push(BusEvent("status", rec.robot, rec))
                cbs = list(self._status_cbs)
            for cb in cbs:  # each callback gets the batch's records in order
                for rec in recs:
                    try:
                        cb(rec)
                    except Exception as e:  # noqa: BLE001 - never raise into Zenoh's thread
                        self._callback_failed(cb, e)
        except Exception as e:  # noqa: BLE001
            self._bad(key, f"internal: {e!r}")

    def subscribe_statuses(self, callback: StatusCallback | None = None) -> BusHandle:
        """Subscribe to ``fleet/*/status`` and ``fleet/batch/*/status`` (once per bus), keep the
        latest record per robot (:meth:`latest`) and call ``callback(rec)``, if given, on Zenoh's
        thread for every valid record, in order per robot; the handle removes the callback."""
        with self._lock:
            if callback is not None:
                self._status_cbs.append(callback)
            need = self._status_sub is None
        if need:
            self._status_sub = self.session.declare_subscriber(STATUS_KEYS, self._on_status_sample)
            self._batch_sub = self.session.declare_subscriber(STATUS_BATCH_KEYS, self._on_batch_sample)

        def remove() -> None:
            with self._lock:
                if callback is not None and callback in self._status_cbs:
                    self._status_cbs.remove(callback)

        h = BusHandle(remove)
        self._handles.append(h)
        return h

    def latest(self) -> dict[str, StatusRecord]:
        """A copy of the latest valid record of every robot seen (by robot name)."""
        with self._lock:
            return dict(self._latest)

    def guard_orders(self, robots: list[str], wildcard: bool = False) -> BusHandle:
        """Count what arrives on the robots' task and grant keys before their agents subscribe
        (while the process starts): a malformed payload is counted in ``malformed`` like any
        other, a valid one in ``early`` (it is dropped: the coordinator sends again). The handle
        ends the guard (undeclare it once the agents are up).

        ``wildcard``: two subscribers on ``fleet/*/task`` and ``fleet/*/grant`` that count only
        ``robots``' keys, instead of two per robot: the same counts, and a fleet of thousands
        starts in seconds (Zenoh's declarations cost more the more there are: 20,000 took
        minutes). Only on an open bus: a secured identity may subscribe to its own keys only."""
        subs: list[Declaration] = []
        mine = set(robots)

        def guard(key: str, parse: Callable[[bytes], object]) -> Callable[[zenoh.Sample], None]:
            def on_sample(sample: zenoh.Sample) -> None:
                if wildcard and str(sample.key_expr).split("/")[1] not in mine:
                    return
                try:
                    if _is_delete(sample):
                        return
                    parse(sample.payload.to_bytes())
                except Exception as e:  # noqa: BLE001 - count and drop
                    self._bad(str(sample.key_expr) if wildcard else key, str(e))
                    return
                with self._lock:
                    self.early += 1

            return on_sample

        if wildcard:
            for template, parse in ((TASK, TaskMessage.from_json), (GRANT, Grant.from_json)):
                keys = template.format(robot="*")
                subs.append(self.session.declare_subscriber(keys, guard(keys, parse)))
        for r in robots if not wildcard else ():
            subs.append(
                self.session.declare_subscriber(task_key(r), guard(task_key(r), TaskMessage.from_json))
            )
            subs.append(self.session.declare_subscriber(grant_key(r), guard(grant_key(r), Grant.from_json)))
        h = BusHandle(lambda: undeclare_all(subs))
        self._handles.append(h)
        return h

    def subscribe_tasks(self, robot: str, callback: TaskCallback) -> BusHandle:
        """Call ``callback(msg)`` (on Zenoh's thread) for every valid order on
        ``fleet/<robot>/task``; ``msg.robot`` is filled from the key if the order left it out,
        and an order naming another robot is malformed. The handle's ``undeclare()`` ends the
        subscription."""

        def parse(data: bytes) -> TaskMessage:
            msg = TaskMessage.from_json(data)
            if msg.robot is None:
                return msgspec.structs.replace(msg, robot=robot)
            if msg.robot != robot:
                raise ValueError(f"task.robot: {msg.robot!r} does not match the key's robot {robot!r}")
            return msg

        return self._subscribe_robot(task_key(robot), robot, "task", parse, callback)

    def subscribe_grants(self, robot: str, callback: GrantCallback) -> BusHandle:
        """Call ``callback(grant)`` (on Zenoh's thread) for every valid traffic grant on
        ``fleet/<robot>/grant``; a malformed one (or one naming another robot) is counted in
        ``malformed`` and dropped."""

        def parse(data: bytes) -> Grant:
            g = Grant.from_json(data)
            if g.robot != robot:
                raise ValueError(f"grant.robot: {g.robot!r} does not match the key's robot {robot!r}")
            return g

        return self._subscribe_robot(grant_key(robot), robot, "grant", parse, callback)

    def _subscribe_robot(
        self,
        key: str,
        robot: str,
        kind: Literal["task", "grant"],
        parse: Callable[[bytes], Order],
        callback: Callable[[Order], None],
    ) -> BusHandle:
        """Subscribe to one robot's ``key``: ``parse`` each payload (an exception = malformed:
        counted and dropped), record a :class:`BusEvent` of ``kind`` and call ``callback``."""

        def on_sample(sample: zenoh.Sample) -> None:
            k = key
            try:
                k = str(sample.key_expr)
                if _is_delete(sample):
                    return
                value = parse(sample.payload.to_bytes())
            except Exception as e:  # noqa: BLE001 - count and drop
                self._bad(k, str(e))
                return
            with self._lock:
                self.received += 1
                self._push(BusEvent(kind, robot, value))
            self._call([callback], value)

        sub: Declaration = self.session.declare_subscriber(key, on_sample)
        h = BusHandle(sub.undeclare)
        self._handles.append(h)
        return h

    def _on_control_sample(self, sample: zenoh.Sample) -> None:
        try:
            if _is_delete(sample):
                return
            ctl = FleetControl.from_json(sample.payload.to_bytes())
        except Exception as e:  # noqa: BLE001 - count and drop
            self._bad(CONTROL_KEY, str(e))
            return
        with self._lock:
            self.received += 1
            cbs = list(self._control_cbs)
        self._call(cbs, ctl)

    def subscribe_control(self, callback: Callable[[FleetControl], None]) -> BusHandle:
        """Call ``callback(ctl)`` (on Zenoh's thread) for every valid control state on
        ``fleet/control/state``; one subscription per bus, however many callbacks."""
        with self._lock:
            self._control_cbs.append(callback)
            need = self._control_sub is None
        if need:
            self._control_sub = self.session.declare_subscriber(CONTROL_KEY, self._on_control_sample)

        def remove() -> None:
            with self._lock:
                if callback in self._control_cbs:
                    self._control_cbs.remove(callback)

        h = BusHandle(remove)
        self._handles.append(h)
        return h

    # -- liveliness ------------------------------------------------------------------

    def declare_alive(self, robot: str) -> BusHandle:
        """Hold the liveliness token ``fleet/<robot>/alive`` until the handle is undeclared
        (or the bus / session closes, or the process dies)."""
        token: Declaration = self.session.liveliness().declare_token(alive_key(robot))
        h = BusHandle(token.undeclare)
        self._handles.append(h)
        return h

    def _on_alive_sample(self, sample: zenoh.Sample) -> None:
        key = "?"
        try:
            key = str(sample.key_expr)
            robot = robot_of_key(key)
            joined = sample.kind == zenoh.SampleKind.PUT
            with self._lock:
                if joined:
                    if robot in self._alive:
                        return
                    self._alive.add(robot)
                else:
                    if robot not in self._alive:
                        return
                    self._alive.discard(robot)
                self._push(BusEvent("join" if joined else "leave", robot))
                cbs = list(self._join_cbs if joined else self._leave_cbs)
            self._call(cbs, robot)
        except Exception as e:  # noqa: BLE001
            self._bad(key, f"liveliness: {e}")

    def watch_alive(
        self, on_join: RobotCallback | None = None, on_leave: RobotCallback | None = None
    ) -> BusHandle:
        """Watch the tokens ``fleet/*/alive`` (history included: tokens already held are
        reported as joins). Callbacks get the robot name on Zenoh's thread; a watcher added
        later is told at once (on the caller's thread) about robots already alive."""
        with self._lock:
            if on_join is not None:
                self._join_cbs.append(on_join)
            if on_leave is not None:
                self._leave_cbs.append(on_leave)
            need = self._alive_sub is None
            already = sorted(self._alive)
        if need:
            self._alive_sub = self.session.liveliness().declare_subscriber(
                ALIVE_KEYS, self._on_alive_sample, history=True
            )
        elif on_join is not None:
            for r in already:
                self._call([on_join], r)

        def remove() -> None:
            with self._lock:
                if on_join is not None and on_join in self._join_cbs:
                    self._join_cbs.remove(on_join)
                if on_leave is not None and on_leave in self._leave_cbs:
                    self._leave_cbs.remove(on_leave)

        h = BusHandle(remove)
        self._handles.append(h)
        return h

    def alive(self) -> set[str]:
        """Robots whose liveliness token is held now (needs :meth:`watch_alive`)."""
        with self._lock:
            return set(self._alive)

    # -- events and shutdown ---------------------------------------------------------

    def drain_events(self) -> list[BusEvent]:
        """Take every queued event (oldest first); thread-safe."""
        with self._lock:
            out = list(self._events)
            self._events.clear()
        return out

    def close(self) -> None:
        """Undeclare every subscription, token and publisher of this bus (idempotent). The
        session stays open."""
        if self._closed:
            return
        self._closed = True
        for h in self._handles:
            h.undeclare()
        self._queued.clear()
        subs = [self._status_sub, self._batch_sub, self._alive_sub, self._control_sub]
        undeclare_all([*subs, *self._publishers.values()])
        self._status_sub = self._batch_sub = self._alive_sub = self._control_sub = None
        self._publishers.clear()
        self._status_pubs.clear()

    def shutdown(self) -> None:
        """:meth:`close`, then close the session."""
        try:
            self.close()
        finally:
            close_session(self.session)

    def __enter__(self) -> StatusBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def process_batch_source() -> str:
    """This process's name on the bus for status batches: ``<host>-<pid>`` (one key chunk)."""
    host = re.sub(r"[^A-Za-z0-9_.-]", "_", socket.gethostname()) or "host"
    return f"{host}-{os.getpid()}"
