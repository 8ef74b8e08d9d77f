"""The step's bookkeeping after the move: batteries (drain, charging at a charger) and the
progress checker (which robots are stuck).

:meth:`Upkeep.update` runs either as NumPy array passes or, with ``compiled``, as one compiled
loop over the robots (:func:`sim.motion_kernels.battery_and_progress`); both give the same
bits. A robot that neither translated nor turned this step within ``charger_radius`` of a
charger charges; every other robot drains by the distance it drove and the time
(:meth:`fleet.robots.BatteryModel.integrate`). A robot whose task wants it to translate but
that stayed within :data:`PROGRESS_RADIUS_M` for ``stuck_time_s`` is stuck. Units m, s.
"""

from __future__ import annotations

import numpy as np

from fleet.robots import SimParams
from sim import motion_kernels
from sim.spatial import near_any
from sim.state import FleetState

#: A robot that moved this far (m) from where it last made progress has made progress.
PROGRESS_RADIUS_M = 0.1

_NONE = np.zeros(0, dtype=np.int64)


class Upkeep:
    """Batteries and the progress checker over ``state`` (see the module docstring)."""

    def __init__(self, state: FleetState, params: SimParams, chargers: np.ndarray, compiled: bool) -> None:
        self.state = state
        self.params = params
        self.compiled = compiled
        self._chargers = chargers
        order = np.argsort(chargers[:, 0], kind="stable")
        self._sites_x = np.ascontiguousarray(chargers[order, 0])
        self._sites_y = np.ascontiguousarray(chargers[order, 1])
        self._stuck = np.zeros(16, dtype=np.int64)

    def update(self, moved: np.ndarray, w: np.ndarray, ds: np.ndarray, dt: float, now: float) -> np.ndarray:
        """Batteries and progress after a step of ``dt`` s ending at ``now`` in which each robot
        translated (``moved``), turned at ``w`` (rad/s) and moved ``ds`` m along its heading.
        Returns the robots that are now stuck, in increasing order (their tasks are told)."""
        if not self.compiled:
            self._battery(moved, w, np.abs(ds), dt)
            return self._check_progress(now)
        s = self.state
        n = moved.size
        if self._stuck.size < n:
            self._stuck = np.zeros(s.capacity, dtype=np.int64)
        b = self.params.battery
        k = motion_kernels.battery_and_progress(
            moved, w, ds, s.x[:n], s.y[:n], s.battery[:n], s.charging[:n], self._sites_x, self._sites_y,
            self.params.charger_radius, b.charge_per_s * dt, b.drain_per_m, b.drain_per_s * dt,
            s.px[:n], s.py[:n], s.pt[:n], s.stuck[:n], s.has_task[:n], s.drives[:n], s.fol[:n], s.f_xy[:n],
            now, PROGRESS_RADIUS_M, self.params.stuck_time_s, self._stuck,
        )  # fmt: skip
        return self._stuck[:k] if k else _NONE

    def _battery(self, moved: np.ndarray, w: np.ndarray, adist: np.ndarray, dt: float) -> None:
        """Drain by the distance ``adist`` (m) driven and the time; charge robots that stand
        still (no move, no turn) within ``charger_radius`` of a charger."""
        s = self.state
        n = moved.size
        charging = np.zeros(n, dtype=bool)
        if self._chargers.shape[0]:
            idle = np.flatnonzero(~moved & (w == 0.0))
            if idle.size:
                x, y = s.x[:n], s.y[:n]
                cx = self._chargers[:, 0]
                cy = self._chargers[:, 1]
                charging[idle] = near_any(x[idle], y[idle], cx, cy, self.params.charger_radius)
        s.battery[:n] = self.params.battery.integrate(s.battery[:n], adist, dt, charging)
        s.charging[:n] = charging

    def _check_progress(self, now: float) -> np.ndarray:
        """The progress checker (module docstring); returns the stuck robots."""
        s = self.state
        n = s.n
        x, y = s.x[:n], s.y[:n]
        px, py, pt = s.px[:n], s.py[:n], s.pt[:n]
        far = np.hypot(x - px, y - py) > PROGRESS_RADIUS_M
        if far.any():
            np.copyto(px, x, where=far)
            np.copyto(py, y, where=far)
            pt[far] = now
            s.stuck[:n][far] = False
        near_p = ~far
        # a path follower wants to move until it stands at its final position, also while it
        # turns in place to get round something in its way
        trying = s.has_task[:n] & (s.drives[:n] | (s.fol[:n] & ~s.f_xy[:n]))
        pt[near_p & ~trying] = now
        return np.flatnonzero(near_p & trying & (now - pt >= self.params.stuck_time_s - 1e-9))
