"""A secured ``fleet run`` (in-process router with credentials and access control): the HTTP
API's mutating calls need the key directory's token (401 otherwise, nothing changes), reads
stay open; ``FleetClient`` and ``fleet task`` send the token with ``--secure DIR``; an
outsider on the bus with the observer identity cannot stop the fleet."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from conftest import DEADLINE_S, PATROL, REPO, wait_for
from ports import free_endpoint

from fleet.bus.keyring import init_keyring
from fleet.bus.keys import CONTROL_KEY, task_key
from fleet.bus.session import Secure, open_session
from fleet.client import FleetClient
from fleet.config.loader import load_config
from fleet.errors import ApiError
from fleet.messages import FleetControl, TaskMessage
from fleet.runtime.report import RunReport
from fleet.runtime.runner import FleetRunner
from fleet.viz.display import NullDisplay


class Secured:
    def __init__(self, runner: FleetRunner, keys: Path, endpoint: str, thread: threading.Thread) -> None:
        self.runner, self.keys, self.endpoint, self.thread = runner, keys, endpoint, thread
        self.report: list[RunReport] = []
        assert runner.host is not None and runner.host.api is not None
        self.url = runner.host.api.url
        self.token = (keys / "api.token").read_text().strip()


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[Secured]:
    ep = free_endpoint()
    cfg = load_config(PATROL, robots=2)
    keys = tmp_path / "keys"
    init_keyring(keys, [r.name for r in cfg.robots], ep)
    runner = FleetRunner(
        cfg, duration=None, speed=1.0, endpoint=ep, display=NullDisplay(), state_dir=tmp_path / "state",
        api="127.0.0.1:0", tree_kind="picking", secure=Secure(keys, "router"),
    )  # fmt: skip
    report: list[RunReport] = []
    thread = threading.Thread(target=lambda: report.append(runner.run()), daemon=True)
    thread.start()
    wait_for(lambda: runner.host is not None and runner.host.api is not None or not thread.is_alive(), "API")
    assert thread.is_alive()
    fleet = Secured(runner, keys, ep, thread)
    fleet.report = report
    yield fleet
    runner.stop()
    thread.join(DEADLINE_S)
    assert not thread.is_alive(), "the fleet did not stop"


def test_mutating_calls_need_the_token(secured: Secured) -> None:
    with httpx.Client(base_url=secured.url, timeout=30.0) as http:
        assert http.get("/api/fleet").status_code == 200  # reads are open (loopback)
        assert http.get("/api/robots").status_code == 200
        before = len(http.get("/api/tasks").json())
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Basic {secured.token}"}):
            r = http.post("/api/tasks", json={"kind": "go_to", "target": "a3_n"}, headers=headers)
            assert r.status_code == 401, r.text
            assert r.json()["field"] == "Authorization" and "token" in r.json()["error"]
            assert r.headers["www-authenticate"] == "Bearer"
            assert http.post("/api/fleet/estop", headers=headers).status_code == 401
        assert len(http.get("/api/tasks").json()) == before  # nothing was submitted
        assert http.get("/api/fleet").json()["control"]["state"] == "running"
        r = http.post(
            "/api/tasks",
            json={"kind": "go_to", "target": "a3_n"},
            headers={"Authorization": f"Bearer {secured.token}"},
        )
        assert r.status_code == 201, r.text
    # the Python client and the CLI
    with pytest.raises(ApiError) as e:
        FleetClient(secured.url).pause("no token")
    assert e.value.status == 401
    assert FleetClient(secured.url, token=secured.token).pause("with the token")["state"] == "paused"
    api = secured.url.removeprefix("http://")
    cli = [sys.executable, "-m", "fleet.cli"]
    r = subprocess.run([*cli, "resume", "--api", api], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "401" in r.stderr and "Bearer" in r.stderr, r.stderr
    r = subprocess.run(
        [*cli, "resume", "--api", api, "--secure", str(secured.keys)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert FleetClient(secured.url).fleet()["control"]["state"] == "running"


def test_an_observer_on_the_bus_cannot_command_the_fleet(secured: Secured) -> None:
    session = open_session(
        secured.endpoint, "client", secure=Secure(secured.keys, "observer"), connect_timeout_s=30.0
    )
    try:
        # the fleet's robots got work from the coordinator
        agents = secured.runner.agents
        wait_for(lambda: len(agents) == 2 and all(a.bb.task_id for a in agents), "both robots' first orders")
        for a in agents:  # what stopped a whole open fleet: an idle order from outside
            session.put(task_key(a.name), TaskMessage("i-9999", "idle", a.name).to_json())
        session.put(CONTROL_KEY, FleetControl(estop=True, paused=True, seq=10**9, by="outsider").to_json())
        # an open bus applies an order at the agents' next tick: give them many
        world = secured.runner.world
        assert world is not None
        t0 = world.clock.now()
        wait_for(lambda: world.clock.now() > t0 + 10.0, "10 simulated seconds")
        assert all("i-9999" not in a._seen and a.bb.task_id for a in agents)
        assert FleetClient(secured.url).fleet()["control"]["state"] == "running"
        assert not secured.runner.latch.engaged
    finally:
        session.close()  # type: ignore[no-untyped-call]
