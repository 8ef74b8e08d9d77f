"""``fleet status`` and the fleet table."""

from __future__ import annotations

import io
import json
import subprocess

import msgspec
from bus_peer import record

from fleet.viz.table import COMPACT_FROM, LiveTable, render_table


def _ready(p: subprocess.Popen[str]) -> None:
    assert p.stdout is not None
    assert p.stdout.readline().strip() == "ready"


def test_status_once_sees_every_robot_of_another_process(spawn, zenoh_endpoint: str) -> None:
    robots = [f"robot{i}" for i in range(1, 7)]
    # the publisher is the router here: start a router that only relays
    router = spawn(["-c", _ROUTER, zenoh_endpoint])
    _ready(router)
    pub = spawn(["tests/helpers/bus_peer.py", "status", zenoh_endpoint, ",".join(robots), "100000", "20"])
    _ready(pub)
    viewer = spawn(["-m", "fleet.cli.status", "--once", "--endpoint", zenoh_endpoint, "--wait", "10"])
    out, err = viewer.communicate(timeout=20)
    assert viewer.returncode == 0, err
    for r in robots:
        assert r in out
    assert "6 robots, 6 alive" in out
    viewer = spawn(["-m", "fleet.cli.status", "--once", "--json", "--endpoint", zenoh_endpoint])
    out, err = viewer.communicate(timeout=20)
    assert viewer.returncode == 0, err
    data = json.loads(out)
    assert [r["robot"] for r in data["robots"]] == robots
    assert data["alive"] == robots and data["malformed"] == 0


def test_status_once_without_robots_exits_1_and_without_router_exits_2(spawn, zenoh_endpoint: str) -> None:
    v = spawn(["-m", "fleet.cli.status", "--once", "--endpoint", zenoh_endpoint, "--connect-timeout", "0.3"])
    _, err = v.communicate(timeout=20)
    assert v.returncode == 2 and "no Zenoh router at" in err
    router = spawn(["-c", _ROUTER, zenoh_endpoint])
    _ready(router)
    v = spawn(["-m", "fleet.cli.status", "--once", "--endpoint", zenoh_endpoint, "--wait", "0.5"])
    _, err = v.communicate(timeout=20)
    assert v.returncode == 1 and "no robot status seen" in err


def test_status_live_mode_stops_on_sigterm(spawn, zenoh_endpoint: str) -> None:
    router = spawn(["-c", _ROUTER, zenoh_endpoint])
    _ready(router)
    v = spawn(["-m", "fleet.cli.status", "--endpoint", zenoh_endpoint])
    assert v.stdout is not None
    assert "watching" in v.stdout.readline()
    v.terminate()
    assert v.wait(5) == 0


def test_table_fits_100_columns_and_compacts() -> None:
    six = {f"robot{i}": record(f"robot{i}", i) for i in range(1, 7)}
    six["robot3"] = msgspec.structs.replace(six["robot3"], stuck=True)
    text = render_table(six, alive=set(six) - {"robot6"})
    lines = text.splitlines()
    assert len(lines) == 2 + 6 and max(map(len, lines)) <= 100
    assert "STUCK" in lines[2 + 2] and "DEAD" in lines[2 + 5]
    many = {f"robot{i}": record(f"robot{i}", i) for i in range(1, COMPACT_FROM + 2)}
    lines = render_table(many, alive=set(many)).splitlines()
    assert len(lines) == 2 + (COMPACT_FROM + 2) // 2 and max(map(len, lines)) <= 100
    assert render_table({}, set()).endswith("(no robots seen yet)")


def test_live_table_rate_limits_and_redraws_in_place() -> None:
    t = [0.0]
    buf = io.StringIO()
    table = LiveTable(buf, tty=True, wall=lambda: t[0])
    recs = [record("robot1", 1), record("robot2", 2)]
    assert table.update(recs)
    assert not table.update(recs)  # within 0.5 s
    t[0] = 0.6
    assert table.update(recs)
    assert "\x1b[4F\x1b[J" in buf.getvalue()
    plain = io.StringIO()
    table = LiveTable(plain, tty=False, line_every_s=5.0, wall=lambda: t[0])
    table.update(recs)
    t[0] = 2.0
    table.update(recs)
    assert plain.getvalue().count("\n") == 1 and "2 robots" in plain.getvalue()


_ROUTER = """
import signal, sys, threading
from fleet.bus.session import open_session
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
with open_session(sys.argv[1], "router"):
    print("ready", flush=True)
    stop.wait()
"""
