"""Action leaves on the real simulator: success and failure of each, cancel on preemption,
no cancel of a finished leaf, the Charge leaf."""

from __future__ import annotations

import math

import py_trees
import pytest
from nodes_world import BOX, CHARGER, Loop, make_world, pose_of
from py_trees.common import Status

from fleet.types import ErrorCode, GoalStatus, Mode, Pose2D
from nodes.blackboard import key_path, robot_blackboard
from nodes.leaves import (
    BackUpAction,
    Charge,
    DriveOnHeadingAction,
    FollowWaypointsAction,
    GoalAction,
    NavigateThroughPosesAction,
    NavigateToPoseAction,
    SpinAction,
    WaitAction,
)

NS = "/robot1"


def finish(loop: Loop, leaf: py_trees.behaviour.Behaviour, seconds: float = 60.0) -> Status:
    """Tick ``leaf`` (the loop's root) until it is no longer RUNNING."""
    assert loop.run(seconds, until=lambda: leaf.status != Status.RUNNING), f"{leaf.name} still running"
    return leaf.status


def goal_status(leaf: GoalAction) -> GoalStatus:
    assert leaf.goal_id is not None
    return leaf.backend.goal_state(leaf.goal_id).status


@pytest.fixture
def sim():  # type: ignore[no-untyped-def]
    return make_world({NS: Pose2D(2.0, 3.0, 0.0)})


def test_navigate_to_pose_succeeds_and_records_its_goal(sim) -> None:  # type: ignore[no-untyped-def]
    leaf = NavigateToPoseAction(sim.backend(NS), Pose2D(5.0, 3.0, 0.0), mode=Mode.PATROL)
    loop = Loop(sim, leaf)
    loop.tick()
    assert leaf.status == Status.RUNNING
    assert leaf.goal_id is not None and leaf.goals_sent == 1
    bb = robot_blackboard(NS, keys=("active_leaf", "mode", "active_goal"))
    assert (bb.active_leaf, bb.mode, bb.active_goal) == ("NavigateToPose", "patrol", leaf.goal_id)
    assert finish(loop, leaf) == Status.SUCCESS
    assert goal_status(leaf) is GoalStatus.SUCCEEDED
    assert leaf.last_state is not None and leaf.last_state.status is GoalStatus.SUCCEEDED
    assert pose_of(sim, NS).distance_to(Pose2D(5.0, 3.0)) <= sim.params.goal_tolerance + 0.01
    assert bb.active_goal is None


def test_navigate_to_pose_fails_with_error_code(sim) -> None:  # type: ignore[no-untyped-def]
    leaf = NavigateToPoseAction(sim.backend(NS), Pose2D(0.0, 0.0))  # the wall corner
    assert finish(Loop(sim, leaf), leaf) == Status.FAILURE
    assert leaf.last_state is not None and leaf.last_state.status is GoalStatus.ABORTED
    assert f"code={int(ErrorCode.GOAL_OCCUPIED)}" in leaf.feedback_message
    assert "GOAL_OCCUPIED" in leaf.feedback_message
    assert py_trees.blackboard.Blackboard.get(key_path(NS, "last_error")).startswith(
        "NavigateToPose: ABORTED"
    )


def test_goal_from_a_callable_none_fails_without_sending(sim) -> None:  # type: ignore[no-untyped-def]
    leaf = NavigateToPoseAction(sim.backend(NS), lambda: None)
    leaf.tick_once()
    assert leaf.status == Status.FAILURE
    assert leaf.goal_id is None and leaf.goals_sent == 0
    assert "no goal" in leaf.feedback_message


def test_navigate_through_poses_success_and_failure(sim) -> None:  # type: ignore[no-untyped-def]
    poses = [Pose2D(4.0, 3.0), Pose2D(4.0, 4.0), Pose2D(2.0, 4.0)]
    ok = NavigateThroughPosesAction(sim.backend(NS), lambda: poses)
    assert finish(Loop(sim, ok), ok) == Status.SUCCESS
    assert ok.goal is not None and ok.goal.kind == "navigate_through_poses"
    unreachable = NavigateThroughPosesAction(sim.backend(NS), [Pose2D(3.0, 2.0), Pose2D(*BOX)])
    assert finish(Loop(sim, unreachable), unreachable) == Status.FAILURE
    assert "NO_VALID_PATH" in unreachable.feedback_message
    empty = NavigateThroughPosesAction(sim.backend(NS), ())
    empty.tick_once()
    assert empty.status == Status.FAILURE and empty.goal_id is None


def test_follow_waypoints_success_with_missed_waypoint_and_failure(sim) -> None:  # type: ignore[no-untyped-def]
    leaf = FollowWaypointsAction(sim.backend(NS), [Pose2D(3.0, 3.0), Pose2D(*BOX), Pose2D(3.0, 4.0)])
    assert finish(Loop(sim, leaf), leaf) == Status.SUCCESS
    assert leaf.last_state is not None and leaf.last_state.missed_waypoints == (1,)
    assert "missed waypoints [1]" in leaf.feedback_message
    empty = FollowWaypointsAction(sim.backend(NS), ())
    assert finish(Loop(sim, empty), empty) == Status.FAILURE
    assert "WAYPOINT_UNKNOWN" in empty.feedback_message


def test_spin_success_and_timeout(sim) -> None:  # type: ignore[no-untyped-def]
    start = pose_of(sim, NS).theta
    leaf = SpinAction(sim.backend(NS), math.pi / 2)
    assert finish(Loop(sim, leaf), leaf) == Status.SUCCESS
    turned = (pose_of(sim, NS).theta - start) % (2 * math.pi)
    assert abs(turned - math.pi / 2) < 0.1
    slow = SpinAction(sim.backend(NS), 6.0, time_allowance_s=0.5)
    assert finish(Loop(sim, slow), slow) == Status.FAILURE
    assert "SPIN_TIMEOUT" in slow.feedback_message


def test_backup_success_and_collision_behind() -> None:
    sim = make_world({NS: Pose2D(3.0, 3.0, 0.0), "/wall": Pose2D(1.0, 5.0, 0.0)})
    leaf = BackUpAction(sim.backend(NS), 0.3, 0.15)
    assert finish(Loop(sim, leaf), leaf) == Status.SUCCESS
    assert pose_of(sim, NS).x == pytest.approx(2.7, abs=0.02)
    # the other robot stands right behind /wall's back: facing +x at x = 1.0 with a wall at x = 0.1
    blocked = BackUpAction(sim.backend("/wall"), 1.0, 0.15)
    assert finish(Loop(sim, blocked), blocked) == Status.FAILURE
    assert "BACKUP_COLLISION_AHEAD" in blocked.feedback_message


def test_drive_on_heading_success_and_collision_ahead() -> None:
    sim = make_world({NS: Pose2D(3.0, 3.0, 0.0), "/front": Pose2D(9.0, 1.0, 0.0)})
    leaf = DriveOnHeadingAction(sim.backend(NS), 0.5, 0.2)
    assert finish(Loop(sim, leaf), leaf) == Status.SUCCESS
    assert pose_of(sim, NS).x == pytest.approx(3.5, abs=0.02)
    blocked = DriveOnHeadingAction(sim.backend("/front"), 1.0, 0.2)  # the wall is 0.6 m ahead
    assert finish(Loop(sim, blocked), blocked) == Status.FAILURE
    assert "DRIVE_COLLISION_AHEAD" in blocked.feedback_message


def test_wait_success_and_external_cancel_is_failure(sim) -> None:  # type: ignore[no-untyped-def]
    leaf = WaitAction(sim.backend(NS), lambda: 1.0)
    loop = Loop(sim, leaf)
    t0 = sim.clock.now()
    assert finish(loop, leaf) == Status.SUCCESS
    assert sim.clock.now() - t0 == pytest.approx(1.0, abs=0.15)
    canceled = WaitAction(sim.backend(NS), 10.0)
    loop = Loop(sim, canceled)
    loop.run(0.5)
    assert canceled.status == Status.RUNNING and canceled.goal_id is not None
    sim.backend(NS).cancel_goal(canceled.goal_id)
    assert finish(loop, canceled) == Status.FAILURE
    assert canceled.feedback_message.startswith("CANCELED")


def test_interrupted_leaf_cancels_its_goal(sim) -> None:  # type: ignore[no-untyped-def]
    leaf = NavigateToPoseAction(sim.backend(NS), Pose2D(6.0, 3.0))
    loop = Loop(sim, leaf)
    loop.run(1.0)
    assert leaf.status == Status.RUNNING
    leaf.stop(Status.INVALID)
    assert goal_status(leaf) is GoalStatus.CANCELED
    assert leaf.cancels == 1
    sim.run_until(lambda: False, 1.0)
    assert sim.robot_state(NS).linear_velocity == pytest.approx(0.0, abs=1e-6)


def test_finished_leaves_are_not_canceled_on_terminate_invalid(sim) -> None:  # type: ignore[no-untyped-def]
    done = WaitAction(sim.backend(NS), 0.3, name="Done")
    failed = NavigateToPoseAction(sim.backend(NS), Pose2D(0.0, 0.0), name="Failed")
    running = WaitAction(sim.backend(NS), 30.0, name="Running")
    seq = py_trees.composites.Sequence(
        "Seq", memory=True, children=[done, py_trees.decorators.FailureIsSuccess("Ok", failed), running]
    )
    loop = Loop(sim, seq)
    loop.run(2.0)
    assert (done.status, failed.status, running.status) == (Status.SUCCESS, Status.FAILURE, Status.RUNNING)
    seq.stop(Status.INVALID)  # reaches every child, finished or not
    assert (done.cancels, failed.cancels, running.cancels) == (0, 0, 1)
    assert goal_status(done) is GoalStatus.SUCCEEDED
    assert goal_status(failed) is GoalStatus.ABORTED
    assert goal_status(running) is GoalStatus.CANCELED


def test_a_new_leaf_cancels_the_goal_another_left_outstanding(sim) -> None:  # type: ignore[no-untyped-def]
    first = NavigateToPoseAction(sim.backend(NS), Pose2D(6.0, 3.0), name="First")
    second = WaitAction(sim.backend(NS), 1.0, name="Second")
    first.tick_once()
    sim.step()
    second.tick_once()  # starts before anyone stopped `first`
    assert goal_status(first) is GoalStatus.CANCELED
    first.stop(Status.INVALID)
    assert first.cancels == 1 and goal_status(second) is GoalStatus.EXECUTING


def test_charge_success_on_charger_and_failure_off_it(fast_battery) -> None:  # type: ignore[no-untyped-def]
    sim = make_world({NS: (CHARGER, 0.5), "/away": (Pose2D(4.0, 3.0), 0.5)}, battery=fast_battery)
    charge = Charge(sim.backend(NS), sim.clock, fast_battery.resume)
    loop = Loop(sim, charge)
    loop.run(0.5)
    assert charge.status == Status.RUNNING and sim.robot_state(NS).charging
    assert finish(loop, charge, 10.0) == Status.SUCCESS
    assert sim.robot_state(NS).battery >= fast_battery.resume
    assert py_trees.blackboard.Blackboard.get(key_path(NS, "mode")) == "charging"
    off = Charge(sim.backend("/away"), sim.clock, fast_battery.resume, grace_s=2.0)
    loop = Loop(sim, off)
    t0 = sim.clock.now()
    assert finish(loop, off, 10.0) == Status.FAILURE
    assert 2.0 < sim.clock.now() - t0 < 2.5
    assert "not charging" in off.feedback_message
