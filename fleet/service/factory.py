"""Specs to tasks: resolve a submitted :data:`~fleet.service.specs.TaskSpec` against the
fleet (stations, roadmap nodes, routes, robots, the map) and build the coordinator's
:class:`~fleet.coordination.tasks.Task` for it.

Checks (each failure an :class:`~fleet.errors.InvalidTask` naming the field):

* a name target must be a station or a roadmap node (with a did-you-mean);
* a pose target must be on the map, clear of obstacles by the robot radius, and reachable: a
  straight free segment joins it to one of its :data:`NEAREST_NODES` nearest roadmap nodes
  (robots join the roadmap there; under traffic management they stop at that node);
* ``route`` must be a route of the config, ``robot`` a robot of the fleet;
* a patrol needs two distinct waypoints.

Poses are in the ``map`` frame. A node target without a heading faces along the way the
robot comes (from the previous target; the first faces east, ``theta = 0``).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from fleet.config.checks import Placer
from fleet.config.model import FleetConfig, PickTask
from fleet.coordination.kinds import StepTask, drive
from fleet.coordination.state import pick_task
from fleet.coordination.tasks import PatrolRoute, Pick, Task
from fleet.errors import ConfigError, InvalidTask
from fleet.messages import Action, Step
from fleet.service.specs import (
    ChargeSpec,
    GoToSpec,
    InspectionSpec,
    InspectionStop,
    ParkSpec,
    PatrolSpec,
    PickSpec,
    PoseRef,
    TaskSpec,
)
from fleet.types import Pose2D, TaskKind

#: A pose target is reachable through a free straight segment to one of this many nearest nodes.
NEAREST_NODES = 3


@dataclass(frozen=True)
class Resolved:
    """A resolved target: ``pose`` (``map`` frame; ``theta`` ``None`` if the user gave none),
    the roadmap ``node`` a robot stops at under traffic management, and a ``label``."""

    x: float
    y: float
    theta: float | None
    node: str
    label: str


class TaskFactory:
    """Builds tasks for ``config`` (see the module docstring)."""

    def __init__(self, config: FleetConfig) -> None:
        self.config = config
        self.roadmap = config.roadmap
        self.place = Placer(str(config.path), config.grid, config.sim.model.radius)
        self.robots = {r.name for r in config.robots}

    # -- targets --------------------------------------------------------------------------

    def target(self, ref: str | PoseRef, field: str) -> Resolved:
        """Resolve one target (station, node or pose); :class:`InvalidTask` if it cannot be."""
        if isinstance(ref, str):
            st = self.config.stations.get(ref)
            if st is not None:
                p = st.pose
                return Resolved(p.x, p.y, p.theta, self.roadmap.nearest_node(p.x, p.y), ref)
            if ref in self.roadmap:
                x, y = self.roadmap.pos(ref)
                return Resolved(x, y, None, ref, ref)
            known = [*self.config.stations, *self.roadmap.nodes]
            raise InvalidTask(field, f"unknown station or roadmap node {ref!r}{_suggest(ref, known)}")
        pose = Pose2D(ref.x, ref.y, ref.theta or 0.0)
        try:
            self.place.check(pose, field)
        except ConfigError as e:
            raise InvalidTask(field, f"unreachable pose: {e.reason}") from None
        node = self._join(pose, field)
        return Resolved(ref.x, ref.y, ref.theta, node, f"({ref.x:g}, {ref.y:g})")

    def _join(self, pose: Pose2D, field: str) -> str:
        """The nearest roadmap node joined to ``pose`` by a free straight segment."""
        nodes = sorted(self.roadmap.nodes, key=lambda n: math.dist(self.roadmap.pos(n), (pose.x, pose.y)))
        for n in nodes[:NEAREST_NODES]:
            try:
                self.place.segment((pose.x, pose.y), self.roadmap.pos(n), field, "the way from the roadmap")
            except ConfigError:
                continue
            return n
        raise InvalidTask(
            field,
            f"unreachable pose ({pose.x:g}, {pose.y:g}): no free straight way to any of its "
            f"{NEAREST_NODES} nearest roadmap nodes",
        )

    def poses(self, targets: Sequence[Resolved]) -> list[Pose2D]:
        """Poses of ``targets``; one without a heading faces away from the previous target."""
        out: list[Pose2D] = []
        for i, t in enumerate(targets):
            theta = t.theta
            if theta is None:
                prev = targets[i - 1] if i > 0 else None
                theta = (
                    math.atan2(t.y - prev.y, t.x - prev.x) if prev and (prev.x, prev.y) != (t.x, t.y) else 0.0
                )
            out.append(Pose2D(t.x, t.y, theta))
        return out

    def robot(self, name: str | None) -> str | None:
        if name is not None and name not in self.robots:
            raise InvalidTask("robot", f"unknown robot {name!r}{_suggest(name, sorted(self.robots))}")
        return name

    # -- tasks ----------------------------------------------------------------------------

    def build(self, spec: TaskSpec, name: str, parking_taken: Sequence[Pose2D] = ()) -> Task:
        """The task ``name`` for ``spec``; ``parking_taken``: parking spots other park tasks
        head for. Raises :class:`InvalidTask`."""
        only = self.robot(spec.robot)
        if isinstance(spec, PatrolSpec):
            return self.patrol(spec, name, only)
        if isinstance(spec, PickSpec):
            shelf, dropoff = self.target(spec.pickup, "pickup"), self.target(spec.dropoff, "dropoff")
            ps = self.poses([shelf, dropoff])
            pick = PickTask(
                name, ps[0], ps[1], float(spec.dwell_s), shelf_station=shelf.label, drop_station=dropoff.label
            )
            return pick_task(pick, self.roadmap, spec.priority, only)
        if isinstance(spec, GoToSpec):
            t = self.target(spec.target, "target")
            (pose,) = self.poses([t])
            return StepTask(
                name, TaskKind.GO_TO, (drive(pose, t.node, t.label),), only=only, priority=spec.priority
            )
        if isinstance(spec, InspectionSpec):
            return StepTask(
                name, TaskKind.INSPECTION, self.inspection(spec), only=only, priority=spec.priority
            )
        if isinstance(spec, ChargeSpec):
            return StepTask(name, TaskKind.CHARGE, (), only=only, priority=spec.priority)
        assert isinstance(spec, ParkSpec)
        t = (
            self.target(spec.target, "target")
            if spec.target is not None
            else self.free_parking(parking_taken)
        )
        (pose,) = self.poses([t])
        return StepTask(
            name, TaskKind.PARK, (drive(pose, t.node, t.label),), only=only, priority=spec.priority
        )

    def patrol(self, spec: PatrolSpec, name: str, only: str | None) -> PatrolRoute:
        if spec.route is not None:
            try:
                r = self.config.route(spec.route)
            except KeyError:
                known = [x.name for x in self.config.routes]
                raise InvalidTask(
                    "route", f"unknown route {spec.route!r}{_suggest(spec.route, known)}"
                ) from None
            poses = self.config.route_poses(r)
        else:
            assert spec.waypoints is not None
            ts = [self.target(w, f"waypoints[{i}]") for i, w in enumerate(spec.waypoints)]
            if len({(t.x, t.y) for t in ts}) < 2:
                raise InvalidTask("waypoints", "a patrol needs at least 2 distinct waypoints")
            if all(t.label == t.node for t in ts):  # roadmap nodes: the loop follows the roadmap
                dense = self.roadmap.expand_route([t.node for t in ts], closed=True)
                poses = self.roadmap.poses_for(dense, closed=True)
            else:
                poses = tuple(self.poses(ts))
        nodes = tuple(self.roadmap.nearest_node(p.x, p.y) for p in poses)
        return PatrolRoute(name, poses, nodes, None, spec.laps, spec.priority, only)

    def inspection(self, spec: InspectionSpec) -> tuple[Step, ...]:
        stops: list[tuple[Resolved, str, float, float, str | None]] = []
        for i, w in enumerate(spec.waypoints):
            f = f"waypoints[{i}]"
            if isinstance(w, InspectionStop):
                t = self.target(w.target, f + ".target")
                action = w.action or spec.action
                dur = spec.duration_s if w.duration_s is None else w.duration_s
                yaw = spec.yaw if w.yaw is None else w.yaw
                stops.append((t, action, dur, yaw, w.capture))
            else:
                stops.append((self.target(w, f), spec.action, spec.duration_s, spec.yaw, None))
        poses = self.poses([s[0] for s in stops])
        steps: list[Step] = []
        for i, ((t, action, dur, yaw, cap), pose) in enumerate(zip(stops, poses, strict=True)):
            steps.append(drive(pose, t.node, t.label))
            base, _, label = action.partition(":")
            if base == "wait":
                steps.append(Step(Action.WAIT, duration_s=float(dur), name=t.label))
            elif base == "spin":
                steps.append(Step(Action.SPIN, yaw=float(yaw), name=t.label))
            else:
                steps.append(Step(Action.CAPTURE, name=cap or label or f"{t.label}#{i}"))
        return tuple(steps)

    def free_parking(self, taken: Sequence[Pose2D]) -> Resolved:
        """The first parking spot of the config no other park task heads for."""
        for i, p in enumerate(self.config.parking):
            if all(math.hypot(p.x - q.x, p.y - q.y) > 1e-6 for q in taken):
                try:
                    node = self._join(p, "target")
                except InvalidTask:
                    continue
                return Resolved(p.x, p.y, p.theta, node, f"parking[{i}]")
        raise InvalidTask("target", "no free parking spot in the config (give a target)")


def _suggest(word: str, options: Sequence[str]) -> str:
    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def config_spec(task: Task) -> dict[str, Any]:
    """The spec of a config task as the store keeps it (for people: it is rebuilt from the
    config by name)."""
    if isinstance(task, PatrolRoute):
        return {"kind": "patrol", "route": task.name}
    if isinstance(task, Pick):
        sp = task.spec
        return {
            "kind": "pick",
            "pickup": sp.shelf_station or [sp.shelf.x, sp.shelf.y, sp.shelf.theta],
            "dropoff": sp.drop_station or [sp.drop.x, sp.drop.y, sp.drop.theta],
            "dwell_s": sp.dwell_s,
        }
    return {"kind": str(task.kind)}
