"""The fleet clock of a simulator in another process, read from ``fleet/sim/clock``."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from fleet.bus.keys import CLOCK_KEY
from fleet.bus.session import undeclare_all
from fleet.messages.nav import CLOCK_CODEC

logger = logging.getLogger(__name__)

#: A clock message more than this many simulated seconds ahead of the clock is a jump: applied
#: only once the next message confirms it (docs/protocol.md).
MAX_CLOCK_JUMP_S = 300.0


class BusClock:
    """A :class:`~fleet.navigation.Clock` following ``fleet/sim/clock`` (simulated seconds).

    :meth:`now` is the latest time received (``start`` before the first message); ``speed``
    and ``step_s`` are the simulator's (``None`` before the first message). A malformed clock
    message is counted in ``malformed`` (``last_malformed`` says why) and dropped. A message
    more than :data:`MAX_CLOCK_JUMP_S` ahead of the clock is held back and applied only if the
    next message confirms the jump (is not earlier and not again that far ahead); a lone one
    (a message such as ``t = 1e9`` put by an outsider, which would end every run at once) is
    counted in ``rejected`` and dropped. With
    ``sources`` (:meth:`fleet.bus.lease.SimLeaseWatch.admits`), a message whose ``src`` is not
    a live simulator's is counted in ``rejected`` and dropped. Call
    :meth:`close` when done (the session stays open).

    The clock never goes backwards: a simulator restarted behind the time already read (a
    ``fleet sim`` started again from its snapshot, or from zero without one) holds
    :meth:`now` where it was until the simulator's time passes it (``rewinds`` counts these).
    """

    def __init__(
        self, session: zenoh.Session, *, start: float = 0.0, sources: Callable[[str], bool] | None = None
    ) -> None:
        self.sources = sources
        self._t = float(start)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self.updates = 0
        self.malformed = 0
        self.last_malformed: str | None = None
        self.rejected = 0
        self._jump: float | None = None
        self.speed: float | None = None
        self.step_s: float | None = None
        self.rewinds = 0
        self._behind = False
        self._sub: zenoh.Subscriber[None] | None = session.declare_subscriber(CLOCK_KEY, self._on_clock)

    def _on_clock(self, sample: zenoh.Sample) -> None:
        try:
            msg = CLOCK_CODEC.decode(sample.payload.to_bytes())
        except Exception as e:  # noqa: BLE001 - count and drop
            with self._lock:
                self.malformed += 1
                self.last_malformed = f"{CLOCK_KEY}: {e}"
            return
        with self._cond:
            if self.sources is not None and not self.sources(msg.src):
                self.rejected += 1  # not from a live simulator
                return
            if not self._admit(msg.t):
                return
            if msg.t < self._t - 1e-9 and self.updates:
                if not self._behind:
                    self.rewinds += 1
                    logger.warning(
                        "the simulator's clock went back from %.2f s to %.2f s (a restarted `fleet sim`): "
                        "fleet time holds at %.2f s until the simulator catches up",
                        self._t,
                        msg.t,
                        self._t,
                    )
                self._behind = True
            else:
                self._behind = False
                self._t = msg.t
            self.speed, self.step_s = msg.speed, msg.step_s
            self.updates += 1
            self._cond.notify_all()

    def _admit(self, t: float) -> bool:
        # caller holds self._lock
        jump, self._jump = self._jump, None
        confirmed = jump is not None and jump <= t <= jump + MAX_CLOCK_JUMP_S
        if jump is not None and not confirmed:
            self.rejected += 1  # the jump held back was a lone message: dropped
        if self.updates == 0 or t <= self._t + MAX_CLOCK_JUMP_S or confirmed:
            return True
        self._jump = t
        return False

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
        """Undeclare the subscription (idempotent)."""
        sub, self._sub = self._sub, None
        undeclare_all([sub])
