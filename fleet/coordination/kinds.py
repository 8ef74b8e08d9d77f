"""Tasks a robot runs once as a list of steps: ``go_to``, ``inspection``, ``park`` and
``charge`` (:class:`StepTask`). Patrols and picks are in :mod:`fleet.coordination.tasks`.

* ``go_to``: drive to a pose (a roadmap node, a station or an explicit pose);
* ``inspection``: drive to each waypoint in turn and act there: ``wait`` (stand), ``spin``
  (turn in place) or ``capture`` (a named capture, logged and recorded in the task's events);
* ``park``: drive to a parking spot;
* ``charge``: go to the robot's charger now and charge to ``battery.resume`` (no steps: the
  robot's charger is its own; traffic management drives it there as a charging errand).

Drive steps carry the pose (``map`` frame) and the roadmap node nearest it: without traffic
management the robot drives to the pose; with it, along granted paths to the node (the
task's :class:`~fleet.coordination.tasks.TrafficRoute` is those nodes, driven once).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fleet.coordination.tasks import PatrolRoute, TrafficRoute
from fleet.coordination.views import Assignment, Observation, TaskOrder
from fleet.messages import Action, Step
from fleet.types import Pose2D, TaskKind

if TYPE_CHECKING:
    from fleet.roadmap.graph import Roadmap

#: Id prefixes of the assignments of each kind (patrols ``p``, picks ``k``, idle orders ``i``).
PREFIXES = {TaskKind.GO_TO: "g", TaskKind.INSPECTION: "n", TaskKind.PARK: "q", TaskKind.CHARGE: "c"}

#: Seconds a robot may stand still per radian of a spin step before it counts as stuck.
SPIN_GRACE_S_PER_RAD = 3.0


@dataclass(frozen=True)
class StepTask:
    """A task of ``kind`` (``go_to``, ``inspection``, ``park`` or ``charge``) made of
    ``steps`` (see the module docstring).

    As a :class:`~fleet.coordination.tasks.Task`: entered at the roadmap node of its first
    drive step (plus the distance from the node to the pose; a charge task has no entry);
    finished when the robot reports its steps done (the generic result); its stall grace is
    the longest wait or spin of its steps (standing still there is no stall). ``robot`` is a
    preferred robot, ``only`` the one robot allowed, ``priority`` higher first.
    """

    name: str
    kind: TaskKind
    steps: tuple[Step, ...]
    robot: str | None = None
    only: str | None = None
    priority: int = 0

    @property
    def id_prefix(self) -> str:
        return PREFIXES.get(self.kind, "t")

    @property
    def stall_grace_s(self) -> float:
        grace = 0.0
        for s in self.steps:
            if s.action == Action.WAIT:
                grace = max(grace, float(s.duration_s))
            elif s.action == Action.SPIN:
                grace = max(grace, abs(float(s.yaw)) * SPIN_GRACE_S_PER_RAD)
        return grace

    def drives(self) -> list[Step]:
        """The drive steps, in order."""
        return [s for s in self.steps if s.action == Action.DRIVE and s.pose is not None]

    def entries(self, roadmap: Roadmap) -> Sequence[tuple[str, float]]:
        drives = self.drives()
        if not drives:
            return []
        first = drives[0]
        assert first.pose is not None
        node = first.node if first.node is not None and first.node in roadmap else None
        node = node or roadmap.nearest_node(first.pose.x, first.pose.y)
        px, py = roadmap.pos(node)
        return [(node, math.hypot(first.pose.x - px, first.pose.y - py))]

    def poses_from(self, entry: int) -> tuple[Pose2D, ...]:
        return ()

    def traffic_route(self) -> TrafficRoute | PatrolRoute | None:
        nodes = tuple(s.node for s in self.drives() if s.node is not None)
        return TrafficRoute(nodes) if nodes else None

    def record(self, a: Assignment, obs: Observation, now: float, active: bool) -> bool:
        return False  # finished by the robot's reported result (TaskBook.record)

    def order(self, robot: str, a: Assignment, charger: Pose2D | None) -> TaskOrder:
        return TaskOrder(robot, a.task_id, self.kind, None, (), charger, steps=self.steps)


def drive(pose: Pose2D, node: str | None, name: str = "") -> Step:
    """A drive step to ``pose`` (``node``: the roadmap node traffic management stops at)."""
    return Step(Action.DRIVE, pose, node, name=name)
