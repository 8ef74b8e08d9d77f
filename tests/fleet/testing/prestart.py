"""Conformance servers started ahead of the case that will use them.

Every conformance case gets a fresh server process; a harness asks its :class:`Pool` for the
server started (in a background thread) while the previous case ran, prepares the next one,
and hands the finished case's server to :meth:`Pool.stop_later` so that neither start-up nor
exit adds to a case. :meth:`Pool.between_cases` stops the spare after the backend's last case.
"""

from __future__ import annotations

import atexit
import threading
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar


class Stoppable(Protocol):
    def stop(self) -> object: ...


S = TypeVar("S", bound=Stoppable)


class Spare(Generic[S]):
    """A server being started in a background thread; ``tag`` is the harness's own note
    (e.g. the ROS domain it serves)."""

    def __init__(self, start: Callable[[], S], tag: int = 0) -> None:
        self.tag = tag
        self.server: S | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(start,), daemon=True)
        self._thread.start()

    def _run(self, start: Callable[[], S]) -> None:
        try:
            self.server = start()
        except BaseException as e:  # noqa: BLE001 - raised again by take()
            self.error = e

    def take(self) -> S:
        """The started server (waits for its start-up to end); raises what the start raised."""
        self._thread.join()
        if self.error is not None:
            raise self.error
        assert self.server is not None
        return self.server

    def discard(self) -> None:
        self._thread.join()
        if self.server is not None:
            self.server.stop()


class Pool(Generic[S]):
    """The spare server of one backend's conformance cases and the servers being stopped."""

    def __init__(self, backend: str) -> None:
        self.backend = backend
        self._spare: list[Spare[S]] = []
        self._stopping: list[threading.Thread] = []
        atexit.register(self.discard)

    def take(self) -> Spare[S] | None:
        """The spare started for this case, or ``None`` (the first case starts its own)."""
        return self._spare.pop() if self._spare else None

    def prepare(self, start: Callable[[], S], tag: int = 0) -> None:
        """Start the next case's server in the background."""
        self._spare.append(Spare(start, tag))

    def stop_later(self, server: S) -> None:
        """Stop ``server`` in a background thread: the next case need not wait for the exit."""
        t = threading.Thread(target=server.stop, daemon=True)
        t.start()
        self._stopping.append(t)

    def wait_stopped(self) -> None:
        """Wait until every server handed to :meth:`stop_later` has exited."""
        for t in list(self._stopping):
            t.join()

    def discard(self) -> None:
        while self._spare:
            self._spare.pop().discard()
        while self._stopping:
            self._stopping.pop().join()

    def between_cases(self, next_backend: str | None) -> None:
        """Called by ``conftest.py`` after each conformance test: no spare server outlives the
        last case of this backend (it would run in the background through other cases)."""
        if next_backend != self.backend:
            self.discard()
