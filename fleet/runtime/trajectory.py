"""A robot's trajectory kept in bounded memory, and what a process saw of the fleet on the bus.

:class:`Trajectory` samples ``(t, x, y)`` (s, m, m; ``map`` frame) at least ``period_s``
simulated seconds apart. It never holds more than ``max_points`` samples: when full, every
other sample is dropped and the sampling period doubles, so a run of any length keeps an
outline of the whole run (evenly spaced in time, at most ``max_points`` x 24 bytes per robot)
instead of growing with the run.

:class:`BusView` is what the runner keeps of the statuses it receives on the bus: the latest
record of each robot and, for the robots whose world cannot record their trajectories (robots
of other processes, worlds that cannot see their robots), a :class:`Trajectory` from the
records' poses.
"""

from __future__ import annotations

import threading
from array import array
from collections.abc import Iterable

from fleet.messages import StatusRecord

#: Default sampling period of a trajectory (simulated seconds).
TRAJECTORY_PERIOD_S = 0.5
#: Default bound on the samples of one trajectory.
TRAJECTORY_MAX_POINTS = 1024


class Trajectory:
    """Samples ``(t, x, y)`` at least ``period_s`` apart, at most ``max_points`` of them
    (see the module docstring). ``period_s`` is the current period (it doubles when the
    trajectory is decimated)."""

    def __init__(
        self, period_s: float = TRAJECTORY_PERIOD_S, max_points: int = TRAJECTORY_MAX_POINTS
    ) -> None:
        if max_points < 2:
            raise ValueError(f"a trajectory needs max_points >= 2, got {max_points}")
        if not period_s >= 0:
            raise ValueError(f"period_s must be >= 0, got {period_s}")
        self.period_s = float(period_s)
        self.max_points = int(max_points)
        self._t = array("d")
        self._x = array("d")
        self._y = array("d")

    def add(self, t: float, x: float, y: float) -> bool:
        """Record the pose ``(x, y)`` at time ``t`` unless the last sample is less than
        ``period_s`` older; returns whether it was recorded."""
        if self._t and t < self._t[-1] + self.period_s:
            return False
        if len(self._t) >= self.max_points:
            self._t, self._x, self._y = self._t[::2], self._x[::2], self._y[::2]
            self.period_s = 2 * self.period_s if self.period_s > 0 else TRAJECTORY_PERIOD_S
            if t < self._t[-1] + self.period_s:
                return False
        self._t.append(t)
        self._x.append(x)
        self._y.append(y)
        return True

    def points(self) -> list[tuple[float, float, float]]:
        """The samples as ``(t, x, y)`` tuples, oldest first (a copy)."""
        return list(zip(self._t, self._x, self._y, strict=True))

    def __len__(self) -> int:
        return len(self._t)

    @property
    def nbytes(self) -> int:
        """Bytes held by the samples (the arrays' buffers)."""
        return sum(a.buffer_info()[1] * a.itemsize for a in (self._t, self._x, self._y))


class BusView:
    """The latest status of every robot seen on the bus, and bounded trajectories of the
    robots not listed in :meth:`skip_trajectories`. Thread-safe (the bus calls :meth:`see`
    from its callback thread)."""

    def __init__(
        self, period_s: float = TRAJECTORY_PERIOD_S, max_points: int = TRAJECTORY_MAX_POINTS
    ) -> None:
        self._period = period_s
        self._max = max_points
        self._latest: dict[str, StatusRecord] = {}
        self._tracks: dict[str, Trajectory] = {}
        self._skip: set[str] = set()
        self._lock = threading.Lock()

    def see(self, rec: StatusRecord) -> None:
        """Take one status record (the bus's status callback)."""
        with self._lock:
            self._latest[rec.robot] = rec
            if rec.pose is None or rec.robot in self._skip:
                return
            track = self._tracks.get(rec.robot)
            if track is None:
                track = self._tracks[rec.robot] = Trajectory(self._period, self._max)
            track.add(float(rec.t), float(rec.pose[0]), float(rec.pose[1]))

    def skip_trajectories(self, robots: Iterable[str]) -> None:
        """Stop keeping (and drop) the trajectories of ``robots`` (their world records them)."""
        names = set(robots)
        with self._lock:
            self._skip |= names
            for r in names:
                self._tracks.pop(r, None)

    def latest(self) -> dict[str, StatusRecord]:
        """The latest record of each robot seen (a copy)."""
        with self._lock:
            return dict(self._latest)

    def trajectory(self, robot: str) -> list[tuple[float, float, float]]:
        """The trajectory of ``robot`` from its records (empty if none or skipped)."""
        with self._lock:
            track = self._tracks.get(robot)
            return track.points() if track is not None else []

    def trajectory_bytes(self) -> int:
        """Bytes held by every trajectory kept (for measurements)."""
        with self._lock:
            return sum(t.nbytes for t in self._tracks.values())
