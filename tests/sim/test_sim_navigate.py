"""NavigateToPose, NavigateThroughPoses and FollowWaypoints in the simulator."""

from __future__ import annotations

import math

from sim_testworld import BOX_CENTER, advance, corridor_grid, make_sim, room_grid, run_goal

from fleet.types import (
    ErrorCode,
    FollowWaypoints,
    GoalStatus,
    NavigateThroughPoses,
    NavigateToPose,
    Pose2D,
    normalize_angle,
)

START = Pose2D(2.0, 2.0, 0.0)
BEHIND_SHELF = Pose2D(9.0, 2.0, -math.pi / 2)  # the shelf (x 5..6, y 0..5) is in between


def _never_overlaps_static(sim, ns: str) -> bool:
    r = sim.params.model.radius
    return all(sim.grid.is_free(x, y, r - 0.06) for _, x, y in sim.trajectory(ns))


# -- NavigateToPose -----------------------------------------------------------------------


def test_navigate_to_pose_goes_around_the_shelf_and_ends_within_tolerance() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", NavigateToPose(BEHIND_SHELF))
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    advance(sim, 1.0)
    pose = sim.robot_state("/r1").pose
    assert pose is not None
    assert pose.distance_to(BEHIND_SHELF) <= sim.params.goal_tolerance
    assert abs(normalize_angle(pose.theta - BEHIND_SHELF.theta)) <= sim.params.yaw_tolerance
    ys = [y for _, _, y in sim.trajectory("/r1")]
    assert max(ys) > 5.0, "the robot must drive around the shelf, not through it"
    assert _never_overlaps_static(sim, "/r1")
    assert sim.robot_state("/r1").distance_m > START.distance_to(BEHIND_SHELF)


def test_navigate_to_pose_feedback_counts_down() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateToPose(Pose2D(4.0, 6.5, 0.0)))
    advance(sim, 1.0)
    a = sim.goal_state(gid).feedback
    advance(sim, 1.0)
    b = sim.goal_state(gid).feedback
    assert a.distance_remaining_m is not None and b.distance_remaining_m is not None
    assert b.distance_remaining_m < a.distance_remaining_m
    assert b.estimated_time_remaining_s == b.distance_remaining_m / sim.params.model.max_linear_speed
    assert b.navigation_time_s is not None and abs(b.navigation_time_s - 2.0) < 1e-6
    assert b.number_of_recoveries == 0
    assert b.number_of_poses_remaining is None
    assert b.current_pose == sim.robot_state("/r1").pose


def test_goal_inside_shelf_aborts_goal_occupied() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(5.5, 2.0, 0.0)), timeout_s=1.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.GOAL_OCCUPIED
    assert "(5.50, 2.00" in state.error_msg


def test_goal_next_to_wall_within_robot_radius_is_occupied() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(4.85, 2.0, 0.0)), timeout_s=1.0)
    assert state.error_code == ErrorCode.GOAL_OCCUPIED


def test_goal_off_the_map_aborts_goal_outside_map() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(30.0, -4.0, 0.0)), timeout_s=1.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.GOAL_OUTSIDE_MAP
    assert "(30.00, -4.00" in state.error_msg


def test_goal_in_closed_box_aborts_no_valid_path() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(*BOX_CENTER, 0.0)), timeout_s=1.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.NO_VALID_PATH
    assert "(10.00, 6.00" in state.error_msg


def test_robot_blocked_by_obstacle_aborts_and_reports_stuck_until_it_moves() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 0.7, 0.0)}, grid=corridor_grid(), stuck_time_s=3.0)
    oid = sim.add_obstacle(3.5, 0.7, 0.3)
    gid = sim.send_goal("/r1", NavigateToPose(Pose2D(6.0, 0.7, 0.0)))
    advance(sim, 2.0)
    assert sim.goal_state(gid).status is GoalStatus.EXECUTING
    assert not sim.robot_state("/r1").stuck
    assert sim.run_until(lambda: sim.goal_state(gid).status.terminal, 10.0)
    state = sim.goal_state(gid)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.FAILED_TO_MAKE_PROGRESS
    assert "(6.00, 0.70" in state.error_msg
    rs = sim.robot_state("/r1")
    assert rs.stuck
    assert rs.pose is not None and math.hypot(rs.pose.x - 3.5, rs.pose.y - 0.7) >= 0.6  # stopped, no contact
    sim.remove_obstacle(oid)
    again = run_goal(sim, "/r1", NavigateToPose(Pose2D(6.0, 0.7, 0.0)), timeout_s=20.0)
    assert again.status is GoalStatus.SUCCEEDED
    assert not sim.robot_state("/r1").stuck


def test_robot_steers_around_an_obstacle_in_the_open() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 6.0, 0.0)})
    sim.add_obstacle(3.5, 6.0, 0.4)
    state = run_goal(sim, "/r1", NavigateToPose(Pose2D(4.5, 6.0, 0.0)), timeout_s=30.0)
    assert state.status is GoalStatus.SUCCEEDED
    closest = min(math.hypot(x - 3.5, y - 6.0) for _, x, y in sim.trajectory("/r1"))
    assert closest >= 0.7 - 0.01


def test_cancel_navigate_to_pose_stops_the_robot() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateToPose(BEHIND_SHELF))
    advance(sim, 3.0)
    assert abs(sim.robot_state("/r1").linear_velocity) > 0.5
    sim.cancel_goal(gid)
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
    advance(sim, 1.5)
    assert sim.robot_state("/r1").linear_velocity == 0.0
    p1 = sim.robot_state("/r1").pose
    advance(sim, 2.0)
    assert sim.robot_state("/r1").pose == p1
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
    assert sim.goal_state(gid).feedback.current_pose is not None  # last feedback is kept


def test_new_goal_preempts_navigate_to_pose() -> None:
    sim = make_sim({"/r1": START})
    first = sim.send_goal("/r1", NavigateToPose(BEHIND_SHELF))
    advance(sim, 2.0)
    second = sim.send_goal("/r1", NavigateToPose(Pose2D(2.0, 6.0, 0.0)))
    old = sim.goal_state(first)
    assert old.status is GoalStatus.ABORTED
    assert "preempted" in old.error_msg and second in old.error_msg
    assert first != second
    assert run_goal(sim, "/r1", NavigateToPose(Pose2D(2.0, 6.0, 0.0))).status is GoalStatus.SUCCEEDED


# -- NavigateThroughPoses ------------------------------------------------------------------


def test_navigate_through_poses_passes_intermediate_pose_without_stopping() -> None:
    sim = make_sim({"/r1": START})
    via = Pose2D(4.0, 4.0, 0.0)
    end = Pose2D(2.0, 6.5, math.pi)
    gid = sim.send_goal("/r1", NavigateThroughPoses((via, end)))
    remaining: list[int] = []
    speed_near_via: list[float] = []
    while not sim.goal_state(gid).status.terminal and sim.clock.now() < 60.0:
        sim.step()
        st = sim.goal_state(gid)
        if st.feedback.number_of_poses_remaining is not None:
            remaining.append(st.feedback.number_of_poses_remaining)
        rs = sim.robot_state("/r1")
        assert rs.pose is not None
        if rs.pose.distance_to(via) <= sim.params.goal_tolerance:
            speed_near_via.append(abs(rs.linear_velocity))
    state = sim.goal_state(gid)
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    assert speed_near_via and min(speed_near_via) > 0.2, "intermediate poses are passed, not stopped at"
    assert remaining[0] == 2 and 1 in remaining
    assert remaining == sorted(remaining, reverse=True)
    pose = sim.robot_state("/r1").pose
    assert pose is not None and pose.distance_to(end) <= sim.params.goal_tolerance + 0.05


def test_navigate_through_poses_with_occupied_pose_aborts_naming_it() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", NavigateThroughPoses((Pose2D(3.0, 3.0), Pose2D(5.5, 1.0))), timeout_s=1.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.GOAL_OCCUPIED
    assert "pose 1 (5.50, 1.00" in state.error_msg


def test_navigate_through_no_poses_is_rejected() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateThroughPoses(()))
    assert sim.goal_state(gid).status is GoalStatus.REJECTED


def test_cancel_navigate_through_poses() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateThroughPoses((Pose2D(4.0, 6.0), BEHIND_SHELF)))
    advance(sim, 2.0)
    sim.cancel_goal(gid)
    advance(sim, 2.0)
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
    assert sim.robot_state("/r1").linear_velocity == 0.0


def test_new_goal_preempts_navigate_through_poses() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", NavigateThroughPoses((Pose2D(4.0, 6.0), BEHIND_SHELF)))
    advance(sim, 2.0)
    new = sim.send_goal("/r1", NavigateToPose(START))
    assert sim.goal_state(gid).status is GoalStatus.ABORTED
    assert sim.run_until(lambda: sim.goal_state(new).status.terminal, 30.0)
    assert sim.goal_state(new).status is GoalStatus.SUCCEEDED


# -- FollowWaypoints -----------------------------------------------------------------------


def test_follow_waypoints_visits_each_waypoint_in_order() -> None:
    sim = make_sim({"/r1": START})
    wps = (Pose2D(3.5, 2.0, 0.0), Pose2D(3.5, 5.5, math.pi / 2), Pose2D(2.0, 6.5, math.pi))
    gid = sim.send_goal("/r1", FollowWaypoints(wps))
    seen: list[int] = []
    closest = [math.inf] * len(wps)
    while not sim.goal_state(gid).status.terminal and sim.clock.now() < 60.0:
        sim.step()
        fb = sim.goal_state(gid).feedback
        if fb.current_waypoint is not None and (not seen or seen[-1] != fb.current_waypoint):
            seen.append(fb.current_waypoint)
        pose = sim.robot_state("/r1").pose
        assert pose is not None
        closest = [min(c, pose.distance_to(w)) for c, w in zip(closest, wps, strict=True)]
    state = sim.goal_state(gid)
    assert state.status is GoalStatus.SUCCEEDED
    assert state.missed_waypoints == ()
    assert seen == [0, 1, 2]
    assert max(closest) <= sim.params.goal_tolerance


def test_follow_waypoints_skips_unreachable_waypoint_and_lists_it_as_missed() -> None:
    sim = make_sim({"/r1": START})
    wps = (Pose2D(3.0, 3.0), Pose2D(5.5, 2.0), Pose2D(*BOX_CENTER), Pose2D(3.0, 6.0))
    state = run_goal(sim, "/r1", FollowWaypoints(wps))
    assert state.status is GoalStatus.SUCCEEDED
    assert state.missed_waypoints == (1, 2)
    pose = sim.robot_state("/r1").pose
    assert pose is not None and pose.distance_to(wps[3]) <= sim.params.goal_tolerance + 0.05


def test_follow_waypoints_marks_blocked_waypoint_missed_and_continues() -> None:
    sim = make_sim({"/r1": Pose2D(1.0, 0.7, 0.0)}, grid=corridor_grid(), stuck_time_s=2.0)
    sim.add_obstacle(3.5, 0.7, 0.3)
    wps = (Pose2D(6.0, 0.7), Pose2D(2.0, 0.7, math.pi))
    state = run_goal(sim, "/r1", FollowWaypoints(wps))
    assert state.status is GoalStatus.SUCCEEDED
    assert state.missed_waypoints == (0,)


def test_follow_waypoints_without_poses_aborts() -> None:
    sim = make_sim({"/r1": START})
    state = run_goal(sim, "/r1", FollowWaypoints(()), timeout_s=1.0)
    assert state.status is GoalStatus.ABORTED
    assert state.error_code == ErrorCode.WAYPOINT_UNKNOWN


def test_cancel_follow_waypoints() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", FollowWaypoints((Pose2D(4.0, 6.0), BEHIND_SHELF)))
    advance(sim, 2.0)
    sim.cancel_goal(gid)
    advance(sim, 2.0)
    assert sim.goal_state(gid).status is GoalStatus.CANCELED
    assert sim.robot_state("/r1").linear_velocity == 0.0


def test_new_goal_preempts_follow_waypoints() -> None:
    sim = make_sim({"/r1": START})
    gid = sim.send_goal("/r1", FollowWaypoints((Pose2D(4.0, 6.0), BEHIND_SHELF)))
    advance(sim, 2.0)
    new = sim.send_goal("/r1", NavigateToPose(START))
    assert sim.goal_state(gid).status is GoalStatus.ABORTED
    assert "preempted" in sim.goal_state(gid).error_msg
    assert sim.run_until(lambda: sim.goal_state(new).status.terminal, 30.0)
    assert sim.goal_state(new).status is GoalStatus.SUCCEEDED


def test_path_with_turns_sharper_than_90_degrees_is_followed_to_the_end() -> None:
    """Regression: the follower only advanced when its projection reached a segment's end, so
    at a turn sharper than 90 degrees it orbited the corner near (3.1, 2.3) forever."""
    sim = make_sim({"/r1": Pose2D(2.0, 3.0, 0.0)}, grid=room_grid(12.0, 8.0, furnished=False))
    poses = (Pose2D(3.0, 2.0, 0.0), Pose2D(4.0, 4.0, 0.0), Pose2D(2.0, 4.0, 0.0))
    state = run_goal(sim, "/r1", NavigateThroughPoses(poses), timeout_s=40.0)
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    pose = sim.robot_state("/r1").pose
    assert pose is not None and pose.distance_to(poses[-1]) <= sim.params.goal_tolerance


def test_closed_loop_route_is_driven_all_the_way_round() -> None:
    """A NavigateThroughPoses that ends where the robot starts (a patrol lap) passes every pose
    before it can succeed: being at the final position does not count until the vias are passed."""
    sim = make_sim({"/r1": Pose2D(2.0, 2.0, 0.0)}, grid=room_grid(12.0, 8.0, furnished=False))
    lap = (Pose2D(6.0, 2.0, 0.0), Pose2D(6.0, 5.0, 0.0), Pose2D(2.0, 5.0, 0.0), Pose2D(2.0, 2.0, 0.0))
    state = run_goal(sim, "/r1", NavigateThroughPoses(lap), timeout_s=60.0)
    assert state.status is GoalStatus.SUCCEEDED, state.error_msg
    assert sim.robot_state("/r1").distance_m > 12.0
