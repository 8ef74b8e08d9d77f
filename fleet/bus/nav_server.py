"""The simulator's navigation actions served over Zenoh (``fleet sim``); see
``docs/status_bus.md`` for the protocol."""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import zenoh

from fleet.bus.keys import CLOCK_KEY, nav_key, robot_key_name
from fleet.bus.lease import sim_lease_key
from fleet.bus.session import Declaration, undeclare_all
from fleet.messages.nav import (
    CANCEL_REQUEST_CODEC,
    GOAL_REQUEST_CODEC,
    CancelRequest,
    ClockMsg,
    GoalRequest,
    NavState,
    goal_of,
)
from fleet.navigation import Clock
from fleet.robots import SimParams
from fleet.types import MOTION_GOAL_KINDS, Goal, GoalState, GoalStatus, RobotState

#: Terminal goals stay in state messages this many wall seconds.
DEFAULT_LINGER_S = 3.0


#: Goal ids remembered per robot by the server (for de-duplication of re-sends).
REMEMBER_IDS = 4096


class ServedSimulator(Protocol):
    """What :class:`SimNavServer` needs of a simulator (:class:`sim.simulator.Simulator`):
    its robots' namespaces, clock and step, and per-namespace navigation. ``steps`` (the
    step count, in clock messages) is read if present."""

    @property
    def namespaces(self) -> list[str]: ...

    @property
    def clock(self) -> Clock: ...

    @property
    def params(self) -> SimParams: ...

    def send_goal(self, namespace: str, goal: Goal) -> str: ...

    def goal_state(self, goal_id: str) -> GoalState: ...

    def cancel_goal(self, goal_id: str) -> None: ...

    def robot_state(self, namespace: str) -> RobotState: ...


@dataclass(frozen=True)
class _Request:
    robot: str
    goal_id: str
    goal: Goal | None = None  # None: a cancel
    client: str = ""
    seq: int = 0


@dataclass
class _ServedGoal:
    goal_id: str
    kind: str
    sim_id: str | None = None
    # a state decided by the bridge (never executed), or the final state of an ended goal (kept
    # while it lingers: the simulator forgets old finished goals, sim.goals.KEEP_FINISHED)
    fixed: GoalState | None = None
    ended_wall: float | None = None


class SimNavServer:
    """Serves every robot of ``simulator`` over ``session`` (see the module docstring).

    Call :meth:`process` before each simulator step and :meth:`publish` after a batch of
    steps, both from the thread that steps the simulator. ``wall`` is a monotonic clock in
    seconds (for how long terminal goals stay listed).

    Counters: ``received`` valid requests queued, ``requests`` requests applied,
    ``malformed`` requests dropped (``last_malformed`` says why: ``<key>: <field>: <reason>``).
    """

    def __init__(
        self,
        session: zenoh.Session,
        simulator: ServedSimulator,
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
        self.received = 0
        self._lock = threading.Lock()
        self._inbox: deque[_Request] = deque()
        self._ns: dict[str, str] = {robot_key_name(ns): ns for ns in simulator.namespaces}
        self._goals: dict[str, OrderedDict[str, _ServedGoal]] = {r: OrderedDict() for r in self._ns}
        self._shown: dict[str, dict[str, _ServedGoal]] = {r: {} for r in self._ns}  # listed in states
        self._last_seq: dict[tuple[str, str], int] = {}
        self._precanceled: dict[str, OrderedDict[str, None]] = {r: OrderedDict() for r in self._ns}
        self._state_pubs = {r: session.declare_publisher(nav_key(ns, "state")) for r, ns in self._ns.items()}
        self._clock_pub = session.declare_publisher(CLOCK_KEY)
        #: This simulator's session id, stamped on its states and clock: the key of its lease.
        self.src = str(session.zid())
        self._lease: Declaration | None = session.liveliness().declare_token(sim_lease_key(self.src))
        self._subs: list[Declaration] = [
            session.declare_subscriber("fleet/*/nav/goal", self._on_request),
            session.declare_subscriber("fleet/*/nav/cancel", self._on_request),
        ]
        self.speed = 0.0

    def _on_request(self, sample: zenoh.Sample) -> None:
        key = "?"
        try:
            key = str(sample.key_expr)
            parts = key.split("/")
            robot, what = parts[1], parts[3]
            if robot not in self._ns:
                raise ValueError(f"no robot {robot!r} in this simulator")
            data = sample.payload.to_bytes()
            msg: GoalRequest | CancelRequest
            if what == "goal":
                msg = GOAL_REQUEST_CODEC.decode(data)
                req = _Request(robot, msg.goal_id, goal_of(msg.goal), msg.client, msg.seq)
            else:
                msg = CANCEL_REQUEST_CODEC.decode(data)
                req = _Request(robot, msg.goal_id)
            with self._lock:
                self._inbox.append(req)
                self.received += 1
        except Exception as e:  # noqa: BLE001 - count and drop
            with self._lock:
                self.malformed += 1
                self.last_malformed = f"{key}: {e}"

    def process(self) -> int:
        """Apply the queued goal and cancel requests to the simulator; returns how many."""
        with self._lock:
            batch = list(self._inbox)
            self._inbox.clear()
        for req in batch:
            self.requests += 1
            if req.goal is not None:
                self._goal(req, req.goal)
            else:
                self._cancel(req.robot, req.goal_id)
        return len(batch)

    def _remember(self, robot: str, g: _ServedGoal) -> None:
        goals = self._goals[robot]
        goals[g.goal_id] = g
        while len(goals) > REMEMBER_IDS:
            goals.popitem(last=False)

    def _goal(self, req: _Request, goal: Goal) -> None:
        robot, gid = req.robot, req.goal_id
        goals = self._goals[robot]
        known = goals.get(gid)
        if known is not None:  # a re-send: list it again, never execute it twice
            self._shown[robot][gid] = known
            if known.ended_wall is not None:
                known.ended_wall = self._wall()
            return
        g = _ServedGoal(gid, goal.kind)
        client_seq = (req.client, robot)
        seq = req.seq
        motion = goal.kind in MOTION_GOAL_KINDS
        if gid in self._precanceled[robot]:
            g.fixed = GoalState(gid, goal.kind, GoalStatus.CANCELED, error_msg="canceled before it started")
        elif motion and seq < self._last_seq.get(client_seq, -1):
            g.fixed = GoalState(
                gid, goal.kind, GoalStatus.ABORTED, error_msg="preempted by a newer goal of the same client"
            )
        else:
            if motion:  # computation goals run beside the motion goal and preempt nothing
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
            goals: dict[str, GoalState] = {}
            shown = self._shown[robot]
            for g in list(shown.values()):
                st = self._state_of(g)
                if st.status.terminal:
                    g.fixed = st
                    if g.ended_wall is None:
                        g.ended_wall = now_wall
                    elif now_wall - g.ended_wall > self.linger_s:
                        del shown[g.goal_id]
                        continue
                goals[g.goal_id] = st
            msg = NavState.build(robot, t, self.sim.robot_state(ns), goals, self.src)
            self._state_pubs[robot].put(msg.to_json())
        clock = ClockMsg(
            t, int(getattr(self.sim, "steps", 0)), float(self.sim.params.step_s), float(self.speed), self.src
        )
        self._clock_pub.put(clock.to_json())

    def close(self) -> None:
        """Undeclare the subscribers and publishers (the session stays open)."""
        undeclare_all([*self._subs, *self._state_pubs.values(), self._clock_pub, self._lease])
        self._lease = None
        self._subs = []
        self._state_pubs = {}
