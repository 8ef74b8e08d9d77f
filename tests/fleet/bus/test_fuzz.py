"""Hostile and malformed input changes nothing (docs/protocol.md): property-based fuzzing of
every key the fleet subscribes to, on real Zenoh sessions on loopback.

For each key (status, task, grant, control, the simulator clock, the navigation protocol's
goal, cancel and state), hypothesis draws payloads that are garbage bytes, truncated JSON,
deeply nested JSON, a field of the wrong type, NaN / infinity, integers too large for the wire,
or larger than the size limit. An outsider session puts each on the key; the receiver counts it
as malformed (exactly one more), applies nothing (its tables, callbacks, clock and queues are
unchanged) and keeps working. Liveliness tokens with arbitrary robot names come and go without
an error. The whole-run check (a seeded run's outcome is the same with garbage on every key)
is in ``tests/fleet/runtime/test_fuzz_run.py``.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ports import free_endpoint

from fleet.bus.clock import BusClock
from fleet.bus.keys import CLOCK_KEY, CONTROL_KEY, grant_key, nav_key, status_key, task_key
from fleet.bus.nav_client import ZenohNavBackend
from fleet.bus.nav_server import SimNavServer
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.config.loader import load_config
from fleet.messages import (
    MAX_BRIDGE_PAYLOAD,
    MAX_PAYLOAD_BYTES,
    FleetControl,
    Grant,
    StatusRecord,
    TaskMessage,
)
from fleet.messages.nav import CancelRequest, ClockMsg, GoalRequest, NavState, goal_message
from fleet.runtime.serve import simulator_from_config
from fleet.types import NavigateToPose, Pose2D, RobotState

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"
#: Hang guard of one wait on the bus (wall s): far more than loopback needs on a loaded machine.
WAIT_S = 30.0
#: Examples per key: modest, so the suite stays fast on a loaded 2-core machine.
EXAMPLES = 20


def wait_until(pred: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {WAIT_S} s waiting for {what}")
        threading.Event().wait(0.002)


@dataclass
class Rig:
    """The receivers of every key, on one client session, and an outsider's session."""

    endpoint: str
    sessions: list[Any] = field(default_factory=list)
    statuses: list[StatusRecord] = field(default_factory=list)
    tasks: list[TaskMessage] = field(default_factory=list)
    grants: list[Grant] = field(default_factory=list)
    controls: list[FleetControl] = field(default_factory=list)
    closers: list[Callable[[], None]] = field(default_factory=list)

    def setup(self) -> None:
        router = open_session(self.endpoint, "router")
        rx = open_session(self.endpoint, "client", connect_timeout_s=10.0)
        self.outsider = open_session(self.endpoint, "client", connect_timeout_s=10.0)
        self.sessions = [self.outsider, rx, router]
        self.bus = StatusBus(rx, robot="robot1")
        self.bus.subscribe_statuses(self.statuses.append)
        self.bus.subscribe_tasks("robot1", self.tasks.append)
        self.bus.subscribe_grants("robot1", self.grants.append)
        self.bus.subscribe_control(self.controls.append)
        self.clock = BusClock(rx)
        config = load_config(PATROL, robots=1)
        self.server = SimNavServer(router, simulator_from_config(config))
        self.client = ZenohNavBackend(rx, "/robot1")
        self.closers = [self.client.close, self.server.close, self.clock.close, self.bus.close]
        # the subscriptions are up once a valid message sent now arrives on each
        probe = FleetControl(estop=False, paused=False, seq=1)
        put = self.put
        wait_until(lambda: put(CONTROL_KEY, probe.to_json()) or bool(self.controls), "the subscriptions")
        wait_until(lambda: put(CLOCK_KEY, b"not json") or self.clock.malformed > 0, "the clock subscription")
        wait_until(lambda: put(nav_key("/robot1", "cancel"), b"x") or self.server.malformed > 0, "the server")
        wait_until(lambda: put(nav_key("/robot1", "state"), b"x") or self.client.malformed > 0, "the client")
        self.controls.clear()

    def put(self, key: str, payload: bytes) -> None:
        """An outsider's put, blocking rather than dropped when the link is congested."""
        self.outsider.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def close(self) -> None:
        for c in self.closers:
            c()
        for s in self.sessions:
            s.close()

    def changed(self) -> tuple[int, ...]:
        """What a malformed message must not change: everything applied anywhere."""
        return (
            len(self.statuses), len(self.bus.latest()), len(self.tasks), len(self.grants), len(self.controls),
            self.bus.received, self.bus.callback_errors, self.clock.updates, self.server.received,
            self.client.states_received,
        )  # fmt: skip


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    r = Rig(free_endpoint())
    r.setup()
    try:
        yield r
    finally:
        r.close()


# ----------------------------------------------------------------------------- valid samples

POSE = Pose2D(1.0, 2.0, 0.0)
STATUS = StatusRecord(
    robot="robot1", ns="/robot1", t=1.0, pose=(1.0, 2.0, 0.0), battery=0.9, charging=False, stuck=False,
    bt="RUNNING", leaf="Patrol", mode="patrol", task_id="p-0001", laps=1, progress=0.5, distance_m=3.0,
    collisions=0, seq=4,
)  # fmt: skip
TASK = TaskMessage(task_id="p-0001", kind="patrol", robot="robot1", poses=(POSE,), epoch=3, seq=2)
GRANT = Grant(
    "robot1", 1, 1, "a", ("b",), (POSE,), task_id="p-0001", purpose="patrol", laps=1, seq=5, epoch=3
)
CONTROL = FleetControl(estop=True, paused=True, seq=7)
CLOCK = ClockMsg(12.5, 250, 0.05, 1.0)
GOAL = GoalRequest("/robot1@x#1", "x", 1, goal_message(NavigateToPose(POSE)))
CANCEL = CancelRequest("/robot1@x#1")
STATE = NavState.build("robot1", 1.0, RobotState(POSE, 0.9, 0.0, 0.0, False, False, 0.0, 0), {})


@dataclass(frozen=True)
class Target:
    """A key, a valid payload for it, its size limit, its integer fields and its counter."""

    key: str
    valid: dict[str, Any]
    limit: int
    ints: tuple[str, ...]
    count: Callable[[Rig], int]


def _dict(msg: Any) -> dict[str, Any]:
    d: dict[str, Any] = json.loads(msg.to_json())
    return d


TARGETS = {
    "status": Target(status_key("robot1"), _dict(STATUS), MAX_PAYLOAD_BYTES, ("laps", "seq", "collisions"),
                     lambda r: r.bus.malformed),
    "task": Target(task_key("robot1"), _dict(TASK), MAX_PAYLOAD_BYTES, ("epoch", "seq"), lambda r: r.bus.malformed),
    "grant": Target(grant_key("robot1"), _dict(GRANT), MAX_PAYLOAD_BYTES, ("seq", "laps", "epoch"),
                    lambda r: r.bus.malformed),
    "control": Target(CONTROL_KEY, _dict(CONTROL), MAX_PAYLOAD_BYTES, ("seq",), lambda r: r.bus.malformed),
    "clock": Target(CLOCK_KEY, _dict(CLOCK), MAX_BRIDGE_PAYLOAD, ("step",), lambda r: r.clock.malformed),
    "nav-goal": Target(nav_key("/robot1", "goal"), _dict(GOAL), MAX_BRIDGE_PAYLOAD, ("seq",),
                       lambda r: r.server.malformed),
    "nav-cancel": Target(nav_key("/robot1", "cancel"), _dict(CANCEL), MAX_BRIDGE_PAYLOAD, (),
                         lambda r: r.server.malformed),
    "nav-state": Target(nav_key("/robot1", "state"), _dict(STATE), MAX_BRIDGE_PAYLOAD, (),
                        lambda r: r.client.malformed),
}  # fmt: skip


def _with(valid: dict[str, Any], name: str, raw: bytes) -> bytes:
    """The valid payload's JSON with field ``name`` set to the raw JSON text ``raw``."""
    marker = "\u0000FUZZ\u0000"
    text = json.dumps({**valid, name: marker}).encode()
    return text.replace(json.dumps(marker).encode(), raw)


def garbage(t: Target) -> st.SearchStrategy[bytes]:
    """Payloads that must all be malformed for ``t``'s key."""
    text = json.dumps(t.valid).encode()
    fields = st.sampled_from(sorted(t.valid))

    def not_an_object(b: bytes) -> bool:
        try:
            return not isinstance(json.loads(b), dict)
        except (ValueError, RecursionError):
            return True

    strategies: list[st.SearchStrategy[bytes]] = [
        st.binary(max_size=64).filter(not_an_object),  # garbage bytes
        st.integers(0, len(text) - 1).map(lambda n: text[:n]),  # truncated
        st.tuples(fields, st.integers(100, 20000)).map(  # deeply nested
            lambda fd: _with(t.valid, fd[0], b"[" * fd[1] + b"]" * fd[1])
        ),
        fields.filter(lambda f: f != "goals").map(lambda f: _with(t.valid, f, b'{"wrong": "type"}')),
        st.tuples(fields, st.sampled_from([b"NaN", b"Infinity", b"-Infinity", b"1e999", b"-1e999"])).map(
            lambda fv: _with(t.valid, fv[0], fv[1])
        ),
        st.integers(t.limit + 1, t.limit + 4096).map(lambda n: _with(t.valid, "pad", b'"' + b"x" * n + b'"')),
    ]
    if t.ints:  # integers the wire cannot carry (2^64, 10^30) or below zero
        huge = st.sampled_from([b"18446744073709551616", b"1" + b"0" * 30, b"-1"])
        strategies.append(
            st.tuples(st.sampled_from(t.ints), huge).map(lambda fv: _with(t.valid, fv[0], fv[1]))
        )
    seqs = [f for f in ("epoch", "seq") if f in t.valid and t.key.endswith(("/task", "/grant"))]
    if seqs:  # an epoch or seq above 2^53 (2^62 locked robots out before)
        big = st.sampled_from([b"4611686018427387904", b"9007199254740993"])
        strategies.append(st.tuples(st.sampled_from(seqs), big).map(lambda fv: _with(t.valid, fv[0], fv[1])))
    return st.one_of(strategies)


def _fuzz_key(rig: Rig, name: str, data: st.DataObject) -> None:
    t = TARGETS[name]
    payload = data.draw(garbage(t), label="payload")
    before, count = rig.changed(), t.count(rig)
    rig.put(t.key, payload)
    wait_until(lambda: t.count(rig) >= count + 1, f"the malformed {name} message to be counted")
    assert t.count(rig) == count + 1
    assert rig.changed() == before  # nothing applied, nothing half-applied


@pytest.mark.parametrize("name", sorted(TARGETS))
@settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(data=st.data())
def test_malformed_payloads_are_counted_and_dropped(rig: Rig, name: str, data: st.DataObject) -> None:
    _fuzz_key(rig, name, data)


def test_receivers_still_work_after_the_garbage(rig: Rig) -> None:
    """After the fuzzing, valid messages still arrive and apply (no subscription died)."""
    rig.put(status_key("robot1"), STATUS.to_json())
    rig.put(task_key("robot1"), TASK.to_json())
    rig.put(grant_key("robot1"), GRANT.to_json())
    rig.put(CLOCK_KEY, CLOCK.to_json())
    wait_until(lambda: bool(rig.statuses and rig.tasks and rig.grants), "valid messages")
    wait_until(lambda: rig.clock.now() == 12.5, "the valid clock")
    assert rig.statuses[-1] == STATUS and rig.tasks[-1] == TASK and rig.grants[-1] == GRANT
    assert rig.bus.callback_errors == 0


@settings(
    max_examples=10,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(name=st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,40}", fullmatch=True))
def test_liveliness_tokens_of_any_robot_name_come_and_go(rig: Rig, name: str) -> None:
    joined: list[str] = []
    left: list[str] = []
    h = rig.bus.watch_alive(joined.append, left.append)
    try:
        token = rig.outsider.liveliness().declare_token(f"fleet/{name}/alive")
        wait_until(lambda: name in joined, "the join")
        token.undeclare()
        wait_until(lambda: name in left, "the leave")
        assert rig.bus.callback_errors == 0 and name not in rig.bus.alive()
    finally:
        h.undeclare()
