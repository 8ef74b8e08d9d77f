"""What the traffic policy reads of the coordinator's values, as structural types.

The coordinator (``fleet.coordination``) hands :class:`~fleet.traffic.policy.ReservationTraffic`
its robot views and patrol routes; these protocols name only the attributes the policy
reads, so the policy does not depend on how the coordinator builds them (its
``RobotView``, ``Observation`` and ``PatrolRoute`` satisfy them)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from fleet.types import Pose2D


class ObservationLike(Protocol):
    """The latest status of a robot: ``pose`` (``map`` frame, ``None`` if unknown),
    ``mode`` (its tree's :class:`~fleet.types.Mode`), ``battery`` in [0, 1]."""

    @property
    def pose(self) -> Pose2D | None: ...

    @property
    def mode(self) -> str: ...

    @property
    def battery(self) -> float: ...


class RobotViewLike(Protocol):
    """A robot as the coordinator sees it: ``alive`` (its agent is there), ``obs`` (its
    latest status, ``None`` before the first) and ``assignment`` (its patrol or ``None``)."""

    @property
    def alive(self) -> bool: ...

    @property
    def obs(self) -> ObservationLike | None: ...

    @property
    def assignment(self) -> object | None: ...


class RouteLike(Protocol):
    """A patrol route: its waypoints' roadmap ``nodes``, in driving order."""

    @property
    def nodes(self) -> Sequence[str]: ...
