"""The emergency-stop latch below the behaviour trees (``docs/service.md``).

Two layers hold it, so that nothing moves while it is latched, whatever the coordinator or an
agent sends:

* :class:`WorldLatch` at the simulator: engaged, it stalls every robot's wheels at the next
  simulator step (speed zero at once, no deceleration ramp) and keeps them stalled until it
  is released; ``fleet run``'s simulator and ``fleet sim`` (for robots driven from other
  processes) each apply it before every step, on the stepping thread.
* :class:`LatchedBackend` at every agent's navigation backend: while latched it refuses new
  goals (they end ``REJECTED``, error message ``e-stop latched``) and it cancels the goals
  it let through when the latch engages. It works on every backend (simulator, ``fleet sim``
  over Zenoh, ROS 2, SUMO).

Both follow a :class:`Latch`, a thread-safe flag set from the fleet's control state
(:class:`~fleet.messages.FleetControl`, newest ``seq`` wins).
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Protocol

from fleet.messages import FleetControl
from fleet.navigation import state_reader
from fleet.types import Goal, GoalState, GoalStatus, RobotState

if TYPE_CHECKING:
    from fleet.navigation import NavigationBackend

#: The error message of a goal refused while the e-stop is latched.
LATCHED_MSG = "e-stop latched"


class Latch:
    """A thread-safe e-stop flag following the fleet's control state."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._engaged = False
        self._seq = -1
        #: Bumped at every change, so that holders notice a change they have not applied.
        self.version = 0

    @property
    def engaged(self) -> bool:
        return self._engaged

    def follow(self, ctl: FleetControl) -> None:
        """Apply ``ctl`` if it is newer than the last one applied."""
        with self._lock:
            if ctl.seq < self._seq:
                return
            self._seq = ctl.seq
            if ctl.estop != self._engaged:
                self._engaged = ctl.estop
                self.version += 1

    def set(self, engaged: bool) -> None:
        """Engage or release directly (tests, tools)."""
        with self._lock:
            if engaged != self._engaged:
                self._engaged = engaged
                self.version += 1


class Stallable(Protocol):
    """What :class:`WorldLatch` needs of a simulator (:class:`sim.simulator.Simulator`)."""

    @property
    def namespaces(self) -> list[str]: ...

    def fault_of(self, namespace: str) -> str | None: ...

    def set_fault(self, namespace: str, fault: str | None) -> None: ...

    def cancel_all(self) -> int: ...


class WorldLatch:
    """Applies a :class:`Latch` to a simulator before each step (see the module docstring).

    Engaging stalls every robot (the simulator's ``stalled`` fault: zero speed at the next
    step) and cancels every running goal; releasing cancels every goal again (one sent while
    latched must not start moving a robot: motion starts again only with new goals after
    ``resume``) and clears the stall of the robots it stalled (a fault injected by someone
    else stays). ``engagements`` counts the applications that engaged it."""

    def __init__(self, latch: Latch, sim: Stallable) -> None:
        self.latch = latch
        self.sim = sim
        self._applied = 0
        self._stalled: list[str] = []
        self.engagements = 0

    def apply(self) -> bool:
        """Call on the stepping thread before each step; returns whether the latch is engaged."""
        if self.latch.version == self._applied:
            return self.latch.engaged
        self._applied = self.latch.version
        if self.latch.engaged:
            self._stalled = []
            for ns in self.sim.namespaces:
                if self.sim.fault_of(ns) is None:
                    self.sim.set_fault(ns, "stalled")
                    self._stalled.append(ns)
            self.sim.cancel_all()
            self.engagements += 1
            return True
        self.sim.cancel_all()
        for ns in self._stalled:
            self.sim.set_fault(ns, None)
        self._stalled = []
        return False


class LatchedBackend:
    """A :class:`~fleet.navigation.NavigationBackend` that refuses goals while ``latch`` is
    engaged and cancels the goals it let through when it engages (see the module docstring).
    Everything else passes through to ``inner``."""

    def __init__(self, inner: NavigationBackend, latch: Latch) -> None:
        self.inner = inner
        self.latch = latch
        self._refused: dict[str, GoalState] = {}
        self._sent: list[str] = []
        self._seen_version = latch.version
        self._read_state = state_reader(inner)  # robot_state below the pass-through wrappers
        self._n = 0
        #: Goals refused while latched.
        self.refused = 0

    @property
    def namespace(self) -> str:
        return self.inner.namespace

    def _check(self) -> None:
        if self.latch.version != self._seen_version:
            self._seen_version = self.latch.version
            if self.latch.engaged:
                for gid in self._sent:
                    self.inner.cancel_goal(gid)
                self._sent = []

    def send_goal(self, goal: Goal) -> str:
        self._check()
        if self.latch.engaged:
            self._n += 1
            gid = f"{self.namespace}#estop-{self._n}"
            self._refused[gid] = GoalState(gid, goal.kind, GoalStatus.REJECTED, error_msg=LATCHED_MSG)
            if len(self._refused) > 1000:
                self._refused.pop(next(iter(self._refused)))
            self.refused += 1
            return gid
        gid = self.inner.send_goal(goal)
        self._sent = [*self._sent[-7:], gid]
        return gid

    def goal_state(self, goal_id: str) -> GoalState:
        self._check()
        refused = self._refused.get(goal_id)
        return refused if refused is not None else self.inner.goal_state(goal_id)

    def cancel_goal(self, goal_id: str) -> None:
        if goal_id not in self._refused:
            self.inner.cancel_goal(goal_id)

    def robot_state(self) -> RobotState:
        self._check()
        return self._read_state()
