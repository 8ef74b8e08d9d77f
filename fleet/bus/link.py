"""The bus-loss watchdog's eye: whether a client session still has its link to the bus.

A process that *connects* to the fleet's endpoint (``fleet agent``, ``fleet coordinator``, or
a runner with ``listen=False``) is on the bus only through its Zenoh router. :class:`LinkWatch`
reports, in wall time, how long that link has been down; the runner stops its robots when it
has been down for the config's ``bus.link_timeout_s`` (``docs/faults.md``).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import zenoh

from fleet.bus.session import has_router


class LinkWatch:
    """The link of a client ``session`` to its router, checked on demand.

    :meth:`check` returns why the link counts as lost (``""`` while it is up or has been down
    for less than ``timeout_s`` wall seconds). ``losses`` counts the times a check found the
    router gone after it had been there (at once, whatever ``timeout_s``), ``outages`` the
    times the link counted as lost, ``down_s`` is the length of the current outage (0 while up). ``wall`` is a monotonic
    clock in seconds.
    """

    def __init__(
        self, session: zenoh.Session, timeout_s: float, *, wall: Callable[[], float] = time.monotonic
    ) -> None:
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self.session = session
        self.timeout_s = float(timeout_s)
        self._wall = wall
        self._down_since: float | None = None
        self._lost = False
        self.outages = 0
        self.losses = 0

    @property
    def down_s(self) -> float:
        return 0.0 if self._down_since is None else self._wall() - self._down_since

    def check(self) -> str:
        """``""`` while the link is up (or down for less than ``timeout_s``), else the reason."""
        if has_router(self.session):
            self._down_since = None
            self._lost = False
            return ""
        now = self._wall()
        if self._down_since is None:
            self._down_since = now
            self.losses += 1
        down = now - self._down_since
        if down < self.timeout_s:
            return ""
        if not self._lost:
            self._lost = True
            self.outages += 1
        return f"bus link lost: no Zenoh router for {self.timeout_s:g} s"
