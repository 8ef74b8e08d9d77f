"""The process hosting the Zenoh router and the simulator dies: ``kill -9`` of ``fleet sim``
under a split fleet (``fleet agent`` for three robots, ``fleet coordinator``), then the same
``fleet sim --state DIR`` started again on the same endpoint. The agents and the coordinator
stay up and reconnect on their own, the robots come back where they stood and drive the same
tasks again (the coordinator does not take a robot's task back for a liveliness token that
vanished with its own bus link), and no process prints a traceback."""

from __future__ import annotations

import math
from pathlib import Path

from fleet_procs import BusWatch, kill, output, processes, spawn, temp_config, two_routes_three_robots
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

ROBOTS = ("robot1", "robot2", "robot3")
#: Hang guard (wall s) for each wait: a few seconds on an idle machine.
WAIT_S = 180.0


def _patrolling(latest: dict[str, StatusRecord]) -> dict[str, str]:
    return {n: r.task_id for n, r in latest.items() if r.mode == "patrol" and r.task_id}


def test_sim_kill_9_and_restart_the_fleet_reconnects_and_drives_on(tmp_path: Path) -> None:
    cfg = temp_config(tmp_path, lambda d: two_routes_three_robots(d, "robot1"))
    ep = free_endpoint()
    sim_args = ["sim", str(cfg), "--endpoint", ep, "--speed", "2", "--state", str(tmp_path / "sim")]
    with processes() as procs:
        sim = spawn(procs, sim_args, tmp_path / "sim1.log")
        output(sim).wait_line("fleet sim:", 60)
        session = open_session(ep, "client", connect_timeout_s=30.0)
        bus = BusWatch(StatusBus(session))
        try:
            robots = [a for n in ROBOTS for a in ("--robot", n)]
            agents = spawn(
                procs, ["agent", str(cfg), *robots, "--endpoint", ep, "--no-traffic"], tmp_path / "agents.log"
            )
            coord = spawn(
                procs,
                ["coordinator", str(cfg), "--endpoint", ep, "--no-traffic", "--no-live",
                 "--state", str(tmp_path / "book")],
                tmp_path / "coord.log",
            )  # fmt: skip
            bus.wait(lambda latest: len(_patrolling(latest)) == 2, WAIT_S, "both routes driven")
            d0 = {n: r.distance_m for n, r in bus.latest().items()}
            bus.wait(
                lambda latest: all(latest[n].distance_m > d0[n] + 2.0 for n in _patrolling(latest)),
                WAIT_S,
                "the robots driving",
            )

            held = _patrolling(bus.latest())
            kill(sim, tmp_path / "sim1.log")
            before = dict(bus.latest())
            t_kill = max(r.t for r in before.values())
            # the agents' bus-loss watchdog stops their robots; nobody exits
            output(agents).wait_line("bus link lost", WAIT_S)
            assert agents.poll() is None and coord.poll() is None

            sim2 = spawn(procs, sim_args, tmp_path / "sim2.log")
            output(sim2).wait_line("fleet sim:", 60)

            def after(latest: dict[str, StatusRecord]) -> dict[str, StatusRecord]:
                return {n: r for n, r in latest.items() if r.t > t_kill + 0.5}

            bus.wait(
                lambda latest: set(after(latest)) == set(ROBOTS), WAIT_S, "statuses from every robot again"
            )
            # the restarted simulator put every robot back where it stood (its snapshot is at
            # most 0.5 wall s old: 1 s simulated at speed 2, under 1.2 m of driving)
            first = after(bus.latest())
            for n in ROBOTS:
                (x0, y0, _), (x1, y1, _) = before[n].pose, first[n].pose  # type: ignore[misc]
                assert math.hypot(x1 - x0, y1 - y0) < 3.0, (n, before[n].pose, first[n].pose)
            # and the fleet works again: both routes driven, the drivers making way
            bus.wait(lambda latest: len(_patrolling(after(latest))) == 2, WAIT_S, "both routes driven again")
            d1 = {n: r.distance_m for n, r in after(bus.latest()).items()}
            bus.wait(
                lambda latest: all(
                    after(latest)[n].distance_m > d1[n] + 4.0 for n in _patrolling(after(latest))
                ),
                WAIT_S,
                "the robots driving under the restarted simulator",
            )
            output(agents).wait_line("bus link back", WAIT_S)
            assert agents.poll() is None and coord.poll() is None
            # the same robots on the same tasks: nothing was taken back or handed out again
            assert _patrolling(after(bus.latest())) == held
        finally:
            bus.bus.close()
            session.close()
    for log in tmp_path.glob("*.log"):
        assert "Traceback" not in log.read_text(), log.read_text()
    # the coordinator's summary (printed as it was terminated) counts no reassignment
    assert "reassignments: 0 " in (tmp_path / "coord.log").read_text()
