"""A :class:`~fleet.navigation.NavigationBackend` for a robot of a simulator served over Zenoh
by another process (``fleet sim``)."""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable, Container
from dataclasses import dataclass

import zenoh

from fleet.bus.keys import nav_key, robot_key_name
from fleet.bus.session import undeclare_all
from fleet.errors import BackendError
from fleet.messages.nav import NAV_STATE_CODEC, CancelRequest, GoalRequest, goal_message, robot_state_of
from fleet.types import ErrorCode, Goal, GoalState, GoalStatus, RobotState

#: Default wall seconds without a state message before an active goal is declared lost.
DEFAULT_TIMEOUT_S = 3.0


#: Default wall seconds between re-sends of an unacknowledged goal or cancel.
DEFAULT_RESEND_S = 0.3


#: Goals that ended are remembered (for :meth:`ZenohNavBackend.goal_state`) up to this many;
#: older ones are forgotten first, so a long run's client stays bounded.
KEEP_ENDED = 1024


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
    thread). ``sources`` (:meth:`fleet.bus.lease.SimLeaseWatch.admits`): only states whose
    ``src`` is a live simulator's are used; the others are counted in ``rejected``. Call
    :meth:`close` when done (the session stays open).
    """

    def __init__(
        self,
        session: zenoh.Session,
        namespace: str,
        *,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        resend_s: float = DEFAULT_RESEND_S,
        wall: Callable[[], float] = time.monotonic,
        sources: Callable[[str], bool] | None = None,
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
        self._open: set[str] = set()  # acknowledged goals that have not ended
        self._robot_state = RobotState(pose=None)
        self._last_state_wall: float | None = None
        self.sim_time: float | None = None
        self.states_received = 0
        self.malformed = 0
        self.last_malformed: str | None = None
        #: States ignored: not from a live simulator (``sources``).
        self.rejected = 0
        self.sources = sources
        self._first_state = threading.Event()
        self._goal_pub = session.declare_publisher(
            nav_key(namespace, "goal"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._cancel_pub = session.declare_publisher(
            nav_key(namespace, "cancel"), congestion_control=zenoh.CongestionControl.BLOCK
        )
        self._sub: zenoh.Subscriber[None] = session.declare_subscriber(
            nav_key(namespace, "state"), self._on_state
        )

    @property
    def namespace(self) -> str:
        """The robot's namespace, e.g. ``/robot1``."""
        return self._namespace

    # -- state messages (Zenoh's thread) -------------------------------------------------

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            msg = NAV_STATE_CODEC.decode(sample.payload.to_bytes())
            if self.sources is not None and not self.sources(msg.src):
                with self._lock:
                    self.rejected += 1
                return
            t = msg.t
            rs = robot_state_of(msg.robot_state)
            with self._lock:
                mine = [gid for gid in msg.goals if gid in self._goals]
            parsed = {gid: msg.goal_state(gid) for gid in mine}  # other clients' goals stay unparsed
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
            self._first_state.set()
            for gid, st in parsed.items():
                g = self._goals[gid]
                g.acked = True
                g.payload = b""
                if g.state.status.terminal:
                    continue
                if not st.status.terminal and g.state.status is GoalStatus.CANCELING:
                    g.state = GoalState(gid, st.kind, GoalStatus.CANCELING, st.feedback)
                    self._open.add(gid)
                    continue
                g.state = st
                if st.status.terminal:
                    self._open.discard(gid)
                else:
                    self._open.add(gid)
            self._forgotten(msg.goals)

    def _forget_ended(self) -> None:
        """Forget the oldest ended goals beyond :data:`KEEP_ENDED` (caller holds the lock)."""
        ended = [gid for gid, g in self._goals.items() if g.state.status.terminal]
        for gid in ended[: max(0, len(ended) - KEEP_ENDED)]:
            del self._goals[gid]

    def _forgotten(self, listed: Container[str]) -> None:
        """End the goals the server acknowledged and no longer lists (caller holds the lock): a
        server lists every goal it runs, so it was restarted and forgot them."""
        for gid in [gid for gid in self._open if gid not in listed]:
            self._open.discard(gid)
            g = self._goals[gid]
            if not g.state.status.terminal:
                g.state = _unavailable(g.state, "the simulator no longer knows the goal (was it restarted?)")

    # -- the protocol --------------------------------------------------------------------

    def send_goal(self, goal: Goal) -> str:
        """Publish ``goal`` and return its id at once (``PENDING`` until acknowledged). A goal
        that cannot be encoded (a non-finite pose) is ``REJECTED`` at once; an object that is
        not a goal raises :class:`~fleet.errors.BackendError`."""
        if not isinstance(goal, Goal):
            raise BackendError(
                f"{self._namespace}: send_goal: {type(goal).__name__} is not a navigation goal"
            )
        with self._lock:
            self._seq += 1
            seq = self._seq
        gid = f"{self._namespace}@{self._tag}#{seq}"
        now = self._wall()
        kind = getattr(goal, "kind", type(goal).__name__)
        try:
            payload = GoalRequest(gid, self._tag, seq, goal_message(goal)).to_json()
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
            if seq % 256 == 0:
                self._forget_ended()
        self._put(self._goal_pub, payload)
        return gid

    def _put(self, pub: zenoh.Publisher, payload: bytes) -> None:
        try:
            pub.put(payload)
        except Exception:  # noqa: BLE001 - a closed session: the timeout will end the goal
            pass

    def goal_state(self, goal_id: str) -> GoalState:
        """Latest state of ``goal_id`` (``KeyError`` if this backend never issued it, or it ended
        more than :data:`KEEP_ENDED` ended goals ago)."""
        resend: list[tuple[zenoh.Publisher, bytes]] = []
        with self._lock:
            g = self._goals[goal_id]
            self._check(goal_id, g, resend)
            st = g.state
        for pub, payload in resend:
            self._put(pub, payload)
        return st

    def _check(self, gid: str, g: _ClientGoal, resend: list[tuple[zenoh.Publisher, bytes]]) -> None:
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
            self._open.discard(gid)
            g.state = _unavailable(g.state, reason)
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
            resend.append((self._cancel_pub, CancelRequest(gid).to_json()))

    def cancel_goal(self, goal_id: str) -> None:
        """Ask to cancel (``CANCELING`` until the server reports the end); a no-op for an
        unknown or finished goal."""
        with self._lock:
            g = self._goals.get(goal_id)
            if g is None or g.state.status.terminal or g.state.status is GoalStatus.CANCELING:
                return
            g.state = GoalState(goal_id, g.state.kind, GoalStatus.CANCELING, g.state.feedback)
            g.cancel_sent_wall = self._wall()
        self._put(self._cancel_pub, CancelRequest(goal_id).to_json())

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
        return self._first_state.wait(timeout_s)

    def close(self) -> None:
        """Undeclare the subscriber and publishers (idempotent; the session stays open)."""
        undeclare_all([self._sub, self._goal_pub, self._cancel_pub])

    def __repr__(self) -> str:
        return f"ZenohNavBackend({self._namespace!r})"


def _unavailable(state: GoalState, reason: str) -> GoalState:
    """``state`` ended ABORTED with SERVER_UNAVAILABLE and ``reason`` (the simulator is gone or
    forgot the goal)."""
    return GoalState(
        state.goal_id,
        state.kind,
        GoalStatus.ABORTED,
        state.feedback,
        error_code=int(ErrorCode.SERVER_UNAVAILABLE),
        error_msg=reason,
    )
