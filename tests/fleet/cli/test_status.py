"""``fleet status``: one table or JSON from another process's fleet, exit codes, live mode
(the table itself is tested in ``tests/fleet/viz``)."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable

Spawn = Callable[..., subprocess.Popen[str]]


def _ready(p: subprocess.Popen[str]) -> None:
    assert p.stdout is not None
    assert p.stdout.readline().strip() == "ready"


def test_status_once_sees_every_robot_of_another_process(spawn: Spawn, zenoh_endpoint: str) -> None:
    robots = [f"robot{i}" for i in range(1, 7)]
    # the publisher is the router here: start a router that only relays
    router = spawn(["-c", _ROUTER, zenoh_endpoint])
    _ready(router)
    pub = spawn(
        ["tests/helpers/bus_peer.py", "status", zenoh_endpoint, ",".join(robots), "100000", "20", "robot2"]
    )
    _ready(pub)
    viewer = spawn(["-m", "fleet.cli", "status", "--once", "--endpoint", zenoh_endpoint, "--wait", "30"])
    out, err = viewer.communicate(timeout=60)
    assert viewer.returncode == 0, err
    lines = out.splitlines()
    assert "6 robots, 6 alive" in lines[0]
    assert [line.split()[0] for line in lines[2:]] == robots  # one row per robot, in order
    assert lines[1].split()[:5] == ["robot", "x", "y", "yaw", "bat"] and lines[1].split()[-1] == "flags"
    # diagnostics travel with the statuses: robot2's lost localization is flagged, no one else's
    assert [line.split()[0] for line in lines[2:] if "ERROR:localization" in line] == ["robot2"]
    viewer = spawn(
        ["-m", "fleet.cli.status", "--once", "--json", "--endpoint", zenoh_endpoint, "--wait", "30"]
    )
    out, err = viewer.communicate(timeout=60)
    assert viewer.returncode == 0, err
    data = json.loads(out)
    assert [r["robot"] for r in data["robots"]] == robots
    assert data["alive"] == robots and data["malformed"] == 0
    by_name = {r["robot"]: r for r in data["robots"]}
    assert by_name["robot2"]["health"] == 2
    assert by_name["robot2"]["diag"] == [["localization", 2, "localization lost"]]
    assert by_name["robot1"]["health"] == 0 and by_name["robot1"]["diag"] == []


def test_status_once_without_robots_exits_1_and_without_router_exits_2(
    spawn: Spawn, zenoh_endpoint: str
) -> None:
    v = spawn(["-m", "fleet.cli.status", "--once", "--endpoint", zenoh_endpoint, "--connect-timeout", "0.3"])
    _, err = v.communicate(timeout=60)
    assert v.returncode == 2 and "no Zenoh router at" in err
    router = spawn(["-c", _ROUTER, zenoh_endpoint])
    _ready(router)
    v = spawn(["-m", "fleet.cli.status", "--once", "--endpoint", zenoh_endpoint, "--wait", "0.5"])
    _, err = v.communicate(timeout=60)
    assert v.returncode == 1 and "no robot status seen" in err


def test_status_live_mode_stops_on_sigterm(spawn: Spawn, zenoh_endpoint: str) -> None:
    router = spawn(["-c", _ROUTER, zenoh_endpoint])
    _ready(router)
    v = spawn(["-m", "fleet.cli.status", "--endpoint", zenoh_endpoint])
    assert v.stdout is not None
    assert "watching" in v.stdout.readline()
    v.terminate()
    assert v.wait(30) == 0


_ROUTER = """
import signal, sys, threading
from fleet.bus.session import open_session
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
with open_session(sys.argv[1], "router"):
    print("ready", flush=True)
    stop.wait()
"""


def test_json_battery_is_null_before_the_robots_first_state() -> None:
    """``fleet status --json``: a status sent before the robot's first state (no pose) has
    ``battery: null``, not the navigation client's default of 1.0."""
    import msgspec
    from bus_peer import record

    from fleet.cli.status import robot_json

    known = record("robot1", 1)
    waiting = msgspec.structs.replace(record("robot2", 2), pose=None, battery=1.0)
    assert robot_json(known, known.t)["battery"] == known.battery
    row = robot_json(waiting, known.t)
    assert row["battery"] is None and row["pose"] is None and row["stale"] is False
