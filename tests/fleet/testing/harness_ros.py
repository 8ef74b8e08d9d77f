"""Conformance harness of the ROS 2 backend (:mod:`fleet.ros.backend`), registered as ``"ros"``.

The world is the simulator's conformance room (:data:`fleet.testing.room.SIM_WORLD`), served
as namespaced Nav2 by :mod:`fleet.ros.nav2_server` in a child process (this file, run as a
script with ``--serve``) at :data:`SPEED` times real time; the backend under test talks to it
through real rclpy action clients on a private ROS domain. ``advance(s)`` sleeps ``s / SPEED``
wall seconds while the backend's executor thread spins. Skipped when the ROS 2 wheels or the
built nav2_msgs are missing.

Every case still gets a fresh server process, but the next case's server starts (in a
background thread) while the current case runs, on the other of two private ROS domains, so
two servers never answer for the same ``/robot1``; the case mostly sleeps, so the start-up
overlaps it instead of adding to it. The spare server is stopped after the last ROS case.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from conformance_harness import register_backend  # noqa: E402
from prestart import Pool  # noqa: E402

from fleet.navigation import NavigationBackend  # noqa: E402
from fleet.ros.domains import DomainClaim, claim_domains, ensure_private_domain  # noqa: E402
from fleet.ros.env import apply_ros_env_defaults, ros_available  # noqa: E402
from fleet.ros.launch import ServerProcess  # noqa: E402
from fleet.testing.conformance import ConformanceHarness, ConformanceWorld  # noqa: E402
from fleet.testing.room import SIM_PARAMS, SIM_WORLD, conformance_grid  # noqa: E402

#: Simulated seconds per wall second in the server process. Real time: the harness lets time
#: pass by sleeping, so a scheduling hiccup on a loaded machine must not turn into several
#: simulated seconds (at 4x, cancel and spin checks failed now and then under load).
SPEED = 1.0


@dataclass
class RosHarness:
    backend: NavigationBackend
    world: ConformanceWorld
    speed: float

    def advance(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds) / self.speed)


#: The spare server (on the other domain) and the ones being stopped.
_POOL: Pool[ServerProcess] = Pool("ros")
between_cases = _POOL.between_cases


def _pair() -> DomainClaim:
    """Two ROS domains ``d, d ^ 1`` claimed for this process (the cases alternate between
    them, so a case never meets the last case's server), free of every other claimer."""
    if not _PAIR:
        _PAIR.append(claim_domains(2, align=2))
    return _PAIR[0]


_PAIR: list[DomainClaim] = []


def _start_spare(domain_id: int) -> ServerProcess:
    # the servers of earlier cases, one of them on this domain, are gone first
    _POOL.wait_stopped()
    return _start_server(domain_id)


def _start_server(domain_id: int) -> ServerProcess:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id))
    return ServerProcess([sys.executable, str(Path(__file__).resolve()), "--serve", str(SPEED)], env=env)


@register_backend("ros", marks=(pytest.mark.ros,))
@contextmanager
def ros_harness() -> Iterator[ConformanceHarness]:
    if not ros_available():
        pytest.skip("ROS 2 Jazzy wheels / nav2_msgs not installed (make setup-ros)")
    ensure_private_domain()
    apply_ros_env_defaults()
    from fleet.ros.backend import make_ros_backends

    spare = _POOL.take()
    if spare is not None:
        domain_id, srv = spare.tag, spare.take()
    else:
        domain_id = _pair().first
        srv = _start_server(domain_id)
    rb = None
    try:
        nxt = domain_id ^ 1  # the next case's server, on the other domain of the pair
        _POOL.prepare(lambda: _start_spare(nxt), nxt)
        rb = make_ros_backends(["/robot1"], domain_id=domain_id, wait_s=20.0)
        backend = rb["/robot1"]
        deadline = time.monotonic() + 30.0
        while backend.robot_state().pose is None:
            assert time.monotonic() < deadline, "no amcl_pose / odom from the server"
            time.sleep(0.02)
        yield RosHarness(backend, SIM_WORLD, SPEED)
    finally:
        if rb is not None:
            rb.close()
        _POOL.stop_later(srv)


def _serve(argv: list[str]) -> int:
    """Child process: the conformance world's robot as namespaced Nav2."""
    from fleet.clock import SimClock
    from fleet.robots import RobotSpec
    from fleet.ros.nav2_server import serve
    from sim.simulator import Simulator

    speed = float(argv[0])
    ready = argv[argv.index("--ready-file") + 1] if "--ready-file" in argv else None
    sim = Simulator(conformance_grid(), SIM_PARAMS, SimClock())
    sim.add_robot(RobotSpec("robot1", "/robot1", SIM_WORLD.start))
    return serve(
        sim, ready_file=ready, speed=speed, feedback_hz=20.0, odom_hz=20.0, amcl_hz=2.0, profile="full"
    )


if __name__ == "__main__" and len(sys.argv) > 1 and sys.argv[1] == "--serve":
    sys.exit(_serve(sys.argv[2:]))
