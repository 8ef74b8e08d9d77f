"""The simulator's navigation actions served over Zenoh (``fleet sim``); see
``docs/status_bus.md`` for the protocol."""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from fleet.bus.keys import CLOCK_KEY, nav_key, robot_key_name
from fleet.messages import (
    BRIDGE_VERSION,
    _dumps,
    _loads,
    as_int,
    as_str,
    goal_from_dict,
    goal_state_to_dict,
    req,
    robot_state_to_dict,
)
from fleet.types import Goal, GoalState, GoalStatus

#: Terminal goals stay in state messages this many wall seconds.
DEFAULT_LINGER_S = 3.0


#: Goal ids remembered per robot by the server (for de-duplication of re-sends).
REMEMBER_IDS = 4096


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
