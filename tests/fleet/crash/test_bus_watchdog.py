"""The bus-loss watchdog with a real router kill: robots whose agents run beside their robots
(an in-process simulator standing in for the robots' own navigation) and reach the fleet through
a Zenoh router in another process (the coordinator runs beside them here). ``kill -9`` of the router stops every robot within
``bus.link_timeout_s`` (their goals are canceled; they stand still while the bus is gone) and a
router started again on the same endpoint lets them resume their tasks."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

from fleet_procs import ROOT, temp_config, two_routes_three_robots, wait_for
from ports import free_endpoint

from fleet.config.loader import load_config
from fleet.runtime.runner import FleetRunner
from fleet.viz.display import NullDisplay

#: Hang guard (wall s) for each wait: a few seconds on an idle machine.
WAIT_S = 120.0
LINK_TIMEOUT_S = 1.0

_ROUTER = """
import sys, threading
from fleet.bus.session import open_session
s = open_session(sys.argv[1], "router")
print("router up", flush=True)
threading.Event().wait()
"""


def _router(ep: str) -> subprocess.Popen[str]:
    p = subprocess.Popen([sys.executable, "-c", _ROUTER, ep], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert p.stdout is not None and p.stdout.readline().strip() == "router up"
    return p


def test_router_kill_stops_the_robots_and_its_return_resumes_them(tmp_path: Path) -> None:
    def edit(doc: dict) -> None:  # type: ignore[type-arg]
        two_routes_three_robots(doc, "robot1")
        doc.setdefault("bus", {})["link_timeout_s"] = LINK_TIMEOUT_S

    config = load_config(temp_config(tmp_path, edit))
    ep = free_endpoint()
    routers = [_router(ep)]
    runner = FleetRunner(
        config, duration=None, speed=2.0, endpoint=ep, listen=False, traffic=False, display=NullDisplay()
    )
    thread = threading.Thread(target=runner.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: runner.world is not None and len(runner.agents) == 3, WAIT_S, "the runner's setup")
        sim = runner.world.sim  # type: ignore[union-attr]
        ns = [a.namespace for a in runner.agents]

        def driving() -> list[str]:
            return [n for n in ns if abs(sim.robot_state(n).linear_velocity) > 0.05]

        wait_for(lambda: len(driving()) == 2, WAIT_S, "two robots driving their routes")

        routers[0].kill()
        routers[0].wait(timeout=10)
        t_kill = time.monotonic()
        wait_for(lambda: all(a.link_lost for a in runner.agents), WAIT_S, "the watchdog tripping")
        wait_for(lambda: not driving(), WAIT_S, "every robot standing")
        stopped_after = time.monotonic() - t_kill
        # they stay put while the bus is gone, however long the simulator runs on
        d0 = {n: sim.robot_state(n).distance_m for n in ns}
        t0 = sim.clock.now()
        wait_for(lambda: sim.clock.now() > t0 + 6.0, WAIT_S, "6 simulated seconds without the bus")
        assert all(sim.robot_state(n).distance_m - d0[n] < 0.05 for n in ns)
        assert all(a.bb.mode == "safety_stop" and a.link_stops == 1 for a in runner.agents)

        routers.append(_router(ep))
        wait_for(lambda: not any(a.link_lost for a in runner.agents), WAIT_S, "the link back")
        wait_for(
            lambda: (
                all(sim.robot_state(n).distance_m > d0[n] + 2.0 for n in driving()) and len(driving()) == 2
            ),
            WAIT_S,
            "the robots driving again",
        )
        # on patrol again (the coordinator took the stopped robots' tasks back and handed them out)
        assert sorted(str(a.bb.mode) for a in runner.agents).count("patrol") == 2
        print(
            f"robots stopped {stopped_after:.2f} s after the router was killed (timeout {LINK_TIMEOUT_S} s)"
        )
        assert stopped_after < LINK_TIMEOUT_S + 30.0  # hang guard, not a speed target
    finally:
        runner.stop()
        thread.join(timeout=60)
        for r in routers:
            r.kill()
            r.wait(timeout=10)
    assert not thread.is_alive()
