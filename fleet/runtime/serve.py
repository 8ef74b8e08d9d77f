"""``fleet sim``: serve the kinematic simulator's robots over Zenoh and step it in (paced) time.

:func:`serve_simulator` steps the simulator at ``speed`` x real time with the one
:class:`fleet.clock.Pacer`, applies the navigation requests received before every step and
publishes the robots' states and the simulated clock ``publish_hz`` times per wall second
(:class:`fleet.bus.nav_server.SimNavServer`). It prints nothing: progress goes to an optional
callback (``fleet sim`` shows it with :mod:`fleet.viz.display`). It follows the fleet's
control state on the bus (``fleet/control/state``): while the coordinator's e-stop is latched,
every robot is stalled before each step (:class:`fleet.runtime.latch.WorldLatch`), whatever
its agent sends. With ``state_dir`` it keeps the simulator's snapshot there
(:mod:`fleet.runtime.snapshot`) and starts from the one it finds: a ``fleet sim`` killed and
started again puts its robots back where they were.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh

from fleet.bus.nav_server import SimNavServer
from fleet.bus.status_bus import StatusBus
from fleet.clock import Pacer, WallClock
from fleet.config.model import FleetConfig
from fleet.errors import BackendError
from fleet.runtime.latch import Latch, WorldLatch
from fleet.runtime.snapshot import SnapshotWriter, resume_simulator, simulator_from_config

if TYPE_CHECKING:
    from fleet.bus.session import Secure
    from sim.simulator import Simulator

logger = logging.getLogger(__name__)


@dataclass
class ServeResult:
    """What :func:`serve_simulator` returns: the simulator, steps taken, simulated and wall
    seconds, and whether it was interrupted (Ctrl-C / SIGTERM / ``stop_event``);
    ``malformed``: payloads dropped unparsed (navigation requests and control states)."""

    simulator: Simulator
    steps: int
    sim_time_s: float
    wall_time_s: float
    interrupted: bool
    malformed: int = 0


@dataclass(frozen=True)
class ServeProgress:
    """Progress of :func:`serve_simulator`: simulated seconds served, wall seconds since the
    start, simulator steps taken and navigation requests applied so far, and payloads
    dropped unparsed (``malformed``)."""

    sim_time_s: float
    wall_s: float
    steps: int
    requests: int
    malformed: int = 0


@contextmanager
def _sigterm_sets(stop: threading.Event) -> Iterator[None]:
    """While inside, SIGTERM sets ``stop`` (main thread only; elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def serve_simulator(
    simulator: Simulator | FleetConfig,
    session: zenoh.Session | None = None,
    *,
    endpoint: str | None = None,
    secure: Secure | None = None,
    speed: float = 1.0,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
    publish_hz: float = 50.0,
    quiet: bool = False,
    progress: Callable[[ServeProgress], None] | None = None,
    progress_every_s: float = 10.0,
    state_dir: Path | None = None,
) -> ServeResult:
    """Step ``simulator`` at ``speed`` x real time (``0``: as fast as possible) and serve it
    with a :class:`SimNavServer` until ``duration`` simulated seconds passed (``None``:
    forever), ``stop_event`` is set, Ctrl-C or SIGTERM (when called from the main thread).

    ``simulator`` may also be a fleet config (the simulator is built with its robots).
    Without ``session`` a router session listening on ``endpoint`` is opened and closed here
    (:class:`~fleet.errors.BusError` if it cannot be); with ``secure`` it enforces the key
    directory's credentials and access control (``docs/security.md``). Requests are applied before every step;
    states and the clock are published ``publish_hz`` times per wall second. Unless ``quiet``,
    ``progress`` is called every ``progress_every_s`` wall seconds. With ``state_dir`` the
    simulator (built from a config) resumes from the snapshot there, and a snapshot is written
    every :data:`~fleet.runtime.snapshot.SNAPSHOT_EVERY_S` wall seconds and at the end. Raises
    :class:`~fleet.errors.BackendError` for a negative or infinite ``speed``.
    """
    from fleet.bus.session import open_session
    from fleet.messages import DEFAULT_ENDPOINT

    if speed < 0 or not math.isfinite(speed):
        raise BackendError(f"speed must be >= 0, got {speed}")
    if isinstance(simulator, FleetConfig):
        config: FleetConfig | None = simulator
        sim = (
            simulator_from_config(simulator) if state_dir is None else resume_simulator(simulator, state_dir)
        )
    else:
        config, sim = None, simulator
    stop = stop_event or threading.Event()
    sess = open_session(endpoint or DEFAULT_ENDPOINT, "router", secure=secure) if session is None else session
    server: SimNavServer | None = None
    loop = _ServeLoop(sim, speed, duration, stop, 1.0 / publish_hz)
    if state_dir is not None and config is not None:
        loop.snapshots = SnapshotWriter(sim, config, state_dir)
    bus = StatusBus(sess)
    try:
        bus.subscribe_control(loop.latch.latch.follow)  # the e-stop latch, from the coordinator
        with _sigterm_sets(stop):
            server = SimNavServer(sess, sim)
            server.speed = speed
            loop.run(server, None if quiet else progress, progress_every_s)
    finally:
        if server is not None:
            server.close()
        bus.close()
        if session is None:
            sess.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves Session.close unannotated
    malformed = bus.malformed + (server.malformed if server is not None else 0)
    return ServeResult(
        sim, loop.steps, float(sim.clock.now() - loop.t0), loop.wall_s(), loop.interrupted, malformed
    )


class _ServeLoop:
    """The paced stepping loop of :func:`serve_simulator`."""

    def __init__(
        self, sim: Simulator, speed: float, duration: float | None, stop: threading.Event, period_s: float
    ) -> None:
        self.sim = sim
        self.stop = stop
        self.period_s = period_s
        self.wall = WallClock()
        self.pacer = Pacer(sim.clock, speed, self.wall)
        self.t0 = sim.clock.now()
        self.w0 = self.wall.now()
        self.end = None if duration is None else self.t0 + duration
        self.steps = 0
        self.interrupted = False
        #: The e-stop latch below every agent, applied before each step (``fleet.runtime.latch``).
        self.latch = WorldLatch(Latch(), sim)
        #: Where the simulator's snapshot goes (``None``: nowhere).
        self.snapshots: SnapshotWriter | None = None

    def wall_s(self) -> float:
        return self.wall.now() - self.w0

    def run(
        self, server: SimNavServer, progress: Callable[[ServeProgress], None] | None, progress_every_s: float
    ) -> None:
        """Step, publish and report progress until the end, ``stop`` or Ctrl-C."""
        server.process()
        server.publish()
        self.pacer.start()
        next_pub = self.wall.now() + self.period_s
        next_progress = self.wall.now() + progress_every_s
        try:
            while not self.stop.is_set():
                if self.end is not None and self.sim.clock.now() >= self.end - 1e-9:
                    break
                ahead = self.pacer.ahead()
                if ahead <= 0:  # due (or unpaced): one step
                    server.process()
                    self.latch.apply()
                    self.sim.step()
                    self.steps += 1
                else:  # early: wait for the step's time or the next publication
                    self.stop.wait(min(ahead, max(0.0, next_pub - self.wall.now())))
                w = self.wall.now()
                if w < next_pub:
                    continue
                server.process()
                server.publish()
                next_pub = max(next_pub + self.period_s, w)
                if self.snapshots is not None:
                    self.snapshots.maybe(w)
                if progress is not None and w >= next_progress:
                    progress(
                        ServeProgress(
                            self.sim.clock.now(), w - self.w0, self.steps, server.requests, server.malformed
                        )
                    )
                    next_progress = w + progress_every_s
        except KeyboardInterrupt:
            self.interrupted = True
        server.process()
        server.publish()
        if self.snapshots is not None:
            self.snapshots.save()
        self.interrupted = self.interrupted or self.stop.is_set()
