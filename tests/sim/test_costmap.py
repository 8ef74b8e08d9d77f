"""The simulator's live costmaps: robots learn obstacles they see, forget them (decay, seen
gone, cleared), and plan around what they learned."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fleet.clock import SimClock
from fleet.maps import load_map
from fleet.robots import RobotSpec, SimParams
from fleet.types import ErrorCode, GoalStatus, NavigateToPose, Pose2D
from sim.costmap import DECAY_S, INSCRIBED, LETHAL, LOCAL_SIZE_M, SENSE_PERIOD_S, STATIONARY_S
from sim.simulator import Simulator
from tests.sim.sim_testworld import advance, make_sim, run_goal

ROOT = Path(__file__).resolve().parents[2]
#: Aisle 3 of the warehouse map runs north-south at x = 12 between shelves (x 11..13 free).
AISLE_X = 12.0
SOUTH = Pose2D(AISLE_X, 4.0, math.pi / 2)
NORTH = Pose2D(AISLE_X, 17.5, math.pi / 2)
BLOCK = (AISLE_X, 11.5, 0.8)  # a pallet that closes the aisle (free width 0.2 m each side)


def warehouse(robots: dict[str, Pose2D], **params: float) -> Simulator:
    sim = Simulator(
        load_map(ROOT / "configs" / "maps" / "warehouse.yaml"),
        SimParams(**params),  # type: ignore[arg-type]
        SimClock(),
    )
    for ns, pose in robots.items():
        sim.add_robot(RobotSpec(ns.strip("/"), ns, pose))
    return sim


def in_aisle_3(x: float, y: float) -> bool:
    return 11.0 < x < 13.0 and 7.0 < y < 16.0


def test_a_blocked_aisle_is_routed_around_once_seen_and_used_again_once_cleared() -> None:
    sim = warehouse({"/r1": SOUTH}, stuck_time_s=3.0)
    assert len(sim.plan("/r1", (SOUTH.x, SOUTH.y), (NORTH.x, NORTH.y)).path) == 2  # straight up the aisle
    sim.add_obstacle(*BLOCK)
    first = run_goal(sim, "/r1", NavigateToPose(NORTH), timeout_s=60.0)
    # the pallet was not in the map: the robot drove into the aisle, stopped before it, gave up
    assert first.status is GoalStatus.ABORTED and first.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    marks = sim.costmap_marks("/r1")
    assert [m.source for m in marks] == ["obstacle 1"]
    assert math.hypot(marks[0].x - BLOCK[0], marks[0].y - BLOCK[1]) < 1e-9
    t_retry = sim.clock.now()
    second = run_goal(sim, "/r1", NavigateToPose(NORTH), timeout_s=120.0)
    assert second.status is GoalStatus.SUCCEEDED
    after = [(x, y) for t, x, y in sim.trajectory("/r1") if t > t_retry + 1.0]
    # it backed out and took another aisle: never past the pallet inside aisle 3 again
    assert not any(in_aisle_3(x, y) and y > BLOCK[1] - 1.0 for x, y in after)
    assert sim.costmap_marks("/r1")  # the mark is still known (not decayed yet)
    assert sim.clear_costmaps("/r1", "global") == 1
    assert sim.costmap_marks("/r1", "global") == []
    assert len(sim.costmap_marks("/r1", "local")) <= 1  # the local one is separate
    assert len(sim.plan("/r1", (SOUTH.x, SOUTH.y), (NORTH.x, NORTH.y)).path) == 2


def test_strict_planning_reports_no_valid_path_when_learned_obstacles_close_every_way() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 6.0, 0.0)})
    sim.add_obstacle(3.0, 6.0, 0.4)
    advance(sim, 1.0)
    assert sim.costmap_marks("/r1")
    around = sim.plan("/r1", (1.0, 6.0), (5.0, 6.0))
    assert around.ok and len(around.path) > 2  # detours around the learned obstacle
    assert all(math.hypot(x - 3.0, y - 6.0) > 0.4 for x, y in around.path)


def test_marks_are_cleared_when_seen_gone_and_decay_when_out_of_sight() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 6.0, 0.0)})
    oid = sim.add_obstacle(2.5, 6.0, 0.3)
    advance(sim, SENSE_PERIOD_S + 0.1)
    assert [m.source for m in sim.costmap_marks("/r1", "both")] == ["obstacle 1"]
    sim.remove_obstacle(oid)
    advance(sim, SENSE_PERIOD_S + 0.1)
    assert sim.costmap_marks("/r1", "both") == []  # raytraced free: cleared
    sim.add_obstacle(2.5, 6.0, 0.3)
    advance(sim, SENSE_PERIOD_S + 0.1)
    assert sim.costmap_marks("/r1", "global")
    run_goal(sim, "/r1", NavigateToPose(Pose2D(10.0, 3.0, 0.0)), timeout_s=60.0)  # out of range
    assert math.hypot(sim.robot_state("/r1").pose.x - 2.5, 0) > 2.5  # type: ignore[union-attr]
    assert sim.costmap_marks("/r1", "local") == []  # outside the local window
    assert sim.costmap_marks("/r1", "global")  # still remembered ...
    advance(sim, DECAY_S + 1.0)
    assert sim.costmap_marks("/r1", "global") == []  # ... until it decays


def test_a_robot_standing_still_becomes_an_obstacle_to_its_neighbours() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 6.0, 0.0), "/r2": Pose2D(3.0, 6.0, 0.0)})
    advance(sim, STATIONARY_S - 1.0)
    assert sim.costmap_marks("/r1") == []  # not yet: it may only be pausing
    advance(sim, 1.0 + SENSE_PERIOD_S)
    assert [m.source for m in sim.costmap_marks("/r1")] == ["robot /r2"]
    assert [m.source for m in sim.costmap_marks("/r2")] == ["robot /r1"]
    assert run_goal(sim, "/r2", NavigateToPose(Pose2D(3.0, 2.5, 0.0))).status is GoalStatus.SUCCEEDED
    advance(sim, SENSE_PERIOD_S)
    assert sim.costmap_marks("/r1") == []  # it left: seen gone


def test_clear_region_services_and_the_costmap_raster() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 6.0, 0.0)})
    sim.add_obstacle(2.0, 6.0, 0.2)
    sim.add_obstacle(1.0, 7.5, 0.2)
    advance(sim, SENSE_PERIOD_S + 0.1)
    assert len(sim.costmap_marks("/r1", "local")) == 2
    # clear_except: keep a 3.2 m square around the robot -> (2.0, 6.0) and (1.0, 7.5) stay;
    # with 2.4 m the one 1.5 m away goes
    assert sim.clear_costmap_region("/r1", "local", 3.2, keep_inside=True) == 0
    assert sim.clear_costmap_region("/r1", "global", 2.4, keep_inside=True) == 1
    assert [m.source for m in sim.costmap_marks("/r1", "global")] == ["obstacle 1"]
    # clear_around the pose (2, 6) with 1 m -> only that one goes
    assert sim.clear_costmap_region("/r1", "local", 1.0, center=Pose2D(2.0, 6.0)) == 1
    assert [m.source for m in sim.costmap_marks("/r1", "local")] == ["obstacle 2"]
    glob = sim.costmap("/r1", "global")
    assert glob.cost.shape == (80, 120)  # the whole 12 x 8 m room at 0.1 m
    row, col = int(6.0 / 0.1), int(2.0 / 0.1)
    assert glob.cost[row, col] == LETHAL  # the learned obstacle is in the global costmap
    assert glob.cost[row, col + 3] == INSCRIBED  # within a robot radius of it
    assert glob.cost[int(3.0 / 0.1), int(3.0 / 0.1)] == 0
    static = sim.costmap("/r1", "global", "static_layer")
    assert static.cost[row, col] == 0 and static.cost[0, 0] == LETHAL
    local = sim.costmap("/r1", "local")
    cells = int(round(LOCAL_SIZE_M / 0.1))
    assert local.cost.shape == (cells, cells)
    assert math.isclose(local.origin_x, 1.0 - LOCAL_SIZE_M / 2, abs_tol=0.1)
    assert int(np.count_nonzero(local.cost == LETHAL)) > 0
