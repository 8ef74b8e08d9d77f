"""The navigation backend conformance suite: every registered backend must pass all of it.

Each test receives a fresh ``harness`` (see ``conformance_harness.py``) for every entry of
``BACKEND_FACTORIES``; the tests only use the :class:`fleet.navigation.NavigationBackend`
protocol, ``harness.advance`` and the facts in ``harness.world``.
"""

from __future__ import annotations

import math

import pytest
from conformance_harness import ConformanceHarness, wait_for

from fleet.navigation import NavigationBackend
from fleet.types import (
    BackUp,
    ErrorCode,
    GoalState,
    GoalStatus,
    NavigateToPose,
    Pose2D,
    Spin,
    TaskResult,
    Wait,
    normalize_angle,
)


def _finish(h: ConformanceHarness, goal_id: str, timeout_s: float) -> GoalState:
    ok = wait_for(h, lambda: h.backend.goal_state(goal_id).status.terminal, timeout_s)
    state = h.backend.goal_state(goal_id)
    assert ok, f"goal {goal_id} still {state.status} after {timeout_s} s"
    return state


def _pose(h: ConformanceHarness) -> Pose2D:
    pose = h.backend.robot_state().pose
    assert pose is not None, "the harness robot must be localized"
    return pose


def test_backend_satisfies_protocol(harness: ConformanceHarness) -> None:
    assert isinstance(harness.backend, NavigationBackend)
    assert harness.backend.namespace.startswith("/")


def test_send_goal_returns_at_once_with_unique_ids(harness: ConformanceHarness) -> None:
    b = harness.backend
    ids = [b.send_goal(NavigateToPose(harness.world.reachable)) for _ in range(4)]
    assert len(set(ids)) == 4
    # no time has passed: the goals were only sent; the last one is waiting or running
    assert b.goal_state(ids[-1]).status in (GoalStatus.PENDING, GoalStatus.EXECUTING)


def test_navigate_to_reachable_pose_succeeds_within_tolerance(harness: ConformanceHarness) -> None:
    w = harness.world
    gid = harness.backend.send_goal(NavigateToPose(w.reachable))
    state = _finish(harness, gid, w.nav_time_s)
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    assert state.result is TaskResult.SUCCEEDED
    harness.advance(1.0)  # let the robot come to rest
    pose = _pose(harness)
    assert pose.distance_to(w.reachable) <= w.goal_tolerance + 0.05
    assert abs(normalize_angle(pose.theta - w.reachable.theta)) <= w.yaw_tolerance + 0.05


def _assert_bad_goal_aborts(harness: ConformanceHarness, where: str, code: ErrorCode) -> None:
    target: Pose2D = getattr(harness.world, where)
    gid = harness.backend.send_goal(NavigateToPose(target))
    state = _finish(harness, gid, 10.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == code
    assert state.error_msg, "an aborted goal must explain itself"


@pytest.mark.parametrize(
    ("where", "code"),
    [("off_map", ErrorCode.GOAL_OUTSIDE_MAP), ("unreachable", ErrorCode.NO_VALID_PATH)],
)
def test_bad_goal_aborts_with_planner_code(harness: ConformanceHarness, where: str, code: ErrorCode) -> None:
    _assert_bad_goal_aborts(harness, where, code)


@pytest.mark.requires("occupancy_map")
def test_goal_inside_obstacle_aborts_goal_occupied(harness: ConformanceHarness) -> None:
    _assert_bad_goal_aborts(harness, "occupied", ErrorCode.GOAL_OCCUPIED)


def test_cancel_ends_canceled_and_robot_stops(harness: ConformanceHarness) -> None:
    b = harness.backend
    gid = b.send_goal(NavigateToPose(harness.world.reachable))
    harness.advance(3.0)
    assert b.goal_state(gid).status is GoalStatus.EXECUTING
    b.cancel_goal(gid)
    state = _finish(harness, gid, 5.0)
    assert state.status is GoalStatus.CANCELED
    harness.advance(2.0)
    before = _pose(harness)
    harness.advance(2.0)
    after = _pose(harness)
    assert before.distance_to(after) < 0.01
    assert abs(b.robot_state().linear_velocity) < 0.01


def test_new_goal_preempts_running_goal(harness: ConformanceHarness) -> None:
    b = harness.backend
    w = harness.world
    first = b.send_goal(NavigateToPose(w.reachable))
    harness.advance(2.0)
    back_home = b.send_goal(NavigateToPose(w.start))
    old = _finish(harness, first, 5.0)
    assert old.status is GoalStatus.ABORTED
    new = _finish(harness, back_home, w.nav_time_s)
    assert new.status is GoalStatus.SUCCEEDED, new.error_msg
    assert _pose(harness).distance_to(w.start) <= w.goal_tolerance + 0.05


def test_cancel_of_finished_goal_is_a_noop(harness: ConformanceHarness) -> None:
    b = harness.backend
    gid = b.send_goal(Wait(0.5))
    assert _finish(harness, gid, 5.0).status is GoalStatus.SUCCEEDED
    b.cancel_goal(gid)
    b.cancel_goal(gid)
    harness.advance(0.5)
    assert b.goal_state(gid).status is GoalStatus.SUCCEEDED


def test_goal_state_of_unknown_id_raises_key_error(harness: ConformanceHarness) -> None:
    with pytest.raises(KeyError):
        harness.backend.goal_state("/nobody#424242")


def test_goal_state_is_a_pure_read(harness: ConformanceHarness) -> None:
    b = harness.backend
    gid = b.send_goal(Wait(5.0))
    harness.advance(0.5)
    states = {b.goal_state(gid).status for _ in range(20)}
    assert states == {GoalStatus.EXECUTING}


def test_feedback_present_during_navigation(harness: ConformanceHarness) -> None:
    b = harness.backend
    gid = b.send_goal(NavigateToPose(harness.world.reachable))
    harness.advance(2.0)
    state = b.goal_state(gid)
    assert state.status is GoalStatus.EXECUTING
    fb = state.feedback
    assert fb.current_pose is not None
    assert fb.distance_remaining_m is not None and fb.distance_remaining_m > 0.5
    assert fb.estimated_time_remaining_s is not None and fb.estimated_time_remaining_s > 0.0
    assert fb.navigation_time_s is not None and fb.navigation_time_s > 0.0
    assert fb.number_of_recoveries is not None


@pytest.mark.requires("spin_in_place")
def test_spin_succeeds_and_turns_the_robot(harness: ConformanceHarness) -> None:
    yaw0 = _pose(harness).theta
    gid = harness.backend.send_goal(Spin(math.pi / 2, time_allowance_s=10.0))
    state = _finish(harness, gid, 12.0)
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    harness.advance(1.0)
    assert abs(normalize_angle(_pose(harness).theta - yaw0 - math.pi / 2)) < 0.2


@pytest.mark.requires("reverse")
def test_backup_succeeds_and_moves_backwards(harness: ConformanceHarness) -> None:
    start = _pose(harness)
    dist = min(0.3, harness.world.free_behind_m / 2)
    gid = harness.backend.send_goal(BackUp(dist, speed_mps=0.15, time_allowance_s=10.0))
    state = _finish(harness, gid, 12.0)
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    harness.advance(1.0)
    end = _pose(harness)
    along = (end.x - start.x) * math.cos(start.theta) + (end.y - start.y) * math.sin(start.theta)
    assert along == pytest.approx(-dist, abs=0.05)


def test_wait_succeeds_after_its_duration(harness: ConformanceHarness) -> None:
    b = harness.backend
    gid = b.send_goal(Wait(1.0))
    harness.advance(0.5)
    assert b.goal_state(gid).status is GoalStatus.EXECUTING
    assert _finish(harness, gid, 3.0).status is GoalStatus.SUCCEEDED
