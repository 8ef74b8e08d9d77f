"""The Zenoh status bus: records, malformed payloads, liveliness, across processes."""

from __future__ import annotations

import json
import subprocess
import time
from collections.abc import Callable

import pytest
import zenoh
from bus_peer import record

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.errors import BusError
from fleet.messages import StatusRecord, TaskMessage
from fleet.types import Pose2D


def _until(pred: Callable[[], bool], timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


def _ready(p: subprocess.Popen[str]) -> None:
    assert p.stdout is not None
    line = p.stdout.readline()
    assert line.strip() == "ready", line


def test_status_record_round_trip_and_field_errors() -> None:
    rec = record("robot1", 3)
    assert StatusRecord.from_json(rec.to_json()) == rec
    d = json.loads(rec.to_json())
    for field, bad, needle in [
        ("battery", "full", "status.battery"),
        ("laps", 1.5, "status.laps"),
        ("charging", 1, "status.charging"),
        ("pose", [1, 2], "status.pose"),
        ("v", 2, "status.v"),
        ("t", None, "status.t"),
    ]:
        with pytest.raises(ValueError, match=needle.replace(".", r"\.")):
            StatusRecord.from_json(json.dumps({**d, field: bad}))
    del d["seq"]
    with pytest.raises(ValueError, match=r"seq: missing"):
        StatusRecord.from_json(json.dumps(d))
    msg = TaskMessage("p-1", "patrol", "robot1", "loop", (Pose2D(1, 2, 0), Pose2D(3, 4, 1)), Pose2D(0, 0, 0))
    assert TaskMessage.from_json(msg.to_json()) == msg
    with pytest.raises(ValueError, match=r"task\.poses\[0\]"):
        TaskMessage.from_json(b'{"v":1,"task_id":"p-8","kind":"patrol","poses":[[1,2]]}')
    with pytest.raises(ValueError, match=r"task\.kind"):
        TaskMessage.from_json(json.dumps({"v": 1, "task_id": "x", "kind": "dance"}))


def test_statuses_cross_processes_router_to_client(spawn, zenoh_endpoint: str) -> None:
    robots = [f"robot{i}" for i in range(1, 7)]
    with open_session(zenoh_endpoint, "router") as session:
        bus = StatusBus(session)
        try:
            seen: list[StatusRecord] = []
            bus.subscribe_statuses(seen.append)
            bus.watch_alive()
            p = spawn(["tests/helpers/bus_peer.py", "status", zenoh_endpoint, ",".join(robots), "20", "100"])
            _ready(p)
            assert _until(
                lambda: all(r.seq == 20 for r in bus.latest().values()) and len(bus.latest()) == 6, 10
            )
            latest = bus.latest()
            assert sorted(latest) == robots
            assert latest["robot4"] == record("robot4", 20)
            assert bus.alive() == set(robots)
            assert bus.malformed == 0
            assert bus.received >= 6 * 15  # a few of the first may precede the subscription
            events = bus.drain_events()
            assert {e.kind for e in events} == {"status", "join"}
            assert bus.drain_events() == []
        finally:
            bus.shutdown()


MALFORMED: list[bytes] = [
    b"not json at all",
    b"\xff\xfe\x00garbage",
    b"[1, 2, 3]",
    b'{"v": 1}',
    b"{" * 100000,
    json.dumps({**json.loads(record("x", 1).to_json()), "battery": "high"}).encode(),
    json.dumps({**json.loads(record("x", 1).to_json()), "v": 99}).encode(),
    json.dumps({**json.loads(record("x", 1).to_json()), "robot": "somebody_else"}).encode(),
    b'{"v":1,"pad":"' + b"a" * (2 * 1024 * 1024) + b'"}',
]


def test_malformed_statuses_and_tasks_are_counted_and_dropped(zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as router, open_session(zenoh_endpoint, "client") as client:
        sub = StatusBus(router)
        pub = StatusBus(client)
        try:
            got: list[StatusRecord] = []
            tasks: list[TaskMessage] = []
            sub.subscribe_statuses(got.append)
            sub.subscribe_tasks("x", tasks.append)
            time.sleep(0.2)
            block = zenoh.CongestionControl.BLOCK  # a burst with 2 MB payloads: do not drop
            for i, payload in enumerate(MALFORMED):
                client.put("fleet/x/status", payload, congestion_control=block)
                client.put("fleet/x/task", payload, congestion_control=block)
                client.put("fleet/x/status", record("x", i + 1).to_json(), congestion_control=block)
            client.put(
                "fleet/x/task",
                b'{"v":1,"task_id":"p-8","kind":"patrol","poses":[[1,2]]}',
                congestion_control=block,
            )
            n_bad = 2 * len(MALFORMED) + 1
            assert _until(lambda: sub.malformed == n_bad and len(got) == len(MALFORMED), 10), (
                sub.malformed,
                sub.last_malformed,
                len(got),
            )
            # the bus still works after the burst: statuses and tasks through StatusBus
            pub.publish_status(record("x", 100))
            pub.publish_task("x", TaskMessage("p-7", "patrol", None, "r", (Pose2D(1, 1, 0),)))
            assert _until(lambda: len(got) == len(MALFORMED) + 1 and bool(tasks), 5)
            assert sub.malformed == n_bad
            assert [r.seq for r in got] == [*range(1, len(MALFORMED) + 1), 100]
            assert tasks[0].task_id == "p-7" and tasks[0].robot == "x"
            assert sub.last_malformed is not None and sub.last_malformed.startswith("fleet/x/")
        finally:
            pub.shutdown()
            sub.shutdown()


def test_callback_exception_is_counted_not_raised(zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as session:
        bus = StatusBus(session)
        try:
            ok: list[int] = []

            def boom(rec: StatusRecord) -> None:
                raise RuntimeError("callback bug")

            bus.subscribe_statuses(boom)
            bus.subscribe_statuses(lambda r: ok.append(r.seq))
            for i in range(1, 4):
                bus.publish_status(record("robot1", i))
            assert _until(lambda: len(ok) == 3, 5)
            assert bus.callback_errors == 3 and "callback bug" in (bus.last_callback_error or "")
        finally:
            bus.shutdown()


def test_liveliness_leave_is_seen_within_a_second_of_sigkill(spawn, zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as session:
        bus = StatusBus(session)
        try:
            left: dict[str, float] = {}

            def on_leave(robot: str) -> None:
                left.setdefault(robot, time.monotonic())

            bus.watch_alive(None, on_leave)
            p = spawn(["tests/helpers/bus_peer.py", "alive", zenoh_endpoint, "robot9"])
            _ready(p)
            assert _until(lambda: "robot9" in bus.alive(), 5)
            t_kill = time.monotonic()
            p.kill()
            p.wait(5)
            assert _until(lambda: "robot9" in left, 2.0)
            latency = left["robot9"] - t_kill
            print(f"liveliness leave latency after SIGKILL: {latency * 1000:.1f} ms")
            assert latency < 2.0
            assert bus.alive() == set()
        finally:
            bus.shutdown()


def test_open_session_errors_are_clear(zenoh_endpoint: str) -> None:
    with pytest.raises(BusError, match="no Zenoh router at"):
        open_session(zenoh_endpoint, "client", connect_timeout_s=0.3)
    with open_session(zenoh_endpoint, "router"):
        with pytest.raises(BusError, match="in use"):
            open_session(zenoh_endpoint, "router")
    with pytest.raises(BusError, match="bad Zenoh endpoint"):
        open_session("127.0.0.1:7447", "router")
