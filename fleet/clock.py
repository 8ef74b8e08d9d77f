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


class Pacer:
    """Paces a simulated clock against the wall clock: the one real-time loop of the project.

    ``speed`` is the multiple of real time (``0``: no pacing, as fast as possible). After each
    step, :meth:`wait` sleeps until the wall clock has caught up with ``speed`` times the
    simulated time passed since :meth:`start` (never sleeping when behind: a slow step is not
    made up by a burst later, the run just falls behind). ``lag()`` tells how far behind (wall
    seconds) the run is. The simulated time is read from ``clock``; the wall time from
    ``wall`` (default :class:`WallClock`), so tests can pass their own.
    """

    def __init__(self, clock: Clock, speed: float, wall: Clock | None = None) -> None:
        if not speed >= 0 or speed == float("inf"):
            raise ValueError(f"speed must be a finite number >= 0 (0 = as fast as possible), got {speed}")
        self.clock = clock
        self.speed = float(speed)
        self.wall = wall or WallClock()
        self._t0 = clock.now()
        self._w0 = self.wall.now()

    def start(self) -> None:
        """Take the current simulated and wall times as the origin of the pacing."""
        self._t0 = self.clock.now()
        self._w0 = self.wall.now()

    def ahead(self) -> float:
        """Wall seconds the simulation is ahead of real time (negative: behind; 0 unpaced)."""
        if self.speed <= 0:
            return 0.0
        return (self.clock.now() - self._t0) / self.speed - (self.wall.now() - self._w0)

    def wait(self, sleep: Callable[[float], None] = time.sleep) -> None:
        """Sleep until real time has caught up with the simulated time (no-op when unpaced)."""
        ahead = self.ahead()
        if ahead > 0:
            sleep(ahead)


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


#: Tolerance on simulated-time comparisons of a tick schedule (s).
TICK_EPS = 1e-9


class TickSchedule:
    """When the agents tick: every ``period`` simulated seconds from ``t0``, until ``t0 +
    duration``. A clock that jumps ahead (a remote simulator) does not cause a burst of ticks."""

    def __init__(self, t0: float, period: float, duration: float | None) -> None:
        self.next = t0
        self.period = period
        self.end = None if duration is None else t0 + duration

    def finished(self, now: float) -> bool:
        return self.end is not None and now >= self.end - TICK_EPS

    def due(self, now: float) -> bool:
        """Whether a tick is due at ``now``; if so, schedule the next one."""
        if now < self.next - TICK_EPS:
            return False
        self.next += self.period
        if self.next <= now:
            self.next = now + self.period
        return True
