"""A seeded run's outcome is the same with hostile and malformed input on every key
(docs/protocol.md): the same fleet runs twice as fast as possible (``speed=0``, which does not
depend on network timing), once clean and once with an outsider putting garbage on every key
(statuses, orders, grants, control, clock, navigation), a forged idle order on the wildcard of
every robot's orders, garbage queries to the task service's bus face and garbage requests to
its HTTP API, all while the fleet runs. Laps, assignments, reassignments and collisions are
the same; the garbage is counted in the report."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import zenoh
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.config.loader import load_config
from fleet.messages import TaskMessage
from fleet.runtime.report import RunReport
from fleet.runtime.runner import FleetRunner
from fleet.viz.display import NullDisplay

PATROL = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"
#: Hang guard (wall s) for the garbage to be counted on a loaded 2-core machine.
WAIT_S = 60.0

GARBAGE: list[bytes] = [
    b"{not json",
    b"\xff\xfe\x00garbage",
    b'{"v": 1, "robot": "robot1", "t": 1.0, "pose": [1.0, 2.0',  # truncated
    b'{"v": 1, "robot": ' + b"[" * 5000 + b"]" * 5000 + b"}",  # deeply nested
    b'{"v": 1, "robot": {"wrong": "type"}}',
    b'{"v": 1, "robot": "robot1", "t": NaN}',
    b'{"v": 1, "robot": "robot1", "seq": 18446744073709551616}',
    b'{"v": 1, "pad": "' + b"x" * (300 * 1024) + b'"}',  # larger than the size limit
]
KEYS = [
    "fleet/{r}/status", "fleet/{r}/task", "fleet/{r}/grant", "fleet/{r}/nav/goal", "fleet/{r}/nav/cancel",
    "fleet/{r}/nav/state", "fleet/control/state", "fleet/sim/clock",
]  # fmt: skip


class Outsider:
    """Puts the garbage once, at simulated t >= 1 s, from the runner's own loop (an observer),
    and holds the run there until every counted piece is counted: the run's outcome cannot
    depend on when the garbage arrives."""

    def __init__(self, robots: list[str]) -> None:
        self.robots = robots
        self.done = False
        self.expected = 0

    def __call__(self, now: float, runner: FleetRunner) -> None:
        if self.done or now < 1.0:
            return
        self.done = True
        base = runner.malformed()
        session = open_session(runner.endpoint, "client", connect_timeout_s=30.0)
        try:
            block = zenoh.CongestionControl.BLOCK  # an outsider's put, not dropped when congested
            session.put(
                "fleet/*/task", TaskMessage(task_id="i-9999", kind="idle").to_json(), congestion_control=block
            )
            for key in KEYS:
                for r in self.robots:
                    for g in GARBAGE:
                        session.put(key.format(r=r), g, congestion_control=block)
            statuses = len(self.robots) * len(GARBAGE)  # the keys this process subscribes to
            for g in GARBAGE:
                replies = list(session.get("fleet/service/submit", payload=g, timeout=30.0))
                assert replies and all(x.err is not None for x in replies)
            assert runner.host is not None and runner.host.api is not None
            with httpx.Client(base_url=runner.host.api.url, timeout=30.0) as http:
                for g in GARBAGE:
                    r = http.post("/api/tasks", content=g, headers={"content-type": "application/json"})
                    assert r.status_code in (400, 413, 422), r.text
                r = http.post(
                    "/api/tasks", content=b'{"kind": "go_to", "target": 1e999}',
                    headers={"content-type": "application/json"},
                )  # fmt: skip
                assert r.status_code in (400, 422)
            self.expected = base + statuses + 2 * len(GARBAGE) + 1
            deadline = time.monotonic() + WAIT_S
            while runner.malformed() < self.expected:
                assert time.monotonic() < deadline, f"{runner.malformed()} of {self.expected} counted"
                threading.Event().wait(0.01)
        finally:
            session.close()


def run(outsider: Outsider | None, tmp: Path) -> RunReport:
    config = load_config(PATROL, robots=3)
    runner = FleetRunner(
        config, duration=90.0, speed=0.0, endpoint=free_endpoint(), display=NullDisplay(), state_dir=tmp,
        api="127.0.0.1:0",
    )  # fmt: skip
    if outsider is not None:
        runner.observers.append(outsider)
    return runner.run()


def outcome(r: RunReport) -> dict[str, Any]:
    d = json.loads(json.dumps(r.to_dict(), default=str))
    return {
        "laps": d["laps_completed"],
        "laps_by_route": d["laps_by_route"],
        "collisions": d["collisions"],
        "deadlocks": d["deadlocks"],
        "assignments": [(a["task_id"], a["robot"], a.get("laps")) for a in d["assignments"]],
        "reassignments": [(e["route"], e["from_robot"], e["reason"]) for e in d["reassignment_events"]],
        "distance": [round(p["distance_m"], 6) for p in d["per_robot"]],
    }


def test_a_seeded_run_is_the_same_with_garbage_on_every_key(tmp_path: Path) -> None:
    clean = run(None, tmp_path / "clean")
    outsider = Outsider(["robot1", "robot2", "robot3"])
    hostile = run(outsider, tmp_path / "hostile")
    assert outsider.done and clean.malformed_messages == 0
    assert hostile.malformed_messages >= outsider.expected > 0
    assert clean.laps_completed > 0
    assert outcome(hostile) == outcome(clean)
