"""The durable task book on a real process: ``kill -9`` of a ``fleet run`` and a restart with
the same ``--state`` resumes with no task lost, none done twice and no id reused."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
from conftest import wait_for
from ports import free_endpoint, pick_free_port

SPECS: list[dict[str, Any]] = [
    {"kind": "go_to", "target": t} for t in ("a1_n", "a3_n", "a5_n", "a7_n", "a2_s", "a4_s", "a6_s")
] + [
    {"kind": "patrol", "waypoints": ["a1_s", "a1_n"], "laps": 3},
    {"kind": "patrol", "waypoints": ["a5_s", "a5_n"], "laps": 3},
    {"kind": "pick", "pickup": "pick_a2_1_w", "dropoff": "drop1"},
    {"kind": "inspection", "waypoints": ["a3_s", "a3_n"], "action": "spin"},
    {"kind": "park"},
]


def start(
    spawn: Callable[..., subprocess.Popen[str]], state: Path, port: int
) -> tuple[subprocess.Popen[str], httpx.Client]:
    p = spawn(
        [
            "-m",
            "fleet.cli",
            "run",
            "configs/warehouse_patrol.yaml",
            "--robots",
            "4",
            "--tree",
            "picking",
            "--speed",
            "0",
            "--no-live",
            "--state",
            str(state),
            "--api",
            f"127.0.0.1:{port}",
            "--endpoint",
            free_endpoint(),
        ]
    )
    http = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30.0)

    def up() -> bool:
        if p.poll() is not None:
            raise AssertionError(f"fleet run exited {p.returncode}: {p.stderr.read() if p.stderr else ''}")
        try:
            return http.get("/api/fleet").status_code == 200
        except httpx.HTTPError:
            return False

    wait_for(up, "the API")
    return p, http


def events(state: Path) -> list[tuple[Any, ...]]:
    db = sqlite3.connect(state / "tasks.sqlite3")
    try:
        return db.execute(
            "SELECT seq, task_id, event, state, robot, assignment FROM events ORDER BY seq"
        ).fetchall()
    finally:
        db.close()


def test_kill_9_and_restart_loses_nothing_and_repeats_nothing(
    spawn: Callable[..., subprocess.Popen[str]], tmp_path: Path
) -> None:
    state = tmp_path / "book"
    port = pick_free_port()
    p, http = start(spawn, state, port)
    ids = [http.post("/api/tasks", json=s).json()["id"] for s in SPECS]
    assert len(set(ids)) == len(ids)

    def mid_run() -> bool:
        ts = {t["id"]: t["state"] for t in http.get("/api/tasks").json()}
        done = sum(ts[i] == "completed" for i in ids)
        held = sum(ts[i] in ("assigned", "active") for i in ids)
        return done >= 2 and held >= 1

    wait_for(mid_run, "some tasks done and some held")
    p.send_signal(signal.SIGKILL)
    p.wait(30)
    http.close()

    before_events = events(state)
    # what the store says the dead process had done (committed before anyone could see it)
    last: dict[str, str] = {}
    for _, tid, _, st, _, _ in before_events:
        last[tid] = st
    completed_before = {t for t, s in last.items() if s == "completed"}
    assignments_before = {e[5] for e in before_events if e[5]}
    assert completed_before and any(s in ("assigned", "active") for s in last.values())

    p2, http2 = start(spawn, state, pick_free_port())
    after = {t["id"]: t for t in http2.get("/api/tasks").json()}
    assert set(ids) <= set(after), "a task was lost"
    for tid in completed_before:
        assert after[tid]["state"] == "completed"
    new = http2.post("/api/tasks", json={"kind": "go_to", "target": "a2_n"}).json()
    assert new["id"] not in last and int(new["id"][2:]) > max(int(t[2:]) for t in last)

    for tid in [*ids, new["id"]]:
        wait_for(
            lambda tid=tid: (
                http2.get(f"/api/tasks/{tid}").json()["state"] in ("completed", "failed", "canceled")
            ),
            tid,
        )
    final = {t["id"]: t for t in http2.get("/api/tasks").json()}
    assert all(final[t]["state"] == "completed" for t in [*ids, new["id"]]), {
        t: final[t]["state"] for t in ids
    }

    all_events = events(state)
    restart_seq = before_events[-1][0]
    later = [e for e in all_events if e[0] > restart_seq]
    # none done twice: a task completed before the kill is never handed out or completed again
    assert not [e for e in later if e[1] in completed_before and e[2] in ("assigned", "active", "completed")]
    # each task completed exactly once over both runs
    completions = [e[1] for e in all_events if e[2] == "completed"]
    assert sorted(completions) == sorted(set(completions))
    # no assignment id reused: ids handed out after the restart are new (restored leases keep theirs)
    restored = {e[5] for e in later if e[2] == "restored"}
    fresh = {e[5] for e in later if e[2] == "assigned"}
    assert not (fresh & (assignments_before - restored))
    http2.close()
    p2.send_signal(signal.SIGINT)
    assert p2.wait(60) in (0, 130)
