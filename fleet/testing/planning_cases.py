"""Conformance cases of the planner, the controller, the smoother and the costmaps: the goals
ComputePathToPose, ComputePathThroughPoses, FollowPath, SmoothPath and ClearCostmaps
(:data:`PLANNING_CASES`, run by :func:`fleet.testing.conformance.check_backend` after the
navigation cases). A backend without free-path following or costmaps (SUMO) declares
``path_following`` / ``costmaps`` in ``lacks``."""

from __future__ import annotations

from fleet.testing.harness import ConformanceHarness, case_registry, expect, finish, robot_pose
from fleet.types import (
    ClearCostmaps,
    ComputePathThroughPoses,
    ComputePathToPose,
    ErrorCode,
    FollowPath,
    GoalState,
    GoalStatus,
    NavigateToPose,
    SmoothPath,
    Wait,
    normalize_angle,
)

_CASES, _case = case_registry()

#: A computed path may start this far (m) from the robot (a lane-bound backend snaps it).
_PATH_START_TOLERANCE_M = 1.0


def _computed_path(h: ConformanceHarness, goal: ComputePathToPose | ComputePathThroughPoses) -> GoalState:
    state = finish(h, h.backend.send_goal(goal), 10.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"{goal.kind} ended {state.status.value}: {state.error_msg}")
    expect(len(state.path) >= 2, f"{goal.kind} succeeded with a path of {len(state.path)} poses")
    here = robot_pose(h)
    off = state.path[0].distance_to(here)
    expect(off <= _PATH_START_TOLERANCE_M, f"the path starts {off:.2f} m from the robot")
    return state


@_case()
def compute_path_to_pose_returns_the_path(h: ConformanceHarness) -> None:
    """ComputePathToPose SUCCEEDS with a path from the robot to the goal, and moves nothing."""
    w = h.world
    before = robot_pose(h)
    state = _computed_path(h, ComputePathToPose(w.reachable))
    end = state.path[-1].distance_to(w.reachable)
    expect(end <= w.goal_tolerance + 0.05, f"the path ends {end:.2f} m from the goal")
    h.advance(1.0)
    moved = before.distance_to(robot_pose(h))
    expect(moved < 0.01, f"the robot moved {moved:.3f} m while a path was computed")


@_case()
def compute_path_failures_carry_planner_codes(h: ConformanceHarness) -> None:
    """ComputePathToPose off the map ends ABORTED GOAL_OUTSIDE_MAP (204), to an enclosed pose
    NO_VALID_PATH (208), each with a message and no path."""
    for target, code in (
        (h.world.off_map, ErrorCode.GOAL_OUTSIDE_MAP),
        (h.world.unreachable, ErrorCode.NO_VALID_PATH),
    ):
        state = finish(h, h.backend.send_goal(ComputePathToPose(target)), 10.0)
        expect(state.status is GoalStatus.ABORTED, f"planning to {target} ended {state.status.value}")
        expect(state.error_code == code, f"planning to {target}: code {state.error_code}, not {int(code)}")
        expect(bool(state.error_msg) and not state.path, "a failed plan needs a message and no path")


@_case()
def compute_path_through_poses_joins_the_legs(h: ConformanceHarness) -> None:
    """ComputePathThroughPoses through two poses SUCCEEDS with one path passing both; no
    poses ends ABORTED NO_VIAPOINTS_GIVEN (309); a pose off the map THROUGH_POSES_GOAL_OUTSIDE_MAP
    (304)."""
    w = h.world
    state = _computed_path(h, ComputePathThroughPoses((w.reachable, w.start)))
    near = min(p.distance_to(w.reachable) for p in state.path)
    expect(near <= w.goal_tolerance + 0.05, f"the path passes {near:.2f} m from the first pose")
    end = state.path[-1].distance_to(w.start)
    expect(end <= w.goal_tolerance + 0.05, f"the path ends {end:.2f} m from the last pose")
    for goals, code in (
        ((), ErrorCode.NO_VIAPOINTS_GIVEN),
        ((w.off_map,), ErrorCode.THROUGH_POSES_GOAL_OUTSIDE_MAP),
    ):
        bad = finish(h, h.backend.send_goal(ComputePathThroughPoses(goals)), 10.0)
        expect(bad.status is GoalStatus.ABORTED, f"through {goals} ended {bad.status.value}")
        expect(bad.error_code == code, f"through {goals}: code {bad.error_code}, not {int(code)}")


@_case()
def computation_goals_do_not_preempt_motion(h: ConformanceHarness) -> None:
    """A ComputePathToPose sent while the robot navigates leaves the navigation goal running,
    and it still SUCCEEDS."""
    b, w = h.backend, h.world
    nav = b.send_goal(NavigateToPose(w.reachable))
    h.advance(2.0)
    plan = finish(h, b.send_goal(ComputePathToPose(w.start)), 10.0)
    expect(plan.status is GoalStatus.SUCCEEDED, f"the plan ended {plan.status.value}: {plan.error_msg}")
    status = b.goal_state(nav).status
    expect(
        status is GoalStatus.EXECUTING, f"the navigation goal became {status.value} when a path was computed"
    )
    state = finish(h, nav, w.nav_time_s)
    expect(
        state.status is GoalStatus.SUCCEEDED, f"the navigation ended {state.status.value}: {state.error_msg}"
    )


@_case("path_following")
def follow_path_drives_the_computed_path(h: ConformanceHarness) -> None:
    """FollowPath of a computed path SUCCEEDS with the robot at the path's end, within the
    tolerances."""
    w = h.world
    path = _computed_path(h, ComputePathToPose(w.reachable)).path
    state = finish(h, h.backend.send_goal(FollowPath(path)), w.nav_time_s)
    expect(state.status is GoalStatus.SUCCEEDED, f"FollowPath ended {state.status.value}: {state.error_msg}")
    h.advance(1.0)
    pose = robot_pose(h)
    off = pose.distance_to(w.reachable)
    expect(off <= w.goal_tolerance + 0.05, f"ended {off:.2f} m from the path's end")
    yaw = abs(normalize_angle(pose.theta - w.reachable.theta))
    expect(yaw <= w.yaw_tolerance + 0.05, f"ended {yaw:.2f} rad off the path's final yaw")


@_case("path_following")
def empty_follow_path_aborts_invalid_path(h: ConformanceHarness) -> None:
    """FollowPath of an empty path ends ABORTED with INVALID_PATH (103) and a message."""
    state = finish(h, h.backend.send_goal(FollowPath(())), 10.0)
    expect(state.status is GoalStatus.ABORTED, f"an empty FollowPath ended {state.status.value}")
    expect(state.error_code == ErrorCode.INVALID_PATH, f"error code {state.error_code}, not 103")
    expect(bool(state.error_msg), "an aborted goal must explain itself (empty error_msg)")


@_case()
def smooth_path_keeps_the_ends(h: ConformanceHarness) -> None:
    """SmoothPath of a computed path SUCCEEDS with a path of the same start and end; an empty
    path ends ABORTED SMOOTHER_INVALID_PATH (505)."""
    path = _computed_path(h, ComputePathToPose(h.world.reachable)).path
    state = finish(h, h.backend.send_goal(SmoothPath(path)), 10.0)
    expect(state.status is GoalStatus.SUCCEEDED, f"SmoothPath ended {state.status.value}: {state.error_msg}")
    expect(len(state.path) >= 2, f"the smoothed path has {len(state.path)} poses")
    ends = (state.path[0].distance_to(path[0]), state.path[-1].distance_to(path[-1]))
    expect(max(ends) <= 0.01, f"the smoothed path moved its ends by {ends[0]:.3f} / {ends[1]:.3f} m")
    bad = finish(h, h.backend.send_goal(SmoothPath(())), 10.0)
    expect(bad.status is GoalStatus.ABORTED, f"an empty SmoothPath ended {bad.status.value}")
    expect(bad.error_code == ErrorCode.SMOOTHER_INVALID_PATH, f"error code {bad.error_code}, not 505")


@_case("costmaps")
def clear_costmaps_succeeds(h: ConformanceHarness) -> None:
    """ClearCostmaps SUCCEEDS, and does not disturb a running Wait."""
    b = h.backend
    wait = b.send_goal(Wait(5.0))
    h.advance(0.5)
    state = finish(h, b.send_goal(ClearCostmaps()), 10.0)
    expect(
        state.status is GoalStatus.SUCCEEDED, f"ClearCostmaps ended {state.status.value}: {state.error_msg}"
    )
    status = b.goal_state(wait).status
    expect(
        status is GoalStatus.EXECUTING,
        f"the running Wait became {status.value} when the costmaps were cleared",
    )


#: The cases of this module, in the order they run.
PLANNING_CASES = tuple(_CASES)
