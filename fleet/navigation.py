"""The navigation backend protocol: the one contract between behavior-tree leaves and a robot.

A backend drives one robot, identified by its ROS-style namespace (``/robot1``). The
in-process simulator (:mod:`sim.backend`), the Zenoh bridge to a simulator in another
process, the ROS 2 / Nav2 adapter and the SUMO adapter each implement it; the conformance
suite in ``tests/conformance`` checks that they behave alike.

Contract:

* :meth:`NavigationBackend.send_goal` never blocks. It returns a fresh goal id at once; the
  goal starts ``PENDING`` and becomes ``EXECUTING`` when the server accepts it (or
  ``REJECTED``).
* A robot executes one *motion* goal at a time (:data:`fleet.types.MOTION_GOAL_KINDS`:
  navigation, FollowPath, the behaviors). A new motion goal preempts the one executing: the
  old goal ends ``ABORTED`` (Nav2's action servers abort the goal they drop) and the new one
  runs. Goals that only compute (:data:`fleet.types.COMPUTE_GOAL_KINDS`: ComputePathToPose,
  ComputePathThroughPoses, SmoothPath, ClearCostmaps) run beside it, as Nav2's planner,
  smoother and costmap servers run beside its controller: they neither preempt the motion
  goal nor are preempted by it. Their result (``GoalState.path`` for the planners and the
  smoother) is in the terminal state; a backend may finish them before ``send_goal``
  returns.
* A backend that cannot execute a goal kind at all (SUMO vehicles cannot follow a free path
  and have no costmaps) ends such a goal ``REJECTED`` with a message saying why.
* :meth:`NavigationBackend.goal_state` is a pure read: polling it any number of times changes
  nothing. Ids are never reused, so a stale id can never observe (or complete) a newer goal.
* :meth:`NavigationBackend.cancel_goal` is idempotent: canceling a finished or unknown goal is
  a no-op. A canceled goal ends ``CANCELED`` and the robot stops.
* If the server goes away mid-goal, the goal ends ``ABORTED`` with
  ``ErrorCode.SERVER_UNAVAILABLE`` instead of staying ``EXECUTING`` forever.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from fleet.types import Goal, GoalState, RobotState


class Clock(Protocol):
    """A source of time in seconds. The simulator's clock is simulated time."""

    def now(self) -> float: ...


@runtime_checkable
class NavigationBackend(Protocol):
    """Drives one namespaced robot. See the module docstring for the contract."""

    @property
    def namespace(self) -> str:
        """The robot's namespace, e.g. ``/robot1``."""
        ...

    def send_goal(self, goal: Goal) -> str:
        """Send ``goal``; return its id at once (never blocks)."""
        ...

    def goal_state(self, goal_id: str) -> GoalState:
        """Return the latest state of ``goal_id``. Raises ``KeyError`` for an id never issued."""
        ...

    def cancel_goal(self, goal_id: str) -> None:
        """Ask to cancel ``goal_id``; a no-op if it already finished."""
        ...

    def robot_state(self) -> RobotState:
        """Return the robot's current pose, battery and health."""
        ...
