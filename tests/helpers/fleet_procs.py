"""A fleet split over processes for end-to-end tests: ``fleet sim``, ``fleet agent`` and
``fleet coordinator`` subprocesses on one free loopback endpoint, their output, and waits on
conditions (a line in a process's output, a status on the bus) with deadlines.

Imported by the end-to-end tests of several packages (``from fleet_procs import ...``: the
fleet tests' conftest puts ``tests/helpers`` on ``sys.path``).
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

import yaml
from ports import free_endpoint

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

ROOT = Path(__file__).resolve().parents[2]
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
