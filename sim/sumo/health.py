"""What the SUMO world reports about each robot's health besides its goal: contacts with other
robots and the battery.

* :class:`Contacts` reads ``simulation.getCollisions()`` every step (SUMO runs with
  ``--collision.action warn``, junction checks on, only real overlaps): a pair that starts
  touching is one collision event, counted for both robots.
* :class:`Chargers` integrates a robot's battery whenever its state is read
  (:meth:`fleet.robots.BatteryModel.integrate`): charging while it stands still within
  ``charger_radius`` (+ a vehicle length) of a charger's lane point, else draining with time
  and odometry.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from fleet.robots import BatteryModel
from fleet.types import Pose2D
from sim.history import EVENTS_KEPT, trim_oldest
from sim.sumo.lanes import LanePoint
from sim.sumo.launch import Libsumo
from sim.sumo.vehicles import Vehicle


class Contacts:
    """Robot-robot contacts: ``total`` events and ``events`` ``(t, ns_a, ns_b, x, y)`` (the
    midpoint of the two poses, NaN when one is unknown; the last :data:`sim.history.EVENTS_KEPT`
    at least)."""

    def __init__(self, ls: Libsumo) -> None:
        self.ls = ls
        self.total = 0
        self.events: list[tuple[float, str, str, float, float]] = []
        self._touching: set[tuple[str, str]] = set()

    def count(self, now: float, by_vid: dict[str, Vehicle], pose: Callable[[Vehicle], Pose2D | None]) -> None:
        """Count the pairs of robots (``by_vid``: vehicle id -> robot) that started touching at
        ``now`` (s); ``pose`` gives a robot's pose."""
        touching: set[tuple[str, str]] = set()
        for c in self.ls.simulation.getCollisions():
            a, b = c.collider, c.victim
            if a not in by_vid or b not in by_vid:
                continue
            pair = (a, b) if a < b else (b, a)
            touching.add(pair)
            if pair not in self._touching:
                ra, rb = by_vid[a], by_vid[b]
                self.total += 1
                ra.collisions += 1
                rb.collisions += 1
                pa, pb = pose(ra), pose(rb)
                x, y = (0.5 * (pa.x + pb.x), 0.5 * (pa.y + pb.y)) if pa and pb else (math.nan, math.nan)
                self.events.append((now, ra.namespace, rb.namespace, x, y))
                trim_oldest(self.events, EVENTS_KEPT)
        self._touching = touching


class Chargers:
    """The chargers' lane points and the battery step of the robots."""

    def __init__(self, points: list[LanePoint], radius: float, battery: BatteryModel) -> None:
        self.points = points
        self.radius = radius
        self.battery = battery

    def at_charger(self, pose: Pose2D | None, speed: float) -> bool:
        """Whether a robot at ``pose`` moving at ``speed`` (m/s) stands at a charger."""
        if pose is None or speed > 1e-3:
            return False
        return any(math.hypot(c.x - pose.x, c.y - pose.y) <= self.radius for c in self.points)

    def update(self, v: Vehicle, now: float, odo: float, speed: float, pose: Pose2D | None) -> None:
        """Integrate ``v``'s battery from when it was last updated to ``now`` (s), with its
        odometer ``odo`` (m)."""
        dt = max(0.0, now - v.last_batt_t)
        dd = max(0.0, odo - v.last_odo)
        charging = self.at_charger(pose, speed) and dd < 1e-6
        v.battery = float(self.battery.integrate(v.battery, dd, dt, charging))
        v.last_batt_t = now
        v.last_odo = odo
