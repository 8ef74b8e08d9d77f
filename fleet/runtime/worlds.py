"""Worlds: what a navigation backend factory returns to the runner (the robots' backends plus
time), and the two built-in worlds: the in-process simulator and a simulator served over Zenoh."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import zenoh

from fleet.clock import SimClock, WallClock
from fleet.config.model import FleetConfig
from fleet.errors import BackendError, BusError
from fleet.navigation import Clock, NavigationBackend
from fleet.robots import RobotSpec
from fleet.runtime.snapshot import SnapshotWriter, resume_simulator

logger = logging.getLogger(__name__)

if TYPE_CHECKING:
    from fleet.bus.nav_client import ZenohNavBackend

#: How long a remote world waits for the simulator's clock (wall seconds).
CONNECT_TIMEOUT_S = 10.0


#: A remote world whose simulator is silent this long (wall s) says so in the log (and
#: again every as long), until it is back or ``bus.reconnect_s`` ends the run.
SIM_SILENT_S = 5.0


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

        self.config = config
        self.clock = SimClock()
        self.sim = Simulator(config.grid, config.sim, self.clock)
        self.step_s = config.sim.step_s
        for spec in config.robots:
            self.sim.add_robot(spec)
        #: Where the simulator's snapshot goes (``None``: nowhere; see :meth:`keep_state`).
        self.snapshots: SnapshotWriter | None = None

    def keep_state(self, state_dir: Path) -> None:
        """Resume the simulator from the snapshot in ``state_dir`` (its robots' poses,
        batteries and docking states and its clock; as configured when there is none) and keep
        its snapshot there from now on (:mod:`fleet.runtime.snapshot`): every
        :data:`~fleet.runtime.snapshot.SNAPSHOT_EVERY_S` wall s while it steps, and at
        :meth:`close`. Call it before anything uses the world. Raises
        :class:`~fleet.errors.ConfigError` for a file there that is not a snapshot of this fleet."""
        self.sim = resume_simulator(self.config, state_dir)
        self.clock = self.sim.clock
        self.snapshots = SnapshotWriter(self.sim, self.config, state_dir)
        self.snapshots.save()

    def backend(self, namespace: str) -> NavigationBackend:
        return self.sim.backend(namespace)

    def advance(self) -> None:
        self.sim.step()
        if self.snapshots is not None:
            self.snapshots.maybe()

    def collisions(self) -> int | None:
        return self.sim.collisions

    def collision_points(self) -> list[tuple[float, float]]:
        return [(x, y) for _, _, _, x, y in self.sim.collision_events]

    def trajectory(self, namespace: str) -> list[tuple[float, float, float]] | None:
        return self.sim.trajectory(namespace)

    def close(self) -> None:
        if self.snapshots is not None:
            self.snapshots.save()


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
    """Robots of a simulator served over Zenoh by ``fleet sim`` (see :mod:`fleet.bus.nav_server`).

    A simulator that goes silent (its process was killed, it hangs, the bus is down) is waited
    for: the Zenoh client reconnects when a ``fleet sim`` listens again on the endpoint, and
    the fleet clock holds until the restarted simulator's time passes it
    (:class:`~fleet.bus.clock.BusClock`). Only after the config's ``bus.reconnect_s`` wall
    seconds of silence does :meth:`advance` end the run."""

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
        self._updates = self.clock.updates
        self._warned_wall = self._last_wall
        self.reconnect_s = config.reconnect_s
        #: Times the simulator went silent for longer than :data:`SIM_SILENT_S` and came back.
        self.outages = 0

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
        when no clock message came for ``bus.reconnect_s`` wall seconds (see the class)."""
        moved = self.clock.wait_until(self._last + 1e-6, 0.05)
        now = self._wall.now()
        updates = self.clock.updates
        if moved or updates != self._updates:  # a clock message: the simulator is there
            silent = now - self._last_wall
            if silent > SIM_SILENT_S:
                self.outages += 1
                logger.warning(
                    "the simulator is back after %.1f s of silence (t=%.1f s)", silent, self.clock.now()
                )
            self._last = self.clock.now()
            self._last_wall = self._warned_wall = now
            self._updates = updates
            return
        silent = now - self._last_wall
        if self.reconnect_s is not None and silent > self.reconnect_s:
            raise BackendError(
                f"no message from the simulator for {self.reconnect_s:g} s (did `fleet sim` stop? "
                "bus.reconnect_s sets how long to wait)"
            )
        if now - self._warned_wall > SIM_SILENT_S:
            self._warned_wall = now
            logger.warning(
                "no message from the simulator for %.0f s: waiting for `fleet sim` to come back on the "
                "endpoint (Ctrl-C to stop)",
                silent,
            )

    def close(self) -> None:
        for b in self._backends.values():
            b.close()
        self.clock.close()
        self.sims.close()
