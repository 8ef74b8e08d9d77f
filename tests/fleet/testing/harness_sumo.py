"""Conformance harness of the SUMO backend (:mod:`sim.sumo.world`), registered as ``"sumo"``.

The world is a small SUMO network generated from a roadmap: a straight aisle
``w (0, 0) - m (10, 0) - e (20, 0)`` with a spur ``m - n (10, 6)``, plus an island aisle
``i1 (30, 0) - i2 (36, 0)`` that no route reaches. SUMO drives on the right, so the eastbound
lane of the aisle runs along ``y = -lane_width / 2`` (-0.45 m for the default robot model); the
start and the reachable pose lie on that lane, heading east. ``off_map`` is more than
``max_snap_m`` from every lane, ``unreachable`` is on the island.

Differences from the simulator, declared below as capabilities SUMO lacks (the shared suite
then does not generate those tests for SUMO): SUMO knows only lanes, so a pose inside an obstacle is
simply snapped onto the nearest lane (there is no GOAL_OCCUPIED), and SUMO vehicles can
neither turn on the spot nor reverse (Spin and BackUp succeed as timed no-ops; see
``docs/sumo.md``). The world uses the default network (no lanes inside junctions: a robot is
always on a lane it can stop on).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import networkx as nx
import pytest
from conformance_harness import register_backend

from fleet.clock import SimClock
from fleet.navigation import NavigationBackend
from fleet.robots import RobotSpec, SimParams
from fleet.testing.conformance import ConformanceHarness, ConformanceWorld
from fleet.types import Pose2D

if TYPE_CHECKING:
    from sim.sumo.world import SumoWorld

#: Capabilities of the shared suite that SUMO lacks, with the reason (see ``docs/sumo.md``);
#: the suite does not generate those tests for SUMO. What SUMO does instead (snap to a lane,
#: Spin/BackUp as timed no-ops) is tested in ``tests/sim/sumo/test_sumo_world.py``.
SUMO_LACKS: dict[str, str] = {
    "occupancy_map": "SUMO has no occupancy map: a pose inside an obstacle is snapped onto the nearest lane",
    "spin_in_place": "SUMO vehicles cannot turn on the spot: Spin is a timed no-op",
    "reverse": "SUMO vehicles cannot reverse: BackUp is a timed no-op",
    "path_following": "SUMO vehicles drive their lanes: FollowPath is rejected",
    "costmaps": "SUMO keeps no costmaps: ClearCostmaps is rejected",
}

SUMO_PARAMS = replace(SimParams(), step_s=0.1)
_HALF_LANE = (2.0 * SUMO_PARAMS.model.radius + 0.3) / 2.0  # see sim.sumo.net.settings_for_robot

SUMO_WORLD = ConformanceWorld(
    start=Pose2D(2.0, -_HALF_LANE, 0.0),
    reachable=Pose2D(15.0, -_HALF_LANE, 0.0),
    occupied=Pose2D(3.0, 3.0, 0.0),  # not used: SUMO lacks occupancy_map
    off_map=Pose2D(-30.0, 0.0, 0.0),
    unreachable=Pose2D(33.0, -_HALF_LANE, 0.0),
    free_behind_m=0.0,
    goal_tolerance=SUMO_PARAMS.goal_tolerance,
    yaw_tolerance=SUMO_PARAMS.yaw_tolerance,
)


def conformance_roadmap() -> nx.Graph:
    """The roadmap of the SUMO conformance world (see the module docstring)."""
    g = nx.Graph()
    for name, pos in {
        "w": (0.0, 0.0),
        "m": (10.0, 0.0),
        "e": (20.0, 0.0),
        "n": (10.0, 6.0),
        "i1": (30.0, 0.0),
        "i2": (36.0, 0.0),
    }.items():
        g.add_node(name, pos=pos)
    g.add_edges_from([("w", "m"), ("m", "e"), ("m", "n"), ("i1", "i2")])
    return g


@dataclass
class SumoHarness:
    """``advance`` steps the SUMO world."""

    world_obj: SumoWorld
    backend: NavigationBackend
    world: ConformanceWorld

    def advance(self, seconds: float) -> None:
        steps = max(1, int(round(seconds / SUMO_PARAMS.step_s)))
        for _ in range(steps):
            self.world_obj.step()


@register_backend("sumo", marks=(pytest.mark.sumo,), lacks=SUMO_LACKS)
@contextmanager
def sumo_harness() -> Iterator[ConformanceHarness]:
    pytest.importorskip("libsumo")
    from sim.sumo.world import SumoWorld

    world = SumoWorld(
        conformance_roadmap(),
        [RobotSpec("robot1", "/robot1", SUMO_WORLD.start)],
        SUMO_PARAMS,
        SimClock(),
    )
    try:
        world.step()  # insert the vehicle
        yield SumoHarness(world, world.backend("/robot1"), SUMO_WORLD)
    finally:
        world.close()
