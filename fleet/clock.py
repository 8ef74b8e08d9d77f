"""Clocks passed into behaviors, simulators and runners. Nothing in the core reads wall time
except :class:`WallClock`, which only the real-time pacing of a run uses."""

from __future__ import annotations

import time
from collections.abc import Callable

from fleet.navigation import Clock


class SimClock:
    """A simulated clock advanced explicitly by the runner, starting at ``start`` seconds."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def advance(self, dt: float) -> float:
        """Advance by ``dt`` seconds (must be >= 0) and return the new time."""
        if dt < 0:
            raise ValueError(f"cannot advance a clock by a negative step ({dt} s)")
        self._t += dt
        return self._t

    def set(self, t: float) -> None:
        """Jump to ``t`` seconds (used by clocks that follow a remote simulator)."""
        self._t = float(t)


class WallClock:
    """Monotonic wall time in seconds; for pacing real-time runs and measuring them."""

    def now(self) -> float:
        return time.monotonic()


def step_until(
    clock: Clock, step: Callable[[], None], predicate: Callable[[], bool], timeout_s: float
) -> bool:
    """Call ``step()`` until ``predicate()`` is true (checked before each step) or ``clock``
    has advanced ``timeout_s`` seconds. Returns whether the predicate became true. Shared by
    every stepped world (the simulator, SUMO)."""
    end = clock.now() + timeout_s - 1e-9
    while True:
        if predicate():
            return True
        if clock.now() >= end:
            return False
        step()
