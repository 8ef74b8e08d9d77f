"""Ctrl-C (SIGINT) and SIGTERM on every long-running ``fleet`` process: each exits with the
documented code (130; 0 for the ``fleet status`` viewer; ``docs/cli.md``) and prints no traceback. Every process of a round runs
at the same time (a split fleet: ``fleet sim``, ``fleet coordinator`` hosting the task service's
HTTP API, ``fleet agent``, ``fleet status``; and ``fleet run``, ``fleet loadtest``), started in
the background of this process (so SIGINT reaches them as it does from a script)."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest
from fleet_procs import PATROL, BusWatch, output, processes, spawn
from ports import free_endpoint, pick_free_port

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus

#: Hang guard (wall s) for a process to be up, and to exit after the signal.
WAIT_S = 120.0
EXIT_INTERRUPTED = 130
#: ``fleet status`` is a viewer: Ctrl-C is how it ends, with 0 (``docs/cli.md``).
EXIT_CODES = {"status": 0}


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_every_process_exits_130_without_a_traceback(sig: signal.Signals, tmp_path: Path) -> None:
    cfg = str(PATROL)
    ep, ep_run, ep_load = free_endpoint(), free_endpoint(), free_endpoint()
    with processes() as procs:
        started: dict[str, subprocess.Popen[str]] = {}

        ready: dict[str, str] = {}

        def start(name: str, args: list[str], line: str) -> None:
            started[name] = spawn(procs, args, tmp_path / f"{name}.log")
            ready[name] = line

        start("sim", ["sim", cfg, "--endpoint", ep, "--robots", "2"], "fleet sim:")
        output(started["sim"]).wait_line("fleet sim:", WAIT_S)  # the router the others connect to
        start(
            "coordinator",
            ["coordinator", cfg, "--robots", "2", "--endpoint", ep, "--no-live", "--state",
             str(tmp_path / "book"), "--api", f"127.0.0.1:{pick_free_port()}"],
            "tasks:",
        )  # fmt: skip
        start("agent", ["agent", cfg, "--robots", "2", "--robot", "robot1", "--endpoint", ep], "fleet:")
        start(
            "status",
            ["status", "--endpoint", ep, "--interval", "0.2", "--connect-timeout", str(WAIT_S)],
            "1 alive",
        )
        start(
            "run",
            ["run", cfg, "--robots", "2", "--endpoint", ep_run, "--no-live", "--duration", "100000",
             "--state", str(tmp_path / "run-book")],
            "tasks:",
        )  # fmt: skip
        start(
            "loadtest",
            ["loadtest", "--robots", "4", "--duration", "100000", "--speed", "1", "--endpoint", ep_load,
             "--out", str(tmp_path / "load")],
            "tasks:",
        )  # fmt: skip
        for name, line in ready.items():  # they start side by side; each must be up
            output(started[name]).wait_line(line, WAIT_S)
        session = open_session(ep, "client", connect_timeout_s=30.0)
        try:  # the agent drives its robot: it is in its loop, not starting up
            bus = BusWatch(StatusBus(session))
            bus.wait(lambda latest: "robot1" in latest, WAIT_S, "robot1's status")
            bus.bus.close()
        finally:
            session.close()
        # clients first, the simulator (their router) last
        for name in ("status", "agent", "coordinator", "run", "loadtest", "sim"):
            p = started[name]
            assert p.poll() is None, (tmp_path / f"{name}.log").read_text()
            p.send_signal(sig)
            code = p.wait(timeout=WAIT_S)
            log = (tmp_path / f"{name}.log").read_text()
            assert code == EXIT_CODES.get(name, EXIT_INTERRUPTED), f"fleet {name} exited {code}:\n{log}"
            assert "Traceback" not in log, f"fleet {name}:\n{log}"


@pytest.mark.ros
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_sim_ros_exits_130_without_a_traceback(sig: signal.Signals, tmp_path: Path) -> None:
    with processes() as procs:
        p = spawn(procs, ["sim-ros", str(PATROL), "--robots", "1", "--domain-id", "91"], tmp_path / "ros.log")
        output(p).wait_line("[sim-ros] serving", WAIT_S)
        p.send_signal(sig)
        code = p.wait(timeout=WAIT_S)
        log = (tmp_path / "ros.log").read_text()
        assert code == EXIT_INTERRUPTED and "Traceback" not in log, log
