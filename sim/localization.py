"""Localization of the simulated robots: odometry, the localizer's pose estimate, its loss.

What AMCL and the wheel odometry give a Nav2 robot, for every robot of the simulator:

* **Odometry** (frame ``odom``): the robot's motion integrated from where it was added. The
  ``odom`` frame's origin is the robot's start pose in ``map``, so ``odom -> base_link`` is
  the pose relative to the start. The simulator's odometry is exact (no slip).
* **The pose estimate**: the transform ``map -> odom`` the localizer publishes (the
  *correction*), so that ``map -> base_link = correction ∘ odometry``. While the robot is
  localized the correction is exact and confirmed at every step (``updated`` is now).
* **Loss** (fault injection, :meth:`Localization.set_lost`): the localizer stops confirming
  the estimate (``updated`` stays where it was, ``localized`` is False) until the fault is
  cleared, which re-localizes the robot at once.
* **Initial pose** (:meth:`Localization.initial_pose`, ``initialpose`` over ROS): a hint
  within :data:`CONVERGE_RADIUS_M` and :data:`CONVERGE_YAW_RAD` of the true pose converges
  (the estimate is exact and confirmed); a hint farther away becomes the estimate as given,
  and the robot is *mislocalized* (``localized`` False, the estimate follows the odometry from
  the hint) until a hint close to the truth arrives or the robot is re-localized.

Units m, rad, s; ``map`` frame. No wall clock, no randomness: the same inputs give the same
estimates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fleet.types import Pose2D, normalize_angle

#: An initial pose this close (m) to the robot's true position lets the localizer converge.
CONVERGE_RADIUS_M = 1.0
#: ... and this close in heading (rad).
CONVERGE_YAW_RAD = 0.6


def compose(a: Pose2D, b: Pose2D) -> Pose2D:
    """``a ∘ b``: the pose ``b`` (given in ``a``'s frame) expressed in ``a``'s parent frame."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, normalize_angle(a.theta + b.theta))


def inverse(a: Pose2D) -> Pose2D:
    """The inverse transform of ``a`` (``compose(a, inverse(a))`` is the identity)."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(-(c * a.x + s * a.y), -(-s * a.x + c * a.y), normalize_angle(-a.theta))


@dataclass
class Estimate:
    """One robot's localization: ``origin`` is the ``odom`` frame in ``map`` (the start pose),
    ``correction`` the estimated ``map -> odom``; ``localized`` whether the localizer has a
    converged estimate; ``lost`` whether the loss fault is injected; ``updated`` the simulated
    time the estimate was last confirmed; ``reason`` why it is not localized (``""`` when it is)."""

    origin: Pose2D
    correction: Pose2D
    localized: bool = True
    lost: bool = False
    updated: float = 0.0
    reason: str = ""


@dataclass(frozen=True)
class LocalizationState:
    """A snapshot of one robot's localization (see :class:`Localization`).

    ``odom``: ``odom -> base_link``; ``map_to_odom``: the estimated ``map -> odom``;
    ``pose``: the estimated map pose (``map_to_odom ∘ odom``); ``updated``: when the
    estimate was last confirmed (simulated s); ``localized`` / ``reason`` as in
    :class:`Estimate`; ``lost``: the loss fault is injected (no estimate is published);
    ``error_m``: distance of the estimate from the true position."""

    odom: Pose2D
    map_to_odom: Pose2D
    pose: Pose2D
    updated: float
    localized: bool
    lost: bool
    reason: str
    error_m: float


class Localization:
    """The localization of every robot of a simulator (see the module docstring). Robots are
    indexed as in :class:`sim.state.FleetState`."""

    def __init__(self) -> None:
        self.robots: list[Estimate] = []
        #: Robots whose estimate was ever changed (a loss or an initial pose): every other
        #: robot is localized, as added (what batch reads rely on).
        self.touched: set[int] = set()

    def add(self, start: Pose2D, now: float) -> None:
        """A robot added at ``start`` (its odometry starts at zero there), localized."""
        self.robots.append(Estimate(origin=start, correction=start, updated=now))

    def odom(self, i: int, truth: Pose2D) -> Pose2D:
        """Robot ``i``'s odometry pose (``odom -> base_link``) when it truly is at ``truth``."""
        return compose(inverse(self.robots[i].origin), truth)

    def set_lost(self, i: int, lost: bool, now: float) -> None:
        """Inject (``lost``) or clear the loss of robot ``i``'s localization. Clearing it
        re-localizes the robot at once (the estimate is exact again)."""
        e = self.robots[i]
        self.touched.add(i)
        if lost and not e.lost:
            if e.localized:
                e.updated = now  # last confirmed now
            e.lost = True
            e.localized = False
            e.reason = "localization lost (fault injected)"
        elif not lost and e.lost:
            e.lost = False
            self._relocalize(e, now)

    def initial_pose(self, i: int, hint: Pose2D, truth: Pose2D, now: float) -> bool:
        """An initial pose ``hint`` for robot ``i`` truly at ``truth``; returns whether the
        localizer converged (see the module docstring). While the loss fault is injected the
        hint becomes the estimate and the robot stays lost."""
        e = self.robots[i]
        self.touched.add(i)
        near = (
            hint.distance_to(truth) <= CONVERGE_RADIUS_M
            and abs(normalize_angle(hint.theta - truth.theta)) <= CONVERGE_YAW_RAD
        )
        if near and not e.lost:
            self._relocalize(e, now)
            return True
        e.correction = compose(hint, inverse(self.odom(i, truth)))
        e.localized = False
        e.updated = now
        if not e.lost:
            e.reason = (
                f"initial pose ({hint.x:.2f}, {hint.y:.2f}) did not converge: it is "
                f"{hint.distance_to(truth):.1f} m from where the robot is"
            )
        return False

    def _relocalize(self, e: Estimate, now: float) -> None:
        e.correction = e.origin
        e.localized = True
        e.updated = now
        e.reason = ""

    def unlocalized(self) -> list[int]:
        """The robots that are not localized or whose localization is lost, by index."""
        return sorted(i for i in self.touched if not self.robots[i].localized or self.robots[i].lost)

    def confirmed(self, i: int, now: float) -> float:
        """When robot ``i``'s estimate was last confirmed: ``now`` while it is localized and
        not lost (the estimate is confirmed every step, computed on demand)."""
        e = self.robots[i]
        return now if e.localized and not e.lost else e.updated

    def state(self, i: int, truth: Pose2D, now: float) -> LocalizationState:
        """Robot ``i``'s localization at ``now``, when it truly is at ``truth``."""
        e = self.robots[i]
        odom = self.odom(i, truth)
        pose = compose(e.correction, odom)
        return LocalizationState(
            odom=odom,
            map_to_odom=e.correction,
            pose=pose,
            updated=self.confirmed(i, now),
            localized=e.localized,
            lost=e.lost,
            reason=e.reason,
            error_m=pose.distance_to(truth),
        )
