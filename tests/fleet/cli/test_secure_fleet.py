"""A secured fleet split over processes (``fleet keys init``, then ``fleet sim``, ``fleet
agent`` x2 and ``fleet coordinator`` with ``--secure DIR``) completes laps end to end; an
anonymous ``fleet status`` is refused, the observer identity reads the fleet; bad ``--secure``
values are clear errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from fleet_procs import PATROL, ROOT, BusWatch, output, processes, spawn, temp_config
from ports import free_endpoint

from fleet.bus.session import Secure, open_session
from fleet.bus.status_bus import StatusBus

#: Hang guard (wall s) for one step of the run on a loaded 2-core machine.
DEADLINE_S = 120.0


def fleet(*args: str, timeout: float = DEADLINE_S) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fleet.cli", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def test_secured_split_fleet_completes_laps(tmp_path: Path) -> None:
    ep = free_endpoint()
    keys = tmp_path / "keys"
    cfg = [str(PATROL), "--robots", "2"]
    r = fleet("keys", "init", *cfg, str(keys), "--endpoint", ep)
    assert r.returncode == 0, r.stderr
    assert "robot1, robot2, coordinator, simulator, observer, worker" in r.stdout
    again = fleet("keys", "init", *cfg, str(keys))
    assert again.returncode == 2 and "exists; pass --force" in again.stderr and "robot1.json5" in again.stderr
    secure = ["--endpoint", ep, "--secure", str(keys)]
    report = tmp_path / "coord.json"
    with processes() as procs:
        sim = spawn(procs, ["sim", *cfg, *secure, "--speed", "10"], tmp_path / "sim.log")
        assert "secured bus" in output(sim).wait_line("fleet sim:", DEADLINE_S)
        spawn(procs, ["agent", *cfg, "--robot", "robot1", *secure], tmp_path / "robot1.log")
        # robot2's agent finds its keys in its config (bus.secure, relative to the config file)
        cfg2 = temp_config(tmp_path, lambda doc: doc["bus"].update(secure="keys"), "secured.yaml")
        agent2 = spawn(procs, ["agent", str(cfg2), "--robots", "2", "--robot", "robot2", "--endpoint", ep],
                       tmp_path / "robot2.log")  # fmt: skip
        assert "identity 'robot2'" in output(agent2).wait_line("fleet: ", DEADLINE_S)
        session = open_session(ep, "client", secure=Secure(keys, "observer"), connect_timeout_s=30.0)
        watch = BusWatch(StatusBus(session))
        try:
            watch.wait(
                lambda latest: {"robot1", "robot2"} <= set(latest), DEADLINE_S, "both robots' statuses"
            )
            anonymous = fleet("status", "--once", "--endpoint", ep, "--connect-timeout", "2", "--wait", "5")
            assert anonymous.returncode == 2 and f"no Zenoh router at {ep}" in anonymous.stderr
            seen = fleet("status", "--once", "--json", *secure, "--wait", "30")
            assert seen.returncode == 0, seen.stderr
            assert {"robot1", "robot2"} <= {r["robot"] for r in json.loads(seen.stdout)["robots"]}
            coord = spawn(
                procs,
                ["coordinator", *cfg, *secure, "--duration", "200", "--no-live", "--report", str(report),
                 "--state", str(tmp_path / "state")],
                tmp_path / "coord.log",
            )  # fmt: skip
            assert "identity 'coordinator'" in output(coord).wait_line("fleet: ", DEADLINE_S)
            coord.wait(timeout=3 * DEADLINE_S)
            assert coord.returncode == 0, (tmp_path / "coord.log").read_text()
            result = json.loads(report.read_text())
            assert result["laps_completed"] >= 2, result
            assert result["collisions"] == 0
            assert sim.poll() is None
        finally:
            watch.bus.close()
            session.close()  # type: ignore[no-untyped-call]


def test_bad_secure_values_are_clear_errors(tmp_path: Path) -> None:
    ep = free_endpoint()
    missing = tmp_path / "nowhere"
    r = fleet("agent", str(PATROL), "--robot", "robot1", "--endpoint", ep, "--secure", str(missing))
    assert r.returncode == 2 and f"--secure {missing}: no such key directory" in r.stderr, r.stderr
    keys = tmp_path / "keys"
    assert fleet("keys", "init", str(PATROL), str(keys), "--endpoint", ep).returncode == 0
    shown = fleet("keys", "show", str(keys))
    assert shown.returncode == 0, shown.stderr
    assert f"router on {ep}, no TLS" in shown.stdout and "10 identities" in shown.stdout
    observer = shown.stdout.split("observer:")[1].split("worker:")[0]
    assert "(read only)" in observer and "publishes" not in observer
    assert "publishes fleet/robot1/status, fleet/robot1/nav/goal, fleet/robot1/nav/cancel" in shown.stdout
    r = fleet("agent", str(PATROL), "--robot", "robot1,robot2", "--endpoint", ep, "--secure", str(keys))
    assert r.returncode == 2 and "no single identity" in r.stderr and "--identity" in r.stderr, r.stderr
    r = fleet("coordinator", str(PATROL), "--agents", "robot1", "--endpoint", ep, "--secure", str(keys))
    assert r.returncode == 2 and "no single identity" in r.stderr, r.stderr
    r = fleet("agent", str(PATROL), "--robot", "robot1", "--endpoint", ep, "--secure", str(keys),
              "--identity", "robot9")  # fmt: skip
    assert r.returncode == 2 and "robot9.json5" in r.stderr and "fleet keys init" in r.stderr, r.stderr
    r = fleet("keys", "init", str(PATROL), str(tmp_path / "k2"), "--robots", "0")
    assert r.returncode == 2 and "--robots" in r.stderr
    r = fleet("status", "--once", "--endpoint", ep, "--secure", str(missing))
    assert r.returncode == 2 and "no such key directory" in r.stderr
    r = fleet("keys", "init", str(PATROL), str(tmp_path / "k3"), "--tls", "--endpoint", "udp/127.0.0.1:7447")
    assert r.returncode == 2 and "--endpoint: TLS needs a tcp/ or tls/ endpoint" in r.stderr, r.stderr
    assert not (tmp_path / "k3").exists()


def test_the_observer_sees_every_robot_of_a_secured_fleet_run(tmp_path: Path) -> None:
    """``fleet run --secure`` hosts the router and all agents: its statuses go out one robot per
    key (a status batch is in no role, so the observer would receive nothing)."""
    ep = free_endpoint()
    keys = tmp_path / "keys"
    assert fleet("keys", "init", str(PATROL), str(keys), "--robots", "3", "--endpoint", ep).returncode == 0
    with processes() as procs:
        run = spawn(
            procs,
            ["run", str(PATROL), "--robots", "3", "--endpoint", ep, "--secure", str(keys), "--speed", "2",
             "--no-live", "--state", str(tmp_path / "state")],
            tmp_path / "run.log",
        )  # fmt: skip
        assert "secured bus" in output(run).wait_line("fleet: ", DEADLINE_S)
        seen = fleet("status", "--once", "--json", "--endpoint", ep, "--secure", str(keys), "--wait", "30")
        assert seen.returncode == 0, seen.stderr
        assert {r["robot"] for r in json.loads(seen.stdout)["robots"]} == {"robot1", "robot2", "robot3"}
