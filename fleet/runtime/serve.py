"""``fleet sim``: serve the kinematic simulator's robots over Zenoh and step it in (paced) time."""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, TextIO

import zenoh

from fleet.bus.nav_server import SimNavServer
from fleet.errors import BackendError


@dataclass
class ServeResult:
    """What :func:`serve_simulator` returns: the simulator, steps taken, simulated and wall
    seconds, and whether it was interrupted (Ctrl-C / SIGTERM / ``stop_event``)."""

    simulator: Any
    steps: int
    sim_time_s: float
    wall_time_s: float
    interrupted: bool


def simulator_from_config(config: Any) -> Any:
    """A :class:`sim.simulator.Simulator` with every robot of a :class:`fleet.config.FleetConfig`."""
    from fleet.clock import SimClock
    from sim.simulator import Simulator

    sim = Simulator(config.grid, config.sim, SimClock())
    for spec in config.robots:
        sim.add_robot(spec)
    return sim


def serve_simulator(
    simulator: Any,
    session: zenoh.Session | None = None,
    *,
    endpoint: str | None = None,
    speed: float = 1.0,
    duration: float | None = None,
    stop_event: threading.Event | None = None,
    publish_hz: float = 50.0,
    quiet: bool = False,
    out: TextIO | None = None,
    progress_every_s: float = 10.0,
) -> ServeResult:
    """Step ``simulator`` at ``speed`` x real time (``0``: as fast as possible) and serve it
    with a :class:`SimNavServer` until ``duration`` simulated seconds passed (``None``:
    forever), ``stop_event`` is set, Ctrl-C or SIGTERM (when called from the main thread).

    ``simulator`` may also be a fleet config (the simulator is built with its robots).
    Without ``session`` a router session listening on ``endpoint`` is opened and closed here
    (:class:`~fleet.errors.BusError` if it cannot be). Requests are applied before every step;
    states and the clock are published ``publish_hz`` times per wall second. Unless ``quiet``,
    a progress line is printed every ``progress_every_s`` wall seconds to ``out`` (stdout).
    """
    from fleet.bus.session import DEFAULT_ENDPOINT, open_session

    if speed < 0 or not math.isfinite(speed):
        raise BackendError(f"speed must be >= 0, got {speed}")
    sim = simulator if hasattr(simulator, "step") else simulator_from_config(simulator)
    stop = stop_event or threading.Event()
    own = session is None
    sess = open_session(endpoint or DEFAULT_ENDPOINT, "router") if session is None else session
    old_handler: Any = None
    main = threading.current_thread() is threading.main_thread()
    if main:
        old_handler = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    server: SimNavServer | None = None
    interrupted = False
    period = 1.0 / publish_hz
    wall0 = time.monotonic()
    t0 = sim.clock.now()
    steps = 0
    step_s = float(sim.params.step_s)
    try:
        server = SimNavServer(sess, sim)
        server.speed = speed
        server.process()
        server.publish()
        next_pub = time.monotonic() + period
        next_progress = time.monotonic() + progress_every_s
        end = None if duration is None else t0 + duration
        try:
            while not stop.is_set():
                if end is not None and sim.clock.now() >= end - 1e-9:
                    break
                now_w = time.monotonic()
                target = math.inf if speed == 0 else t0 + speed * (now_w - wall0)
                # step until caught up with the target time or it is time to publish
                while sim.clock.now() + step_s <= target + 1e-9 and time.monotonic() < next_pub:
                    if end is not None and sim.clock.now() >= end - 1e-9:
                        break
                    server.process()
                    sim.step()
                    steps += 1
                now_w = time.monotonic()
                if now_w >= next_pub:
                    server.process()
                    server.publish()
                    next_pub = max(next_pub + period, now_w)
                    if not quiet and now_w >= next_progress:
                        print(
                            f"[fleet sim] t={sim.clock.now():8.1f} s sim, {now_w - wall0:7.1f} s wall, "
                            f"{steps} steps, {server.requests} requests",
                            file=out or sys.stdout,
                            flush=True,
                        )
                        next_progress = now_w + progress_every_s
                if speed > 0:
                    nxt = min(next_pub, wall0 + (sim.clock.now() + step_s - t0) / speed)
                    delay = nxt - time.monotonic()
                    if delay > 0:
                        stop.wait(min(delay, period))
        except KeyboardInterrupt:
            interrupted = True
        server.process()
        server.publish()
        interrupted = interrupted or stop.is_set()
    finally:
        if server is not None:
            server.close()
        if own:
            sess.close()
        if main:
            signal.signal(signal.SIGTERM, old_handler)
    return ServeResult(sim, steps, float(sim.clock.now() - t0), time.monotonic() - wall0, interrupted)
