"""Small in-memory worlds and helpers shared by the simulator tests (no files, no configs/)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from fleet.clock import SimClock
from fleet.maps import OCCUPIED, OccupancyGrid
from fleet.robots import RobotSpec, SimParams
from fleet.types import Goal, GoalState, Pose2D
from sim.simulator import Simulator

#: The shelf block of :func:`room_grid` (x0, x1, y0, y1) in meters.
SHELF = (5.0, 6.0, 0.0, 5.0)
#: Center of the closed 2 x 2 m box of :func:`room_grid`.
BOX_CENTER = (10.0, 6.0)


def room_grid(
    width_m: float = 12.0, height_m: float = 8.0, res: float = 0.1, furnished: bool = True
) -> OccupancyGrid:
    """A walled room with origin (0, 0). ``furnished`` adds a shelf block (:data:`SHELF`,
    attached to the bottom wall, so robots go around it above y = 5) and a closed 2 x 2 m box
    around :data:`BOX_CENTER` (free inside, unreachable)."""
    w, h = int(round(width_m / res)), int(round(height_m / res))
    cells = np.zeros((h, w), dtype=np.int8)
    cells[0, :] = cells[-1, :] = OCCUPIED
    cells[:, 0] = cells[:, -1] = OCCUPIED
    if furnished:
        x0, x1, y0, y1 = (int(round(v / res)) for v in SHELF)
        cells[y0:y1, x0:x1] = OCCUPIED
        bx, by = (int(round(v / res)) for v in BOX_CENTER)
        k = int(round(1.0 / res))
        cells[by - k : by + k + 1, bx - k] = cells[by - k : by + k + 1, bx + k] = OCCUPIED
        cells[by - k, bx - k : bx + k + 1] = cells[by + k, bx - k : bx + k + 1] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=res, origin_x=0.0, origin_y=0.0, source="<test room>")


def corridor_grid(length_m: float = 10.0, width_m: float = 1.4, res: float = 0.1) -> OccupancyGrid:
    """A walled corridor along x with ``width_m`` outer width (1.2 m free inside by default:
    one robot fits, two cannot pass each other). Its center line is y = ``width_m / 2``."""
    return room_grid(length_m, width_m, res, furnished=False)


def make_sim(robots: dict[str, Pose2D], grid: OccupancyGrid | None = None, **overrides: Any) -> Simulator:
    """A simulator on ``grid`` (default :func:`room_grid`) with ``SimParams`` fields
    overridden by keyword, and one robot per namespace in ``robots``."""
    params = replace(SimParams(), **overrides)
    sim = Simulator(grid if grid is not None else room_grid(), params, SimClock())
    for ns, pose in robots.items():
        sim.add_robot(RobotSpec(ns.strip("/"), ns, pose))
    return sim


def run_goal(sim: Simulator, ns: str, goal: Goal, timeout_s: float = 60.0) -> GoalState:
    """Send ``goal`` to ``ns`` and step until it is terminal (or ``timeout_s``)."""
    gid = sim.send_goal(ns, goal)
    sim.run_until(lambda: sim.goal_state(gid).status.terminal, timeout_s)
    return sim.goal_state(gid)


def advance(sim: Simulator, seconds: float) -> None:
    """Step the simulator for ``seconds`` of simulated time."""
    for _ in range(int(round(seconds / sim.params.step_s))):
        sim.step()
