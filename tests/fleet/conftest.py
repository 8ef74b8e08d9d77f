"""Shared fixtures of the fleet tests.

* ``free_port``: a TCP port on 127.0.0.1 that was free a moment ago.
* ``zenoh_endpoint``: ``tcp/127.0.0.1:<free_port>`` for one test's private Zenoh network.
* ``spawn``: start a Python subprocess (``spawn([... args])``) that is always reaped: at the
  end of the test it gets SIGTERM, then SIGKILL after 3 s if it is still running.

``tests/helpers`` (subprocess scripts such as ``bus_peer.py``) is put on ``sys.path`` so tests
can import their helper functions (``from bus_peer import record``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HELPERS = REPO / "tests" / "helpers"
if str(HELPERS) not in sys.path:
    sys.path.insert(0, str(HELPERS))

from ports import pick_free_port  # noqa: E402


@pytest.fixture
def free_port() -> int:
    return pick_free_port()


@pytest.fixture
def zenoh_endpoint(free_port: int) -> str:
    return f"tcp/127.0.0.1:{free_port}"


def stop_process(p: subprocess.Popen[str], grace_s: float = 3.0) -> None:
    """SIGTERM ``p``, wait ``grace_s``, then SIGKILL; always reap it."""
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)


@pytest.fixture
def spawn() -> Iterator[Callable[..., subprocess.Popen[str]]]:
    """``spawn(args, **popen_kw)`` runs ``python <args>`` with text pipes for stdout and
    stderr, the repository as working directory and on ``PYTHONPATH``."""
    procs: list[subprocess.Popen[str]] = []

    def start(args: list[str], **kw: object) -> subprocess.Popen[str]:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))
        env.setdefault("PYTHONUNBUFFERED", "1")
        p: subprocess.Popen[str] = subprocess.Popen(  # type: ignore[call-overload]
            [sys.executable, *args],
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            **kw,
        )
        procs.append(p)
        return p

    yield start
    for p in procs:
        stop_process(p)
        for f in (p.stdout, p.stderr, p.stdin):
            if f is not None:
                f.close()


@pytest.fixture(autouse=True)
def _state_root(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs without ``--state`` keep their task book under a temporary directory, not the
    repository's ``out/state`` (subprocesses inherit it)."""
    monkeypatch.setenv("FLEET_STATE_ROOT", str(tmp_path_factory.getbasetemp() / "fleet-state"))
