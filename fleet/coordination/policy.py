"""The coordinator's extension point for traffic management (:class:`TrafficPolicy`) and its
default, :class:`NoTraffic`. :class:`fleet.traffic.policy.ReservationTraffic` implements it."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from fleet.types import Pose2D

if TYPE_CHECKING:
    from fleet.coordination.tasks import PatrolRoute, TrafficRoute
    from fleet.coordination.views import RobotView, TaskOrder
    from fleet.messages import Grant


class TrafficPolicy(Protocol):
    """Extension point for traffic management (e.g. roadmap segment reservations).

    The coordinator calls :meth:`on_assign` when it gives a task with a traffic route to a
    robot (``route.nodes``, driven as a loop if ``route.loop``; the policy may return
    different poses, e.g. with waiting points), :meth:`on_release` when a robot loses
    its route or dies, and :meth:`cycle` once per coordinator cycle with every robot's view;
    :meth:`cycle` returns extra orders to send (usually none). Policies must keep
    :meth:`cycle` roughly linear in the number of robots.
    """

    def on_assign(
        self,
        robot: str,
        route: TrafficRoute | PatrolRoute,
        poses: tuple[Pose2D, ...],
        task_id: str | None = None,
    ) -> tuple[Pose2D, ...]: ...

    def on_release(self, robot: str) -> None: ...

    def waiting(self, robot: str) -> bool:
        """True while the policy holds ``robot`` back (it is then not stuck, only waiting)."""
        ...

    def cycle(self, now: float, robots: Mapping[str, RobotView]) -> Sequence[TaskOrder]: ...


@runtime_checkable
class GrantSender(Protocol):
    """A policy that hands out traffic grants through ``deliver(robot, grant)``. A
    :class:`~fleet.coordination.coordinator.Coordinator` given such a policy with ``deliver``
    unset sets it to its own grant delivery (in-process agents at once, others on the bus)."""

    deliver: Callable[[str, Grant], None] | None


class NoTraffic:
    """The default :class:`TrafficPolicy`: robots rely on their own reactive safety layer."""

    def on_assign(
        self,
        robot: str,
        route: TrafficRoute | PatrolRoute,
        poses: tuple[Pose2D, ...],
        task_id: str | None = None,
    ) -> tuple[Pose2D, ...]:
        return poses

    def on_release(self, robot: str) -> None:
        return None

    def waiting(self, robot: str) -> bool:
        return False

    def cycle(self, now: float, robots: Mapping[str, RobotView]) -> Sequence[TaskOrder]:
        return ()
