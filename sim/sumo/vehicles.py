"""The robots as SUMO vehicles: where each one is, and bringing it to rest.

:class:`Vehicle` is one robot of a :class:`sim.sumo.world.SumoWorld` (its spec, its SUMO vehicle
id and what the world reports about it: battery, stuck, collisions, teleports, odometry,
trajectory). :class:`Vehicles` commands them through libsumo: inserting a vehicle parked at its
start lane point, reading its lane position and pose (the vehicle's centre, ``map`` frame; SUMO
reports the front bumper), bringing it to rest (brake, then park off the lane or hold on it)
and putting back a vehicle SUMO removed after a teleport.

``epoch`` counts SUMO steps and commands; poses and route progress read from SUMO are cached
until it changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from fleet.robots import RobotSpec
from fleet.types import Pose2D, normalize_angle
from sim.sumo.lanes import LaneIndex, LanePoint
from sim.sumo.launch import ROBOT_TYPE, Libsumo

#: Stop duration used for "stay until told otherwise" (s).
FOREVER_S = 1.0e7


@dataclass
class Vehicle:
    """One robot as a SUMO vehicle. ``mode`` is ``parked``, ``holding``, ``driving``,
    ``braking`` or ``crossing`` (leaving a junction before it can stop)."""

    spec: RobotSpec
    vid: str
    battery: float
    stuck: bool = False
    collisions: int = 0
    teleports: int = 0
    mode: str = "parked"
    last_batt_t: float = 0.0
    last_odo: float = 0.0
    last_pose: Pose2D | None = None
    last_where: tuple[str, float, int] | None = None
    present: bool = False
    trajectory: list[tuple[float, float, float]] = field(default_factory=list)
    reinserted: int = 0
    prog: tuple[int, float] = (0, 0.0)
    prog_epoch: int = -1
    pose_epoch: int = -1
    odo_base: float = 0.0  # odometry of earlier incarnations of the vehicle
    odo_total: float = 0.0

    @property
    def namespace(self) -> str:
        return self.spec.namespace


class Vehicles:
    """Commands the robots' vehicles in the running libsumo ``ls`` (see the module docstring).

    Args:
        ls: the libsumo module, with a simulation loaded.
        lanes: the lane index of the loaded network.
        length: vehicle length (m), the robot's diameter.
        park_idle: idle robots park off the lane (else they hold on it).
    """

    def __init__(self, ls: Libsumo, lanes: LaneIndex, length: float, park_idle: bool) -> None:
        self.ls = ls
        self.lanes = lanes
        self.length = length
        self.park_idle = park_idle
        self.epoch = 0
        self.closed = False
        #: namespace -> park? for vehicles being brought to rest (retried every step)
        self.resting: dict[str, bool] = {}

    def idle_flags(self) -> int:
        """SUMO stop flags of an idle robot: 1 (parking) or 0 (holding on the lane)."""
        return 1 if self.park_idle else 0

    def front_pos(self, edge: str, center_pos: float) -> float:
        """Lane position of the front bumper when the vehicle's centre is at ``center_pos``."""
        return min(max(center_pos + self.length / 2.0, self.length), self.lanes.edge_length[edge])

    def insert(self, spec: RobotSpec, now: float) -> Vehicle:
        """Add ``spec`` as a vehicle (named ``spec.name``) parked or holding at the lane point
        nearest its start pose, however far."""
        lp = self.lanes.nearest(spec.start.x, spec.start.y, spec.start.theta)
        vid = spec.name
        front = round(self.front_pos(lp.edge, lp.pos), 3)  # the stop must not lie before departPos
        self._depart(vid, f"__start_{vid}", lp.edge, front, lp.lane)
        vehicle = Vehicle(
            spec=spec,
            vid=vid,
            battery=spec.battery,
            last_batt_t=now,
            last_pose=Pose2D(lp.x, lp.y, spec.start.theta),
        )
        vehicle.trajectory.append((now, lp.x, lp.y))
        return vehicle

    def _depart(self, vid: str, route_id: str, edge: str, front: float, lane: int) -> None:
        ls = self.ls
        ls.route.add(route_id, [edge])
        ls.vehicle.add(
            vid,
            route_id,
            ROBOT_TYPE,
            depart="now",
            departPos=f"{front:.3f}",
            departSpeed="0",
            departLane=str(lane),
        )
        ls.vehicle.setStop(vid, edge, pos=front, laneIndex=lane, duration=FOREVER_S, flags=self.idle_flags())

    def where(self, v: Vehicle) -> tuple[str, float, int] | None:
        """``(edge, front lane pos, lane index)`` of a vehicle on a normal edge, else ``None``."""
        ls = self.ls
        if not v.present:
            return None
        road = ls.vehicle.getRoadID(v.vid)
        if not road or road.startswith(":"):
            return None
        where = (road, float(ls.vehicle.getLanePosition(v.vid)), int(ls.vehicle.getLaneIndex(v.vid)))
        v.last_where = where
        return where

    def reinsert(self, v: Vehicle, target: LanePoint | None) -> None:
        """Put back a vehicle that SUMO removed (teleported past its route's end), parked (or
        holding) at ``target`` (its goal's last pose), else at the end of the lane it was last
        seen on, else at its start."""
        if target is not None:
            edge, front, lane = target.edge, self.front_pos(target.edge, target.pos), target.lane
        elif v.last_where is not None:
            edge, _, lane = v.last_where
            front = self.lanes.edge_length[edge]
        else:
            s = v.spec.start
            lp = self.lanes.nearest(s.x, s.y, s.theta)
            edge, front, lane = lp.edge, self.front_pos(lp.edge, lp.pos), lp.lane
        front = round(front, 3)
        v.reinserted += 1
        self._depart(v.vid, f"__re{v.reinserted}_{v.vid}", edge, front, lane)
        v.mode = "parked" if self.park_idle else "holding"
        v.odo_base = v.odo_total
        self.resting.pop(v.namespace, None)

    def clear_stops(self, v: Vehicle) -> None:
        """Resume a stopped vehicle and drop every stop it has."""
        self.epoch += 1
        ls = self.ls
        if ls.vehicle.isStopped(v.vid):
            ls.vehicle.resume(v.vid)
        for _ in range(len(ls.vehicle.getStops(v.vid))):
            try:
                ls.vehicle.replaceStop(v.vid, 0, "")
            except Exception:
                break

    def rest(self, v: Vehicle, park: bool) -> bool:
        """Bring the vehicle to rest where it is: brake (``setSpeed(0)``, within its decel)
        while it moves, then replace its stops by one at its lane position, parked off the lane
        (``park``) or holding on it. Returns True once at rest; until then the vehicle is kept
        in :attr:`resting` and this is retried every step (also while it crosses a junction or
        is teleporting: a stop can only be placed on a normal lane)."""
        ls = self.ls
        ns = v.namespace
        self.resting[ns] = park
        if not v.present:
            return False
        want = "parked" if park else "holding"
        stopped = bool(ls.vehicle.isStopped(v.vid))
        if v.mode == want and stopped:
            self.resting.pop(ns, None)
            return True
        where = self.where(v)
        if where is None:
            if v.mode == "braking" and ls.vehicle.getRoadID(v.vid):
                # inside a junction: SUMO would teleport a vehicle held there; cross it first
                ls.vehicle.setSpeed(v.vid, -1.0)
                v.mode = "crossing"
            return False
        speed = float(ls.vehicle.getSpeed(v.vid))
        if not stopped and speed > 1e-3:
            self.epoch += 1
            ls.vehicle.setSpeed(v.vid, 0.0)
            v.mode = "braking"
            return False
        edge, pos, lane = where
        try:
            self.clear_stops(v)
            ls.vehicle.setRoute(v.vid, [edge])
            ls.vehicle.setStop(
                v.vid, edge, pos=pos, laneIndex=lane, duration=FOREVER_S, flags=1 if park else 0
            )
            ls.vehicle.setSpeed(v.vid, -1.0)
        except Exception:  # retried next step
            return False
        v.mode = want
        self.resting.pop(ns, None)
        return True

    def pose(self, v: Vehicle) -> Pose2D | None:
        """The vehicle's centre and heading (``map`` frame), cached until :attr:`epoch`
        changes; the last known pose while it is teleporting, absent or the world is closed."""
        if not v.present or self.closed or v.pose_epoch == self.epoch:
            return v.last_pose
        ls = self.ls
        road = ls.vehicle.getRoadID(v.vid)
        if not road:  # teleporting
            return v.last_pose
        theta = normalize_angle(math.radians(90.0 - float(ls.vehicle.getAngle(v.vid))))
        if not road.startswith(":"):
            # centre = half a vehicle behind the front along the lane, in lane units (a lane may be
            # longer than its drawn shape; parked vehicles are drawn beside the lane)
            lane = min(max(int(ls.vehicle.getLaneIndex(v.vid)), 0), self.lanes.lane_count[road] - 1)
            c = max(0.0, float(ls.vehicle.getLanePosition(v.vid)) - self.length / 2.0)
            xy = self.lanes.point(road, lane, c)
            x, y = xy if xy is not None else ls.simulation.convert2D(road, c, lane)
        else:
            fx, fy = ls.vehicle.getPosition(v.vid)
            x = fx - math.cos(theta) * self.length / 2.0
            y = fy - math.sin(theta) * self.length / 2.0
        pose = Pose2D(float(x), float(y), theta)
        v.last_pose, v.pose_epoch = pose, self.epoch
        return pose
