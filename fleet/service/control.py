"""Pause, resume, e-stop and release: the fleet's control state and who changed it when.

States and commands (``docs/service.md``)::

    running --pause--> paused --resume--> running
    running/paused --estop--> estop --release--> paused --resume--> running

* **pause**: every robot stops where it is (its goal is canceled) and keeps its task and its
  traffic reservations; **resume** lets them carry on with the same tasks.
* **estop**: latched. Every robot stops within one simulator step of the command reaching
  the coordinator (the world's latch zeroes every robot's speed at the next step), and
  nothing moves while it is latched, whatever the coordinator or an agent sends (the latch
  sits below the trees: in the simulator, in ``fleet sim`` for remote robots, and in every
  agent's backend, which refuses goals). Only **release** unlatches it, and the fleet is then
  *paused*: releasing an emergency stop never starts motion by itself (``resume`` does).
* ``resume`` while the e-stop is latched is refused (:class:`~fleet.errors.CommandRefused`);
  a command that changes nothing (``pause`` while paused) is accepted and changes nothing.

Every change gets the next ``seq``, the fleet and wall time, ``by`` and ``reason``; it is
stored in the durable task book (a restarted coordinator is still latched), kept in a
bounded history (the run report lists it) and handed to every sink (the world's latch, the
bus, the in-process agents, the coordinator).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

import msgspec

from fleet.errors import CommandRefused, InvalidTask
from fleet.messages import FleetControl
from fleet.navigation import Clock

logger = logging.getLogger(__name__)

#: The commands.
COMMANDS = ("pause", "resume", "estop", "release")
#: At most this many changes are kept in :attr:`FleetSwitch.history`.
MAX_HISTORY = 1000

Sink = Callable[[FleetControl], None]


class FleetSwitch:
    """The fleet's control state machine (see the module docstring).

    ``save(ctl)`` persists a change (the durable store); ``initial`` is the state read back
    from it after a restart. Thread-safe: commands come from the API's threads."""

    def __init__(
        self,
        clock: Clock | None = None,
        save: Callable[[FleetControl], None] | None = None,
        initial: FleetControl | None = None,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.clock = clock
        self._save = save
        self._wall = wall
        self.current = initial or FleetControl(estop=False, paused=False, seq=0)
        self.history: deque[FleetControl] = deque(maxlen=MAX_HISTORY)
        if initial is not None and initial.seq > 0:
            self.history.append(initial)
        self.sinks: list[Sink] = []
        self._lock = threading.Lock()

    def add_sink(self, sink: Sink) -> None:
        """Hand every change to ``sink`` (and the current state now)."""
        self.sinks.append(sink)
        sink(self.current)

    def command(self, action: str, by: str = "", reason: str = "") -> FleetControl:
        """Apply ``action`` (:data:`COMMANDS`); returns the state after it. Raises
        :class:`~fleet.errors.InvalidTask` for an unknown command and
        :class:`~fleet.errors.CommandRefused` for ``resume`` while latched."""
        if action not in COMMANDS:
            raise InvalidTask("action", f"unknown command {action!r} (expected one of {', '.join(COMMANDS)})")
        with self._lock:
            cur = self.current
            estop, paused = cur.estop, cur.paused
            if action == "pause":
                paused = True
            elif action == "resume":
                if cur.estop:
                    raise CommandRefused("the e-stop is latched: release it first, then resume")
                paused = False
            elif action == "estop":
                estop, paused = True, True
            else:  # release: unlatch, stay paused
                estop = False
            if (estop, paused) == (cur.estop, cur.paused):
                return cur
            ctl = FleetControl(
                estop=estop,
                paused=paused,
                seq=cur.seq + 1,
                t=float(self.clock.now()) if self.clock is not None else 0.0,
                wall=self._wall(),
                by=by[:256],
                action=action,
                reason=reason[:256],
            )
            self.current = ctl
            self.history.append(ctl)
            sinks = list(self.sinks)
        logger.warning("fleet %s by %s (%s): %s", action, by or "?", reason or "no reason given", ctl.state)
        for sink in sinks:  # the latch first: it stops the robots at the next step
            try:
                sink(ctl)
            except Exception as e:  # noqa: BLE001 - one failing sink must not stop the others
                logger.error("control sink %r failed: %s", sink, e)
        if self._save is not None:
            self._save(ctl)
        return ctl

    def restamp(self, seq_floor: int) -> None:
        """Make the next change's ``seq`` exceed ``seq_floor`` (e.g. a newer state seen on the bus)."""
        with self._lock:
            if self.current.seq < seq_floor:
                self.current = msgspec.structs.replace(self.current, seq=seq_floor)
