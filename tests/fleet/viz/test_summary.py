"""The end-of-run summary drawn from a report's JSON fields."""

from __future__ import annotations

from typing import Any

from fleet.viz.summary import MAX_EVENTS_SHOWN, summary_text


def report(**kw: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "robots": 2,
        "sim_time_s": 600.0,
        "wall_time_s": 6.25,
        "interrupted": False,
        "patrols_assigned": 3,
        "patrols_completed": 2,
        "laps_completed": 7,
        "laps_by_route": {"aisles_1_2": 4, "perimeter": 3},
        "picks_assigned": 0,
        "picks_completed": 0,
        "collisions": 1,
        "deadlocks": 2,
        "reassignments": 1,
        "throughput_laps_per_robot_hour": 21.0,
        "traffic": None,
        "reassignment_events": [
            {"t": 185.1, "route": "perimeter", "from_robot": "robot2", "reason": "charging", "to_robot": "robot1",
             "t_reassigned": 185.1},
        ],
        "per_robot": [
            {"name": "robot1", "distance_m": 356.7, "laps": 4, "battery_final": 0.58, "final_state": "patrol"},
            {"name": "robot2", "distance_m": 120.0, "laps": 3, "battery_final": 0.41, "final_state": "dead"},
        ],
    }  # fmt: skip
    d.update(kw)
    return d


def test_summary_lines() -> None:
    lines = summary_text(report()).splitlines()
    assert lines[0] == "finished: 2 robots, 600.0 s simulated in 6.2 s wall (96.0x real time)"
    assert lines[1] == "patrols: 3 assigned, 2 completed, 7 laps (aisles_1_2: 4, perimeter: 3)"
    assert lines[2].startswith("collisions: 1   deadlocks: 2   reassignments: 1   throughput: 21.0")
    assert lines[3] == "  t=185.1 s perimeter: robot2 charging -> robot1 at 185.1 s"
    assert lines[4].split() == ["robot", "dist", "m", "laps", "battery", "goals", "state"]
    assert lines[5].split() == ["robot1", "356.7", "4", "58%", "-", "patrol"]  # no goal metrics
    assert lines[6].split() == ["robot2", "120.0", "3", "41%", "-", "dead"]


def test_interrupted_picks_traffic_and_many_events() -> None:
    traffic = {"mean_wait_s": 5.95, "p95_wait_s": 31.0, "max_wait_s": 40.0, "cycles_detected": 3, "cycles_resolved": 3,
               "reroutes": 2, "sidesteps": 1, "stalls": 0}  # fmt: skip
    event = report()["reassignment_events"][0]
    text = summary_text(
        report(interrupted=True, picks_assigned=5, picks_completed=4, traffic=traffic,
               reassignment_events=[event] * (MAX_EVENTS_SHOWN + 5))
    )  # fmt: skip
    assert text.startswith("interrupted: 2 robots")
    assert "picks: 5 assigned, 4 completed" in text
    assert "traffic: mean wait 6.0 s (p95 31.0 s, max 40.0 s), wait-for cycles 3 found / 3 resolved" in text
    assert text.count("perimeter: robot2 charging") == MAX_EVENTS_SHOWN
    assert "... 5 more reassignments in the report" in text
