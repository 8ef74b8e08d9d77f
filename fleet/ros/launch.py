"""Start and stop a Nav2 simulator server (:mod:`fleet.ros.nav2_server`) in a child process.

Used by the tests, the benchmark and the ``--backend ros`` demo: the child gets its own
process group, the fleet's ROS environment defaults and the caller's ``ROS_DOMAIN_ID``;
:meth:`ServerProcess.stop` sends SIGINT, waits, and kills the whole group as a fallback, so
no process is left behind. Imports nothing from ROS.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from pathlib import Path
from typing import NotRequired, TypedDict

from fleet.errors import BackendError
from fleet.ros.env import apply_ros_env_defaults


class ReadyInfo(TypedDict):
    """The ready file a server writes once every robot's interfaces exist."""

    pid: int
    robots: list[str]
    create_s: float
    domain_id: str
    #: Processes serving the robots (``--shards``; 1 for one process).
    shards: int
    #: DDS participants per process (``--participants``).
    participants: int
    #: With ``--shards`` above 1: each shard process's pid and creation time (wall s).
    shard_pids: NotRequired[list[int]]
    shard_create_s: NotRequired[list[float]]
    #: With ``--shards`` above 1: each shard's ROS domain (differ with ``--shard-domains``).
    shard_domain_ids: NotRequired[list[int]]


def write_ready(path: str, info: ReadyInfo) -> None:
    """Write the ready file ``path`` atomically (:meth:`ServerProcess._wait_ready` never reads
    half of it)."""
    tmp = Path(path + ".tmp")
    tmp.write_text(json.dumps(info) + "\n")
    tmp.replace(path)


class ServerProcess:
    """A running ``python -m fleet.ros.nav2_server`` (or any command that writes the same
    ready file). Use as a context manager, or call :meth:`stop`."""

    def __init__(
        self, argv: list[str], *, env: Mapping[str, str] | None = None, ready_timeout_s: float = 60.0
    ) -> None:
        self._tmp = tempfile.TemporaryDirectory(prefix="fleet-sim-ros-")
        self.ready_file = str(Path(self._tmp.name) / "ready.json")
        self.log_path = Path(self._tmp.name) / "server.log"
        e = dict(os.environ if env is None else env)
        apply_ros_env_defaults(environ=e)
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.argv = list(argv) + ["--ready-file", self.ready_file]
        self.proc = subprocess.Popen(
            self.argv, stdout=self._log, stderr=subprocess.STDOUT, env=e, start_new_session=True
        )
        try:
            #: What the server wrote to its ready file.
            self.info: ReadyInfo = self._wait_ready(ready_timeout_s)
        except BaseException:
            self.stop()
            raise

    @classmethod
    def for_config(
        cls,
        config: str | os.PathLike[str],
        *extra: str,
        env: Mapping[str, str] | None = None,
        ready_timeout_s: float = 60.0,
    ) -> ServerProcess:
        """Serve the robots of a fleet config: ``fleet sim-ros CONFIG EXTRA...``."""
        return cls(
            [sys.executable, "-m", "fleet.ros.nav2_server", str(config), *extra],
            env=env,
            ready_timeout_s=ready_timeout_s,
        )

    def _wait_ready(self, timeout_s: float) -> ReadyInfo:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if os.path.exists(self.ready_file):
                info: ReadyInfo = json.loads(Path(self.ready_file).read_text())
                return info
            if self.proc.poll() is not None:
                raise BackendError(f"Nav2 simulator server exited with {self.proc.returncode}:\n{self.log()}")
            time.sleep(0.05)
        raise BackendError(f"Nav2 simulator server not ready after {timeout_s} s:\n{self.log()}")

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")[-4000:]

    def kill(self) -> None:
        """SIGKILL the server's process group at once (simulates a crashed Nav2)."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=5)

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """SIGINT, then SIGKILL of the process group after ``timeout_s``; returns the exit code."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGINT)
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=5)
            except ProcessLookupError:
                pass
        try:  # stray children of the group, if any
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        if not self._log.closed:
            self._log.close()
        self._tmp.cleanup()
        return self.proc.returncode

    def __enter__(self) -> ServerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
