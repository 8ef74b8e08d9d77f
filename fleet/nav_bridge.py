"""The simulator's navigation actions over Zenoh, so robot agents can run in other processes.

Protocol (JSON, UTF-8, ``v: 1``; ``<robot>`` is the namespace without its slash):

* ``fleet/<robot>/nav/goal`` (client -> server): ``{"v":1, "goal_id": "/robot1@3fa2#7",
  "client": "3fa2", "seq": 7, "goal": {...goal_to_dict}}``. The *client* chooses the goal id
  (unique: namespace, a random client tag, a counter).
* ``fleet/<robot>/nav/cancel`` (client -> server): ``{"v":1, "goal_id": "..."}``.
* ``fleet/<robot>/nav/state`` (server -> clients, every publication cycle): ``{"v":1,
  "robot": "robot1", "t": <sim s>, "robot_state": {...}, "goals": {"<goal_id>":
  {goal state}}}`` with every goal that is not terminal and every terminal goal for
  ``linger_s`` wall seconds after it ended.
* ``fleet/sim/clock`` (server -> all): ``{"v":1, "t": <sim s>, "step": n, "step_s": 0.05,
  "speed": 1.0}``.

Server (:class:`SimNavServer`): requests are queued by Zenoh's thread and applied to the
simulator only by :meth:`SimNavServer.process`, on the thread that steps the simulator. A goal
id seen before is not executed again (a client re-sends a goal until it is acknowledged); a
goal that arrives after a newer goal of the same client (a late re-send) ends ``ABORTED``
unexecuted; a cancel that arrives before its goal makes the goal end ``CANCELED`` unexecuted.

Client (:class:`ZenohNavBackend`, a :class:`fleet.navigation.NavigationBackend`): ``send_goal``
publishes and returns the id at once; the goal is ``PENDING`` until a state message lists it;
it re-sends the request (goal or cancel) every ``resend_s`` while unacknowledged, from the
polling thread. A goal that is not terminal ends ``ABORTED`` with
``ErrorCode.SERVER_UNAVAILABLE`` if no state message arrived for ``timeout_s`` wall seconds, or
if the server never acknowledged it within ``timeout_s``. A terminal state never changes.

Malformed messages are counted (``malformed``, ``last_malformed``) and dropped on both sides.
"""

from __future__ import annotations

import json
import math
import secrets
import signal
import sys
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

import zenoh

from fleet.codec import (
    as_dict,
    as_float,
    as_int,
    as_str,
    goal_from_dict,
    goal_state_from_dict,
    goal_state_to_dict,
    goal_to_dict,
    req,
    robot_state_from_dict,
    robot_state_to_dict,
)
from fleet.errors import BackendError
from fleet.types import ErrorCode, Goal, GoalState, GoalStatus, RobotState

BRIDGE_VERSION = 1
CLOCK_KEY = "fleet/sim/clock"
#: Default wall seconds without a state message before an active goal is declared lost.
DEFAULT_TIMEOUT_S = 3.0
#: Default wall seconds between re-sends of an unacknowledged goal or cancel.
DEFAULT_RESEND_S = 0.3
#: Terminal goals stay in state messages this many wall seconds.
DEFAULT_LINGER_S = 3.0
#: Goal ids remembered per robot by the server (for de-duplication of re-sends).
REMEMBER_IDS = 4096
MAX_BRIDGE_PAYLOAD = 1024 * 1024


def robot_key_name(namespace: str) -> str:
    """``robot1`` for ``/robot1``."""
    name = namespace.strip("/")
    if not name:
        raise BackendError(f"bad robot namespace {namespace!r}")
    return name


def nav_key(namespace: str, what: str) -> str:
    """``fleet/<robot>/nav/<what>`` with ``what`` in ``goal``, ``cancel``, ``state``."""
    return f"fleet/{robot_key_name(namespace)}/nav/{what}"


def _loads(data: bytes, what: str) -> dict[str, Any]:
    if len(data) > MAX_BRIDGE_PAYLOAD:
        raise ValueError(f"payload: {len(data)} bytes is too large")
    try:
        obj = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ValueError(f"payload: not UTF-8 JSON ({str(e)[:80]})") from None
    d = dict(as_dict(obj, what))
    v = req(d, "v", what)
    if isinstance(v, bool) or v != BRIDGE_VERSION:
        raise ValueError(f"{what}.v: unsupported version {v!r}")
    return d


def _dumps(d: dict[str, Any]) -> bytes:
    return json.dumps(d, separators=(",", ":"), allow_nan=False).encode("utf-8")


# ----------------------------------------------------------------------------- server


@dataclass
class _ServedGoal:
    goal_id: str
    kind: str
    sim_id: str | None = None
    fixed: GoalState | None = None  # a state decided by the bridge (never executed)
    ended_wall: float | None = None


class SimNavServer:
    """Serves every robot of ``simulator`` over ``session`` (see the module docstring).

    Call :meth:`process` before each simulator step and :meth:`publish` after a batch of
    steps, both from the thread that steps the simulator. ``wall`` is a monotonic clock in
    seconds (for how long terminal goals stay listed).
    """

    def __init__(
        self,
        session: zenoh.Session,
        simulator: Any,
        *,
        linger_s: float = DEFAULT_LINGER_S,
        wall: Callable[[], float] = time.monotonic,
    ) -> None:
        self.session = session
        self.sim = simulator
        self.linger_s = float(linger_s)
        self._wall = wall
        self.malformed = 0
        self.last_malformed: str | None = None
        self.requests = 0
        self._lock = threading.Lock()
        self._inbox: deque[tuple[str, str, dict[str, Any]]] = deque()
        self._ns: dict[str, str] = {robot_key_name(ns): ns for ns in simulator.namespaces}
        self._goals: dict[str, OrderedDict[str, _ServedGoal]] = {r: OrderedDict() for r in self._ns}
        self._shown: dict[str, dict[str, _ServedGoal]] = {r: {} for r in self._ns}  # listed in states
        self._last_seq: dict[tuple[str, str], int] = {}
        self._precanceled: dict[str, OrderedDict[str, None]] = {r: OrderedDict() for r in self._ns}
        self._state_pubs = {r: session.declare_publisher(nav_key(ns, "state")) for r, ns in self._ns.items()}
        self._clock_pub = session.declare_publisher(CLOCK_KEY)
        self._subs: list[Any] = [
            session.declare_subscriber("fleet/*/nav/goal", self._on_request),
            session.declare_subscriber("fleet/*/nav/cancel", self._on_request),
        ]
        self.speed = 0.0

    def _on_request(self, sample: Any) -> None:
        key = "?"
        try:
            key = str(sample.key_expr)
            parts = key.split("/")
            robot, what = parts[1], parts[3]
            if robot not in self._ns:
                raise ValueError(f"no robot {robot!r} in this simulator")
            d = _loads(sample.payload.to_bytes(), what)
            as_str(req(d, "goal_id", what), f"{what}.goal_id")
            if what == "goal":
                d["_goal"] = goal_from_dict(req(d, "goal", what))
                as_str(req(d, "client", what), "goal.client")
                as_int(req(d, "seq", what), "goal.seq", minimum=0)
            with self._lock:
                self._inbox.append((robot, what, d))
        except Exception as e:  # noqa: BLE001 - count and drop
            with self._lock:
                self.malformed += 1
                self.last_malformed = f"{key}: {e}"

    def process(self) -> int:
        """Apply the queued goal and cancel requests to the simulator; returns how many."""
        with self._lock:
            batch = list(self._inbox)
            self._inbox.clear()
        for robot, what, d in batch:
            self.requests += 1
            if what == "goal":
                self._goal(robot, d)
            else:
                self._cancel(robot, d["goal_id"])
        return len(batch)

    def _remember(self, robot: str, g: _ServedGoal) -> None:
        goals = self._goals[robot]
        goals[g.goal_id] = g
        while len(goals) > REMEMBER_IDS:
            goals.popitem(last=False)

    def _goal(self, robot: str, d: dict[str, Any]) -> None:
        gid: str = d["goal_id"]
        goal: Goal = d["_goal"]
        goals = self._goals[robot]
        known = goals.get(gid)
        if known is not None:  # a re-send: list it again, never execute it twice
            self._shown[robot][gid] = known
            if known.ended_wall is not None:
                known.ended_wall = self._wall()
            return
        g = _ServedGoal(gid, goal.kind)
        client_seq = (d["client"], robot)
        seq = int(d["seq"])
        if gid in self._precanceled[robot]:
            g.fixed = GoalState(gid, goal.kind, GoalStatus.CANCELED, error_msg="canceled before it started")
        elif seq < self._last_seq.get(client_seq, -1):
            g.fixed = GoalState(
                gid, goal.kind, GoalStatus.ABORTED, error_msg="preempted by a newer goal of the same client"
            )
        else:
            self._last_seq[client_seq] = seq
            try:
                g.sim_id = self.sim.send_goal(self._ns[robot], goal)
            except Exception as e:  # noqa: BLE001 - a goal the simulator cannot take
                g.fixed = GoalState(gid, goal.kind, GoalStatus.REJECTED, error_msg=str(e))
        self._remember(robot, g)
        self._shown[robot][gid] = g

    def _cancel(self, robot: str, gid: str) -> None:
        g = self._goals[robot].get(gid)
        if g is None:
            pre = self._precanceled[robot]
            pre[gid] = None
            while len(pre) > REMEMBER_IDS:
                pre.popitem(last=False)
            return
        self._shown[robot][gid] = g
        if g.sim_id is not None:
            self.sim.cancel_goal(g.sim_id)

    def _state_of(self, g: _ServedGoal) -> GoalState:
        if g.fixed is not None:
            return g.fixed
        assert g.sim_id is not None
        return self.sim.goal_state(g.sim_id)

    def publish(self) -> None:
        """Publish every robot's state message and the clock message."""
        now_wall = self._wall()
        t = float(self.sim.clock.now())
        for robot, ns in self._ns.items():
            goals: dict[str, Any] = {}
            shown = self._shown[robot]
            for g in list(shown.values()):
                st = self._state_of(g)
                if st.status.terminal:
                    if g.ended_wall is None:
                        g.ended_wall = now_wall
                    elif now_wall - g.ended_wall > self.linger_s:
                        del shown[g.goal_id]
                        continue
                goals[g.goal_id] = goal_state_to_dict(st)
            msg = {
                "v": BRIDGE_VERSION,
                "robot": robot,
                "t": t,
                "robot_state": robot_state_to_dict(self.sim.robot_state(ns)),
                "goals": goals,
            }
            self._state_pubs[robot].put(_dumps(msg))
        self._clock_pub.put(
            _dumps(
                {
                    "v": BRIDGE_VERSION,
                    "t": t,
                    "step": int(getattr(self.sim, "steps", 0)),
                    "step_s": float(self.sim.params.step_s),
                    "speed": float(self.speed),
                }
            )
        )

    def close(self) -> None:
        """Undeclare the subscribers and publishers (the session stays open)."""
        objs: list[Any] = [*self._subs, *self._state_pubs.values(), self._clock_pub]
        for obj in objs:
            try:
                obj.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._subs = []
        self._state_pubs = {}


# ----------------------------------------------------------------------------- client


@dataclass
class _ClientGoal:
    state: GoalState
    payload: bytes
    sent_wall: float
    last_sent_wall: float
    acked: bool = False
    cancel_sent_wall: float | None = None


class ZenohNavBackend:
    """A :class:`~fleet.navigation.NavigationBackend` for robot ``namespace`` of a simulator
    served by :class:`SimNavServer` over ``session`` (see the module docstring).

    ``timeout_s``: wall seconds without a state message (or without an acknowledgement of a
    goal) before a non-terminal goal ends ``ABORTED`` / ``SERVER_UNAVAILABLE``.
    ``resend_s``: how often an unacknowledged goal or cancel is re-sent (from the polling
    thread). Call :meth:`close` when done (the session stays open).
    """

    def __init__(
        self,
        session: zenoh.Session,
        namespace: str,
        *,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        resend_s: float = DEFAULT_RESEND_S,
        wall: Callable[[], float] = time.monotonic,
    ) -> None:
        self._namespace = "/" + namespace.strip("/")
        self._robot = robot_key_name(namespace)
        self.session = session
        self.timeout_s = float(timeout_s)
        self.resend_s = float(resend_s)
        self._wall = wall
        self._tag = secrets.token_hex(4)
        self._seq = 0
        self._lock = threading.Lock()
        self._goals: dict[str, _ClientGoal] = {}
        self._robot_state = RobotState(pose=None)
        self._last_state_wall: float | None = None
        self.sim_time: float | None = None
        self.states_received = 0
        self.malformed = 0
        self.last_malformed: str | None = None
        self._goal_pub = session.declare_publisher(
            nav_key(namespace, "goal"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._cancel_pub = session.declare_publisher(
            nav_key(namespace, "cancel"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._sub: Any = session.declare_subscriber(nav_key(namespace, "state"), self._on_state)

    @property
    def namespace(self) -> str:
        """The robot's namespace, e.g. ``/robot1``."""
        return self._namespace

    # -- state messages (Zenoh's thread) -------------------------------------------------

    def _on_state(self, sample: Any) -> None:
        try:
            d = _loads(sample.payload.to_bytes(), "state")
            t = as_float(req(d, "t", "state"), "state.t")
            rs = robot_state_from_dict(req(d, "robot_state", "state"), "state.robot_state")
            goals = as_dict(req(d, "goals", "state"), "state.goals")
            parsed: dict[str, GoalState] = {}
            with self._lock:
                mine = [gid for gid in goals if gid in self._goals]
            for gid in mine:
                parsed[gid] = goal_state_from_dict(gid, goals[gid], f"state.goals[{gid!r}]")
        except Exception as e:  # noqa: BLE001 - count and drop
            with self._lock:
                self.malformed += 1
                self.last_malformed = str(e)
            return
        now = self._wall()
        with self._lock:
            self._robot_state = rs
            self.sim_time = t
            self._last_state_wall = now
            self.states_received += 1
            for gid, st in parsed.items():
                g = self._goals[gid]
                g.acked = True
                g.payload = b""
                if g.state.status.terminal:
                    continue
                if not st.status.terminal and g.state.status is GoalStatus.CANCELING:
                    g.state = GoalState(gid, st.kind, GoalStatus.CANCELING, st.feedback)
                    continue
                g.state = st

    # -- the protocol --------------------------------------------------------------------

    def send_goal(self, goal: Goal) -> str:
        """Publish ``goal`` and return its id at once (``PENDING`` until acknowledged). A goal
        that cannot be encoded (a non-finite pose) is ``REJECTED`` at once."""
        with self._lock:
            self._seq += 1
            seq = self._seq
        gid = f"{self._namespace}@{self._tag}#{seq}"
        now = self._wall()
        kind = getattr(goal, "kind", type(goal).__name__)
        try:
            payload = _dumps(
                {
                    "v": BRIDGE_VERSION,
                    "goal_id": gid,
                    "client": self._tag,
                    "seq": seq,
                    "goal": goal_to_dict(goal),
                }
            )
        except (ValueError, TypeError) as e:
            with self._lock:
                self._goals[gid] = _ClientGoal(
                    GoalState(gid, kind, GoalStatus.REJECTED, error_msg=f"cannot send goal: {e}"),
                    b"",
                    now,
                    now,
                    True,
                )
            return gid
        with self._lock:
            self._goals[gid] = _ClientGoal(GoalState(gid, kind, GoalStatus.PENDING), payload, now, now)
        self._put(self._goal_pub, payload)
        return gid

    def _put(self, pub: Any, payload: bytes) -> None:
        try:
            pub.put(payload)
        except Exception:  # noqa: BLE001 - a closed session: the timeout will end the goal
            pass

    def goal_state(self, goal_id: str) -> GoalState:
        """Latest state of ``goal_id`` (``KeyError`` if this backend never issued it)."""
        resend: list[tuple[Any, bytes]] = []
        with self._lock:
            g = self._goals[goal_id]
            self._check(goal_id, g, resend)
            st = g.state
        for pub, payload in resend:
            self._put(pub, payload)
        return st

    def _check(self, gid: str, g: _ClientGoal, resend: list[tuple[Any, bytes]]) -> None:
        # caller holds the lock
        s = g.state.status
        if s.terminal:
            return
        now = self._wall()
        last = max(self._last_state_wall or g.sent_wall, g.sent_wall)
        reason = None
        if now - last > self.timeout_s:
            reason = f"no navigation state from the simulator for {self.timeout_s:g} s (server gone?)"
        elif not g.acked and now - g.sent_wall > self.timeout_s:
            reason = f"the simulator did not acknowledge the goal within {self.timeout_s:g} s"
        if reason is not None:
            g.state = GoalState(
                gid,
                g.state.kind,
                GoalStatus.ABORTED,
                g.state.feedback,
                error_code=int(ErrorCode.SERVER_UNAVAILABLE),
                error_msg=reason,
            )
            return
        if not g.acked and now - g.last_sent_wall >= self.resend_s:
            g.last_sent_wall = now
            resend.append((self._goal_pub, g.payload))
        if (
            s is GoalStatus.CANCELING
            and g.cancel_sent_wall is not None
            and now - g.cancel_sent_wall >= self.resend_s
        ):
            g.cancel_sent_wall = now
            resend.append((self._cancel_pub, _dumps({"v": BRIDGE_VERSION, "goal_id": gid})))

    def cancel_goal(self, goal_id: str) -> None:
        """Ask to cancel (``CANCELING`` until the server reports the end); a no-op for an
        unknown or finished goal."""
        with self._lock:
            g = self._goals.get(goal_id)
            if g is None or g.state.status.terminal or g.state.status is GoalStatus.CANCELING:
                return
            g.state = GoalState(goal_id, g.state.kind, GoalStatus.CANCELING, g.state.feedback)
            g.cancel_sent_wall = self._wall()
        self._put(self._cancel_pub, _dumps({"v": BRIDGE_VERSION, "goal_id": goal_id}))

    def robot_state(self) -> RobotState:
        """The robot state of the latest state message (``pose=None`` before the first)."""
        with self._lock:
            return self._robot_state

    @property
    def connected(self) -> bool:
        """True if a state message arrived within ``timeout_s``."""
        with self._lock:
            last = self._last_state_wall
        return last is not None and self._wall() - last <= self.timeout_s

    def wait_for_server(self, timeout_s: float) -> bool:
        """Block up to ``timeout_s`` wall seconds for the first state message."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self._lock:
                if self._last_state_wall is not None:
                    return True
            time.sleep(0.01)
        with self._lock:
            return self._last_state_wall is not None

    def close(self) -> None:
        """Undeclare the subscriber and publishers (idempotent; the session stays open)."""
        for obj in (self._sub, self._goal_pub, self._cancel_pub):
            try:
                obj.undeclare()
            except Exception:  # noqa: BLE001
                pass

    def __repr__(self) -> str:
        return f"ZenohNavBackend({self._namespace!r})"


class BusClock:
    """A :class:`~fleet.navigation.Clock` following ``fleet/sim/clock`` (simulated seconds).

    :meth:`now` is the latest time received (``start`` before the first message). Call
    :meth:`close` when done.
    """

    def __init__(self, session: zenoh.Session, *, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self.updates = 0
        self.malformed = 0
        self.speed: float | None = None
        self.step_s: float | None = None
        self._sub: Any = session.declare_subscriber(CLOCK_KEY, self._on_clock)

    def _on_clock(self, sample: Any) -> None:
        try:
            d = _loads(sample.payload.to_bytes(), "clock")
            t = as_float(req(d, "t", "clock"), "clock.t")
            speed = as_float(d.get("speed", 0.0), "clock.speed")
            step_s = as_float(d.get("step_s", 0.0), "clock.step_s")
        except Exception:  # noqa: BLE001
            with self._lock:
                self.malformed += 1
            return
        with self._cond:
            self._t = t
            self.speed, self.step_s = speed, step_s
            self.updates += 1
            self._cond.notify_all()

    def now(self) -> float:
        with self._lock:
            return self._t

    def wait_until(self, t: float, timeout_s: float) -> bool:
        """Block until the clock reads ``>= t`` or ``timeout_s`` wall seconds passed."""
        end = time.monotonic() + timeout_s
        with self._cond:
            while self._t < t:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def wait_first(self, timeout_s: float) -> bool:
        """Block until the first clock message arrived (or ``timeout_s`` wall seconds)."""
        end = time.monotonic() + timeout_s
        with self._cond:
            while self.updates == 0:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001
            pass


# ----------------------------------------------------------------------------- the loop


@dataclass
class ServeResult:
    """What :func:`serve_simulator` returns: the simulator, steps taken, simulated and wall
    seconds, and whether it was interrupted (Ctrl-C / SIGTERM / ``stop_event``)."""

    simulator: Any
    steps: int
    sim_time_s: float
    wall_time_s: float
    interrupted: bool


def simulator_from_config(config: Any) -> Any:
    """A :class:`sim.simulator.Simulator` with every robot of a :class:`fleet.config.FleetConfig`."""
    from fleet.clock import SimClock
    from sim.simulator import Simulator

    sim = Simulator(config.grid, config.sim, SimClock())
    for spec in config.robots:
        sim.add_robot(spec)
    return sim


def serve_simulator(
    simulator: Any,
    session: zenoh.Session | None = None,
    *,
    endpoint: str | None = None,
    speed: float = 1.0,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
    publish_hz: float = 50.0,
    quiet: bool = False,
    out: TextIO | None = None,
    progress_every_s: float = 10.0,
) -> ServeResult:
    """Step ``simulator`` at ``speed`` x real time (``0``: as fast as possible) and serve it
    with a :class:`SimNavServer` until ``duration`` simulated seconds passed (``None``:
    forever), ``stop_event`` is set, Ctrl-C or SIGTERM (when called from the main thread).

    ``simulator`` may also be a fleet config (the simulator is built with its robots).
    Without ``session`` a router session listening on ``endpoint`` is opened and closed here
    (:class:`~fleet.errors.BusError` if it cannot be). Requests are applied before every step;
    states and the clock are published ``publish_hz`` times per wall second. Unless ``quiet``,
    a progress line is printed every ``progress_every_s`` wall seconds to ``out`` (stdout).
    """
    from fleet.status_bus import DEFAULT_ENDPOINT, open_session

    if speed < 0 or not math.isfinite(speed):
        raise BackendError(f"speed must be >= 0, got {speed}")
    sim = simulator if hasattr(simulator, "step") else simulator_from_config(simulator)
    stop = stop_event or threading.Event()
    own = session is None
    sess = open_session(endpoint or DEFAULT_ENDPOINT, "router") if session is None else session
    old_handler: Any = None
    main = threading.current_thread() is threading.main_thread()
    if main:
        old_handler = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    server: SimNavServer | None = None
    interrupted = False
    period = 1.0 / publish_hz
    wall0 = time.monotonic()
    t0 = sim.clock.now()
    steps = 0
    step_s = float(sim.params.step_s)
    try:
        server = SimNavServer(sess, sim)
        server.speed = speed
        server.process()
        server.publish()
        next_pub = time.monotonic() + period
        next_progress = time.monotonic() + progress_every_s
        end = None if duration is None else t0 + duration
        try:
            while not stop.is_set():
                if end is not None and sim.clock.now() >= end - 1e-9:
                    break
                now_w = time.monotonic()
                target = math.inf if speed == 0 else t0 + speed * (now_w - wall0)
                # step until caught up with the target time or it is time to publish
                while sim.clock.now() + step_s <= target + 1e-9 and time.monotonic() < next_pub:
                    if end is not None and sim.clock.now() >= end - 1e-9:
                        break
                    server.process()
                    sim.step()
                    steps += 1
                now_w = time.monotonic()
                if now_w >= next_pub:
                    server.process()
                    server.publish()
                    next_pub = max(next_pub + period, now_w)
                    if not quiet and now_w >= next_progress:
                        print(
                            f"[fleet sim] t={sim.clock.now():8.1f} s sim, {now_w - wall0:7.1f} s wall, "
                            f"{steps} steps, {server.requests} requests",
                            file=out or sys.stdout,
                            flush=True,
                        )
                        next_progress = now_w + progress_every_s
                if speed > 0:
                    nxt = min(next_pub, wall0 + (sim.clock.now() + step_s - t0) / speed)
                    delay = nxt - time.monotonic()
                    if delay > 0:
                        stop.wait(min(delay, period))
        except KeyboardInterrupt:
            interrupted = True
        server.process()
        server.publish()
        interrupted = interrupted or stop.is_set()
    finally:
        if server is not None:
            server.close()
        if own:
            sess.close()
        if main:
            signal.signal(signal.SIGTERM, old_handler)
    return ServeResult(sim, steps, float(sim.clock.now() - t0), time.monotonic() - wall0, interrupted)
