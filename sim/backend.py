"""The in-process navigation backend: one robot of a :class:`~sim.simulator.Simulator`.

:class:`SimNavigationBackend` implements :class:`fleet.navigation.NavigationBackend` by
delegating to the simulator. It never blocks and never steps the simulator: time passes only
when the runner (or a test) calls :meth:`Simulator.step`. Goals are EXECUTING as soon as
:meth:`send_goal` returns (or already REJECTED / ABORTED for a request that fails at once).
Cancel ends a goal CANCELED immediately and the robot decelerates to a stop over the next
steps. Ids look like ``"/robot1#3"`` and are never reused.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleet.types import Goal, GoalState, RobotState

if TYPE_CHECKING:
    from sim.simulator import Simulator


class SimNavigationBackend:
    """NavigationBackend for the simulated robot ``namespace`` of ``simulator``."""

    def __init__(self, simulator: Simulator, namespace: str) -> None:
        self._sim = simulator
        self._namespace = namespace

    @property
    def namespace(self) -> str:
        """The robot's namespace, e.g. ``/robot1``."""
        return self._namespace

    @property
    def simulator(self) -> Simulator:
        """The simulator this backend drives (for tests and tools)."""
        return self._sim

    def send_goal(self, goal: Goal) -> str:
        """Start ``goal`` at once (preempting the current goal); return its id."""
        return self._sim.send_goal(self._namespace, goal)

    def goal_state(self, goal_id: str) -> GoalState:
        """Latest state of ``goal_id``; ``KeyError`` for an id never issued."""
        return self._sim.goal_state(goal_id)

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id`` (no-op if finished or unknown)."""
        self._sim.cancel_goal(goal_id)

    def robot_state(self) -> RobotState:
        """Pose, velocities, battery, charging, stuck, odometer and collisions of the robot."""
        return self._sim.robot_state(self._namespace)

    def __repr__(self) -> str:
        return f"SimNavigationBackend({self._namespace!r})"
