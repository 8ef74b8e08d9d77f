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

import atexit
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
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


class _Spare:
    """The next case's server, started in a background thread while the current case runs
    (each case still gets a fresh process; the start-up overlaps the case's waiting)."""

    def __init__(self) -> None:
        self.server: _Server | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._start, daemon=True)
        self._thread.start()

    def _start(self) -> None:
        try:
            self.server = _start_server()
        except BaseException as e:  # noqa: BLE001 - raised again by take()
            self.error = e

    def take(self) -> _Server:
        self._thread.join()
        if self.error is not None:
            raise self.error
        assert self.server is not None
        return self.server

    def discard(self) -> None:
        self._thread.join()
        if self.server is not None:
            self.server.stop()


_spare: list[_Spare] = []


#: Servers of finished cases being stopped (each takes a second or two to exit).
_stopping: list[threading.Thread] = []


def _stop_later(stop: Callable[[], object]) -> None:
    """Run ``stop`` in a background thread: the next case need not wait for the exit."""
    t = threading.Thread(target=stop, daemon=True)
    t.start()
    _stopping.append(t)


def _discard_spare() -> None:
    while _spare:
        _spare.pop().discard()
    while _stopping:
        _stopping.pop().join()


atexit.register(_discard_spare)


def between_cases(next_backend: str | None) -> None:
    """Called by ``conftest.py`` after each conformance test: no spare server outlives the
    last case of this backend."""
    if next_backend != "zenoh-bridge":
        _discard_spare()


@register_backend("zenoh-bridge")
@contextmanager
def zenoh_bridge_harness() -> Iterator[ConformanceHarness]:
    pytest.importorskip("zenoh")
    from fleet.bus.nav_client import ZenohNavBackend
    from fleet.bus.session import open_session

    server = _spare.pop().take() if _spare else _start_server()
    try:
        _spare.append(_Spare())
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
        _stop_later(server.stop)
