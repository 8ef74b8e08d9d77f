"""The Zenoh status bus: records, malformed payloads, liveliness, across processes."""

from __future__ import annotations

import json
import subprocess
import time

import pytest
import zenoh
from bus_peer import record, settle, wait_until

from fleet.bus.keys import grant_key, status_key, task_key
from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.errors import BusError
from fleet.messages import Grant, StatusRecord, TaskMessage
from fleet.types import Pose2D


def _ready(p: subprocess.Popen[str]) -> None:
    assert p.stdout is not None
    line = p.stdout.readline()
    assert line.strip() == "ready", line


def test_status_record_round_trip_and_field_errors() -> None:
    rec = record("robot1", 3)
    assert StatusRecord.from_json(rec.to_json()) == rec
    d = json.loads(rec.to_json())
    for field, bad, needle in [
        ("battery", "full", "status.battery: expected a finite number, got 'full'"),
        ("laps", 1.5, "status.laps: expected an integer, got 1.5"),
        ("charging", 1, "status.charging: expected true or false, got 1"),
        ("pose", [1, 2], "status.pose: expected [x, y, theta] of 3 finite numbers"),
        ("v", 2, "status.v: unsupported version 2 (expected 1)"),
        ("t", None, "status.t: expected a finite number"),
    ]:
        with pytest.raises(ValueError) as err:
            StatusRecord.from_json(json.dumps({**d, field: bad}))
        assert str(err.value).startswith(needle), (field, str(err.value))
    del d["seq"]
    with pytest.raises(ValueError, match=r"^status\.seq: missing$"):
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
            wait_until(
                lambda: len(bus.latest()) == 6 and all(r.seq == 20 for r in bus.latest().values()),
                30,
                "the 20th record of 6 robots",
            )
            latest = bus.latest()
            assert sorted(latest) == robots
            assert latest["robot4"] == record("robot4", 20)
            wait_until(lambda: bus.alive() == set(robots), 30, "6 liveliness tokens")
            assert bus.malformed == 0
            assert bus.received >= 6 * 15  # a few of the first may precede the subscription
            events = bus.drain_events()
            assert {e.kind for e in events} == {"status", "join"}
            assert bus.drain_events() == []
        finally:
            bus.shutdown()


def _status(**changes: object) -> bytes:
    return json.dumps({**json.loads(record("x", 1).to_json()), **changes}).encode()


#: Malformed on every key (status, task and grant): each is counted and dropped.
MALFORMED: list[bytes] = [
    b"not json at all",
    b"\xff\xfe\x00garbage",
    b"[1, 2, 3]",
    b'{"v": 1}',
    b"{" * 100000,
    b'{"v": 1, "robot": "x", "t": NaN}',
    _status(battery="high"),
    _status(battery=1e999),
    _status(v=99),
    _status(v="1"),
    _status(robot="somebody_else"),
    _status(laps=-1),
    b'{"v":1,"pad":"' + b"a" * (2 * 1024 * 1024) + b'"}',
]


def test_malformed_statuses_tasks_and_grants_are_counted_and_dropped(zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as router, open_session(zenoh_endpoint, "client") as client:
        sub = StatusBus(router)
        pub = StatusBus(client)
        try:
            got: list[StatusRecord] = []
            tasks: list[TaskMessage] = []
            grants: list[Grant] = []
            sub.subscribe_statuses(got.append)
            sub.subscribe_tasks("x", tasks.append)
            sub.subscribe_grants("x", grants.append)
            block = zenoh.CongestionControl.BLOCK  # a burst with 2 MB payloads: do not drop
            idle = TaskMessage(None, "idle", "x").to_json()
            grant = Grant("x", 1, 0, "a", (), ()).to_json()
            settle(
                lambda: client.put(status_key("x"), record("x", 0).to_json()),
                lambda: bool(got),
                30,
                "a status",
            )
            settle(lambda: client.put(task_key("x"), idle), lambda: bool(tasks), 30, "a task")
            settle(lambda: client.put(grant_key("x"), grant), lambda: bool(grants), 30, "a grant")
            assert sub.malformed == 0

            def seqs() -> list[int]:  # a late warm-up copy (seq 0) may still arrive
                return [r.seq for r in got if r.seq > 0]

            for i, payload in enumerate(MALFORMED):
                for key in (status_key("x"), task_key("x"), grant_key("x")):
                    client.put(key, payload, congestion_control=block)
                client.put(status_key("x"), record("x", i + 1).to_json(), congestion_control=block)
            n_bad = 3 * len(MALFORMED)
            wait_until(
                lambda: sub.malformed == n_bad and len(seqs()) == len(MALFORMED),
                30,
                f"{n_bad} malformed and {len(MALFORMED)} valid (malformed {sub.malformed}: {sub.last_malformed})",
            )
            # each key has its own callback thread: the reason of one more bad task, after the burst
            client.put(task_key("x"), b'{"v":1,"task_id":"p-8","kind":"patrol","poses":[[1,2]]}')
            n_bad += 1
            wait_until(lambda: sub.malformed == n_bad, 30, "one more malformed task")
            assert sub.last_malformed == (
                "fleet/x/task: task.poses[0]: expected [x, y, theta] of 3 finite numbers, got [1, 2]"
            )
            # the bus still works after the burst: statuses and tasks through StatusBus
            pub.publish_status(record("x", 100))
            pub.publish_task("x", TaskMessage("p-7", "patrol", None, "r", (Pose2D(1, 1, 0),)))
            wait_until(
                lambda: len(seqs()) == len(MALFORMED) + 1 and tasks[-1].task_id == "p-7", 30, "the last two"
            )
            assert sub.malformed == n_bad
            assert seqs() == [*range(1, len(MALFORMED) + 1), 100]
            assert tasks[-1].robot == "x"
            assert {t.task_id for t in tasks} == {None, "p-7"} and {g.path_id for g in grants} == {1}
        finally:
            pub.shutdown()
            sub.shutdown()


def test_robot_of_the_record_must_match_the_key(zenoh_endpoint: str) -> None:
    with open_session(zenoh_endpoint, "router") as session:
        bus = StatusBus(session)
        try:
            got: list[StatusRecord] = []
            bus.subscribe_statuses(got.append)
            session.put(status_key("robot2"), record("robot1", 1).to_json())
            session.put(status_key("robot2"), record("robot2", 2).to_json())
            wait_until(lambda: bool(got), 20, "the matching record")
            assert [r.robot for r in got] == ["robot2"]
            assert bus.malformed == 1
            assert bus.last_malformed == (
                "fleet/robot2/status: status.robot: 'robot1' does not match the key's robot 'robot2'"
            )
        finally:
            bus.shutdown()


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
            wait_until(lambda: len(ok) == 3, 20, "3 records")
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
            wait_until(lambda: "robot9" in bus.alive(), 30, "robot9's token")
            t_kill = time.monotonic()
            p.kill()
            p.wait(5)
            wait_until(lambda: "robot9" in left, 10, "robot9's token to go")
            latency = left["robot9"] - t_kill
            print(f"liveliness leave latency after SIGKILL: {latency * 1000:.1f} ms")
            assert latency < 3.0  # the link lease (1 s) bounds it; a closed TCP link is faster
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


@pytest.mark.parametrize("wildcard", [False, True])
def test_early_orders_are_guarded_per_robot_or_by_wildcard_alike(zenoh_endpoint: str, wildcard: bool) -> None:
    """Before the agents subscribe, orders and grants for this process's robots are counted
    (valid ones in ``early``, bad ones in ``malformed`` with the key named); other robots' keys
    are not this process's business. Two wildcard subscribers count what one per key counts."""
    with open_session(zenoh_endpoint, "router") as router, open_session(zenoh_endpoint, "client") as client:
        bus = StatusBus(router)
        try:
            guard = bus.guard_orders(["r1", "r2"], wildcard=wildcard)
            idle = TaskMessage(None, "idle", "r1").to_json()
            settle(lambda: client.put(task_key("r1"), idle), lambda: bus.early > 0, 30, "an early order")
            before = bus.early
            client.put(task_key("r9"), idle)  # not one of ours (sent first: the wildcard
            client.put(task_key("r9"), b"{not json")  # subscriber takes fleet/*/task in order)
            client.put(grant_key("r2"), Grant("r2", 1, 0, "a", (), ()).to_json())
            client.put(task_key("r2"), b"{not json")
            wait_until(lambda: bus.early == before + 1 and bus.malformed == 1, 30, "one grant, one bad task")
            assert bus.last_malformed.startswith("fleet/r2/task: ")
            guard.undeclare()
        finally:
            bus.shutdown()
        assert bus.malformed == 1


def test_order_publishers_declared_in_set_up_deliver_and_close(zenoh_endpoint: str) -> None:
    """Publishers declared ahead (a coordinator's set-up) carry each robot's orders, reliably,
    to another session; :meth:`StatusBus.close` undeclares them."""
    with open_session(zenoh_endpoint, "router") as router, open_session(zenoh_endpoint, "client") as client:
        agents = StatusBus(client)
        coordinator = StatusBus(router)
        try:
            names = [f"r{i}" for i in range(3)]
            got: dict[str, list[TaskMessage]] = {n: [] for n in names}
            for n in names:
                agents.subscribe_tasks(n, got[n].append)
            coordinator.declare_task_publishers(names)
            coordinator.declare_task_publishers(names)  # again: nothing new
            assert sorted(coordinator._publishers) == sorted(task_key(n) for n in names)
            settle(
                lambda: coordinator.publish_task("r0", TaskMessage(None, "idle", "r0")),
                lambda: bool(got["r0"]),
                30,
                "the first order",
            )
            for n in names:
                coordinator.publish_task(n, TaskMessage(f"t-{n}", "patrol", None, "loop", (Pose2D(1, 1, 0),)))
            wait_until(
                lambda: all(any(t.task_id == f"t-{n}" for t in got[n]) for n in names), 30, "every order"
            )
            assert all(t.robot == n for n in names for t in got[n])
            coordinator.close()
            assert coordinator._publishers == {}
        finally:
            coordinator.shutdown()
            agents.shutdown()
