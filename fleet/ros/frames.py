"""Planar transforms and a time-indexed odometry history: how the ROS backend turns a robot's
``map -> odom`` and ``odom -> base_link`` into its map pose, with the timestamps matched.

A Nav2 robot publishes its odometry (``odom -> base_link``, at 20-50 Hz) and its localizer's
correction (``map -> odom``, at scan rate; AMCL also publishes ``amcl_pose``). The map pose is
``map -> odom ∘ odom -> base_link``. Composing an ``amcl_pose`` of time *t* with the odometry
of another time moves the robot by what it drove in between (metres, at speed, when a backlog
of messages is processed late): the correction must be taken at one time,
``correction = amcl_pose(t) ∘ inverse(odometry(t))``, with the odometry *interpolated at t*
(:class:`OdomHistory`). Nothing here imports ROS.
"""

from __future__ import annotations

import bisect
import math
from collections import deque

from fleet.types import Pose2D, normalize_angle

__all__ = ["OdomHistory", "compose", "inverse", "interpolate"]


def compose(a: Pose2D, b: Pose2D) -> Pose2D:
    """``a ∘ b``: the pose ``b`` (given in ``a``'s frame) expressed in ``a``'s parent frame."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, normalize_angle(a.theta + b.theta))


def inverse(a: Pose2D) -> Pose2D:
    """The inverse transform of ``a`` (``compose(a, inverse(a))`` is the identity)."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(-(c * a.x + s * a.y), -(-s * a.x + c * a.y), normalize_angle(-a.theta))


def interpolate(a: Pose2D, b: Pose2D, f: float) -> Pose2D:
    """The pose a fraction ``f`` in [0, 1] of the way from ``a`` to ``b`` (yaw the short way)."""
    dth = normalize_angle(b.theta - a.theta)
    return Pose2D(a.x + f * (b.x - a.x), a.y + f * (b.y - a.y), normalize_angle(a.theta + f * dth))


class OdomHistory:
    """The last ``keep_s`` seconds (at most ``max_samples``) of a robot's odometry poses, by
    stamp (seconds of the robot's clock), with the distance driven.

    :meth:`add` takes samples in any order but keeps only those newer than the newest (a copy
    of the same sample from a second topic, or a late message, is ignored and counted in
    ``stale``). A step from the previous sample longer than ``max_speed`` allows for the time
    between them (plus 0.1 m) is not added to ``distance_m`` and is counted in ``jumps``: two
    sources publishing on one robot's odometry, or a robot whose odometry was reset.
    """

    def __init__(self, keep_s: float = 10.0, max_samples: int = 512, max_speed: float = 5.0) -> None:
        self.keep_s = keep_s
        self.max_speed = max_speed
        self._t: deque[float] = deque(maxlen=max_samples)
        self._p: deque[Pose2D] = deque(maxlen=max_samples)
        self.distance_m = 0.0
        self.stale = 0
        self.jumps = 0

    def __len__(self) -> int:
        return len(self._t)

    def add(self, t: float, pose: Pose2D) -> bool:
        """Record ``pose`` at ``t``; returns False (and changes nothing) for a sample not newer
        than the newest one."""
        if self._t and t <= self._t[-1]:
            self.stale += 1
            return False
        if self._p:
            step = math.hypot(pose.x - self._p[-1].x, pose.y - self._p[-1].y)
            if step <= self.max_speed * (t - self._t[-1]) + 0.1:
                self.distance_m += step
            else:
                self.jumps += 1
        self._t.append(t)
        self._p.append(pose)
        while len(self._t) > 2 and self._t[0] < t - self.keep_s:
            self._t.popleft()
            self._p.popleft()
        return True

    @property
    def latest(self) -> tuple[float, Pose2D] | None:
        """``(stamp, pose)`` of the newest sample."""
        return (self._t[-1], self._p[-1]) if self._t else None

    def at(self, t: float) -> Pose2D | None:
        """The odometry pose at ``t``, interpolated between the samples around it; the nearest
        end sample when ``t`` is at most 0.5 s outside the kept span; ``None`` beyond, or when
        empty."""
        if not self._t:
            return None
        ts = self._t
        if t <= ts[0]:
            return self._p[0] if ts[0] - t <= 0.5 else None
        if t >= ts[-1]:
            return self._p[-1] if t - ts[-1] <= 0.5 else None
        k = bisect.bisect_right(ts, t)  # ts[k - 1] <= t < ts[k]
        t0, t1 = ts[k - 1], ts[k]
        return interpolate(self._p[k - 1], self._p[k], (t - t0) / (t1 - t0))
