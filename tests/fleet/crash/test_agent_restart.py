"""An agent that dies and comes back: ``kill -9`` of one robot's ``fleet agent`` moves its
route to an idle robot; the same ``fleet agent`` started again rejoins (its robot reports idle
on the bus) and is given work again: when another robot's agent dies, the rejoined robot takes
that robot's route."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fleet_procs import BusWatch, kill, output, processes, spawn, temp_config, two_routes_three_robots
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

ROBOTS = ("robot1", "robot2", "robot3")
#: Hang guard (wall s) for each wait: a few seconds on an idle machine.
WAIT_S = 180.0


def _patrolling(latest: dict[str, StatusRecord], alive: set[str]) -> dict[str, str]:
    return {n: r.task_id for n, r in latest.items() if n in alive and r.mode == "patrol" and r.task_id}


def test_agent_kill_9_moves_its_route_and_the_restarted_agent_gets_work_again(tmp_path: Path) -> None:
    def edit(doc: dict[str, Any]) -> None:
        two_routes_three_robots(doc, "robot1")
        doc["coordinator"]["stuck_reassign_s"] = 10.0  # a new robot stuck beside the dead one moves on

    cfg = temp_config(tmp_path, edit)
    ep = free_endpoint()
    with processes() as procs:
        sim = spawn(procs, ["sim", str(cfg), "--endpoint", ep, "--speed", "3"], tmp_path / "sim.log")
        output(sim).wait_line("fleet sim:", 60)
        session = open_session(ep, "client", connect_timeout_s=30.0)
        bus = BusWatch(StatusBus(session))

        def agent(robot: str, n: int) -> Any:
            args = ["agent", str(cfg), "--robot", robot, "--endpoint", ep, "--no-traffic"]
            return spawn(procs, args, tmp_path / f"agent-{robot}-{n}.log")

        try:
            agents = {r: agent(r, 1) for r in ROBOTS}
            bus.wait(lambda latest: set(ROBOTS) <= set(latest), WAIT_S, "every robot's first status")
            spawn(
                procs,
                ["coordinator", str(cfg), "--endpoint", ep, "--no-traffic", "--no-live", "--state", str(tmp_path / "book")],
                tmp_path / "coord.log",
            )  # fmt: skip
            alive = set(ROBOTS)
            bus.wait(lambda latest: "robot1" in _patrolling(latest, alive), WAIT_S, "robot1 on its route")
            bus.wait(lambda latest: len(_patrolling(latest, alive)) == 2, WAIT_S, "both routes driven")
            route1 = _patrolling(bus.latest(), alive)["robot1"]

            # robot1's agent dies: the idle robot takes the route over (under a new task id)
            kill(agents["robot1"], tmp_path / "agent-robot1-1.log")
            alive.discard("robot1")
            bus.wait(lambda latest: len(_patrolling(latest, alive)) == 2, WAIT_S, "robot1's route taken over")
            assert route1 not in _patrolling(bus.latest(), alive).values()

            # robot1's agent again: it rejoins, idle (the coordinator must not hand it its old task)
            t_back = bus.latest()["robot1"].t
            agents["robot1"] = agent("robot1", 2)
            bus.wait(
                lambda latest: latest["robot1"].t > t_back and latest["robot1"].mode != "patrol",
                WAIT_S,
                "robot1's agent back on the bus",
            )
            alive.add("robot1")

            # another robot's agent dies: its route goes to robot1, the only idle robot
            victim = sorted(_patrolling(bus.latest(), alive))[0]
            kill(agents[victim], tmp_path / f"agent-{victim}-1.log")
            alive.discard(victim)
            bus.wait(lambda latest: "robot1" in _patrolling(latest, alive), WAIT_S, "robot1 given work again")
            d0 = bus.latest()["robot1"].distance_m
            bus.wait(lambda latest: latest["robot1"].distance_m > d0 + 3.0, WAIT_S, "robot1 driving it")
            assert len(_patrolling(bus.latest(), alive)) == 2
        finally:
            bus.bus.close()
            session.close()
    for log in tmp_path.glob("*.log"):
        assert "Traceback" not in log.read_text(), log.read_text()
