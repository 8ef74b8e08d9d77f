"""Conformance harness of the Zenoh bridge (:mod:`fleet.bus.nav_server`), registered as
``"zenoh-bridge"``.

The conformance room (:data:`fleet.testing.room.SIM_WORLD`, the grid of
:func:`fleet.testing.room.conformance_grid`) is simulated in a *separate process*
(``tests/helpers/bus_peer.py navserver``, a Zenoh router serving the simulator at
:data:`SPEED` x real time); the backend under test is a :class:`ZenohNavBackend` in this
process, connected as a client on a free loopback port. ``advance(s)`` waits (wall time)
until the robot's state messages report ``s`` more simulated seconds, and for at least two
state messages, so a request sent before the call has been applied and reported.

Every case gets a fresh simulator process; the next case's one starts while the current case
runs, and the spare is stopped after the last case of this backend.
"""

from __future__ import annotations

import os
import selectors
import signal
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
from prestart import Pool

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


@dataclass
class _Server:
    """A running ``bus_peer.py navserver`` (it printed ``ready``) and its endpoint."""

    proc: subprocess.Popen[str]
    endpoint: str

    def stop(self) -> None:
        proc = self.proc
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(3)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        if proc.stdout is not None:
            proc.stdout.close()


def _start_server() -> _Server:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    )
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "tests/helpers/bus_peer.py"), "navserver", endpoint, str(SPEED)],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    server = _Server(proc, endpoint)
    try:
        ready = _read_line(proc, START_TIMEOUT_S).strip()
        assert ready == "ready", f"the simulator process did not start within {START_TIMEOUT_S} s"
    except BaseException:
        server.stop()
        raise
    return server


#: The spare simulator process and the ones being stopped.
_POOL: Pool[_Server] = Pool("zenoh-bridge")
between_cases = _POOL.between_cases


@register_backend("zenoh-bridge")
@contextmanager
def zenoh_bridge_harness() -> Iterator[ConformanceHarness]:
    pytest.importorskip("zenoh")
    from fleet.bus.nav_client import ZenohNavBackend
    from fleet.bus.session import open_session

    spare = _POOL.take()
    server = spare.take() if spare is not None else _start_server()
    try:
        _POOL.prepare(_start_server)
        session = open_session(server.endpoint, "client")
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
        _POOL.stop_later(server)
