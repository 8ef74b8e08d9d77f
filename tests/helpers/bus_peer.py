"""Subprocess side of the bus tests: ``python tests/helpers/bus_peer.py MODE ENDPOINT ...``.

Modes (each prints ``ready`` once set up, runs until SIGTERM or its count is done, always
closes its Zenoh session):

* ``status ENDPOINT ROBOTS COUNT HZ [LOST]``: a client publishing ``COUNT`` status records per
  robot (comma-separated ``ROBOTS``) at ``HZ``, holding their liveliness tokens, then idling;
  robot ``LOST``'s records carry an ERROR localization diagnostic.
* ``alive ENDPOINT ROBOT``: a client holding the token ``fleet/ROBOT/alive``.
* ``navserver ENDPOINT SPEED``: a router serving a one-robot simulator (the world of
  ``tests/fleet/testing/conformance_harness.py``, robot ``/robot1`` at its start) at ``SPEED`` x
  real time.
* ``navpool - SPEED``: many such servers, one after another, in this one process: each stdin
  line ``new ENDPOINT`` starts a fresh simulator and router on ENDPOINT (answers
  ``ready ENDPOINT``), ``stop ENDPOINT`` stops and closes it (answers ``stopped ENDPOINT``);
  end of input or SIGTERM stops them all.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from fleet.bus.session import open_session
from fleet.bus.status_bus import StatusBus
from fleet.messages import StatusRecord

if TYPE_CHECKING:
    import zenoh

    from sim.simulator import Simulator


def wait_until(pred: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.005) -> None:
    """Poll ``pred`` until it is true; AssertionError naming ``what`` after ``timeout_s`` wall
    seconds (a hang guard: choose it at least 3x what the wait takes on a loaded machine)."""
    end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(poll_s)


def settle(
    send: Callable[[], object], seen: Callable[[], bool], timeout_s: float, what: str, every_s: float = 0.05
) -> None:
    """Call ``send()`` every ``every_s`` wall seconds until ``seen()``: a subscription is live
    once something sent after its declaration reached it. AssertionError naming ``what`` after
    ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while True:
        send()
        step_end = time.monotonic() + every_s
        while time.monotonic() < step_end:
            if seen():
                return
            time.sleep(0.005)
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")


def record(robot: str, seq: int, lost: bool = False) -> StatusRecord:
    """A patrolling robot's status (``lost``: its diagnostics say its localization is lost)."""
    return StatusRecord(
        robot=robot,
        ns="/" + robot,
        t=0.1 * seq,
        pose=(1.0 + seq, 2.0, 0.5),
        battery=0.9,
        charging=False,
        stuck=False,
        bt="RUNNING",
        leaf="FollowRoute",
        mode="patrol",
        task_id=f"p-{robot}",
        laps=seq // 10,
        progress=(seq % 10) / 10.0,
        distance_m=1.5 * seq,
        collisions=0,
        seq=seq,
        health=2 if lost else 0,  # as an agent whose robot's localization is lost reports
        diag=(("localization", 2, "localization lost"),) if lost else (),
    )


def main(argv: list[str]) -> int:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    mode, endpoint = argv[0], argv[1]
    if mode == "navserver":
        return navserver(endpoint, float(argv[2]), stop)
    if mode == "navpool":
        return navpool(float(argv[2]))
    session = open_session(endpoint, "client")
    bus = StatusBus(session)
    try:
        if mode == "status":
            robots = argv[2].split(",")
            count, hz = int(argv[3]), float(argv[4])
            lost = argv[5] if len(argv) > 5 else ""
            for r in robots:
                bus.declare_alive(r)
            print("ready", flush=True)
            for seq in range(1, count + 1):
                for r in robots:
                    bus.publish_status(record(r, seq, lost=r == lost))
                if stop.wait(1.0 / hz):
                    break
            print("done", flush=True)
            stop.wait()
        elif mode == "alive":
            bus.declare_alive(argv[2])
            print("ready", flush=True)
            stop.wait()
        else:
            print(f"unknown mode {mode}", file=sys.stderr)
            return 2
    finally:
        bus.shutdown()
    return 0


def _conformance_sim() -> Simulator:
    """A fresh simulator of the conformance room with ``/robot1`` at its start."""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fleet" / "testing"))
    from conformance_harness import SIM_PARAMS, SIM_WORLD, conformance_grid

    from fleet.clock import SimClock
    from fleet.robots import RobotSpec
    from sim.simulator import Simulator

    sim = Simulator(conformance_grid(), SIM_PARAMS, SimClock())
    sim.add_robot(RobotSpec("robot1", "/robot1", SIM_WORLD.start))
    return sim


def navserver(endpoint: str, speed: float, stop: threading.Event) -> int:
    from fleet.runtime.serve import serve_simulator

    sim = _conformance_sim()
    session = open_session(endpoint, "router")
    try:
        print("ready", flush=True)
        serve_simulator(sim, session, speed=speed, stop_event=stop, quiet=True)
    finally:
        session.close()
    return 0


def navpool(speed: float) -> int:
    """Serve one fresh conformance simulator per ``new ENDPOINT`` line (module docstring)."""
    from fleet.runtime.serve import serve_simulator

    servers: dict[str, tuple[threading.Event, threading.Thread]] = {}

    def serve(sim: Simulator, session: zenoh.Session, ev: threading.Event) -> None:
        try:
            serve_simulator(sim, session, speed=speed, stop_event=ev, quiet=True)
        finally:
            session.close()

    def stop_one(endpoint: str) -> None:
        ev, thread = servers.pop(endpoint)
        ev.set()
        thread.join()

    def sigterm(*_: object) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, sigterm)  # ends the blocking read of stdin
    try:
        for line in sys.stdin:
            verb, endpoint = line.split()
            if verb == "new":
                ev = threading.Event()
                session = open_session(endpoint, "router")
                thread = threading.Thread(target=serve, args=(_conformance_sim(), session, ev))
                servers[endpoint] = (ev, thread)
                thread.start()
                print(f"ready {endpoint}", flush=True)
            elif verb == "stop":
                stop_one(endpoint)
                print(f"stopped {endpoint}", flush=True)
    finally:
        for endpoint in list(servers):
            stop_one(endpoint)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
