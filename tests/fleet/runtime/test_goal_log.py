"""Goal-level metrics (``fleet/runtime/goal_log.py``) on the real simulator: succeeded,
failed by code, canceled, retries with their recoveries counted on one goal, time against the
straight-line and roadmap optimum, and the summary line."""

from __future__ import annotations

from pathlib import Path

from fleet.clock import SimClock
from fleet.config.loader import load_config
from fleet.runtime.goal_log import GoalLog, GoalMetrics
from fleet.types import GoalStatus, NavigateToPose, Pose2D, Wait
from fleet.viz.summary import summary_text
from sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[3]


def _world() -> tuple[Simulator, GoalLog]:
    cfg = load_config(ROOT / "configs" / "warehouse_patrol.yaml", robots=1)
    sim = Simulator(cfg.grid, cfg.sim, SimClock())
    spec = cfg.robots[0]  # at (1, 3) facing +y
    sim.add_robot(spec)
    log = GoalLog(sim.backend(spec.namespace), sim.clock, cfg.sim.model.max_linear_speed, cfg.roadmap)
    return sim, log


def _until_done(sim: Simulator, log: GoalLog, gid: str, limit_s: float = 120.0) -> GoalStatus:
    start = sim.clock.now()
    while not log.goal_state(gid).status.terminal and sim.clock.now() - start < limit_s:
        sim.step()
    return log.goal_state(gid).status


def test_succeeded_goal_and_time_against_the_optimum() -> None:
    sim, log = _world()
    gid = log.send_goal(NavigateToPose(Pose2D(2.5, 14.0, 1.57)))
    assert _until_done(sim, log, gid) is GoalStatus.SUCCEEDED
    d = log.metrics.to_dict()
    assert (d["sent"], d["succeeded"], d["failed"], d["success_rate"]) == (1, 1, 0, 1.0)
    assert d["recoveries_per_goal"] == 0.0
    # 11.1 m straight at 1 m/s: the robot needs longer (turning, accelerating) but not 3x
    assert 1.0 <= d["time_over_straight"] < 3.0
    # the roadmap path is never shorter than the straight line; the simulator's planner drives
    # free space, so it may beat the roadmap's corners a little (0.97x on this warehouse)
    assert 0.8 <= d["time_over_roadmap"] <= d["time_over_straight"]


def test_retries_of_a_failed_goal_are_one_goal_with_its_recoveries() -> None:
    sim, log = _world()
    off_map = NavigateToPose(Pose2D(-20.0, -20.0))
    for _ in range(3):  # the tree's RecoveryNode: attempt, recovery, attempt ...
        gid = log.send_goal(off_map)
        assert _until_done(sim, log, gid) is GoalStatus.ABORTED
        w = log.send_goal(Wait(0.5))
        assert _until_done(sim, log, w) is GoalStatus.SUCCEEDED
    dwell = log.send_goal(Wait(0.5))  # the next goal to another place ends the failed one
    _until_done(sim, log, dwell)
    gid = log.send_goal(NavigateToPose(Pose2D(2.0, 5.0, 0.0)))
    assert _until_done(sim, log, gid) is GoalStatus.SUCCEEDED
    log.close()
    d = log.metrics.to_dict()
    assert (d["sent"], d["succeeded"], d["failed"]) == (2, 1, 1)
    assert d["failed_by_code"] == {"GOAL_OUTSIDE_MAP": 1}
    assert d["recoveries"] == 4 and d["max_recoveries"] == 4  # the dwell after giving up counts too
    assert d["success_rate"] == 0.5


def test_canceled_and_preempted_goals_are_neither_success_nor_failure() -> None:
    sim, log = _world()
    gid = log.send_goal(NavigateToPose(Pose2D(2.5, 14.0)))
    sim.run_until(lambda: False, 2.0)
    log.cancel_goal(gid)
    assert _until_done(sim, log, gid) is GoalStatus.CANCELED
    log.send_goal(NavigateToPose(Pose2D(2.5, 14.0)))
    sim.run_until(lambda: False, 2.0)
    log.send_goal(NavigateToPose(Pose2D(2.0, 5.0)))  # preempts the running one
    log.close()
    d = log.metrics.to_dict()
    assert (d["sent"], d["succeeded"], d["failed"], d["canceled"]) == (3, 0, 0, 2)
    assert d["success_rate"] is None


def test_summary_shows_the_goal_line() -> None:
    m = GoalMetrics(
        sent=10, succeeded=8, failed=2, recoveries=3, max_recoveries=2, time_s=80, straight_s=50, roadmap_s=64
    )
    m.failed_by_code["FAILED_TO_MAKE_PROGRESS"] = 2
    report = {
        "robots": 1, "sim_time_s": 100.0, "wall_time_s": 1.0, "patrols_assigned": 0, "patrols_completed": 0,
        "laps_completed": 0, "collisions": 0, "deadlocks": 0, "reassignments": 0, "per_robot": [],
        "goals": m.to_dict(),
    }  # fmt: skip
    text = summary_text(report)
    assert "goals: 10 sent, 8 succeeded (80.0%), failed: FAILED_TO_MAKE_PROGRESS 2" in text
    assert "recoveries/goal: 0.30 (max 2)" in text
    assert "time/optimum: 1.60x straight line, 1.25x roadmap" in text
