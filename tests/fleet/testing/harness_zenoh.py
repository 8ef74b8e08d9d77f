"""Conformance harness of the Zenoh bridge (:mod:`fleet.bus.nav_server`), registered as
``"zenoh-bridge"``.

The conformance room (:data:`fleet.testing.room.SIM_WORLD`, the grid of
:func:`fleet.testing.room.conformance_grid`) is simulated in a *separate process*
(``tests/helpers/bus_peer.py navserver``, a Zenoh router serving the simulator at
:data:`SPEED` x real time); the backend under test is a :class:`ZenohNavBackend` in this
process, connected as a client on a free loopback port. ``advance(s)`` waits (wall time)
until the robot's state messages report ``s`` more simulated seconds, and for at least two
state messages, so a request sent before the call has been applied and reported.

Every case gets a fresh simulator and a fresh router on a new port, served by one long-lived
process (``bus_peer.py navpool``, started at the first case and stopped after the last case of
this backend), so a case pays neither a Python start-up nor an exit.
"""

from __future__ import annotations

import atexit
import os
import selectors
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from conformance_harness import register_backend

from fleet.navigation import NavigationBackend
from fleet.testing.conformance import ConformanceHarness, ConformanceWorld
from fleet.testing.room import SIM_WORLD

SPEED = 10.0
REPO = Path(__file__).resolve().parents[3]
#: Wall seconds the simulator process and the first state message may take on a loaded machine.
START_TIMEOUT_S = 30.0


@dataclass
class ZenohHarness:
    backend: NavigationBackend
    world: ConformanceWorld

    def advance(self, seconds: float) -> None:
        b = self.backend
        assert hasattr(b, "sim_time") and hasattr(b, "states_received")
        t0 = b.sim_time or 0.0
        n0 = b.states_received
        deadline = time.monotonic() + seconds / SPEED * 3.0 + 5.0
        while time.monotonic() < deadline:
            if (b.sim_time or 0.0) >= t0 + seconds - 1e-6 and b.states_received >= n0 + 2:
                return
            time.sleep(0.002)
        raise AssertionError(f"the served simulator did not advance {seconds} s in time")


def _read_line(proc: subprocess.Popen[str], timeout_s: float) -> str:
    """The child's next stdout line, or "" if none came within ``timeout_s`` wall seconds."""
    assert proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            return ""
    return proc.stdout.readline()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _NavPool:
    """The ``bus_peer.py navpool`` process: one fresh served simulator per case."""

    def __init__(self) -> None:
        self.proc: subprocess.Popen[str] | None = None

    def _process(self) -> subprocess.Popen[str]:
        if self.proc is None or self.proc.poll() is not None:
            env = dict(
                os.environ,
                PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
            )
            self.proc = subprocess.Popen(
                [sys.executable, str(REPO / "tests/helpers/bus_peer.py"), "navpool", "-", str(SPEED)],
                cwd=REPO,
                env=env,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
        return self.proc

    def _ask(self, verb: str, endpoint: str, answer: str) -> None:
        proc = self._process()
        assert proc.stdin is not None
        proc.stdin.write(f"{verb} {endpoint}\n")
        proc.stdin.flush()
        got = _read_line(proc, START_TIMEOUT_S).strip()
        assert got == f"{answer} {endpoint}", f"the simulator process answered {got!r} to {verb}"

    def start(self) -> str:
        """A fresh simulator served by a fresh router; its endpoint."""
        endpoint = f"tcp/127.0.0.1:{_free_port()}"
        self._ask("new", endpoint, "ready")
        return endpoint

    def release(self, endpoint: str) -> None:
        self._ask("stop", endpoint, "stopped")

    def stop(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None:
            return
        if proc.stdin is not None:
            proc.stdin.close()  # end of input: it stops its servers and exits
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        if proc.stdout is not None:
            proc.stdout.close()


_POOL = _NavPool()
atexit.register(_POOL.stop)


def between_cases(next_backend: str | None) -> None:
    """Called by ``conftest.py`` after each conformance test: the process ends after the last
    case of this backend."""
    if next_backend != "zenoh-bridge":
        _POOL.stop()


@register_backend("zenoh-bridge")
@contextmanager
def zenoh_bridge_harness() -> Iterator[ConformanceHarness]:
    pytest.importorskip("zenoh")
    from fleet.bus.nav_client import ZenohNavBackend
    from fleet.bus.session import open_session

    endpoint = _POOL.start()
    try:
        session = open_session(endpoint, "client")
        try:
            backend = ZenohNavBackend(session, "/robot1", timeout_s=2.0)
            try:
                assert backend.wait_for_server(START_TIMEOUT_S), "no state message from the served simulator"
                yield ZenohHarness(backend, SIM_WORLD)
            finally:
                backend.close()
        finally:
            session.close()
    finally:
        _POOL.release(endpoint)
