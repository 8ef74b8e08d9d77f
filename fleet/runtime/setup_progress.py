"""Progress lines of a long set-up: a fleet of thousands of robots takes minutes to build
(world, coordinator, one agent per robot) before it moves; these lines say how far it got."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol


class _Wall(Protocol):
    def now(self) -> float: ...


class SetupProgress:
    """Set-up progress lines: ``done(what)`` after each phase, ``every(what)`` inside a long
    one (at most every :attr:`interval_s` wall seconds); each line says the phase's wall
    seconds, the set-up's so far and this process's CPU seconds so far (on a shared machine
    the CPU seconds are the figures to compare)."""

    interval_s = 10.0

    def __init__(self, out: Callable[[str], None] | None, wall: _Wall) -> None:
        self.out, self.wall = out, wall
        self.t0 = self.t_phase = self.t_line = wall.now()

    def every(self, what: str) -> None:
        if self.out is not None and self.wall.now() - self.t_line >= self.interval_s:
            self._line(what, self.wall.now())

    def done(self, what: str) -> None:
        now = self.wall.now()
        if self.out is not None:
            self._line(f"{what} ready in {now - self.t_phase:.1f} s", now)
        self.t_phase = now

    def _line(self, what: str, now: float) -> None:
        assert self.out is not None
        self.t_line = now
        cpu = time.process_time()
        self.out(f"setup: {what} (set-up {now - self.t0:.0f} s so far, process CPU {cpu:.0f} s)")


__all__ = ["SetupProgress"]
