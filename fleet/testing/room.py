"""The conformance room: a small known occupancy-grid world for backends that plan on a map.

:func:`conformance_grid` is a 12 x 8 m walled room (0.1 m cells, origin (0, 0)) with a 1 x 4 m
shelf block and a closed 2 x 2 m box; :data:`SIM_WORLD` describes it to the conformance cases
(:class:`fleet.testing.conformance.ConformanceWorld`) for one robot starting at (2, 4) facing
+x, and :data:`SIM_PARAMS` are the simulator parameters it was measured with. A harness of the
simulator, or of anything that serves the simulator (the Zenoh bridge, the ROS 2 facade), builds
its robot in this room so the expectations match.
"""

from __future__ import annotations

import math

import numpy as np

from fleet.maps import OCCUPIED, OccupancyGrid
from fleet.robots import SimParams
from fleet.testing.conformance import ConformanceWorld
from fleet.types import Pose2D


def conformance_grid() -> OccupancyGrid:
    """A 12 x 8 m room (0.1 m cells, origin (0, 0)) with outer walls, a 1 x 4 m shelf
    block at x in [5, 6], y in [2, 6], and a closed 2 x 2 m box around (10, 6)."""
    res = 0.1
    cells = np.zeros((80, 120), dtype=np.int8)
    cells[0, :] = cells[-1, :] = OCCUPIED
    cells[:, 0] = cells[:, -1] = OCCUPIED
    cells[20:60, 50:60] = OCCUPIED
    # enclosed box: walls of a 2 x 2 m square centered at (10, 6)
    cells[50:71, 90] = cells[50:71, 110] = OCCUPIED
    cells[50, 90:111] = cells[70, 90:111] = OCCUPIED
    return OccupancyGrid(cells=cells, resolution=res, origin_x=0.0, origin_y=0.0, source="<conformance>")


#: The simulator parameters of the room (the defaults).
SIM_PARAMS = SimParams()
#: The room as the conformance cases see it, for a robot starting at (2, 4) facing +x.
SIM_WORLD = ConformanceWorld(
    start=Pose2D(2.0, 4.0, 0.0),
    reachable=Pose2D(8.5, 4.0, math.pi / 2),
    occupied=Pose2D(5.5, 4.0, 0.0),
    off_map=Pose2D(-3.0, 4.0, 0.0),
    unreachable=Pose2D(10.0, 6.0, 0.0),
    free_behind_m=1.5,
    goal_tolerance=SIM_PARAMS.goal_tolerance,
    yaw_tolerance=SIM_PARAMS.yaw_tolerance,
)
