"""A live fleet for the task service's tests: ``fleet run`` (in-process :class:`FleetRunner`)
on the simulator with its HTTP API on a free port, run in a background thread until the test
ends.

``live(traffic=..., speed=..., robots=..., state_dir=..., tree=...)`` starts one (by default
with the config's picks as its initial tasks, so robots are free once those are done) and returns a
:class:`LiveFleet` (its runner, its API's URL, an ``httpx.Client`` on it); every fleet started
is stopped (and its Zenoh session closed) at the end of the test.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from ports import free_endpoint

from fleet.config.loader import load_config
from fleet.runtime.report import RunReport
from fleet.runtime.runner import FleetRunner
from fleet.viz.display import NullDisplay

REPO = Path(__file__).resolve().parents[3]
PATROL = REPO / "configs" / "warehouse_patrol.yaml"
#: Hang guard for waiting on a live fleet (wall s; a loaded 2-core machine is slow).
DEADLINE_S = 120.0


def wait_for(cond: Callable[[], Any], what: str, timeout_s: float = DEADLINE_S) -> Any:
    """Poll ``cond`` until it returns something truthy; fail after ``timeout_s`` wall seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


@dataclass
class LiveFleet:
    runner: FleetRunner
    url: str
    http: httpx.Client
    thread: threading.Thread
    report: list[RunReport]

    def task(self, task_id: str) -> dict[str, Any]:
        r = self.http.get(f"/api/tasks/{task_id}")
        assert r.status_code == 200, r.text
        body: dict[str, Any] = r.json()
        return body

    def submit(self, spec: dict[str, Any]) -> dict[str, Any]:
        r = self.http.post("/api/tasks", json=spec)
        assert r.status_code == 201, r.text
        body: dict[str, Any] = r.json()
        return body

    def wait_state(self, task_id: str, *states: str) -> dict[str, Any]:
        got: dict[str, Any] = wait_for(
            lambda: (t := self.task(task_id))["state"] in states and t, f"{task_id} to be {states}"
        )
        return got

    def stop(self) -> RunReport:
        self.runner.stop()
        self.thread.join(DEADLINE_S)
        assert not self.thread.is_alive(), "the fleet did not stop"
        self.http.close()
        return self.report[0]


@pytest.fixture
def live(tmp_path: Path) -> Iterator[Callable[..., LiveFleet]]:
    started: list[LiveFleet] = []

    def start(
        *,
        traffic: bool = True,
        speed: float = 0.0,
        robots: int | None = 4,
        state_dir: Path | None = None,
        config: Path = PATROL,
        tree: str = "picking",
    ) -> LiveFleet:
        cfg = load_config(config, robots=robots)
        runner = FleetRunner(
            cfg,
            duration=None,
            speed=speed,
            endpoint=free_endpoint(),
            display=NullDisplay(),
            traffic=traffic,
            state_dir=state_dir or tmp_path / "state",
            api="127.0.0.1:0",
            tree_kind=tree,
        )
        report: list[RunReport] = []
        thread = threading.Thread(target=lambda: report.append(runner.run()), daemon=True)
        thread.start()
        wait_for(
            lambda: runner.host is not None and runner.host.api is not None or not thread.is_alive(), "API"
        )
        assert thread.is_alive() and runner.host is not None and runner.host.api is not None
        url = runner.host.api.url
        fleet = LiveFleet(runner, url, httpx.Client(base_url=url, timeout=30.0), thread, report)
        started.append(fleet)
        return fleet

    yield start
    for f in started:
        if f.thread.is_alive():
            f.runner.stop()
            f.thread.join(DEADLINE_S)
        f.http.close()
