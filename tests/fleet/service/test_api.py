"""The HTTP API's contract on a live fleet: bad input gets a 4xx JSON naming the field and
leaves the store unchanged; the OpenAPI schema; robots, the site, /api/ws; the CLI and the
FleetClient example against the same API."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import REPO, LiveFleet, wait_for
from ports import free_endpoint
from websockets.sync.client import connect

BAD: list[tuple[Any, int, str, str]] = [
    # (body, status, field, words in the reason)
    (b"{not json", 400, "", "invalid JSON"),
    (b"", 400, "", "invalid JSON"),
    (b"[" * 100_00 + b"]" * 100_00, 400, "", "invalid JSON"),
    ({"kind": "teleport", "target": "a1_s"}, 422, "kind", "unknown kind"),
    ({"target": "a1_s"}, 422, "kind", "missing"),
    ({"kind": "go_to", "target": "nowhere"}, 422, "target", "unknown station or roadmap node"),
    ({"kind": "pick", "pickup": "pick_a2_1_w", "dropoff": "drop9"}, 422, "dropoff", "did you mean"),
    ({"kind": "go_to", "target": [500.0, 500.0]}, 422, "target", "unreachable pose"),
    ({"kind": "go_to", "target": [7.5, 10.0]}, 422, "target", "unreachable pose"),  # inside a shelf
    (
        {"kind": "patrol", "waypoints": ["a1_s", "a1_n"], "laps": -1},
        422,
        "laps",
        "greater than or equal to 1",
    ),
    ({"kind": "patrol", "waypoints": ["a1_s", "a1_s"]}, 422, "waypoints", "2 distinct"),
    ({"kind": "patrol", "route": "nope"}, 422, "route", "unknown route"),
    (
        {"kind": "inspection", "waypoints": ["a1_s", {"target": "a1_n", "action": "dance"}]},
        422,
        "waypoints[1].action",
        "dance",
    ),
    ({"kind": "go_to", "target": "a1_s", "robot": "robot99"}, 422, "robot", "unknown robot"),
    ({"kind": "go_to", "target": "a1_s", "priority": 1e9}, 422, "priority", ""),
    ({"kind": "go_to", "target": [float("nan"), 1.0]}, 422, "target", "finite number"),
    ({"kind": "go_to", "target": "a1_s", "colour": "red"}, 422, "colour", "unknown field"),
    ({"kind": "go_to", "target": "x" * 100_000}, 413, "", "larger than"),
    ([1, 2], 422, "", "JSON object"),
]


def rows(state_dir: Path) -> tuple[list[str], list[tuple[str, int]], int]:
    """Task ids, counters and submissions in the store (the fleet's own progress aside)."""
    db = sqlite3.connect(state_dir / "tasks.sqlite3")
    try:
        ids = [r[0] for r in db.execute("SELECT id FROM tasks ORDER BY seq")]
        counters = [(str(n), int(v)) for n, v in db.execute("SELECT name, value FROM counters ORDER BY name")]
        queued = db.execute("SELECT COUNT(*) FROM events WHERE event='queued'").fetchone()[0]
        return ids, counters, int(queued)
    finally:
        db.close()


def test_bad_input_is_4xx_naming_the_field_and_changes_nothing(
    live: Callable[..., LiveFleet], tmp_path: Path
) -> None:
    fleet = live(state_dir=tmp_path / "book")
    fleet.http.post("/api/fleet/pause", json={"by": "test"})  # nothing moves: the store only changes on input
    before_tasks = fleet.http.get("/api/tasks").json()
    before = rows(tmp_path / "book")
    for body, status, field, words in BAD:
        if isinstance(body, bytes):
            r = fleet.http.post("/api/tasks", content=body, headers={"content-type": "application/json"})
        else:
            text = json.dumps(body)  # NaN goes out as the invalid JSON token NaN
            r = fleet.http.post("/api/tasks", content=text, headers={"content-type": "application/json"})
        assert r.status_code == status, (body if len(str(body)) < 200 else "big", r.text)
        err = r.json()
        assert err["status"] == status and words in err["error"], err
        assert err["field"] == field, err
    assert rows(tmp_path / "book") == before
    assert [t["id"] for t in fleet.http.get("/api/tasks").json()] == [t["id"] for t in before_tasks]
    # a good one after all that gets the next id
    ids = {t["id"] for t in before_tasks}
    t = fleet.submit({"kind": "go_to", "target": "a1_s"})
    assert t["id"] not in ids and int(t["id"][2:]) == len(ids) + 1
    r = fleet.http.post("/api/fleet/resume", content=b"{bad")
    assert r.status_code == 400 and r.json()["error"].startswith("invalid JSON")
    assert fleet.http.post("/api/fleet/dance").status_code in (404, 405)
    assert fleet.http.get("/api/tasks/t-9999").status_code == 404


def test_schema_site_robots_and_websocket(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=True)
    schema = fleet.http.get("/openapi.json").json()
    for path in (
        "/api/tasks",
        "/api/tasks/{task_id}",
        "/api/tasks/{task_id}/cancel",
        "/api/robots",
        "/api/fleet/pause",
        "/api/fleet/resume",
        "/api/fleet/estop",
        "/api/fleet/release",
        "/api/map",
        "/api/roadmap",
        "/api/reservations",
    ):
        assert path in schema["paths"], path
    assert "TaskSpec" in schema["components"]["schemas"]
    robots = wait_for(lambda: len(r := fleet.http.get("/api/robots").json()) == 4 and r, "4 robots")
    for r in robots:
        assert {"name", "state", "battery", "pose", "heading", "health"} <= set(r)
        assert 0.0 <= r["battery"] <= 1.0 and r["health"] in ("alive", "silent", "stuck", "dead")
    png = fleet.http.get("/api/map.png")
    assert png.headers["content-type"] == "image/png" and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert float(png.headers["x-map-resolution"]) == fleet.http.get("/api/map").json()["resolution"]
    rm = fleet.http.get("/api/roadmap").json()
    assert rm["nodes"] and rm["edges"] and rm["chargers"] and rm["stations"]
    res = wait_for(lambda: (x := fleet.http.get("/api/reservations").json())["nodes"] and x, "reservations")
    assert res["enabled"] and {n["robot"] for n in res["nodes"]} <= {r["name"] for r in robots}
    ws_url = fleet.url.replace("http://", "ws://") + "/api/ws"
    with connect(ws_url, open_timeout=30) as ws:
        hello = json.loads(ws.recv(timeout=30))
        assert hello["type"] == "hello" and hello["robots_hz"] >= 5
        t = fleet.submit({"kind": "go_to", "target": "a2_n"})
        seen: dict[str, int] = {}
        states: list[str] = []
        robot_t: list[float] = []
        while "completed" not in states:
            msg = json.loads(ws.recv(timeout=60))
            seen[msg["type"]] = seen.get(msg["type"], 0) + 1
            if msg["type"] == "task" and msg["event"]["task_id"] == t["id"]:
                states.append(msg["event"]["state"])
            if msg["type"] == "robots":
                assert len(msg["robots"]) == 4
                robot_t.append(msg["t"])
        assert states[0] == "queued" and "assigned" in states and "active" in states
        assert seen.get("robots", 0) >= 2 and seen.get("traffic", 0) >= 1
        assert robot_t == sorted(robot_t) and robot_t[-1] > robot_t[0]  # robots move on the stream


def fleet_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fleet.cli", *args], cwd=REPO, capture_output=True, text=True, timeout=300
    )


@pytest.mark.timeout(900)  # hang guard: several waits of a loaded 2-core machine in a row
def test_cli_and_client_example(live: Callable[..., LiveFleet]) -> None:
    fleet = live(traffic=True)
    api = fleet.url.removeprefix("http://")
    r = fleet_cli(
        "task", "submit", "go_to", "--target", "a4_n", "--wait", "--timeout", "200", "--api", api, "--json"
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["state"] == "completed"
    r = fleet_cli("task", "submit", "go_to", "--target", "nowhere", "--api", api)
    assert r.returncode == 2 and "target" in r.stderr and "HTTP 422" in r.stderr and not r.stdout
    r = fleet_cli("task", "list", "--api", api, "--json")
    assert r.returncode == 0 and any(t["kind"] == "go_to" for t in json.loads(r.stdout))
    r = fleet_cli("task", "show", "t-0005", "--api", api)
    assert r.returncode == 0 and "completed" in r.stdout
    r = fleet_cli("estop", "--reason", "cli test", "--api", api, "--user", "bob")
    assert r.returncode == 0 and "estop" in r.stdout
    r = fleet_cli("resume", "--api", api)
    assert r.returncode == 2 and "409" in r.stderr
    assert fleet_cli("release", "--api", api).returncode == 0
    ctl = fleet.http.get("/api/fleet").json()
    assert ctl["control"]["state"] == "paused"
    assert any(
        c["action"] == "estop" and c["by"] == "bob" and c["reason"] == "cli test" for c in ctl["history"]
    )
    assert fleet_cli("resume", "--api", api).returncode == 0
    ex = subprocess.run(
        [sys.executable, "examples/client_tour.py", "--api", api, "--timeout", "200"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert ex.returncode == 0, ex.stdout + ex.stderr
    assert "tour ok" in ex.stdout
    report = fleet.stop()
    actions = [c["action"] for c in report.control_events]
    assert actions.count("estop") == 2 and "release" in actions


@pytest.mark.parametrize("bad", ["nohost", "127.0.0.1:99999", "127.0.0.1:x"])
def test_bad_api_address_is_a_clear_error(bad: str) -> None:
    r = fleet_cli(
        "run", "configs/warehouse_patrol.yaml", "--duration", "1", "--api", bad, "--no-live",
        "--endpoint", free_endpoint(),  # its own bus: the default port may be taken on this machine
    )  # fmt: skip
    assert r.returncode == 2 and "api" in r.stderr and "Traceback" not in r.stderr
