"""The fleet's safety watchdog on the in-process simulator: a patrolling robot whose
localization is lost (then, later, whose navigation server goes down) is stopped within one
control period (one agent tick), reports ``safety_stop`` with an ERROR diagnostic, loses its
patrol to another robot (reason ``safety_stop``), drives again once the fault clears, and the
report counts its stops."""

from __future__ import annotations

import io
from typing import Any

from fleet_procs import PATROL
from ports import free_endpoint

from fleet.config.loader import load_config
from fleet.runtime.runner import FleetRunner
from fleet.runtime.worlds import SimWorld

FAULTS = {30.0: "localization_lost", 60.0: None, 90.0: "navigation_down", 120.0: None}


def test_lost_localization_and_a_dead_navigation_server_stop_the_robot_within_one_tick() -> None:
    cfg = load_config(PATROL)
    runner = FleetRunner(
        cfg, duration=160.0, speed=0, endpoint=free_endpoint(), backend="sim", live=False, out=io.StringIO()
    )
    seen: dict[str, Any] = {"stopped_at": [], "moving_after_clear": False, "pending": None, "done": set()}
    period = 1.0 / cfg.tick_hz

    def observe(now: float, r: FleetRunner) -> None:
        world = r.world
        assert isinstance(world, SimWorld)
        agent = next(a for a in r.agents if a.name == "robot1")
        rec = agent.last_status
        assert rec is not None
        pending = seen["pending"]
        if pending is not None and now >= pending[0] + period - 1e-6:
            # one tick after the fault: stopped, reported, diagnosed
            fault = pending[1]
            seen["pending"] = None
            st = world.sim.robot_state("/robot1")
            check = "localization" if fault == "localization_lost" else "navigation"
            seen["stopped_at"].append(
                (fault, rec.mode, abs(st.linear_velocity), [d[:2] for d in rec.diag], rec.health, check)
            )
        for t, fault in FAULTS.items():
            if now >= t and t not in seen["done"]:
                seen["done"].add(t)
                world.sim.set_fault("/robot1", fault)
                if fault is not None:
                    seen["pending"] = (now, fault)
        if now > 140.0 and abs(world.sim.robot_state("/robot1").linear_velocity) > 0.05:
            seen["moving_after_clear"] = True

    runner.observers.append(observe)
    report: Any = runner.run()
    assert len(seen["stopped_at"]) == 2, seen
    for fault, mode, speed, diag, health, check in seen["stopped_at"]:
        assert mode == "safety_stop", (fault, mode)
        assert speed < 1e-6, (fault, speed)
        assert [check, 2] in [list(d) for d in diag], (fault, diag)
        assert health == 2
    row = next(r for r in report.per_robot if r.name == "robot1")
    assert row.safety_stops == 2 and report.safety_stops == 2
    reasons = [e["reason"] for e in report.reassignment_events if e["from_robot"] == "robot1"]
    assert reasons.count("safety_stop") == 2, report.reassignment_events
    assert seen["moving_after_clear"], "robot1 never drove again after its faults cleared"
    assert report.collisions == 0
