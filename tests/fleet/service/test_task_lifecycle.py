"""Tasks at runtime on the simulator, end to end through the HTTP API: every kind goes
queued -> assigned -> active -> completed with timestamps and its robot, with traffic
management on and off; queued and active tasks can be canceled; ids are never reused."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from conftest import LiveFleet, wait_for

KINDS: list[dict[str, Any]] = [
    {"kind": "go_to", "target": "a3_n"},
    {"kind": "go_to", "target": "pick_a4_1_w", "robot": "robot2"},
    {"kind": "patrol", "waypoints": ["a1_s", "a1_n"], "laps": 1},
    {"kind": "patrol", "route": "aisles_3_4", "laps": 1},
    {"kind": "pick", "pickup": "pick_a2_1_w", "dropoff": "drop1", "dwell_s": 2.0},
    {
        "kind": "inspection",
        "waypoints": [
            "a5_s",
            {"target": "a5_n", "action": "spin"},
            {"target": [12.0, 5.0], "action": "capture:gauge"},
        ],
        "action": "wait",
        "duration_s": 1.0,
    },
    {"kind": "park"},
    {"kind": "charge", "priority": 5},
]

ORDER = ["queued", "assigned", "active", "completed"]


def check_completed(fleet: LiveFleet, task: dict[str, Any]) -> None:
    """Completed, by a robot, with ordered timestamps, through every state in order."""
    t = fleet.task(task["id"])
    assert t["state"] == "completed", t
    assert t["robot"] and t["assignment"]
    if task["spec"].get("robot"):
        assert t["robot"] == task["spec"]["robot"]
    assert t["created_at"] <= t["assigned_at"] <= t["started_at"] <= t["ended_at"]  # ISO 8601, UTC
    states = [e["state"] for e in t["events"] if e["event"] in ORDER]
    firsts = [s for i, s in enumerate(states) if s not in states[:i]]
    assert firsts == ORDER, states


@pytest.mark.parametrize("traffic", [True, False], ids=["traffic", "no-traffic"])
def test_every_kind_runs_to_completed(live: Callable[..., LiveFleet], traffic: bool) -> None:
    fleet = live(traffic=traffic)
    submitted = [fleet.submit(spec) for spec in KINDS]
    assert all(t["state"] == "queued" and t["robot"] is None for t in submitted)
    ids = [t["id"] for t in submitted]
    assert len(set(ids)) == len(ids)
    for t in submitted:
        fleet.wait_state(t["id"], "completed", "failed", "canceled")
    for t in submitted:
        check_completed(fleet, t)
    kinds = {t["kind"] for t in fleet.http.get("/api/tasks", params={"state": "completed"}).json()}
    assert {"go_to", "patrol", "pick", "inspection", "park", "charge"} <= kinds
    report = fleet.stop()
    assert report.collisions == 0
    assert report.tasks is not None and report.tasks["by_state"].get("completed", 0) >= len(KINDS)


def test_cancel_queued_and_active(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=True)
    # an endless patrol: active until canceled
    endless = fleet.submit({"kind": "patrol", "waypoints": ["a6_s", "a6_n"], "priority": 100})
    active = fleet.wait_state(endless["id"], "active")
    robot = active["robot"]
    fleet.http.post("/api/fleet/pause", json={"by": "test"})
    queued = fleet.submit({"kind": "go_to", "target": "a2_n"})
    wait_for(lambda: fleet.task(queued["id"])["state"] == "queued", "queued")
    r = fleet.http.post(f"/api/tasks/{queued['id']}/cancel")
    assert r.status_code == 200 and r.json()["state"] == "canceled"
    assert fleet.task(queued["id"])["assigned_at"] is None
    fleet.http.post("/api/fleet/resume", json={"by": "test"})
    r = fleet.http.post(f"/api/tasks/{endless['id']}/cancel", headers={"X-Fleet-User": "alice"})
    assert r.status_code == 200
    done = fleet.wait_state(endless["id"], "canceled")
    assert done["robot"] == robot and "alice" in done["message"] and done["ended_at"]
    # the robot is free again: it takes new work
    after = fleet.submit({"kind": "go_to", "target": "a6_s", "robot": robot})
    fleet.wait_state(after["id"], "completed")
    # a finished task cannot be canceled again; an unknown one is 404
    assert fleet.http.post(f"/api/tasks/{endless['id']}/cancel").status_code == 409
    assert fleet.http.post("/api/tasks/t-9999/cancel").status_code == 404
    ids = [t["id"] for t in fleet.http.get("/api/tasks").json()]
    assert len(ids) == len(set(ids))
