"""A coordinator that dies alone: ``kill -9`` of ``fleet coordinator`` while the robots' agents
(another process) drive their tasks, and a restart with the same ``--state``. The robots drive
on meanwhile, and the restarted coordinator keeps each on the task it held (its lease is
restored, not handed to another robot, not reissued under a new id)."""

from __future__ import annotations

from pathlib import Path

import httpx
from fleet_procs import BusWatch, kill, output, processes, spawn, temp_config, two_routes_three_robots
from ports import free_endpoint, pick_free_port

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

ROBOTS = ("robot1", "robot2", "robot3")
#: Hang guard (wall s) for each wait: a few seconds on an idle machine.
WAIT_S = 180.0


def _patrolling(latest: dict[str, StatusRecord]) -> dict[str, str]:
    return {n: r.task_id for n, r in latest.items() if r.mode == "patrol" and r.task_id}


def test_coordinator_kill_9_and_restart_keeps_driving_robots_on_their_tasks(tmp_path: Path) -> None:
    cfg = temp_config(tmp_path, lambda d: two_routes_three_robots(d, "robot1"))
    ep, port, state = free_endpoint(), pick_free_port(), tmp_path / "book"
    coord_args = ["coordinator", str(cfg), "--endpoint", ep, "--state", str(state), "--no-traffic",
                  "--api", f"127.0.0.1:{port}", "--no-live"]  # fmt: skip
    with processes() as procs:
        sim = spawn(procs, ["sim", str(cfg), "--endpoint", ep, "--speed", "2"], tmp_path / "sim.log")
        output(sim).wait_line("fleet sim:", 60)
        session = open_session(ep, "client", connect_timeout_s=30.0)
        bus = BusWatch(StatusBus(session))
        http = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30.0)
        try:
            robots = [a for n in ROBOTS for a in ("--robot", n)]
            spawn(
                procs, ["agent", str(cfg), *robots, "--endpoint", ep, "--no-traffic"], tmp_path / "agents.log"
            )
            bus.wait(lambda latest: set(ROBOTS) <= set(latest), WAIT_S, "every robot's first status")
            coord = spawn(procs, coord_args, tmp_path / "coord1.log")
            bus.wait(lambda latest: len(_patrolling(latest)) == 2, WAIT_S, "both routes driven")
            held = _patrolling(bus.latest())

            kill(coord, tmp_path / "coord1.log")
            # without a coordinator the robots drive on, on the same tasks
            d0 = {n: bus.latest()[n].distance_m for n in held}
            bus.wait(
                lambda latest: all(latest[n].task_id == t and latest[n].distance_m > d0[n] + 3.0 for n, t in held.items()),
                WAIT_S,
                "the robots driving on while the coordinator is dead",
            )  # fmt: skip

            spawn(procs, coord_args, tmp_path / "coord2.log")

            def api_up() -> bool:
                try:
                    return http.get("/api/tasks").status_code == 200
                except httpx.HTTPError:
                    return False

            bus.wait(lambda latest: api_up(), WAIT_S, "the restarted coordinator's API")
            # a robot's status names its assignment (lease) id; the restored lease keeps it
            tasks = {t["assignment"]: t for t in http.get("/api/tasks").json()}
            for robot, lease in held.items():
                assert tasks[lease]["robot"] == robot, tasks[lease]
                assert tasks[lease]["state"] in ("assigned", "active"), tasks[lease]
            # and they keep them: more driving under the restarted coordinator, same task ids
            d1 = {n: bus.latest()[n].distance_m for n in held}
            bus.wait(
                lambda latest: all(latest[n].distance_m > d1[n] + 6.0 for n in held),
                WAIT_S,
                "the robots driving on under the restarted coordinator",
            )
            assert _patrolling(bus.latest()) == held
            tasks = {t["assignment"]: t for t in http.get("/api/tasks").json()}
            assert {tasks[lease]["robot"] for lease in held.values()} == set(held)
            assert len(tasks) == 2, "the restart issued tasks or leases of its own"
        finally:
            http.close()
            bus.bus.close()
            session.close()
