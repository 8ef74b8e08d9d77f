"""The fleet clock of a simulator in another process, read from ``fleet/sim/clock``."""

from __future__ import annotations

import threading
import time
from typing import Any

import zenoh

from fleet.bus.keys import CLOCK_KEY
from fleet.messages import (
    _loads,
    as_float,
    req,
)


class BusClock:
    """A :class:`~fleet.navigation.Clock` following ``fleet/sim/clock`` (simulated seconds).

    :meth:`now` is the latest time received (``start`` before the first message). Call
    :meth:`close` when done.
    """

    def __init__(self, session: zenoh.Session, *, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self.updates = 0
        self.malformed = 0
        self.speed: float | None = None
        self.step_s: float | None = None
        self._sub: Any = session.declare_subscriber(CLOCK_KEY, self._on_clock)

    def _on_clock(self, sample: Any) -> None:
        try:
            d = _loads(sample.payload.to_bytes(), "clock")
            t = as_float(req(d, "t", "clock"), "clock.t")
            speed = as_float(d.get("speed", 0.0), "clock.speed")
            step_s = as_float(d.get("step_s", 0.0), "clock.step_s")
        except Exception:  # noqa: BLE001
            with self._lock:
                self.malformed += 1
            return
        with self._cond:
            self._t = t
            self.speed, self.step_s = speed, step_s
            self.updates += 1
            self._cond.notify_all()

    def now(self) -> float:
        with self._lock:
            return self._t

    def wait_until(self, t: float, timeout_s: float) -> bool:
        """Block until the clock reads ``>= t`` or ``timeout_s`` wall seconds passed."""
        end = time.monotonic() + timeout_s
        with self._cond:
            while self._t < t:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def wait_first(self, timeout_s: float) -> bool:
        """Block until the first clock message arrived (or ``timeout_s`` wall seconds)."""
        end = time.monotonic() + timeout_s
        with self._cond:
            while self.updates == 0:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001
            pass
