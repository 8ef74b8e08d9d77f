"""The Zenoh status bus: sessions, status and task records, liveliness.

Topics (JSON, UTF-8; see ``docs/status_bus.md`` for schemas and examples):

* ``fleet/<robot>/status``: a :class:`StatusRecord`, robot -> everyone;
* ``fleet/<robot>/task``: a :class:`TaskMessage`, coordinator -> robot;
* ``fleet/<robot>/alive``: a liveliness token held by the robot's agent session.

Sessions: one process *listens* on the endpoint in ``router`` mode (``fleet run``, ``fleet
sim``); every other process connects in ``client`` mode (a ``peer`` that does not listen
receives nothing through a router). Multicast scouting and gossip are off; endpoints are
explicit (``tcp/127.0.0.1:7447``).

Threading: Zenoh runs callbacks on its own threads (one per callback subscriber). :class:`StatusBus` callbacks parse and
validate the payload, update the latest-record table, append a :class:`BusEvent` to a bounded
queue (:meth:`StatusBus.drain_events`) and call the user callbacks, which must be cheap and
thread-safe. A malformed payload is counted (:attr:`StatusBus.malformed`,
:attr:`StatusBus.last_malformed`) and dropped; an exception raised by a user callback is
counted (:attr:`StatusBus.callback_errors`); nothing ever raises out of a Zenoh callback.
"""

from __future__ import annotations

import json
import re
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import zenoh

from fleet.codec import (
    as_bool,
    as_dict,
    as_float,
    as_int,
    as_opt_str,
    as_pose,
    as_poses,
    as_str,
    pose_to_list,
    req,
)
from fleet.errors import BusError
from fleet.types import Pose2D

#: Version of the status and task records (field ``v``).
BUS_VERSION = 1
#: Payloads larger than this are dropped as malformed without being parsed.
MAX_PAYLOAD_BYTES = 256 * 1024
#: The default endpoint of a fleet (where ``fleet run`` / ``fleet sim`` listen).
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
#: Default Zenoh link lease (s): a frozen peer is declared gone after this long.
DEFAULT_LEASE_S = 1.0
#: Default time (s) a client waits for its router when opening a session.
DEFAULT_CONNECT_TIMEOUT_S = 2.0
#: At most this many events wait in :meth:`StatusBus.drain_events` (oldest dropped first).
MAX_EVENTS = 10000

STATUS_KEYS = "fleet/*/status"
ALIVE_KEYS = "fleet/*/alive"

Role = Literal["router", "client", "peer"]

_ROBOT_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
_ENDPOINT_RE = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream)/\S+$")
TASK_KINDS = ("patrol", "pick", "idle")


def check_robot_name(robot: str) -> str:
    """Return ``robot`` if it can be one key chunk (``robot3``); ValueError otherwise."""
    if not isinstance(robot, str) or not _ROBOT_RE.match(robot):
        raise ValueError(f"robot name {robot!r} cannot be a Zenoh key chunk (use letters, digits, _ . -)")
    return robot


def status_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/status"


def task_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/task"


def grant_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/grant"


def alive_key(robot: str) -> str:
    return f"fleet/{check_robot_name(robot)}/alive"


def robot_of_key(key: str) -> str:
    """``robot3`` for ``fleet/robot3/status`` (the second chunk); ValueError if none."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != "fleet" or not parts[1]:
        raise ValueError(f"key {key!r} is not fleet/<robot>/...")
    return parts[1]


# ----------------------------------------------------------------------------- sessions


def zenoh_config(
    endpoint: str,
    role: Role,
    *,
    listen: bool,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    lease_s: float | None = DEFAULT_LEASE_S,
) -> zenoh.Config:
    """A Zenoh config for ``role`` on ``endpoint`` (``tcp/127.0.0.1:7447``).

    ``listen=True`` listens on the endpoint and connects nowhere; ``listen=False`` connects to
    it (waiting up to ``connect_timeout_s``) and listens nowhere. Multicast scouting and gossip
    are off. ``lease_s`` sets ``transport/link/tx/lease`` (``None``: Zenoh's 10 s default).
    Raises :class:`BusError` for a malformed endpoint.
    """
    if not isinstance(endpoint, str) or not _ENDPOINT_RE.match(endpoint):
        raise BusError(f"bad Zenoh endpoint {endpoint!r}: expected e.g. tcp/127.0.0.1:7447")
    if role not in ("router", "client", "peer"):
        raise BusError(f"bad Zenoh role {role!r}: expected router, client or peer")
    if role == "client" and listen:
        raise BusError("a Zenoh client cannot listen; use role 'router' to listen on the endpoint")
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(role))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    if listen:
        c.insert_json5("listen/endpoints", json.dumps([endpoint]))
        c.insert_json5("connect/endpoints", "[]")
    else:
        c.insert_json5("listen/endpoints", "[]")
        c.insert_json5("connect/endpoints", json.dumps([endpoint]))
        c.insert_json5("connect/timeout_ms", str(max(1, int(connect_timeout_s * 1000))))
        c.insert_json5("connect/exit_on_failure", "true")
    if lease_s is not None:
        c.insert_json5("transport/link/tx/lease", str(max(100, int(lease_s * 1000))))
    return c


def open_session(
    endpoint: str,
    role: Role,
    *,
    listen: bool | None = None,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    lease_s: float | None = DEFAULT_LEASE_S,
) -> zenoh.Session:
    """Open a Zenoh session; the caller must ``close()`` it (``with open_session(...) as s``).

    ``listen`` defaults to ``role == "router"``. Raises :class:`BusError` with a message saying
    what to do: the port is in use, or no router answers at the endpoint within
    ``connect_timeout_s``.
    """
    do_listen = role == "router" if listen is None else listen
    config = zenoh_config(
        endpoint, role, listen=do_listen, connect_timeout_s=connect_timeout_s, lease_s=lease_s
    )
    try:
        return zenoh.open(config)
    except Exception as e:  # zenoh.ZError
        text = str(e)
        if "in use" in text.lower():
            raise BusError(
                f"cannot listen on {endpoint}: the address is in use (is another `fleet run` or "
                f"`fleet sim` running there?) — pass --endpoint with a free port, or attach to it "
                f"with `fleet status --endpoint {endpoint}`"
            ) from None
        if not do_listen and ("timeout" in text.lower() or "unable to connect" in text.lower()):
            raise BusError(
                f"no Zenoh router at {endpoint} — start `fleet run` (or `fleet sim`) first or pass --endpoint"
            ) from None
        raise BusError(f"cannot open a Zenoh {role} session on {endpoint}: {text}") from None


# ----------------------------------------------------------------------------- records


def _decode(data: bytes | bytearray | memoryview | str, what: str) -> dict[str, Any]:
    if isinstance(data, str):
        data = data.encode("utf-8")
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ValueError(f"payload: {len(data)} bytes is larger than {MAX_PAYLOAD_BYTES}")
    try:
        text = bytes(data).decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"payload: not UTF-8 ({e.reason} at byte {e.start})") from None
    try:
        obj = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise ValueError(f"payload: not JSON ({str(e)[:80]})") from None
    d = dict(as_dict(obj, what))
    v = req(d, "v", what)
    if isinstance(v, bool) or v != BUS_VERSION:
        raise ValueError(f"{what}.v: unsupported version {v!r} (expected {BUS_VERSION})")
    return d


def _dumps(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":"), allow_nan=False).encode("utf-8")


@dataclass(frozen=True)
class StatusRecord:
    """One robot's status (``fleet/<robot>/status``); see ``docs/architecture.md``.

    ``t`` is simulated seconds; ``pose`` ``(x, y, theta)`` in the ``map`` frame or ``None``;
    ``battery`` a fraction; ``bt`` the root status name (``RUNNING``...); ``leaf`` the active
    leaf; ``progress`` through the current lap in [0, 1]; ``seq`` increases per record;
    ``picks_done`` picks the robot completed since its agent started (optional on the wire,
    ``0`` when absent).
    """

    robot: str
    ns: str
    t: float
    pose: tuple[float, float, float] | None
    battery: float
    charging: bool
    stuck: bool
    bt: str
    leaf: str
    mode: str
    task_id: str | None
    laps: int
    progress: float
    distance_m: float
    collisions: int
    seq: int
    picks_done: int = 0
    v: int = BUS_VERSION

    def to_dict(self) -> dict[str, Any]:
        # a shallow copy of the fields (all plain values): dataclasses.asdict deep-copies
        # recursively and was half the cost of publishing a status
        d = dict(vars(self))
        d["pose"] = None if self.pose is None else [float(x) for x in self.pose]
        return d

    def to_json(self) -> bytes:
        """UTF-8 JSON; ValueError naming the field if the record itself is invalid."""
        d = self.to_dict()
        StatusRecord.from_dict(d)
        return _dumps(d)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> StatusRecord:
        """Parse and validate; ValueError naming the bad field (``status.battery: ...``)."""
        return cls.from_dict(_decode(data, "status"))

    @classmethod
    def from_dict(cls, d: Any) -> StatusRecord:
        p = "status"
        d = as_dict(d, p)
        v = req(d, "v", p)
        if isinstance(v, bool) or v != BUS_VERSION:
            raise ValueError(f"status.v: unsupported version {v!r} (expected {BUS_VERSION})")
        robot = check_robot_name_field(req(d, "robot", p), "status.robot")
        pose_raw = req(d, "pose", p)
        pose = None if pose_raw is None else as_pose(pose_raw, "status.pose").as_tuple()
        return cls(
            robot=robot,
            ns=as_str(req(d, "ns", p), "status.ns"),
            t=as_float(req(d, "t", p), "status.t"),
            pose=pose,
            battery=as_float(req(d, "battery", p), "status.battery"),
            charging=as_bool(req(d, "charging", p), "status.charging"),
            stuck=as_bool(req(d, "stuck", p), "status.stuck"),
            bt=as_str(req(d, "bt", p), "status.bt"),
            leaf=as_str(req(d, "leaf", p), "status.leaf"),
            mode=as_str(req(d, "mode", p), "status.mode"),
            task_id=as_opt_str(req(d, "task_id", p), "status.task_id"),
            laps=as_int(req(d, "laps", p), "status.laps", minimum=0),
            progress=as_float(req(d, "progress", p), "status.progress"),
            distance_m=as_float(req(d, "distance_m", p), "status.distance_m"),
            collisions=as_int(req(d, "collisions", p), "status.collisions", minimum=0),
            seq=as_int(req(d, "seq", p), "status.seq", minimum=0),
            picks_done=as_int(d.get("picks_done", 0), "status.picks_done", minimum=0),
            v=BUS_VERSION,
        )


def check_robot_name_field(value: Any, path: str) -> str:
    s = as_str(value, path, max_len=128)
    if not _ROBOT_RE.match(s):
        raise ValueError(f"{path}: {s!r} is not a valid robot name")
    return s


@dataclass(frozen=True)
class PickOrder:
    """Pick details of a ``pick`` task: drive to ``shelf``, stand ``dwell_s`` s, drive to ``drop``.

    Any object with ``name``, ``shelf``, ``drop`` and ``dwell_s`` (e.g.
    :class:`fleet.config.PickTask`) can be sent; a received one is a :class:`PickOrder`.
    """

    name: str
    shelf: Pose2D
    drop: Pose2D
    dwell_s: float


@dataclass(frozen=True)
class TaskMessage:
    """An order for one robot (``fleet/<robot>/task``).

    ``kind`` is ``patrol`` (``route`` name and the lap's ``poses``), ``pick`` (``pick`` set) or
    ``idle`` (``task_id`` may be ``None``). ``charger`` is the charger pose to use when low.
    ``robot`` is the addressee (filled from the key on receipt if absent). Task ids are never
    reused.
    """

    task_id: str | None
    kind: str
    robot: str | None = None
    route: str | None = None
    poses: tuple[Pose2D, ...] = ()
    charger: Pose2D | None = None
    pick: Any = None
    v: int = BUS_VERSION

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"v": BUS_VERSION, "task_id": self.task_id, "kind": self.kind}
        if self.robot is not None:
            d["robot"] = self.robot
        if self.route is not None:
            d["route"] = self.route
        if self.poses:
            d["poses"] = [pose_to_list(_to_pose(p)) for p in self.poses]
        if self.charger is not None:
            d["charger"] = pose_to_list(_to_pose(self.charger))
        if self.pick is not None:
            pk = self.pick
            d["pick"] = {
                "name": str(getattr(pk, "name", "")),
                "shelf": pose_to_list(_to_pose(pk.shelf)),
                "drop": pose_to_list(_to_pose(pk.drop)),
                "dwell_s": float(pk.dwell_s),
            }
        return d

    def to_json(self) -> bytes:
        d = self.to_dict()
        TaskMessage.from_dict(d)
        return _dumps(d)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> TaskMessage:
        """Parse and validate; ValueError naming the bad field (``task.poses[2]: ...``)."""
        return cls.from_dict(_decode(data, "task"))

    @classmethod
    def from_dict(cls, d: Any) -> TaskMessage:
        p = "task"
        d = as_dict(d, p)
        v = req(d, "v", p)
        if isinstance(v, bool) or v != BUS_VERSION:
            raise ValueError(f"task.v: unsupported version {v!r} (expected {BUS_VERSION})")
        kind = as_str(req(d, "kind", p), "task.kind")
        if kind not in TASK_KINDS:
            raise ValueError(f"task.kind: {kind!r} is not one of {', '.join(TASK_KINDS)}")
        task_id = as_opt_str(req(d, "task_id", p), "task.task_id")
        if task_id is None and kind != "idle":
            raise ValueError(f"task.task_id: a {kind} task needs an id")
        robot = d.get("robot")
        pick = None
        if d.get("pick") is not None:
            pd = as_dict(d["pick"], "task.pick")
            pick = PickOrder(
                name=as_str(pd.get("name", ""), "task.pick.name"),
                shelf=as_pose(req(pd, "shelf", "task.pick"), "task.pick.shelf"),
                drop=as_pose(req(pd, "drop", "task.pick"), "task.pick.drop"),
                dwell_s=as_float(req(pd, "dwell_s", "task.pick"), "task.pick.dwell_s"),
            )
        if kind == "pick" and pick is None:
            raise ValueError("task.pick: missing (a pick task needs shelf, drop and dwell_s)")
        poses = as_poses(d.get("poses", []), "task.poses")
        if kind == "patrol" and not poses:
            raise ValueError("task.poses: a patrol task needs at least one pose")
        return cls(
            task_id=task_id,
            kind=kind,
            robot=None if robot is None else check_robot_name_field(robot, "task.robot"),
            route=as_opt_str(d.get("route"), "task.route"),
            poses=poses,
            charger=None if d.get("charger") is None else as_pose(d["charger"], "task.charger"),
            pick=pick,
        )


def _to_pose(p: Any) -> Pose2D:
    if isinstance(p, Pose2D):
        return p
    x, y, th = (float(v) for v in p)
    return Pose2D(x, y, th)


# ----------------------------------------------------------------------------- the bus


@dataclass(frozen=True)
class BusEvent:
    """What :meth:`StatusBus.drain_events` returns: ``kind`` is ``status`` (``payload`` a
    :class:`StatusRecord`), ``task`` (a :class:`TaskMessage`), ``grant`` (a
    :class:`~fleet.traffic.Grant`), ``join`` or ``leave``
    (``payload`` ``None``)."""

    kind: Literal["status", "task", "grant", "join", "leave"]
    robot: str
    payload: Any = None


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
RobotCallback = Callable[[str], None]


class StatusBus:
    """Status records, task messages and liveliness on one Zenoh ``session``.

    The session belongs to the caller: :meth:`close` undeclares what the bus declared;
    :meth:`shutdown` does that and closes the session. ``robot`` is this process's robot (for
    logs only). See the module docstring for threading and malformed-message handling.

    Counters (read at any time): ``received`` valid status and task messages, ``malformed``
    dropped payloads (``last_malformed`` says why), ``callback_errors`` exceptions raised by
    user callbacks, ``events_dropped`` events pushed out of the bounded event queue.
    """

    def __init__(
        self, session: zenoh.Session, *, robot: str | None = None, max_events: int = MAX_EVENTS
    ) -> None:
        self.session = session
        self.robot = robot
        self.received = 0
        self.malformed = 0
        self.last_malformed: str | None = None
        self.callback_errors = 0
        self.last_callback_error: str | None = None
        self.events_dropped = 0
        self._lock = threading.Lock()
        self._latest: dict[str, StatusRecord] = {}
        self._alive: set[str] = set()
        self._events: deque[BusEvent] = deque()
        self._max_events = max_events
        self._status_cbs: list[StatusCallback] = []
        self._join_cbs: list[RobotCallback] = []
        self._leave_cbs: list[RobotCallback] = []
        self._status_sub: Any = None
        self._alive_sub: Any = None
        self._publishers: dict[str, Any] = {}
        self._handles: list[BusHandle] = []
        self._closed = False

    # -- publishing ------------------------------------------------------------------

    def _publisher(self, key: str, block: bool) -> Any:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(
                key,
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP,
            )
            self._publishers[key] = pub
        return pub

    def publish_status(self, rec: StatusRecord) -> None:
        """Publish ``rec`` on ``fleet/<rec.robot>/status``. ValueError if ``rec`` is invalid."""
        self._publisher(status_key(rec.robot), False).put(rec.to_json())

    def publish_task(self, robot: str | TaskMessage, msg: TaskMessage | None = None) -> None:
        """Publish an order on ``fleet/<robot>/task``: ``publish_task(robot, msg)`` or
        ``publish_task(msg)`` with ``msg.robot`` set. Sent reliably (congestion: block)."""
        if isinstance(robot, TaskMessage):
            msg, name = robot, robot.robot
        else:
            name = robot
        if msg is None or name is None:
            raise ValueError("publish_task needs a robot name and a TaskMessage")
        if msg.robot is None:
            msg = TaskMessage(msg.task_id, msg.kind, name, msg.route, msg.poses, msg.charger, msg.pick)
        elif msg.robot != name:
            raise ValueError(f"task for {msg.robot!r} published to robot {name!r}")
        self._publisher(task_key(name), True).put(msg.to_json())

    def publish_grant(self, grant: Any) -> None:
        """Publish a traffic :class:`~fleet.traffic.Grant` on ``fleet/<grant.robot>/grant``
        (JSON of ``Grant.to_dict``; congestion: block, like orders)."""
        self._publisher(grant_key(grant.robot), True).put(_dumps(grant.to_dict()))

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

    def _call(self, cbs: list[Any], arg: Any) -> None:
        for cb in cbs:
            try:
                cb(arg)
            except Exception as e:  # noqa: BLE001 - never raise into Zenoh's thread
                with self._lock:
                    self.callback_errors += 1
                    self.last_callback_error = f"{getattr(cb, '__qualname__', cb)}: {e!r}"

    def _on_status_sample(self, sample: Any) -> None:
        key = "?"
        try:
            key = str(sample.key_expr)
            if sample.kind == zenoh.SampleKind.DELETE:
                return
            robot = robot_of_key(key)
            rec = StatusRecord.from_json(sample.payload.to_bytes())
            if rec.robot != robot:
                raise ValueError(f"status.robot: {rec.robot!r} does not match the key's robot {robot!r}")
        except Exception as e:  # noqa: BLE001 - count and drop
            self._bad(key, str(e))
            return
        try:
            with self._lock:
                self.received += 1
                self._latest[robot] = rec
                self._push(BusEvent("status", robot, rec))
                cbs = list(self._status_cbs)
            self._call(cbs, rec)
        except Exception as e:  # noqa: BLE001
            self._bad(key, f"internal: {e!r}")

    def subscribe_statuses(self, callback: StatusCallback | None = None) -> BusHandle:
        """Subscribe to ``fleet/*/status`` (once per bus) and keep the latest record per robot
        (:meth:`latest`). ``callback(rec)``, if given, runs on Zenoh's thread for every valid
        record; the returned handle removes it."""
        with self._lock:
            if callback is not None:
                self._status_cbs.append(callback)
            need = self._status_sub is None
        if need:
            self._status_sub = self.session.declare_subscriber(STATUS_KEYS, self._on_status_sample)

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

    def subscribe_tasks(self, robot: str, callback: TaskCallback) -> BusHandle:
        """Call ``callback(msg)`` (on Zenoh's thread) for every valid order on
        ``fleet/<robot>/task``. The handle's ``undeclare()`` ends the subscription."""

        def parse(data: bytes) -> TaskMessage:
            msg = TaskMessage.from_json(data)
            if msg.robot is None:
                return TaskMessage(msg.task_id, msg.kind, robot, msg.route, msg.poses, msg.charger, msg.pick)
            if msg.robot != robot:
                raise ValueError(f"task.robot: {msg.robot!r} does not match the key's robot {robot!r}")
            return msg

        return self._subscribe_robot(task_key(robot), robot, "task", parse, callback)

    def subscribe_grants(self, robot: str, callback: Callable[[Any], None]) -> BusHandle:
        """Call ``callback(grant)`` (on Zenoh's thread) for every valid traffic grant on
        ``fleet/<robot>/grant``; a malformed one is counted in ``malformed`` and dropped."""
        from fleet.traffic import Grant

        def parse(data: bytes) -> Grant:
            try:
                g = Grant.from_dict(_decode(data, "grant"))
            except (KeyError, TypeError, IndexError) as e:
                raise ValueError(f"grant: {type(e).__name__}: {e}") from None
            if g.robot != robot:
                raise ValueError(f"grant.robot: {g.robot!r} does not match the key's robot {robot!r}")
            if len(g.poses) != len(g.nodes):
                raise ValueError(f"grant: {len(g.nodes)} nodes but {len(g.poses)} poses")
            return g

        return self._subscribe_robot(grant_key(robot), robot, "grant", parse, callback)

    def _subscribe_robot(
        self,
        key: str,
        robot: str,
        kind: Literal["task", "grant"],
        parse: Callable[[bytes], Any],
        callback: Callable[[Any], None],
    ) -> BusHandle:
        """Subscribe to one robot's ``key``: ``parse`` each payload (an exception = malformed:
        counted and dropped), record a :class:`BusEvent` of ``kind`` and call ``callback``."""

        def on_sample(sample: Any) -> None:
            k = key
            try:
                k = str(sample.key_expr)
                if sample.kind == zenoh.SampleKind.DELETE:
                    return
                value = parse(sample.payload.to_bytes())
            except Exception as e:  # noqa: BLE001 - count and drop
                self._bad(k, str(e))
                return
            with self._lock:
                self.received += 1
                self._push(BusEvent(kind, robot, value))
            self._call([callback], value)

        sub = self.session.declare_subscriber(key, on_sample)
        h = BusHandle(sub.undeclare)
        self._handles.append(h)
        return h

    # -- liveliness ------------------------------------------------------------------

    def declare_alive(self, robot: str) -> BusHandle:
        """Hold the liveliness token ``fleet/<robot>/alive`` until the handle is undeclared
        (or the bus / session closes, or the process dies)."""
        token = self.session.liveliness().declare_token(alive_key(robot))
        h = BusHandle(token.undeclare)
        self._handles.append(h)
        return h

    def _on_alive_sample(self, sample: Any) -> None:
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
                if on_join in self._join_cbs:
                    self._join_cbs.remove(on_join)  # type: ignore[arg-type]
                if on_leave in self._leave_cbs:
                    self._leave_cbs.remove(on_leave)  # type: ignore[arg-type]

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
        for obj in (self._status_sub, self._alive_sub, *self._publishers.values()):
            if obj is not None:
                try:
                    obj.undeclare()
                except Exception:  # noqa: BLE001 - session already closed
                    pass
        self._status_sub = self._alive_sub = None
        self._publishers.clear()

    def shutdown(self) -> None:
        """:meth:`close`, then close the session."""
        try:
            self.close()
        finally:
            self.session.close()

    def __enter__(self) -> StatusBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
