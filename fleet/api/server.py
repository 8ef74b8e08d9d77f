"""Serving the API: uvicorn in a background thread of the process that runs the coordinator
(``fleet run --api HOST:PORT``, ``fleet coordinator --api HOST:PORT``)."""

from __future__ import annotations

import logging
import re
import threading
import time

import uvicorn
from fastapi import FastAPI

from fleet.errors import ServiceError

logger = logging.getLogger(__name__)

#: How long :meth:`ApiServer.start` waits for the server to listen (wall s).
START_TIMEOUT_S = 15.0

_ADDRESS = re.compile(r"^(?P<host>[A-Za-z0-9_.\-]+|\[[0-9a-fA-F:]+\]):(?P<port>\d{1,5})$")


def parse_address(text: str) -> tuple[str, int]:
    """``("127.0.0.1", 8080)`` for ``127.0.0.1:8080``; ``ValueError`` naming what is wrong."""
    m = _ADDRESS.match(text.strip())
    if m is None:
        raise ValueError(f"expected HOST:PORT such as 127.0.0.1:8080, got {text!r}")
    port = int(m.group("port"))
    if not 0 <= port <= 65535:
        raise ValueError(f"port {port} is not in 0..65535")
    return m.group("host").strip("[]"), port


class ApiServer:
    """``app`` served by uvicorn on ``host:port`` in a daemon thread. :meth:`start` returns
    once it listens (:class:`~fleet.errors.ServiceError` if it cannot); :meth:`stop` ends it."""

    def __init__(self, app: FastAPI, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.config = uvicorn.Config(
            app,
            host=host,
            port=port,
            log_level="warning",
            lifespan="off",
            ws="websockets-sansio",
            access_log=False,
        )
        self.server = uvicorn.Server(self.config)
        self.thread = threading.Thread(target=self._run, name=f"api {host}:{port}", daemon=True)
        self._failed: BaseException | None = None

    @property
    def url(self) -> str:
        """``http://host:port`` (the port actually bound when 0 was asked for)."""
        return f"http://{self.host}:{self.port}"

    def _run(self) -> None:
        try:
            self.server.run()
        except BaseException as e:  # noqa: BLE001 - uvicorn exits with SystemExit when it cannot bind
            self._failed = e

    def start(self) -> ApiServer:
        self.thread.start()
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                self.stop()
                raise ServiceError(
                    f"cannot serve the API on {self.host}:{self.port} (port in use or not allowed?)"
                )
            time.sleep(0.01)
        if self.port == 0:
            for s in self.server.servers:
                for sock in s.sockets:
                    self.port = int(sock.getsockname()[1])
        logger.info("API on %s", self.url)
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self.server.should_exit = True
        if self.thread.is_alive():
            self.thread.join(timeout_s)
