"""Small in-memory worlds on the real simulator and a loop that steps the simulator and
ticks trees at 10 Hz of simulated time, shared by the behavior-tree tests.

The simulator's path follower orbits at turns sharper than 90 degrees and a goal that ends
where the robot stands succeeds at once, so test routes turn by at most 90 degrees."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import py_trees

from fleet.clock import SimClock
from fleet.maps import OCCUPIED, OccupancyGrid
from fleet.robots import RobotSpec, SimParams
from fleet.types import Pose2D
from sim.simulator import Simulator

#: The charger of :func:`make_world` worlds.
CHARGER = Pose2D(1.0, 1.0, 0.0)
#: The center of a closed box of :func:`room` (0.5 m thick walls, 1 x 1 m free inside,
#: unreachable).
BOX = (8.5, 4.0)
#: A 3 x 2 m rectangle route inside :func:`room`, counter-clockwise.
ROUTE_A = (Pose2D(2.0, 2.0, 0.0), Pose2D(5.0, 2.0, 1.57), Pose2D(5.0, 4.0, 3.14), Pose2D(2.0, 4.0, -1.57))
#: A second, smaller route.
ROUTE_B = (Pose2D(6.0, 1.5, 0.0), Pose2D(7.0, 1.5, 1.57), Pose2D(7.0, 2.5, 3.14), Pose2D(6.0, 2.5, -1.57))
#: The loop route of :func:`ring`, counter-clockwise along the middle of its corridor.
RING_ROUTE = (Pose2D(0.6, 0.6, 0.0), Pose2D(7.4, 0.6, 1.57), Pose2D(7.4, 4.4, 3.14), Pose2D(0.6, 4.4, -1.57))
#: A round obstacle (x, y, radius) that closes the bottom corridor of :func:`ring`.
RING_PLUG = (4.0, 0.6, 0.35)


def room(width_m: float = 10.0, height_m: float = 6.0, res: float = 0.1) -> OccupancyGrid:
    """A walled ``width_m`` x ``height_m`` room (origin 0, 0) with a closed box around
    :data:`BOX`."""
    w, h = int(round(width_m / res)), int(round(height_m / res))
    cells = np.zeros((h, w), dtype=np.int8)
    cells[0, :] = cells[-1, :] = OCCUPIED
    cells[:, 0] = cells[:, -1] = OCCUPIED
    bx, by = (int(round(v / res)) for v in BOX)
    outer, inner = int(round(1.0 / res)), int(round(0.5 / res))
    cells[by - outer : by + outer, bx - outer : bx + outer] = OCCUPIED
    cells[by - inner : by + inner, bx - inner : bx + inner] = 0
    return OccupancyGrid(cells=cells, resolution=res, origin_x=0.0, origin_y=0.0, source="<nodes test room>")


def ring(res: float = 0.1) -> OccupancyGrid:
    """An 8 x 5 m walled room filled by a central block, leaving a 1 m wide corridor ring
    around it (free for y in [0.1, 1.1] along the bottom); :data:`RING_PLUG` blocks it so
    that a robot can neither pass nor steer around it."""
    w, h = int(round(8.0 / res)), int(round(5.0 / res))
    cells = np.zeros((h, w), dtype=np.int8)
    cells[0, :] = cells[-1, :] = OCCUPIED
    cells[:, 0] = cells[:, -1] = OCCUPIED
    y0, y1, x0, x1 = (int(round(v / res)) for v in (1.1, 3.9, 1.1, 6.9))
    cells[y0:y1, x0:x1] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=res, origin_x=0.0, origin_y=0.0, source="<nodes test ring>")


def make_world(robots: dict[str, Pose2D | tuple[Pose2D, float]], **overrides: Any) -> Simulator:
    """A simulator on :func:`room` with a charger at :data:`CHARGER`, ``SimParams`` fields
    overridden by keyword, one robot per namespace (pose, or (pose, battery))."""
    params = replace(SimParams(chargers=(CHARGER,)), **overrides)
    sim = Simulator(room(), params, SimClock())
    for ns, spec in robots.items():
        pose, battery = spec if isinstance(spec, tuple) else (spec, 1.0)
        sim.add_robot(RobotSpec(ns.strip("/"), ns, pose, battery))
    return sim


def make_ring_world(ns: str, start: Pose2D, **overrides: Any) -> Simulator:
    """A simulator on :func:`ring` with one robot ``ns`` at ``start``."""
    sim = Simulator(ring(), replace(SimParams(), **overrides), SimClock())
    sim.add_robot(RobotSpec(ns.strip("/"), ns, start))
    return sim


class Loop:
    """Steps ``sim`` and ticks every tree (``root.tick_once()``) at ``tick_hz`` of simulated
    time, ticking first at the current time."""

    def __init__(self, sim: Simulator, *roots: py_trees.behaviour.Behaviour, tick_hz: float = 10.0) -> None:
        self.sim = sim
        self.roots = list(roots)
        self.period = 1.0 / tick_hz
        self.next_tick = sim.clock.now()
        self.ticks = 0
        self.on_tick: list[Callable[[], None]] = []

    def tick(self) -> None:
        for root in self.roots:
            root.tick_once()
        self.ticks += 1
        for hook in self.on_tick:
            hook()

    def run(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Run for ``seconds`` of simulated time or until ``until()`` is true after a tick;
        return whether ``until`` became true (``True`` if no predicate was given)."""
        end = self.sim.clock.now() + seconds - 1e-9
        while self.sim.clock.now() < end:
            if self.sim.clock.now() >= self.next_tick - 1e-9:
                self.tick()
                self.next_tick += self.period
                if until is not None and until():
                    return True
            self.sim.step()
        return until is None


def pose_of(sim: Simulator, ns: str) -> Pose2D:
    """The pose of robot ``ns`` (always known in the simulator)."""
    pose = sim.robot_state(ns).pose
    assert pose is not None
    return pose
