"""Worlds: what a navigation backend factory returns to the runner (the robots' backends plus
time), and the two built-in worlds: the in-process simulator and a simulator served over Zenoh."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import zenoh

from fleet.clock import SimClock, WallClock
from fleet.config.model import FleetConfig
from fleet.errors import BackendError, BusError
from fleet.navigation import Clock, NavigationBackend
from fleet.robots import RobotSpec

if TYPE_CHECKING:
    from fleet.bus.nav_client import ZenohNavBackend

#: How long a remote world waits for the simulator's clock (wall seconds).
CONNECT_TIMEOUT_S = 10.0


#: A remote world whose simulator clock does not move for this long (wall s) ends the run.
SIM_SILENT_S = 10.0


class World(Protocol):
    """What a backend factory returns: the robots' navigation backends plus time.

    ``clock`` is the fleet clock; ``remote`` is True if time is driven elsewhere (then the
    runner does not pace and :meth:`advance` waits for time to move); ``step_s`` the step.
    """

    @property
    def clock(self) -> Clock: ...

    @property
    def remote(self) -> bool: ...

    @property
    def step_s(self) -> float: ...

    def backend(self, namespace: str) -> NavigationBackend: ...

    def advance(self) -> None:
        """Move time forward by one step (in-process) or wait briefly for it to move (remote)."""
        ...

    def collisions(self) -> int | None:
        """Robot-robot collision events so far, or None if this world cannot count them."""
        ...

    def collision_points(self) -> list[tuple[float, float]]:
        """Where robots touched, ``(x, y)`` in the ``map`` frame (empty if it cannot see)."""
        ...

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]] | None:
        """The robot's ``(t, x, y)`` samples so far, or None if this world does not record
        them (the runner then samples them, bounded, from the robot's statuses)."""
        ...

    def close(self) -> None: ...


#: ``factory(config, robots, session) -> World``: ``robots`` are the robots whose agents run
#: in this process; ``session`` the runner's Zenoh session.
WorldFactory = Callable[[FleetConfig, list[RobotSpec], zenoh.Session], World]


class SimWorld:
    """The in-process kinematic simulator with every robot of the config."""

    remote = False

    def __init__(self, config: FleetConfig, robots: list[RobotSpec], session: zenoh.Session | None) -> None:
        from sim.simulator import Simulator

        self.clock = SimClock()
        self.sim = Simulator(config.grid, config.sim, self.clock)
        self.step_s = config.sim.step_s
        for spec in config.robots:
            self.sim.add_robot(spec)

    def backend(self, namespace: str) -> NavigationBackend:
        return self.sim.backend(namespace)

    def advance(self) -> None:
        self.sim.step()

    def collisions(self) -> int | None:
        return self.sim.collisions

    def collision_points(self) -> list[tuple[float, float]]:
        return [(x, y) for _, _, _, x, y in self.sim.collision_events]

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]] | None:
        return self.sim.trajectory(namespace)

    def close(self) -> None:
        return None


class BlindWorld:
    """Base of worlds whose robots run elsewhere: the runner cannot see collisions or record
    trajectories there (it samples them from the robots' statuses instead)."""

    def collisions(self) -> int | None:
        return None

    def collision_points(self) -> list[tuple[float, float]]:
        return []

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]] | None:
        return None


class RemoteWorld(BlindWorld):
    """Robots of a simulator served over Zenoh by ``fleet sim`` (see :mod:`fleet.bus.nav_server`)."""

    remote = True
    #: ``fleet sim`` hosts the Zenoh router: the runner connects to it instead of listening.
    bus_elsewhere = True

    def __init__(self, config: FleetConfig, robots: list[RobotSpec], session: zenoh.Session) -> None:
        from fleet.bus.clock import BusClock
        from fleet.bus.lease import SimLeaseWatch

        self._session = session
        self._wall = WallClock()
        #: The live simulators: only their states and clock are used (``docs/protocol.md``).
        self.sims = SimLeaseWatch(session)
        self.clock = BusClock(session, sources=self.sims.admits)
        self.step_s = config.sim.step_s
        self._backends: dict[str, ZenohNavBackend] = {}
        if not self.clock.wait_first(CONNECT_TIMEOUT_S):
            self.clock.close()
            self.sims.close()
            raise BusError(
                f"no simulator clock on the bus after {CONNECT_TIMEOUT_S:g} s: start `fleet sim "
                f"{config.path}` on the same endpoint first"
            )
        self._last = self.clock.now()
        self._last_wall = self._wall.now()

    def malformed(self) -> int:
        """Payloads dropped unparsed: clock messages and robots' navigation states."""
        return self.clock.malformed + sum(b.malformed for b in self._backends.values())

    def rejected(self) -> int:
        """Well-formed clock and state messages ignored: not from a live simulator, or a lone
        clock jump."""
        return self.clock.rejected + sum(b.rejected for b in self._backends.values())

    def backend(self, namespace: str) -> NavigationBackend:
        from fleet.bus.nav_client import ZenohNavBackend

        b = self._backends.get(namespace)
        if b is None:
            b = self._backends[namespace] = ZenohNavBackend(
                self._session, namespace, sources=self.sims.admits
            )
        return b

    def advance(self) -> None:
        """Wait up to 50 ms for the simulator's clock to move; raises :class:`BackendError`
        when it has not moved for :data:`SIM_SILENT_S` wall seconds."""
        if self.clock.wait_until(self._last + 1e-6, 0.05):
            self._last = self.clock.now()
            self._last_wall = self._wall.now()
        elif self._wall.now() - self._last_wall > SIM_SILENT_S:
            raise BackendError(
                f"the simulator's clock has not moved for {SIM_SILENT_S:g} s (did `fleet sim` stop?)"
            )

    def close(self) -> None:
        for b in self._backends.values():
            b.close()
        self.clock.close()
        self.sims.close()
