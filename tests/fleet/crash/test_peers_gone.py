"""Ctrl-C on processes whose peers are gone: the simulator of a split fleet is stopped first,
then ``fleet coordinator`` (hosting the task service's HTTP API), ``fleet agent`` and ``fleet status`` (all waiting for the router
they lost) get SIGINT. Each exits with its documented code (130; 0 for the ``fleet status``
viewer; ``docs/cli.md``) well within the hang guard and prints no traceback.

Before the fix a coordinator or agent took 1-5 s after Ctrl-C on an idle machine (and about
30 s under load) to finish the interpreter's finalization after its run had ended.

The simulator resumes a snapshot taken at t = 1000 s, as after a restart: the coordinator,
which joined that fleet, shows the fleet's clock in its progress lines (it counted from its
own start, t = 5 s, before)."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

from fleet_procs import PATROL, BusWatch, output, processes, spawn
from ports import free_endpoint, pick_free_port

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus

#: Hang guard (wall s) for the processes to start.
START_S = 120.0
#: Hang guard (wall s) for a process to exit after SIGINT: a clean exit takes well under a
#: second; the bug this guards against took about 30 s.
EXIT_S = 20.0
EXPECTED = {"coordinator": 130, "agent": 130, "status": 0}


def test_ctrl_c_after_the_simulator_stopped_exits_promptly(tmp_path: Path) -> None:
    cfg, ep = str(PATROL), free_endpoint()
    state = tmp_path / "sim-state"
    state.mkdir()
    (state / "sim.json").write_text(
        json.dumps({"version": 1, "fleet": "warehouse_patrol", "t": 1000.0, "robots": {}})
    )
    with processes() as procs:
        sim = spawn(
            procs,
            ["sim", cfg, "--endpoint", ep, "--robots", "2", "--speed", "2", "--state", str(state)],
            tmp_path / "sim.log",
        )
        output(sim).wait_line("fleet sim:", START_S)
        started = {
            "coordinator": spawn(
                procs,
                [
                    "coordinator",
                    cfg,
                    "--robots",
                    "2",
                    "--endpoint",
                    ep,
                    "--no-live",
                    "--state",
                    str(tmp_path / "book"),
                    "--api",
                    f"127.0.0.1:{pick_free_port()}",
                ],
                tmp_path / "coordinator.log",
            ),  # fmt: skip
            "agent": spawn(
                procs,
                ["agent", cfg, "--robots", "2", "--robot", "robot1", "--endpoint", ep],
                tmp_path / "agent.log",
            ),
            "status": spawn(
                procs,
                ["status", "--endpoint", ep, "--interval", "0.2", "--connect-timeout", str(START_S)],
                tmp_path / "status.log",
            ),
        }
        session = open_session(ep, "client", connect_timeout_s=30.0)
        try:  # the agent drives its robot, the coordinator gave it its route
            bus = BusWatch(StatusBus(session))
            bus.wait(
                lambda latest: bool(getattr(latest.get("robot1"), "task_id", "")), START_S, "robot1's task"
            )
            bus.bus.close()
        finally:
            session.close()
        line = output(started["coordinator"]).wait_line(" s sim,", START_S)
        assert float(line.split("t=")[1].split()[0]) >= 1000.0, line
        sim.send_signal(signal.SIGINT)  # the router and the simulator go first
        assert sim.wait(timeout=START_S) == 130
        # the agent noticed: its bus-loss watchdog stopped its robot
        output(started["agent"]).wait_line("bus link lost", START_S)
        sent: dict[str, float] = {}
        for name, p in started.items():
            assert p.poll() is None, (tmp_path / f"{name}.log").read_text()
            p.send_signal(signal.SIGINT)
            sent[name] = time.monotonic()
        for name, p in started.items():
            log = tmp_path / f"{name}.log"
            try:
                code = p.wait(timeout=max(0.1, sent[name] + EXIT_S - time.monotonic()))
            except subprocess.TimeoutExpired:
                raise AssertionError(
                    f"fleet {name} still runs {EXIT_S:g} s after Ctrl-C:\n{log.read_text()}"
                ) from None
            text = log.read_text()
            assert code == EXPECTED[name], f"fleet {name} exited {code}:\n{text}"
            assert "Traceback" not in text, f"fleet {name}:\n{text}"
