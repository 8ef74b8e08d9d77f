"""One navigation backend for every stepped world: a robot's view of a goal server.

:class:`NamespacedBackend` implements :class:`fleet.navigation.NavigationBackend` for the robot
``namespace`` of any :class:`GoalServer` (the kinematic :class:`~sim.simulator.Simulator`, the
SUMO world) by forwarding each call with the namespace. It never blocks and never steps the
world: time passes only when the runner (or a test) steps it. Goal semantics (ids, rejection,
preemption, cancel) are the server's, shared by both through :mod:`sim.goals`.
"""

from __future__ import annotations

import functools
import weakref
from collections.abc import Callable, Sequence
from typing import Protocol

from fleet.navigation import BatchNavigation, NavBatch, batch_from_states
from fleet.types import Goal, GoalState, RobotState


class GoalServer(Protocol):
    """What a stepped world offers its robots' backends."""

    def send_goal(self, namespace: str, goal: Goal) -> str: ...

    def goal_state(self, goal_id: str) -> GoalState: ...

    def cancel_goal(self, goal_id: str) -> None: ...

    def robot_state(self, namespace: str) -> RobotState: ...


class NamespacedBackend:
    """NavigationBackend for robot ``namespace`` of ``server``."""

    def __init__(self, server: GoalServer, namespace: str) -> None:
        self._server = server
        self._namespace = namespace
        self._batch: BatchNavigation | None = None

    @property
    def namespace(self) -> str:
        """The robot's namespace, e.g. ``/robot1``."""
        return self._namespace

    @property
    def server(self) -> GoalServer:
        """The world this backend drives (for tests and tools)."""
        return self._server

    def send_goal(self, goal: Goal) -> str:
        """Start ``goal`` at once (preempting the current goal); return its id."""
        return self._server.send_goal(self._namespace, goal)

    def goal_state(self, goal_id: str) -> GoalState:
        """Latest state of ``goal_id``; ``KeyError`` for an id never issued."""
        return self._server.goal_state(goal_id)

    def cancel_goal(self, goal_id: str) -> None:
        """Cancel ``goal_id`` (no-op if finished or unknown)."""
        self._server.cancel_goal(goal_id)

    def robot_state(self) -> RobotState:
        """Pose, velocities, battery, charging, stuck, odometer and collisions of the robot."""
        return self._server.robot_state(self._namespace)

    @property
    def state_reader(self) -> Callable[[], RobotState]:
        """:meth:`robot_state` as one call to the server (:func:`fleet.navigation.state_reader`)."""
        return functools.partial(self._server.robot_state, self._namespace)

    @property
    def batch_server(self) -> BatchNavigation:
        """The world's batch query (:func:`fleet.navigation.query_batch`): the server itself
        when it answers batches (the simulator), else a loop over its per-robot reads (SUMO)."""
        if self._batch is None:
            server = self._server
            self._batch = server if isinstance(server, BatchNavigation) else LoopBatch.of(server)
        return self._batch

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._namespace!r})"


class LoopBatch:
    """:class:`~fleet.navigation.BatchNavigation` of a :class:`GoalServer` without a batch query
    of its own: one ``robot_state`` and one ``goal_state`` per row. :meth:`of` gives the one
    instance of a server, so backends of the same world batch together."""

    _instances: weakref.WeakKeyDictionary[GoalServer, LoopBatch] = weakref.WeakKeyDictionary()

    def __init__(self, server: GoalServer) -> None:
        self.server = server

    @classmethod
    def of(cls, server: GoalServer) -> LoopBatch:
        found = cls._instances.get(server)
        if found is None:
            found = cls._instances[server] = cls(server)
        return found

    def query_batch(self, namespaces: Sequence[str], goal_ids: Sequence[str | None]) -> NavBatch:
        """Rows of ``server.robot_state(ns)`` and ``server.goal_state(goal_id)`` (an unknown id is
        :data:`~fleet.navigation.NO_GOAL`)."""
        if len(namespaces) != len(goal_ids):
            raise ValueError(f"query_batch: {len(namespaces)} namespaces but {len(goal_ids)} goal ids")
        goals: list[GoalState | None] = []
        for gid in goal_ids:
            try:
                goals.append(None if gid is None else self.server.goal_state(gid))
            except KeyError:
                goals.append(None)
        robots = [self.server.robot_state(ns) for ns in namespaces]
        return batch_from_states(namespaces, goal_ids, robots, goals)
