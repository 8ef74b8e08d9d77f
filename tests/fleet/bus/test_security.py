"""The secured bus on real Zenoh sessions (loopback, scouting off): ``fleet keys init``'s
key directory, authentication at the router, and the access control generated from
``fleet.bus.keys.ACCESS`` (a robot publishes only for itself, only the coordinator commands,
the observer only reads)."""

from __future__ import annotations

import json
import logging
import stat
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
from bus_peer import record
from ports import pick_free_port

from fleet.bus.access import describe
from fleet.bus.keyring import Keyring, init_keyring
from fleet.bus.keys import (
    CLOCK_KEY,
    CONTROL_KEY,
    access_of,
    alive_key,
    grant_key,
    nav_key,
    status_key,
    task_key,
)
from fleet.bus.session import Secure, open_session
from fleet.bus.status_bus import StatusBus
from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.errors import BusError
from fleet.messages import TaskMessage
from fleet.service.bus_face import ServiceBus
from fleet.service.service import TaskService

ROBOTS = ["robot1", "robot2"]
#: Hang guard for one delivery (wall s) on a loaded 2-core machine.
DEADLINE_S = 30.0


class Inbox:
    """Every sample received by one session's subscriptions, by key; :meth:`wait` waits for a
    key with a deadline."""

    def __init__(self) -> None:
        self.got: list[tuple[str, bytes]] = []
        self._cond = threading.Condition()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._cond:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))
            self._cond.notify_all()

    def keys(self) -> list[str]:
        with self._cond:
            return [k for k, _ in self.got]

    def payloads(self, key: str) -> list[bytes]:
        with self._cond:
            return [p for k, p in self.got if k == key]

    def wait(self, key: str, payload: bytes) -> None:
        deadline = time.monotonic() + DEADLINE_S
        with self._cond:
            while (key, payload) not in self.got:
                left = deadline - time.monotonic()
                assert left > 0, f"{key} {payload!r} never arrived; got {self.got}"
                self._cond.wait(left)


@pytest.fixture
def keys(tmp_path: Path, zenoh_endpoint: str) -> Path:
    init_keyring(tmp_path / "keys", ROBOTS, zenoh_endpoint)
    return tmp_path / "keys"


@pytest.fixture
def bus(keys: Path, zenoh_endpoint: str) -> Iterator[Callable[[str], zenoh.Session]]:
    """The secured router (on ``zenoh_endpoint``), and ``connect(identity)`` for client
    sessions; every session is closed at the end."""
    sessions = [open_session(zenoh_endpoint, "router", secure=Secure(keys, "router"))]

    def connect(identity: str) -> zenoh.Session:
        s = open_session(zenoh_endpoint, "client", secure=Secure(keys, identity), connect_timeout_s=10.0)
        sessions.append(s)
        return s

    yield connect
    for s in reversed(sessions):
        s.close()  # type: ignore[no-untyped-call]


def settle(pub: zenoh.Session, key: str, inbox: Inbox) -> None:
    """Put markers on ``key`` (allowed) until ``inbox`` has one: the subscriptions have
    reached the router. Later puts from ``pub`` arrive after the marker, in order."""
    deadline = time.monotonic() + DEADLINE_S
    n = 0
    while not inbox.payloads(key):
        assert time.monotonic() < deadline, f"no marker on {key} arrived"
        n += 1
        pub.put(key, f"marker{n}".encode())
        time.sleep(0.05)


def test_keys_init_writes_secret_files_that_plain_zenoh_opens(keys: Path, zenoh_endpoint: str) -> None:
    names = sorted(p.name for p in keys.iterdir())
    assert names == sorted(
        ["robot1.json5", "robot2.json5", "coordinator.json5", "simulator.json5", "observer.json5", "worker.json5",
         "router.json5", "router.passwords", "api.token"]
    )  # fmt: skip
    assert stat.S_IMODE(keys.stat().st_mode) == 0o700
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in keys.iterdir())
    passwords = dict(line.split(":", 1) for line in (keys / "router.passwords").read_text().split())
    assert len(set(passwords.values())) == len(passwords) == 7  # router + 6 identities, all different
    assert all(len(p) >= 32 for p in passwords.values())
    # the files as they are, with nothing of ours: a router and a client that talk
    router = zenoh.open(zenoh.Config.from_file(keys / "router.json5"))
    try:
        client = zenoh.open(zenoh.Config.from_file(keys / "robot1.json5"))
        inbox = Inbox()
        sub = router.declare_subscriber("fleet/**", inbox)
        settle(client, status_key("robot1"), inbox)
        sub.undeclare()
        client.close()  # type: ignore[no-untyped-call]
    finally:
        router.close()  # type: ignore[no-untyped-call]


def test_the_router_enforces_exactly_the_key_table(keys: Path) -> None:
    """Read back from the written router config, each identity may do what ``ACCESS`` says
    for its role and nothing else."""
    rights = describe(Keyring(keys).access())
    assert set(rights) == {*ROBOTS, "coordinator", "simulator", "observer", "worker"}
    verbs = {"put": "publishes", "subscribe": "receives", "token": "holds", "watch": "watches", "serve": "serves",
             "query": "asks"}  # fmt: skip
    for identity, role, robot in [
        *(("r", "robot", r) for r in ROBOTS),
        ("coordinator", "coordinator", None),
        ("simulator", "simulator", None),
        ("observer", "observer", None),
        ("worker", "worker", None),
    ]:
        name = robot or identity
        want: dict[str, set[str]] = {}
        for u in access_of(role, robot):  # type: ignore[arg-type]
            want.setdefault(verbs[u.use], set()).add(u.key)
        assert {v: set(k) for v, k in rights[name].items()} == want, name
    assert set(rights["observer"]) == {"receives", "watches", "asks"}  # reads only


def test_keys_init_refuses_to_overwrite_and_bad_names(keys: Path, zenoh_endpoint: str) -> None:
    before = (keys / "robot1.json5").read_text()
    with pytest.raises(BusError, match=r"robot1\.json5 exists; pass --force"):
        init_keyring(keys, ROBOTS, zenoh_endpoint)
    assert (keys / "robot1.json5").read_text() == before
    init_keyring(keys, ROBOTS, zenoh_endpoint, force=True)
    assert (keys / "robot1.json5").read_text() != before  # new passwords
    for bad in (["coordinator"], ["sim"], ["robot1", "robot1"], ["a/b"]):
        with pytest.raises(ValueError, match="robot name"):
            init_keyring(keys.parent / "other", bad, zenoh_endpoint)
    assert not (keys.parent / "other").exists()


def test_unauthenticated_and_wrong_keys_are_refused(
    keys: Path, tmp_path: Path, zenoh_endpoint: str, bus: Callable[[str], zenoh.Session]
) -> None:
    with pytest.raises(BusError, match="no Zenoh router at"):
        open_session(zenoh_endpoint, "client", connect_timeout_s=1.0)
    other = tmp_path / "other"
    init_keyring(other, ROBOTS, zenoh_endpoint)  # another fleet's keys: same names, other passwords
    with pytest.raises(BusError) as e:
        open_session(zenoh_endpoint, "client", secure=Secure(other, "robot1"), connect_timeout_s=1.0)
    assert "identity 'robot1'" in str(e.value) and zenoh_endpoint in str(e.value)
    assert "refused these credentials" in str(e.value)
    with pytest.raises(BusError, match=r"no identity file for 'robot9' .*robot9\.json5.*fleet keys init"):
        open_session(zenoh_endpoint, "client", secure=Secure(keys, "robot9"))
    bus("robot1")  # the right keys connect


def test_a_robot_publishes_only_for_itself(bus: Callable[[str], zenoh.Session]) -> None:
    r1, r2, coord, simulator = bus("robot1"), bus("robot2"), bus("coordinator"), bus("simulator")
    at_coord, at_r2, at_sim = Inbox(), Inbox(), Inbox()
    coord.declare_subscriber("fleet/*/status", at_coord)
    for key in (task_key("robot2"), grant_key("robot2"), CLOCK_KEY, CONTROL_KEY, nav_key("robot2", "state")):
        r2.declare_subscriber(key, at_r2)
    simulator.declare_subscriber("fleet/*/nav/goal", at_sim)  # as the nav server does
    simulator.declare_subscriber("fleet/*/nav/cancel", at_sim)
    settle(r1, status_key("robot1"), at_coord)
    settle(r1, nav_key("robot1", "goal"), at_sim)
    settle(coord, task_key("robot2"), at_r2)
    # robot1 acts for robot2 and as coordinator / simulator: all dropped at the router
    for key in (status_key("robot2"), nav_key("robot2", "goal"), nav_key("robot2", "cancel"), task_key("robot2"),
                grant_key("robot2"), CLOCK_KEY, CONTROL_KEY, nav_key("robot2", "state")):  # fmt: skip
        r1.put(key, b"forged")
    # through the StatusBus too (a declared publisher), then one allowed record as the end marker
    robot1_bus = StatusBus(r1)
    r1.put(status_key("robot1"), b"end")
    r1.put(nav_key("robot1", "cancel"), b"end")
    at_coord.wait(status_key("robot1"), b"end")
    at_sim.wait(nav_key("robot1", "cancel"), b"end")
    coord.put(task_key("robot2"), b"end")
    at_r2.wait(task_key("robot2"), b"end")
    assert b"forged" not in at_coord.payloads(status_key("robot2"))
    assert all(p != b"forged" for _, p in at_r2.got), at_r2.got
    assert all(p != b"forged" for _, p in at_sim.got), at_sim.got
    robot1_bus.close()


def test_status_bus_publishers_deliver_what_is_allowed(bus: Callable[[str], zenoh.Session]) -> None:
    """A declared publisher (what the fleet uses) needs to see its subscribers: robot1's
    status records and the coordinator's orders arrive through StatusBus on both sides."""
    r1, coord = StatusBus(bus("robot1")), StatusBus(bus("coordinator"))
    coord.subscribe_statuses()
    coord.watch_alive()
    orders: list[TaskMessage] = []
    r1.subscribe_tasks("robot1", orders.append)
    r1.declare_alive("robot1")
    deadline = time.monotonic() + DEADLINE_S
    rec = record("robot1", 1)
    while "robot1" not in coord.latest() or not orders or "robot1" not in coord.alive():
        assert time.monotonic() < deadline, (coord.latest(), orders, coord.alive())
        r1.publish_status(rec)
        coord.publish_task(TaskMessage("i-0001", "idle", "robot1"))
        time.sleep(0.05)
    assert coord.malformed == r1.malformed == 0
    r1.close()
    coord.close()


def test_the_observer_reads_but_cannot_command(bus: Callable[[str], zenoh.Session]) -> None:
    r1, obs, coord = bus("robot1"), bus("observer"), bus("coordinator")
    at_r1, at_obs = Inbox(), Inbox()
    for key in (task_key("robot1"), grant_key("robot1"), CONTROL_KEY, CLOCK_KEY, nav_key("robot1", "state")):
        r1.declare_subscriber(key, at_r1)
    for key in ("fleet/*/status", "fleet/*/task", "fleet/**"):  # orders: denied
        obs.declare_subscriber(key, at_obs)
    settle(r1, status_key("robot1"), at_obs)  # the observer sees statuses
    settle(coord, CONTROL_KEY, at_r1)
    for key in (task_key("robot1"), grant_key("robot1"), CONTROL_KEY, CLOCK_KEY, nav_key("robot1", "state"),
                status_key("robot1"), "fleet/service/submit"):  # fmt: skip
        obs.put(key, b"forged")
    coord.put(task_key("robot1"), b"end")
    at_r1.wait(task_key("robot1"), b"end")
    assert all(p != b"forged" for _, p in at_r1.got), at_r1.got
    # the observer does not see orders (only statuses, control, liveliness, task events); its
    # own puts it sees, as every session sees its own (they never left it)
    r1.put(status_key("robot1"), b"end")
    at_obs.wait(status_key("robot1"), b"end")
    assert b"end" not in at_obs.payloads(task_key("robot1"))
    # liveliness: an identity holds only its own token; the observer watches them
    alive: list[str] = []
    obs.liveliness().declare_subscriber(
        "fleet/*/alive", lambda s: alive.append(str(s.key_expr)), history=True
    )
    # held in names: a token whose object is dropped is undeclared at once (on a busy machine
    # the observer then saw neither its declaration nor its end)
    forged = r1.liveliness().declare_token(alive_key("robot2"))  # dropped by the router
    own = r1.liveliness().declare_token(alive_key("robot1"))
    deadline = time.monotonic() + DEADLINE_S
    while alive_key("robot1") not in alive:
        assert time.monotonic() < deadline, alive
        time.sleep(0.02)
    assert alive_key("robot2") not in alive
    forged.undeclare()
    own.undeclare()


def test_service_queries_reads_for_the_observer_commands_for_nobody(
    bus: Callable[[str], zenoh.Session],
) -> None:
    coord, obs = bus("coordinator"), bus("observer")
    asked: list[str] = []

    def answer(q: zenoh.Query) -> None:
        asked.append(str(q.key_expr))
        q.reply(q.key_expr, json.dumps({"ok": str(q.key_expr)}))

    for key in ("fleet/service/robots", "fleet/service/submit", "fleet/service/command/*"):
        coord.declare_queryable(key, answer)
    deadline = time.monotonic() + DEADLINE_S
    got: list[str] = []
    while not got:
        assert time.monotonic() < deadline, "the observer's read query was never answered"
        got = [r.ok.payload.to_string() for r in obs.get("fleet/service/robots", timeout=2.0) if r.ok]
    assert "fleet/service/robots" in got[0]
    for key in ("fleet/service/submit", "fleet/service/command/estop"):
        replies = [r for r in obs.get(key, payload=b"{}", timeout=1.0) if r.ok]
        assert replies == []
    assert asked.count("fleet/service/submit") == 0 and "fleet/service/command/estop" not in asked


def test_task_events_reach_the_observer_through_the_secured_router(
    bus: Callable[[str], zenoh.Session],
) -> None:
    """The coordinator's service face sends task events only while a subscriber matches: the
    secured router tells it of the observer's subscription, and the observer gets the event."""
    coord, obs = bus("coordinator"), bus("observer")
    service = TaskService(
        load_config(Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"), SimClock()
    )
    face = ServiceBus(coord, service)
    inbox = Inbox()
    try:
        assert not face.matching
        obs.declare_subscriber("fleet/service/events/*", inbox)
        deadline = time.monotonic() + DEADLINE_S
        while not face.matching:
            assert time.monotonic() < deadline, "the coordinator never heard of the observer's subscription"
            time.sleep(0.02)
        t = service.submit({"kind": "go_to", "target": "a2_n"}, by="test")
        deadline = time.monotonic() + DEADLINE_S
        while not inbox.payloads(f"fleet/service/events/{t.id}"):
            assert time.monotonic() < deadline, "the observer never got the task event"
            time.sleep(0.02)
        (payload,) = inbox.payloads(f"fleet/service/events/{t.id}")
        assert json.loads(payload)["event"]["event"] == "queued"
    finally:
        face.close()


def test_router_config_follows_the_directory(keys: Path, tmp_path: Path, zenoh_endpoint: str) -> None:
    moved = tmp_path / "moved"
    keys.rename(moved)
    ring = Keyring(moved)
    c = ring.router_config(zenoh_endpoint)
    assert json.loads(c.get_json("transport/auth/usrpwd/dictionary_file")) == str(moved / "router.passwords")
    with pytest.raises(BusError, match=r"no API token .*api\.token"):
        Keyring(tmp_path / "nowhere").api_token()


def test_tls_keys_need_the_identity_s_own_certificate(tmp_path: Path, zenoh_endpoint: str) -> None:
    """``--tls``: the bus runs on ``tls/`` with mutual TLS; the files open with plain Zenoh; a
    session without a client certificate is refused, and one with robot1's password but
    robot2's certificate connects but may do nothing."""
    keys = tmp_path / "keys"
    ring = init_keyring(keys, ROBOTS, zenoh_endpoint, tls=True)
    tls_ep = zenoh_endpoint.replace("tcp/", "tls/")
    assert ring.tls and ring.endpoint(zenoh_endpoint) == tls_ep
    assert stat.S_IMODE((keys / "tls").stat().st_mode) == 0o700
    assert all(stat.S_IMODE(p.stat().st_mode) == 0o600 for p in (keys / "tls").iterdir())
    assert sorted(p.name for p in (keys / "tls").iterdir()) == sorted(
        ["ca.pem"] + [f"{n}.{x}" for n in ("router", *ROBOTS, "coordinator", "simulator", "observer", "worker")
                      for x in ("pem", "key")]
    )  # fmt: skip
    assert json.loads(ring.client_config("robot1").get_json("connect/endpoints")) == [tls_ep]
    router = zenoh.open(zenoh.Config.from_file(keys / "router.json5"))
    sessions: list[zenoh.Session] = []
    try:
        inbox = Inbox()
        router.declare_subscriber("fleet/*/status", inbox)
        good = zenoh.open(zenoh.Config.from_file(keys / "robot1.json5"))
        sessions.append(good)
        settle(good, status_key("robot1"), inbox)
        no_cert = ring.client_config("robot1")
        no_cert.insert_json5(
            "transport/link/tls", json.dumps({"root_ca_certificate": str(keys / "tls/ca.pem")})
        )
        no_cert.insert_json5("connect/timeout_ms", "1000")
        with pytest.raises(zenoh.ZError):
            sessions.append(zenoh.open(no_cert))
        swapped = ring.client_config("robot1")  # robot1's password, robot2's certificate
        swapped.insert_json5(
            "transport/link/tls/connect_certificate", json.dumps(str(keys / "tls/robot2.pem"))
        )
        swapped.insert_json5(
            "transport/link/tls/connect_private_key", json.dumps(str(keys / "tls/robot2.key"))
        )
        thief = zenoh.open(swapped)
        sessions.append(thief)
        thief.put(status_key("robot1"), b"forged")
        thief.put(status_key("robot2"), b"forged")
        good.put(status_key("robot1"), b"end")
        inbox.wait(status_key("robot1"), b"end")
        assert all(p != b"forged" for _, p in inbox.got)
        # the fleet's own path: open_session on the key directory, with a tcp/ endpoint given
        s = open_session(zenoh_endpoint, "client", secure=Secure(keys, "robot2"), connect_timeout_s=10.0)
        sessions.append(s)
        settle(s, status_key("robot2"), inbox)
    finally:
        for s in sessions:
            s.close()  # type: ignore[no-untyped-call]
        router.close()  # type: ignore[no-untyped-call]


def test_a_bus_on_another_endpoint_than_the_keys_is_named_once(
    keys: Path, zenoh_endpoint: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Keys made for one endpoint, a router run on another (the config's ``bus.endpoint``):
    the fleet follows its bus and says once that the identity files point elsewhere."""
    other = f"tcp/127.0.0.1:{pick_free_port()}"
    with caplog.at_level(logging.WARNING, logger="fleet.bus.session"):
        open_session(zenoh_endpoint, "router", secure=Secure(keys, "router")).close()  # type: ignore[no-untyped-call]
        assert not caplog.records  # the keys' own endpoint: nothing to say
        for _ in range(2):
            open_session(other, "router", secure=Secure(keys, "router")).close()  # type: ignore[no-untyped-call]
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1, warned
    assert zenoh_endpoint in warned[0] and other in warned[0] and "--endpoint" in warned[0]
