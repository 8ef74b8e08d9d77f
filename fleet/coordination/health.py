"""Robot health as the coordinator judges it from status records: silent (dead), progress,
stuck, charging, robots blocking each other, and waypoints blocked by something standing on
them. Pure functions over :class:`~fleet.coordination.views.RobotView`; times in seconds of
the fleet clock, distances in m (``map`` frame).

* **Dead**: the liveliness token disappeared, or no status for ``status_timeout_s``
  (:func:`silent`).
* **Progress**: a robot has made progress when it is :data:`PROGRESS_M` from where it last
  made progress (:func:`note_progress`).
* **Stuck**: it holds an assignment, its status carries the assignment's id, its mode is one
  of :data:`fleet.types.DRIVING_MODES`, and it made no progress since the later of its last
  progress and the assignment for longer than the allowed time (:func:`stalled`).
* **Charging**: its status reports ``mode == "charging"`` (:func:`charging`).
* **Blocked by another robot**: it turned ``stuck`` with another live robot within
  :data:`DEADLOCK_RADIUS_M` (:func:`someone_near`; counted as a deadlock).
* **Blocked waypoint**: a robot stuck within :data:`BLOCKED_RADIUS_M` of a waypoint of its lap
  marks the waypoint blocked for :data:`BLOCKED_WAYPOINT_S` (:class:`BlockedWaypoints`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from fleet.coordination.views import Assignment, RobotView
from fleet.types import DRIVING_MODES, Mode, Pose2D

#: A robot has made progress when it moved this far (m) from where it last made progress.
PROGRESS_M = 0.5
#: Two robots closer than this (m) when one of them becomes stuck count as a deadlock.
DEADLOCK_RADIUS_M = 1.5
#: A robot stuck this close (m) to a waypoint of its lap marks the waypoint blocked ...
BLOCKED_RADIUS_M = 1.5
#: ... and new assignments skip it for this long (s).
BLOCKED_WAYPOINT_S = 300.0


def silent(v: RobotView, now: float, timeout_s: float) -> bool:
    """``v`` is alive but sent no status for more than ``timeout_s``."""
    return v.alive and v.last_seen is not None and now - v.last_seen > timeout_s


def note_progress(v: RobotView, pose: Pose2D, now: float) -> None:
    """``v`` is at ``pose``: if that is more than :data:`PROGRESS_M` from its last progress
    pose (or it has none), it made progress at ``now``."""
    if v.progress_pose is None or v.progress_pose.distance_to(pose) > PROGRESS_M:
        v.progress_pose = pose
        v.progress_t = now


def charging(v: RobotView) -> bool:
    """``v``'s latest status says it went to charge."""
    return v.obs is not None and v.obs.mode == Mode.CHARGING


def stalled(v: RobotView, a: Assignment, now: float, allowed_s: float) -> bool:
    """``v`` is stuck on ``a``: executing it (its status carries ``a.task_id``) in a driving
    mode, without progress since ``max(progress_t, a.t_assigned)`` for more than ``allowed_s``."""
    o = v.obs
    return (
        o is not None
        and o.task_id == a.task_id
        and o.mode in DRIVING_MODES
        and now - max(v.progress_t, a.t_assigned) > allowed_s
    )


def someone_near(robots: Iterable[RobotView], v: RobotView, pose: Pose2D) -> bool:
    """Another live robot with a known pose stands within :data:`DEADLOCK_RADIUS_M` of ``pose``."""
    for other in robots:
        if other is v or not other.alive or other.obs is None or other.obs.pose is None:
            continue
        if other.obs.pose.distance_to(pose) < DEADLOCK_RADIUS_M:
            return True
    return False


@dataclass(frozen=True)
class Blocked:
    """A waypoint at ``(x, y)`` (map frame) skipped by new assignments until ``until`` (s)."""

    x: float
    y: float
    until: float


class BlockedWaypoints:
    """Waypoints something stands on (e.g. a dead robot), skipped in new assignments."""

    def __init__(self) -> None:
        self.items: list[Blocked] = []

    def mark_near(self, poses: tuple[Pose2D, ...], pose: Pose2D | None, now: float) -> Pose2D | None:
        """A robot got stuck at ``pose`` driving ``poses``: if the nearest of them is within
        :data:`BLOCKED_RADIUS_M`, block it until ``now +`` :data:`BLOCKED_WAYPOINT_S` and
        return it (else ``None``)."""
        if pose is None or not poses:
            return None
        wp = min(poses, key=pose.distance_to)
        if wp.distance_to(pose) > BLOCKED_RADIUS_M:
            return None
        self.items.append(Blocked(wp.x, wp.y, now + BLOCKED_WAYPOINT_S))
        return wp

    def skip(self, poses: tuple[Pose2D, ...], now: float) -> tuple[Pose2D, ...]:
        """``poses`` without the waypoints blocked at ``now`` (expired blocks are dropped), if
        at least 2 remain; else ``poses`` unchanged."""
        self.items = [b for b in self.items if b.until > now]
        if not self.items:
            return poses
        kept = tuple(p for p in poses if not any(math.hypot(p.x - b.x, p.y - b.y) < 1e-6 for b in self.items))
        return kept if 2 <= len(kept) < len(poses) else poses
