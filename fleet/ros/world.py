"""The ``ros`` world of the fleet runner: the config's robots driven through namespaced Nav2.

``fleet run CONFIG --backend ros`` runs the same behavior trees and coordinator as the
in-process simulator, but every robot's :class:`~fleet.navigation.NavigationBackend` is a
:class:`~fleet.ros.backend.RosNavigationBackend` talking to Nav2 under the robot's namespace
(a real Nav2 bringup per robot, or ``fleet sim-ros CONFIG`` serving all of them).

Time: the fleet clock is :class:`RosStampClock`, the newest odometry stamp every robot has
reached (simulated time with ``fleet sim-ros``, ROS time with a real Nav2), and each robot's
pose is read at that time (its odometry interpolated there), never at another robot's;
so tick rates and timeouts follow the robots' time whatever speed the simulator runs at.
The world is ``remote``: the runner does not pace it.

Environment: ``FLEET_ROS_WAIT_S`` (default 30) bounds the wait for every robot's action
servers at start; a robot still missing then is a :class:`~fleet.errors.BackendError`.
"""

from __future__ import annotations

import os
import time

from fleet.config.model import FleetConfig
from fleet.navigation import NavigationBackend
from fleet.robots import RobotSpec
from fleet.ros.backend import RosBackends, make_ros_backends
from fleet.runtime.worlds import BlindWorld


class RosStampClock:
    """Seconds of the robots' time every robot's odometry has reached
    (:meth:`~fleet.ros.backend.RosBackends.fleet_time`; 0 until the first message)."""

    def __init__(self, backends: RosBackends) -> None:
        self._rb = backends

    def now(self) -> float:
        return self._rb.fleet_time()


class RosWorld(BlindWorld):
    """Runner world over ROS 2: see the module docstring. Signature of a runner backend
    factory: ``RosWorld(config, robots, session)`` (the Zenoh session is not used)."""

    remote = True

    def __init__(self, config: FleetConfig, robots: list[RobotSpec], session: object = None) -> None:
        wait_s = float(os.environ.get("FLEET_ROS_WAIT_S", "30"))
        self.step_s = float(config.sim.step_s)
        self._rb = make_ros_backends([r.namespace for r in robots], wait_s=wait_s)
        self.clock = RosStampClock(self._rb)
        deadline = time.monotonic() + wait_s
        while self._rb.latest_stamp == 0.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        self._last = self.clock.now()

    def backend(self, namespace: str) -> NavigationBackend:
        return self._rb[namespace]

    def advance(self) -> None:
        """Wait (at most 50 ms) for the robots' time to move."""
        deadline = time.monotonic() + 0.05
        while self.clock.now() <= self._last and time.monotonic() < deadline:
            time.sleep(0.002)
        self._last = self.clock.now()

    def close(self) -> None:
        self._rb.close()
