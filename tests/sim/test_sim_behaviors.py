"""Spin, BackUp, DriveOnHeading and Wait in the simulator."""

from __future__ import annotations

import math

import pytest
from sim_testworld import advance, make_sim, run_goal

from fleet.types import (
    BackUp,
    DriveOnHeading,
    ErrorCode,
    GoalStatus,
    NavigateToPose,
    Pose2D,
    Spin,
    Wait,
    normalize_angle,
)

START = Pose2D(2.0, 4.0, 0.0)


def _yaw(sim) -> float:
    pose = sim.robot_state("/r1").pose
    assert pose is not None
    return pose.theta


def _x(sim) -> float:
    pose = sim.robot_state("/r1").pose
    assert pose is not None
    return pose.x


# -- Spin ------------------------------------------------------------------------------


@pytest.mark.parametrize("target", [math.pi / 2, -2.0, 2 * math.pi])
def test_spin_turns_by_the_signed_target(target: float) -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", Spin(target))
    turned: list[float] = []
    while not sim.goal_state(gid).status.terminal:
        sim.step()
        fb = sim.goal_state(gid).feedback
        if fb.angular_distance_traveled is not None:
            turned.append(fb.angular_distance_traveled)
    state = sim.goal_state(gid)
    assert state.status is GoalStatus.SUCCEEDED
    assert turned == sorted(turned)
    assert state.feedback.angular_distance_traveled == pytest.approx(abs(target), abs=0.03)
    advance(sim, 1.0)
    assert normalize_angle(_yaw(sim) - START.theta - target) == pytest.approx(0.0, abs=0.15)
    assert sim.robot_state("/r1").distance_m == 0.0  # rotation in place


def test_spin_times_out_when_the_wheels_are_stalled() -> None:
    sim = make_sim({"/r1": START})
    sim.set_fault("/r1", "stalled")
    state = run_goal(sim, "/r1", Spin(1.0, time_allowance_s=2.0), timeout_s=5.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.SPIN_TIMEOUT
    assert sim.clock.now() == pytest.approx(2.05, abs=0.06)


def test_cancel_spin_stops_rotation() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", Spin(6.0))
    advance(sim, 1.0)
    sim.cancel_goal(gid)
    advance(sim, 1.0)
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
    assert sim.robot_state("/r1").angular_velocity == 0.0
    yaw = _yaw(sim)
    advance(sim, 1.0)
    assert _yaw(sim) == yaw


def test_new_goal_preempts_spin() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", Spin(6.0))
    advance(sim, 1.0)
    new = sim.send_goal("/r1", Wait(0.5))
    assert sim.goal_state(gid).status is GoalStatus.ABORTED
    assert sim.run_until(lambda: sim.goal_state(new).status.terminal, 5.0)
    assert sim.goal_state(new).status is GoalStatus.SUCCEEDED


# -- BackUp / DriveOnHeading -----------------------------------------------------------------


@pytest.mark.parametrize(("goal_type", "sign"), [(BackUp, -1.0), (DriveOnHeading, 1.0)])
def test_straight_drive_covers_the_distance(goal_type: type, sign: float) -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", goal_type(0.5, speed_mps=0.25, time_allowance_s=10.0))
    assert state.status is GoalStatus.SUCCEEDED
    assert state.feedback.distance_traveled == pytest.approx(0.5, abs=0.01)
    advance(sim, 1.0)
    assert _x(sim) - START.x == pytest.approx(sign * 0.5, abs=0.02)
    assert abs(normalize_angle(_yaw(sim) - START.theta)) < 1e-9


@pytest.mark.parametrize(
    ("goal", "code"),
    [
        (BackUp(0.0), ErrorCode.BACKUP_INVALID_INPUT),
        (BackUp(0.5, speed_mps=-0.1), ErrorCode.BACKUP_INVALID_INPUT),
        (DriveOnHeading(-1.0), ErrorCode.DRIVE_INVALID_INPUT),
        (DriveOnHeading(0.5, speed_mps=0.0), ErrorCode.DRIVE_INVALID_INPUT),
    ],
)
def test_straight_drive_rejects_non_positive_input(goal: BackUp | DriveOnHeading, code: ErrorCode) -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", goal, timeout_s=1.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == code
    assert _x(sim) == START.x


def test_backup_aborts_when_a_robot_is_behind() -> None:
    sim = make_sim({"/r1": START, "/r2": Pose2D(START.x - 0.8, START.y, 0.0)})
    state = run_goal(sim, "/r1", BackUp(1.0, speed_mps=0.2), timeout_s=10.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.BACKUP_COLLISION_AHEAD
    assert sim.collisions == 0


def test_drive_on_heading_aborts_before_a_wall() -> None:
    sim = make_sim({"/r1": Pose2D(4.0, 2.0, 0.0)})  # the shelf starts at x = 5
    state = run_goal(sim, "/r1", DriveOnHeading(2.0, speed_mps=0.3), timeout_s=20.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.DRIVE_COLLISION_AHEAD
    assert _x(sim) < 5.0 - sim.params.model.radius


def test_drive_on_heading_aborts_before_a_dynamic_obstacle() -> None:
    sim = make_sim({"/r1": START})
    sim.add_obstacle(START.x + 1.0, START.y, 0.2)
    state = run_goal(sim, "/r1", DriveOnHeading(2.0, speed_mps=0.3), timeout_s=20.0)
    assert state.error_code == ErrorCode.DRIVE_COLLISION_AHEAD
    assert _x(sim) < START.x + 1.0 - 0.5


@pytest.mark.parametrize(
    ("goal_type", "code"), [(BackUp, ErrorCode.BACKUP_TIMEOUT), (DriveOnHeading, ErrorCode.DRIVE_TIMEOUT)]
)
def test_straight_drive_times_out_when_stalled(goal_type: type, code: ErrorCode) -> None:
    sim = make_sim({"/r1": START})
    sim.set_fault("/r1", "stalled")
    state = run_goal(sim, "/r1", goal_type(0.5, speed_mps=0.2, time_allowance_s=3.0), timeout_s=10.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == code


@pytest.mark.parametrize("goal_type", [BackUp, DriveOnHeading])
def test_cancel_straight_drive_stops_the_robot(goal_type: type) -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", goal_type(1.0, speed_mps=0.3, time_allowance_s=20.0))
    advance(sim, 1.0)
    sim.cancel_goal(gid)
    advance(sim, 1.0)
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
    assert sim.robot_state("/r1").linear_velocity == 0.0
    assert 0.1 < sim.goal_state(gid).feedback.distance_traveled < 0.5  # type: ignore[operator]


@pytest.mark.parametrize("goal_type", [BackUp, DriveOnHeading])
def test_new_goal_preempts_straight_drive(goal_type: type) -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", goal_type(1.0, speed_mps=0.3, time_allowance_s=20.0))
    advance(sim, 1.0)
    new = sim.send_goal("/r1", NavigateToPose(START))
    assert sim.goal_state(gid).status is GoalStatus.ABORTED
    assert sim.run_until(lambda: sim.goal_state(new).status.terminal, 20.0)
    assert sim.goal_state(new).status is GoalStatus.SUCCEEDED


# -- Wait ------------------------------------------------------------------------------


def test_wait_succeeds_after_duration_and_counts_down() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", Wait(2.0))
    advance(sim, 0.5)
    assert sim.goal_state(gid).feedback.time_left_s == pytest.approx(1.5)
    assert sim.run_until(lambda: sim.goal_state(gid).status.terminal, 5.0)
    assert sim.goal_state(gid).status is GoalStatus.SUCCEEDED
    assert sim.clock.now() == pytest.approx(2.0, abs=0.06)
    assert sim.robot_state("/r1").distance_m == 0.0


def test_cancel_wait() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", Wait(5.0))
    advance(sim, 1.0)
    sim.cancel_goal(gid)
    advance(sim, 5.0)
    assert sim.goal_state(gid).status is GoalStatus.CANCELED


def test_new_goal_preempts_wait_which_is_its_only_way_to_abort() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", Wait(5.0))
    advance(sim, 1.0)
    new = sim.send_goal("/r1", Spin(1.0))
    state = sim.goal_state(gid)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == 0 and "preempted" in state.error_msg
    assert state.feedback.time_left_s == pytest.approx(4.0)
    assert sim.run_until(lambda: sim.goal_state(new).status.terminal, 5.0)
    assert sim.goal_state(new).status is GoalStatus.SUCCEEDED
