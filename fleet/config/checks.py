"""The second stage of :func:`fleet.config.load_config`: checks that need the map and the
roadmap, run on a file that already passed the schema (:mod:`fleet.config.schema`).

Poses must be on the map and clear of obstacles by the robot radius, roadmap nodes and edges
too, the roadmap connected, robots at least two radii apart, and every reference (a route's
waypoint, a task's shelf or drop, a preferred robot) must name something that exists. The
first problem raises a :class:`~fleet.errors.ConfigError` ``<file>: <field>: <reason>``.
Poses are in the ``map`` frame: meters and radians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fleet.config.fields import suggest
from fleet.config.model import NamedPose, PickTask, Route
from fleet.config.schema import NamedPoseEntry, RobotEntry, RouteEntry, TaskEntry
from fleet.errors import ConfigError
from fleet.maps import OccupancyGrid
from fleet.roadmap.graph import Roadmap
from fleet.robots import RobotSpec
from fleet.types import Pose2D

XYZ = tuple[float, float, float]


class Placer:
    """Checks that poses and segments of config ``file`` are on ``grid`` and clear of
    obstacles by ``radius`` meters (every cell in reach free: unknown cells count as blocked)."""

    def __init__(self, file: str, grid: OccupancyGrid, radius: float) -> None:
        self.file, self.grid, self.radius = file, grid, radius

    def pose(self, xyz: XYZ, field: str) -> Pose2D:
        """``xyz`` as a :class:`Pose2D`, after :meth:`check`."""
        pose = Pose2D(*xyz)
        self.check(pose, field)
        return pose

    def check(self, pose: Pose2D, field: str) -> None:
        """Raise unless ``pose`` is on the map and clear of obstacles."""
        if not self.grid.in_bounds(pose.x, pose.y):
            xmin, xmax, ymin, ymax = self.grid.extent
            raise ConfigError(
                self.file,
                field,
                f"pose ({pose.x:g}, {pose.y:g}) is off the map "
                f"(x in [{xmin:g}, {xmax:g}), y in [{ymin:g}, {ymax:g}))",
            )
        if not self.grid.is_free(pose.x, pose.y, self.radius):
            raise ConfigError(
                self.file,
                field,
                f"pose ({pose.x:g}, {pose.y:g}) is inside an obstacle or within robot_model.radius "
                f"({self.radius:g} m) of one",
            )

    def segment(self, a: tuple[float, float], b: tuple[float, float], field: str, what: str) -> None:
        """Raise unless every point of segment ``a``-``b``, sampled every map cell, is clear
        (all samples in one array pass; the first blocked one is named)."""
        (ax, ay), (bx, by) = a, b
        n = max(1, math.ceil(math.hypot(bx - ax, by - ay) / self.grid.resolution))
        k = np.arange(n + 1)
        xs, ys = ax + (bx - ax) * k / n, ay + (by - ay) * k / n
        if self.radius > 0:
            free = self.grid.free_at(xs, ys, self.radius)
        else:
            free = np.array(
                [self.grid.is_free(float(x), float(y), self.radius) for x, y in zip(xs, ys, strict=True)]
            )
        if not free.all():
            i = int(np.argmin(free))
            x, y = float(xs[i]), float(ys[i])
            raise ConfigError(
                self.file,
                field,
                f"{what} passes through an obstacle at ({x:.2f}, {y:.2f}) "
                f"(clearance robot_model.radius = {self.radius:g} m)",
            )


class NearIndex:
    """A uniform hash grid answering "is a stored point closer than ``d``" (``d <= cell``)."""

    def __init__(self, cell: float) -> None:
        self.cell = cell
        self.buckets: dict[tuple[int, int], list[tuple[float, float, int]]] = {}

    def _key(self, x: float, y: float) -> tuple[int, int]:
        return (math.floor(x / self.cell), math.floor(y / self.cell))

    def add(self, x: float, y: float, idx: int) -> None:
        """Store point ``(x, y)`` (m) under index ``idx``."""
        self.buckets.setdefault(self._key(x, y), []).append((x, y, idx))

    def closer_than(self, x: float, y: float, d: float) -> int | None:
        """The index of the nearest stored point closer than ``d`` to ``(x, y)``, or ``None``."""
        cx, cy = self._key(x, y)
        best: tuple[float, int] | None = None
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                for px, py, idx in self.buckets.get((cx + i, cy + j), ()):
                    dd = math.hypot(px - x, py - y)
                    if dd < d - 1e-9 and (best is None or (dd, idx) < best):
                        best = (dd, idx)
        return None if best is None else best[1]


def check_roadmap(place: Placer, roadmap: Roadmap, listed: Sequence[tuple[str, str]] = ()) -> None:
    """Every node and (straight) edge clear of obstacles, and the roadmap connected.

    ``listed`` are the edges as the file lists them, so that ``roadmap.edges[i]`` names the
    entry ``i`` of the file (the roadmap keeps its edges in its own order). Fields:
    ``roadmap.nodes.<name>`` / ``roadmap.edges[i]``, or for a roadmap read from a SUMO network
    ``roadmap.net.junctions.<id>`` / ``roadmap.net.edges[a, b]``; ``roadmap``.
    """
    net = roadmap.source_net is not None
    for n in roadmap.nodes:
        place.check(Pose2D(*roadmap.pos(n)), f"roadmap.net.junctions.{n}" if net else f"roadmap.nodes.{n}")
    for i, (a, b) in enumerate(list(listed) if listed and not net else roadmap.edges):
        f = f"roadmap.net.edges[{a}, {b}]" if net else f"roadmap.edges[{i}]"
        place.segment(roadmap.pos(a), roadmap.pos(b), f, f"edge {a} - {b}")
    if not roadmap.is_connected():
        first = roadmap.nodes[0]
        cut = next(n for n in roadmap.nodes if not roadmap.shortest_path(first, n))
        raise ConfigError(place.file, "roadmap", f"not connected: {cut!r} cannot be reached from {first!r}")


def named_poses(place: Placer, entries: Sequence[NamedPoseEntry], section: str) -> list[NamedPose]:
    """The chargers or stations of ``section``, each pose checked (``<section>[i].pose``)."""
    return [NamedPose(e.name, place.pose(e.pose, f"{section}[{i}].pose")) for i, e in enumerate(entries)]


def check_station_names(file: str, stations: Mapping[str, NamedPose], roadmap: Roadmap) -> None:
    """A station may not share its name with a roadmap node (a waypoint names either)."""
    for i, name in enumerate(stations):
        if name in roadmap:
            raise ConfigError(file, f"stations[{i}].name", f"{name!r} is also a roadmap node name")


def listed_robots(place: Placer, entries: Sequence[RobotEntry], initial: float) -> list[RobotSpec]:
    """The listed robots: starts clear of obstacles and at least two radii from every earlier
    robot's start (``robots[i].start``); battery ``initial`` unless given."""
    out: list[RobotSpec] = []
    near = NearIndex(2 * place.radius)
    for i, e in enumerate(entries):
        f = f"robots[{i}].start"
        start = place.pose(e.start, f)
        hit = near.closer_than(start.x, start.y, 2 * place.radius)
        if hit is not None:
            other = out[hit]
            raise ConfigError(
                place.file,
                f,
                f"{start.distance_to(other.start):.2f} m from {other.name}'s start, closer than "
                f"2 * robot_model.radius ({2 * place.radius:g} m)",
            )
        near.add(start.x, start.y, len(out))
        battery = initial if e.battery is None else e.battery
        out.append(RobotSpec(name=e.name, namespace=e.ns, start=start, battery=battery))
    return out


class References:
    """Resolves names in routes and tasks: roadmap nodes, stations and robots (of the fleet as
    resized by ``load_config(robots=N)``). An unknown name is an error with a did-you-mean."""

    def __init__(
        self, place: Placer, roadmap: Roadmap, stations: Mapping[str, NamedPose], robot_names: set[str]
    ) -> None:
        self.place, self.roadmap, self.stations, self.robot_names = place, roadmap, stations, robot_names

    def route(self, e: RouteEntry, f: str) -> Route:
        """Route ``e`` (field ``f``, e.g. ``routes[0]``). A roadmap node waypoint faces the next
        waypoint (the last faces the first: routes are loops); a station keeps its heading."""
        xy: list[tuple[float, float, float | None]] = []
        nodes: list[str | None] = []
        for j, w in enumerate(e.waypoints):
            wf = f"{f}.waypoints[{j}]"
            if isinstance(w, str) and w in self.roadmap:
                xy.append((*self.roadmap.pos(w), None))
                nodes.append(w)
                continue
            pose = self._place(w, wf, "roadmap node or station", [*self.roadmap.nodes, *self.stations])
            xy.append((pose.x, pose.y, pose.theta))
            nodes.append(None)
        poses = []
        for j, (x, y, th) in enumerate(xy):
            if th is None:
                nx_, ny_, _ = xy[(j + 1) % len(xy)]
                th = math.atan2(ny_ - y, nx_ - x) if (nx_, ny_) != (x, y) else 0.0
            poses.append(Pose2D(x, y, th))
        robot = self.robot(e.robot, f"{f}.robot")
        return Route(name=e.name, waypoints=tuple(poses), node_names=tuple(nodes), robot=robot)

    def task(self, e: TaskEntry, f: str) -> PickTask:
        """Task ``e`` (field ``f``, e.g. ``tasks[0]``): ``shelf`` / ``drop`` are stations or poses."""
        shelf = self._place(e.shelf, f"{f}.shelf", "station", self.stations)
        drop = self._place(e.drop, f"{f}.drop", "station", self.stations)
        return PickTask(
            name=e.name,
            shelf=shelf,
            drop=drop,
            dwell_s=e.dwell_s,
            robot=self.robot(e.robot, f"{f}.robot"),
            shelf_station=e.shelf if isinstance(e.shelf, str) else "",
            drop_station=e.drop if isinstance(e.drop, str) else "",
        )

    def robot(self, name: str | None, f: str) -> str | None:
        """A preferred robot: ``None`` or the name of a robot of the fleet."""
        if name is not None and name not in self.robot_names:
            raise ConfigError(
                self.place.file, f, f"unknown robot {name!r}{suggest(name, sorted(self.robot_names))}"
            )
        return name

    def _place(
        self, ref: str | XYZ, f: str, what: str, known: Sequence[str] | Mapping[str, object]
    ) -> Pose2D:
        if not isinstance(ref, str):
            return self.place.pose(ref, f)
        if ref not in self.stations:
            raise ConfigError(self.place.file, f, f"unknown {what} {ref!r}{suggest(ref, known)}")
        return self.stations[ref].pose
