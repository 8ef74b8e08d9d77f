"""Localization in the simulator: odometry and the map -> odom estimate, initial poses, loss
by fault injection, and the safety watchdog that stops a robot within one step."""

from __future__ import annotations

import math

import pytest

from fleet.errors import BackendError
from fleet.types import ErrorCode, GoalStatus, NavigateToPose, Pose2D, Wait
from sim.localization import compose
from tests.sim.sim_testworld import advance, make_sim, run_goal

START = Pose2D(1.0, 6.0, 0.3)
FAR = Pose2D(10.0, 3.0, 0.0)


def test_odometry_and_estimate_compose_to_the_true_pose() -> None:
    sim = make_sim({"/r1": START})
    sim.send_goal("/r1", NavigateToPose(FAR))
    advance(sim, 6.0)
    loc = sim.localization_state("/r1")
    truth = sim._robot("/r1").pose
    assert loc.localized and loc.error_m < 1e-9
    o = loc.map_to_odom  # the odom frame starts where the robot was added
    assert (o.x, o.y, o.theta) == pytest.approx((START.x, START.y, START.theta), abs=1e-12)
    est = compose(loc.map_to_odom, loc.odom)
    assert math.hypot(est.x - truth.x, est.y - truth.y) < 1e-9
    assert loc.odom.distance_to(Pose2D(0.0, 0.0)) > 1.0  # it moved in its odom frame
    assert sim.robot_state("/r1").pose_age_s == 0.0


def test_lost_localization_stops_the_robot_within_one_step_and_aborts_its_goal() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateToPose(FAR))
    advance(sim, 3.0)
    assert sim.robot_state("/r1").linear_velocity > 0.3
    sim.set_fault("/r1", "localization_lost")
    state = sim.goal_state(gid)
    assert state.status is GoalStatus.ABORTED and state.error_code == ErrorCode.SAFETY_STOPPED
    assert "localization lost" in state.error_msg
    sim.step()  # one control period
    rs = sim.robot_state("/r1")
    assert rs.linear_velocity == 0.0 and rs.angular_velocity == 0.0
    assert not rs.localized and rs.safety_stop == "localization lost"
    here = rs.pose
    advance(sim, 2.0)
    later = sim.robot_state("/r1")
    assert later.pose == here  # not a millimetre more
    assert later.pose_age_s == pytest.approx(2.0 + sim.params.step_s, abs=1e-6)
    again = run_goal(sim, "/r1", NavigateToPose(FAR), timeout_s=5.0)
    assert again.status is GoalStatus.ABORTED and again.error_code == ErrorCode.SAFETY_STOPPED
    assert run_goal(sim, "/r1", Wait(0.5)).status is GoalStatus.SUCCEEDED  # waiting is harmless
    assert [e[1:] for e in sim.safety_events] == [("/r1", "localization lost")]
    sim.set_fault("/r1", None)  # localization regained
    rs = sim.robot_state("/r1")
    assert rs.localized and rs.safety_stop == "" and rs.pose_age_s == 0.0
    assert run_goal(sim, "/r1", NavigateToPose(FAR)).status is GoalStatus.SUCCEEDED


def test_navigation_server_down_stops_the_robot() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateToPose(FAR))
    advance(sim, 2.0)
    sim.set_fault("/r1", "navigation_down")
    assert sim.goal_state(gid).error_code == ErrorCode.SERVER_UNAVAILABLE
    sim.step()
    rs = sim.robot_state("/r1")
    assert rs.linear_velocity == 0.0 and not rs.navigation_ready
    assert rs.localized and rs.safety_stop == "navigation server down"
    sim.set_fault("/r1", None)
    assert sim.robot_state("/r1").navigation_ready


def test_initial_pose_near_the_truth_converges_and_far_from_it_mislocalizes() -> None:
    sim = make_sim({"/r1": START})
    assert sim.set_initial_pose("/r1", Pose2D(START.x + 0.4, START.y - 0.3, START.theta + 0.2))
    assert sim.robot_state("/r1").pose == sim._robot("/r1").pose  # converged on the truth
    assert not sim.set_initial_pose("/r1", Pose2D(8.0, 2.0, 0.0))
    rs = sim.robot_state("/r1")
    assert not rs.localized
    assert rs.pose is not None and rs.pose.distance_to(Pose2D(8.0, 2.0)) < 1e-9  # believes the hint
    assert "did not converge" in rs.safety_stop
    assert sim.localization_state("/r1").error_m > 5.0
    assert run_goal(sim, "/r1", NavigateToPose(FAR), timeout_s=5.0).error_code == ErrorCode.SAFETY_STOPPED
    assert sim.set_initial_pose("/r1", START)  # a good hint localizes it again
    assert run_goal(sim, "/r1", NavigateToPose(FAR)).status is GoalStatus.SUCCEEDED


def test_unknown_fault_is_an_error() -> None:
    sim = make_sim({"/r1": START})
    with pytest.raises(BackendError, match="known faults: stalled, localization_lost, navigation_down"):
        sim.set_fault("/r1", "gremlins")
