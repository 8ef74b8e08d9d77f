"""End to end: the demo through ``fleet.cli.main`` (6 robots patrol every route, no
collisions), a low-battery robot whose route is covered while it charges, ``fleet status
--once`` attached to a running ``fleet run``, and a SIGKILLed agent process whose route the
coordinator reassigns (simulator, coordinator and agents in separate processes).

Real Zenoh on loopback (a free port per test), real py_trees trees, the real simulator.
Every subprocess is terminated, then killed, in ``finally``. Waits are on conditions (a line
in a process's output, a status on the bus) with generous deadlines, never fixed sleeps.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.cli.main import main
from fleet.messages import StatusRecord

ROOT = Path(__file__).resolve().parents[3]
PATROL = ROOT / "configs" / "warehouse_patrol.yaml"
FLEET = [sys.executable, "-m", "fleet.cli"]


def temp_config(tmp_path: Path, edit: Any, name: str = "fleet.yaml") -> Path:
    doc = yaml.safe_load(PATROL.read_text())
    doc["map"] = str(PATROL.parent / doc["map"])
    edit(doc)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def two_routes_three_robots(doc: dict[str, Any], first_route_robot: str) -> None:
    """Edit a config document: robots 1-3, routes aisles_1_2 (preferred robot
    ``first_route_robot``) and aisles_3_4."""
    doc["robots"] = doc["robots"][:3]
    doc["routes"] = [r for r in doc["routes"] if r["name"] in ("aisles_1_2", "aisles_3_4")]
    doc["routes"][0]["robot"] = first_route_robot


@contextmanager
def processes() -> Iterator[list[subprocess.Popen[str]]]:
    """Start processes into the yielded list; all are terminated (then killed) on exit."""
    procs: list[subprocess.Popen[str]] = []
    try:
        yield procs
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + 10.0
        for p in procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


class Output:
    """A process's output, copied line by line to ``log`` by a reader thread;
    :meth:`wait_line` waits for a line containing some text."""

    def __init__(self, p: subprocess.Popen[str], log: Path) -> None:
        self.log = log
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self._done = False
        self._thread = threading.Thread(target=self._read, args=(p,), daemon=True)
        self._thread.start()

    def _read(self, p: subprocess.Popen[str]) -> None:
        assert p.stdout is not None
        with open(self.log, "w") as f:
            for line in p.stdout:
                f.write(line)
                f.flush()
                with self._cond:
                    self.lines.append(line)
                    self._cond.notify_all()
        with self._cond:
            self._done = True
            self._cond.notify_all()

    def wait_line(self, text: str, timeout: float) -> str:
        """The first line containing ``text``; fails after ``timeout`` s or when the output ends."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                hit = next((line for line in self.lines if text in line), None)
                if hit is not None:
                    return hit
                left = deadline - time.monotonic()
                if left <= 0 or self._done:
                    raise AssertionError(f"no line with {text!r} in {self.log.name}:\n{''.join(self.lines)}")
                self._cond.wait(left)


_outputs: dict[int, Output] = {}


def spawn(procs: list[subprocess.Popen[str]], args: list[str], log: Path) -> subprocess.Popen[str]:
    """Start ``fleet <args>``; its output goes to ``log`` (see :func:`output`)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    p = subprocess.Popen(
        [*FLEET, *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT, env=env
    )
    procs.append(p)
    _outputs[p.pid] = Output(p, log)
    return p


def output(p: subprocess.Popen[str]) -> Output:
    """The output of a process started by :func:`spawn`."""
    return _outputs[p.pid]


def wait_for(pred: Callable[[], bool], timeout: float, what: str, step: float = 0.05) -> None:
    """Wait until ``pred()`` holds, checking every ``step`` s; fail after ``timeout`` s (for
    conditions nothing signals; prefer :meth:`BusWatch.wait` and :meth:`Output.wait_line`)."""
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        threading.Event().wait(step)


class BusWatch:
    """A bus client seeing every status; :meth:`wait` re-checks its condition at each status."""

    def __init__(self, bus: StatusBus) -> None:
        self.bus = bus
        self._cond = threading.Condition()
        bus.subscribe_statuses(self._on_status)

    def _on_status(self, rec: StatusRecord) -> None:
        with self._cond:
            self._cond.notify_all()

    def latest(self) -> dict[str, StatusRecord]:
        return self.bus.latest()

    def wait(self, pred: Callable[[dict[str, StatusRecord]], bool], timeout: float, what: str) -> None:
        """Wait until ``pred(latest statuses)`` holds; fail after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not pred(self.bus.latest()):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"timed out after {timeout} s waiting for {what}")
                self._cond.wait(left)


@dataclass
class SplitFleet:
    """A fleet split over processes (see :func:`split_fleet`)."""

    bus: BusWatch
    sim: subprocess.Popen[str]
    agent: subprocess.Popen[str]
    coord: subprocess.Popen[str]
    report: Path

    def result(self, timeout: float) -> dict[str, Any]:
        """Wait for the coordinator to finish (it must exit 0, the simulator must still run)
        and return its JSON report."""
        self.coord.wait(timeout=timeout)
        assert self.coord.returncode == 0, (self.report.parent / "coord.log").read_text()
        assert self.sim.poll() is None
        return dict(json.loads(self.report.read_text()))


@contextmanager
def split_fleet(
    tmp_path: Path, cfg: Path, victim: str, others: str, speed: float, duration: float, *extra: str
) -> Iterator[SplitFleet]:
    """``fleet sim`` at ``speed``, ``fleet agent`` for ``victim`` alone and ``fleet coordinator``
    hosting the agents ``others`` for ``duration`` simulated seconds (report in
    ``tmp_path/coord.json``), all on one free loopback endpoint with ``extra`` CLI options for
    the agent and the coordinator, plus a bus client that sees every status. Every process is
    terminated (then killed) and the bus closed on exit."""
    ep = free_endpoint()
    report = tmp_path / "coord.json"
    with processes() as procs:
        sim = spawn(procs, ["sim", str(cfg), "--endpoint", ep, "--speed", str(speed)], tmp_path / "sim.log")
        output(sim).wait_line("fleet sim:", 60)
        session = open_session(ep, "client", connect_timeout_s=30.0)
        bus = BusWatch(StatusBus(session))
        try:
            agent = spawn(
                procs,
                ["agent", str(cfg), "--robot", victim, "--endpoint", ep, *extra],
                tmp_path / "agent.log",
            )
            bus.wait(lambda latest: victim in latest, 60, f"{victim}'s first status")
            coord = spawn(
                procs,
                ["coordinator", str(cfg), "--endpoint", ep, "--agents", others, "--duration", str(duration),
                 "--no-live", "--report", str(report), *extra],
                tmp_path / "coord.log",
            )  # fmt: skip
            yield SplitFleet(bus, sim, agent, coord, report)
        finally:
            bus.bus.close()
            session.close()


def kill(p: subprocess.Popen[str], log: Path) -> None:
    """SIGKILL a process that must still be running (else fail with its log)."""
    assert p.poll() is None, log.read_text()
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=10)


@pytest.mark.slow
def test_six_robots_patrol_every_route_without_collisions(tmp_path: Path) -> None:
    report, png = tmp_path / "r.json", tmp_path / "r.png"
    code = main(
        [
            "run", str(PATROL), "--speed", "0", "--duration", "240", "--no-live",
            "--endpoint", free_endpoint(), "--report", str(report), "--plot", str(png),
        ]
    )  # fmt: skip
    assert code == 0
    r = json.loads(report.read_text())
    assert r["robots"] == 6 and r["collisions"] == 0
    assert all(laps >= 1 for laps in r["laps_by_route"].values()), r["laps_by_route"]
    assert len(r["laps_by_route"]) == 5
    assert r["patrols_completed"] >= 5 and r["laps_completed"] >= 5
    assert {row["name"] for row in r["per_robot"]} == {f"robot{i}" for i in range(1, 7)}
    assert sum(row["distance_m"] for row in r["per_robot"]) > 500
    ids = [a["task_id"] for a in r["assignments"]]
    assert len(ids) == len(set(ids)) == r["patrols_assigned"]
    assert png.stat().st_size > 10_000


@pytest.mark.slow
def test_low_battery_robot_charges_and_its_route_is_covered(tmp_path: Path) -> None:
    def edit(doc: dict[str, Any]) -> None:
        two_routes_three_robots(doc, "robot1")
        doc["robots"][0]["battery"] = 0.32  # reaches battery.low (0.25) after ~15 m

    cfg = temp_config(tmp_path, edit)
    report = tmp_path / "r.json"
    code = main(["run", str(cfg), "--speed", "0", "--duration", "200", "--no-live",
                 "--endpoint", free_endpoint(), "--report", str(report)])  # fmt: skip
    assert code == 0
    r = json.loads(report.read_text())
    (ev,) = [e for e in r["reassignment_events"] if e["from_robot"] == "robot1"]
    assert ev["reason"] == "charging" and ev["route"] == "aisles_1_2"
    assert ev["to_robot"] in ("robot2", "robot3") and ev["t_reassigned"] - ev["t"] < 1.0
    robot1 = next(row for row in r["per_robot"] if row["name"] == "robot1")
    assert robot1["charges"] >= 1
    # the route was driven by the other robot while robot1 charged
    cover = next(a for a in r["assignments"] if a["task_id"] == ev["new_task_id"])
    assert cover["laps"] >= 1 and cover["t_first_lap"] is not None
    assert r["collisions"] == 0


@pytest.mark.slow
def test_status_once_sees_every_robot_of_a_run(tmp_path: Path) -> None:
    ep = free_endpoint()
    with processes() as procs:
        run = spawn(procs, ["run", str(PATROL), "--speed", "1", "--duration", "120", "--no-live", "--endpoint", ep],
                    tmp_path / "run.log")  # fmt: skip
        output(run).wait_line("fleet:", 60)
        # waits until every robot holding a liveliness token has sent a status
        res = subprocess.run(
            [*FLEET, "status", "--once", "--endpoint", ep, "--wait", "60", "--settle", "10"],
            capture_output=True, text=True, timeout=120, cwd=ROOT,
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        for i in range(1, 7):
            assert f"robot{i}" in res.stdout, res.stdout
        assert run.poll() is None, "".join(output(run).lines)
        run.send_signal(signal.SIGINT)
        run.wait(timeout=60)
        assert run.returncode == 130, "".join(output(run).lines)
        output(run).wait_line("interrupted: 6 robots", 30)


@pytest.mark.slow
def test_killed_agent_process_route_is_reassigned_and_completed(tmp_path: Path) -> None:
    victim = "robot2"

    def edit(doc: dict[str, Any]) -> None:
        two_routes_three_robots(doc, victim)
        # the dead robot stops on a waypoint of its route (its last goal runs to its end); the
        # new robot gets stuck next to it, and the coordinator then skips that waypoint
        doc["coordinator"]["stuck_reassign_s"] = 10.0

    cfg = temp_config(tmp_path, edit)
    speed = 5.0
    duration = 170.0
    with split_fleet(tmp_path, cfg, victim, "robot1,robot3", speed, duration) as f:
        bus = f.bus
        # let the victim get its route and drive it for 20 simulated seconds
        bus.wait(lambda latest: latest[victim].task_id is not None, 60, f"{victim}'s route")
        t_route = bus.latest()[victim].t
        bus.wait(lambda latest: latest[victim].t >= t_route + 20.0, 60, f"{victim} driving")
        t_kill = bus.latest()[victim].t  # simulated seconds of the victim's last status
        kill(f.agent, tmp_path / "agent.log")
        r = f.result(duration / speed + 60)
    (ev,) = [e for e in r["reassignment_events"] if e["from_robot"] == victim]
    assert ev["route"] == "aisles_1_2" and ev["reason"] == "dead"
    assert ev["to_robot"] in ("robot1", "robot3")
    # the victim drove its route for ~20 s before the kill; reassigned within 5 simulated s of its death
    first = next(a for a in r["assignments"] if a["robot"] == victim)
    assert 19.0 < ev["t"] - first["t_assigned"] < 20.0 + 3 * speed
    assert 0.0 <= ev["t"] - t_kill < 2.0  # the liveliness token vanished at once
    assert ev["t_reassigned"] - ev["t"] < 5.0
    # the new robot completed laps of the route (under this or a later id)
    cover = [a for a in r["assignments"] if a["route"] == "aisles_1_2" and a["t_assigned"] >= ev["t"]]
    assert cover[0]["task_id"] == ev["new_task_id"]
    assert sum(a["laps"] for a in cover if a["robot"] == ev["to_robot"]) >= 1, cover
    assert r["laps_by_route"]["aisles_1_2"] >= 1
