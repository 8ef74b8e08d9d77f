"""Paths driven once (a pick, a go_to, an inspection) under traffic management keep every stop."""

from __future__ import annotations

import math
from pathlib import Path

from fleet.config.loader import load_config
from fleet.traffic.policy import traffic_from_config
from fleet.types import Pose2D

ROOT = Path(__file__).resolve().parents[3]


def test_a_task_whose_last_stop_is_where_the_robot_stands_still_visits_its_first_stop() -> None:
    # a robot that just dropped a pick at e_1 gets the next pick: shelf at a7_1, drop at e_1
    # again. It used to be given an empty path (the new path "passed" where it stood), so it
    # stood still until the coordinator called it stuck and gave it the same pick again.
    policy = traffic_from_config(load_config(ROOT / "configs" / "warehouse_picking.yaml"))
    m = policy.manager
    m.add_robot("r1", Pose2D(27.5, 9.0, -math.pi / 2), 0.0)
    assert m.path("r1") == ["e_1"]
    path = policy.roadmap.expand_route(["a7_1", "e_1"], closed=False)
    m.set_path("r1", path, 0.0, must_visit=[0, len(path) - 1])
    got = m.path("r1")
    assert got[0] == "e_1" and "a7_1" in got and got[-1] == "e_1"
    m.cycle(0.0)
    assert m.grant("r1").nodes  # it drives


def test_a_loop_joins_where_it_passes_the_robot() -> None:
    policy = traffic_from_config(load_config(ROOT / "configs" / "warehouse_picking.yaml"))
    m = policy.manager
    m.add_robot("r1", Pose2D(12.0, 9.0, math.pi / 2), 0.0)
    loop = policy.roadmap.expand_route(["a3_s", "a3_n", "a4_n", "a4_s"], closed=True)
    m.set_path("r1", loop, 0.0, loop=True)
    # on from a3_1, not back to a3_s first (the cells the aisle is cut into left out)
    assert _nodes(m.path("r1"))[:3] == ["a3_1", "a3_2", "a3_n"]


def test_a_pick_drives_its_legs_with_the_flow() -> None:
    # both drops stand on the east corridor, which the patrol loops drive southwards: a robot
    # taking a pick from aisle 7 to drop1 enters that corridor from the north and leaves it
    # south, so robots heading for the drops follow each other instead of meeting head-on
    policy = traffic_from_config(load_config(ROOT / "configs" / "warehouse_picking.yaml"))
    m = policy.manager
    m.add_robot("r1", Pose2D(24.0, 9.0, math.pi / 2), 0.0)
    assert m.path("r1") == ["a7_1"]
    policy.on_assign("r1", _Stops(("a7_1", "e_1", "e_s")), (), task_id="k-0001")
    got = m.path("r1")
    east = [n for n in got if n.startswith("e_")]
    assert east == ["e_n", "e_2", "e_1", "e_s"], got
    # the shortest way to drop1 is against it (south down aisle 7, then north into the corridor)
    assert _nodes(policy.roadmap.expand_route(["a7_1", "e_1"], closed=False))[-2] == "e_s"


def _nodes(path: list[str]) -> list[str]:
    """``path`` without the cells its edges were cut into (``traffic.cell_m``)."""
    return [n for n in path if not n.startswith("cell:")]


class _Stops:
    """A task's stops as the coordinator hands them over (driven once)."""

    def __init__(self, nodes: tuple[str, ...]) -> None:
        self.nodes, self.loop = nodes, False
