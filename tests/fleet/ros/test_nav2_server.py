"""The simulator served as namespaced Nav2 (``fleet.ros.nav2_server``), driven across processes
by a BasicNavigator-style client (``commander.py``): server in a child process, clients here.

World: ``configs/warehouse_patrol.yaml`` (robots 1-6 start at (i, 3) facing +y; the cross
aisle at y = 5 and the aisle at x = 6 are free). Each test uses its own robots so that the
module-scoped server can be shared.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pytest
from starts import LocalizedCommanders, start_pose
from waiting import DISCOVERY_S, GOAL_S

from fleet.ros.env import ros_available
from fleet.types import ErrorCode, Pose2D

if ros_available() or TYPE_CHECKING:  # else every test here is skipped (conftest.py)
    from commander import Commander, TaskResult

    from fleet.ros.conversions import pose2d_to_pose_stamped, pose_stamped_to_pose2d

pytestmark = pytest.mark.ros


def _ps(x: float, y: float, th: float = math.pi / 2) -> Any:
    return pose2d_to_pose_stamped(Pose2D(x, y, th))


#: Robots of this module's server already given their initial pose (the server lives as long
#: as the module).
_GIVEN_POSE: set[str] = set()


@pytest.fixture()
def navs(warehouse_server: Any, ros_context: Any) -> Iterator[LocalizedCommanders]:
    made = LocalizedCommanders(ros_context, _GIVEN_POSE)
    yield made
    made.close()


def _run(nav: Commander, timeout_s: float = GOAL_S) -> list[Any]:
    """Spin until the task is complete (``isTaskComplete`` spins 0.1 s); the feedback seen."""
    feedback = []
    deadline = time.monotonic() + timeout_s
    while not nav.isTaskComplete():
        if nav.getFeedback() is not None:
            feedback.append(nav.getFeedback())
        assert time.monotonic() < deadline, f"task did not finish within {timeout_s:.0f} s"
    return feedback


def _wait_executing(nav: Commander, timeout_s: float = GOAL_S) -> None:
    """Spin until the server has published feedback for the task: it is executing."""
    deadline = time.monotonic() + timeout_s
    while nav.getFeedback() is None:
        assert not nav.isTaskComplete(), f"task ended before it executed: {nav.result_message()}"
        assert time.monotonic() < deadline, f"no feedback within {timeout_s:.0f} s"


def test_several_robots_navigate_concurrently(navs: dict[str, Commander]) -> None:
    goals = {"/robot2": (2.0, 4.2), "/robot5": (5.0, 4.2), "/robot6": (6.0, 4.2)}
    for ns in goals:
        navs[ns].waitUntilNav2Active()
    for ns, (x, y) in goals.items():
        assert navs[ns].goToPose(_ps(x, y))
    deadline = time.monotonic() + GOAL_S
    pending = set(goals)
    while pending:
        pending = {ns for ns in pending if not navs[ns].isTaskComplete()}
        assert time.monotonic() < deadline, f"still running: {pending}"
    for ns in goals:
        assert navs[ns].getResult() is TaskResult.SUCCEEDED, navs[ns].result_message()


def test_lifecycle_and_amcl_pose_facade(navs: dict[str, Commander]) -> None:
    nav = navs["/robot1"]
    nav.waitUntilNav2Active()  # bt_navigator + amcl active, amcl_pose received
    from lifecycle_msgs.srv import GetState

    for node in ("bt_navigator", "amcl", "planner_server", "controller_server"):
        cli = nav.create_client(GetState, f"{node}/get_state")
        assert cli.wait_for_service(timeout_sec=DISCOVERY_S)
        fut = cli.call_async(GetState.Request())
        nav._spin_until(fut, DISCOVERY_S)
        assert fut.result().current_state.label == "active"
    # amcl_pose is transient local: a late subscriber gets the robot's pose at once
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    got: list[Any] = []
    qos = QoSProfile(
        depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
    )
    nav.create_subscription(PoseWithCovarianceStamped, "amcl_pose", got.append, qos)
    nav.spin_until(lambda: bool(got), DISCOVERY_S, "amcl_pose received by a late subscriber")
    assert got[-1].header.frame_id == "map"
    p = pose_stamped_to_pose2d(got[-1].pose)  # type: ignore[arg-type]
    assert p.distance_to(Pose2D(1.0, 3.0)) < 0.05
    # initialpose is accepted (the simulator answers with a fresh amcl_pose)
    nav.initial_pose_received = False
    nav.setInitialPose(pose2d_to_pose_stamped(start_pose("/robot1")))
    nav.spin_until(lambda: nav.initial_pose_received, DISCOVERY_S, "amcl_pose answering initialpose")
    # costmap services answer
    assert nav.clear_global.wait_for_service(timeout_sec=DISCOVERY_S)
    fut = nav.clear_global.call_async(nav.clear_global.srv_type.Request())
    nav._spin_until(fut, DISCOVERY_S)
    assert fut.result() is not None


def test_go_to_pose_succeeds_with_feedback(navs: dict[str, Commander]) -> None:
    nav = navs["/robot1"]
    nav.waitUntilNav2Active()
    assert nav.goToPose(_ps(1.0, 5.0, 0.0))
    feedback = _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message()
    assert nav.result_message().error_code == 0
    assert feedback, "no feedback received"
    assert feedback[0].distance_remaining > feedback[-1].distance_remaining
    assert feedback[-1].navigation_time.sec + feedback[-1].navigation_time.nanosec > 0


def test_spin_and_backup_behaviors(navs: dict[str, Commander]) -> None:
    nav = navs["/robot1"]
    assert nav.spin(spin_dist=1.57, time_allowance=10)
    fb = _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message()
    assert fb and fb[-1].angular_distance_traveled > 0.5
    assert nav.backup(backup_dist=0.2, backup_speed=0.1, time_allowance=10)
    _run(nav)
    assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message()
    # DriveOnHeading with contradictory signs is rejected by Nav2's rule: INVALID_INPUT
    assert nav.driveOnHeading(dist=0.3, speed=-0.1)
    _run(nav)
    assert nav.getResult() is TaskResult.FAILED
    assert nav.result_message().error_code == 724


@pytest.mark.parametrize(
    ("goal", "code"),
    [((-50.0, -50.0), ErrorCode.GOAL_OUTSIDE_MAP), ((0.0, 0.0), ErrorCode.GOAL_OCCUPIED)],
)
def test_bad_goal_aborts_with_nav2_error_code(
    navs: dict[str, Commander], goal: tuple[float, float], code: int
) -> None:
    nav = navs["/robot3"]
    assert nav.goToPose(_ps(*goal))
    _run(nav)
    assert nav.getResult() is TaskResult.FAILED
    res = nav.result_message()
    assert res.error_code == code
    assert res.error_msg


def test_cancel_task(navs: dict[str, Commander]) -> None:
    nav = navs["/robot3"]
    assert nav.goThroughPoses([_ps(3.0, 5.0), _ps(2.5, 14.0)])
    _wait_executing(nav)
    nav.cancelTask()
    _run(nav)
    assert nav.getResult() is TaskResult.CANCELED


def test_new_goal_preempts_running_goal(navs: dict[str, Commander], ros_context: Any) -> None:
    first = navs["/robot4"]
    second = Commander("/robot4", ros_context)
    try:
        assert first.goToPose(_ps(6.0, 14.0))
        _wait_executing(first)
        assert second.goToPose(_ps(4.0, 4.2))
        _run(first)
        assert first.getResult() is TaskResult.FAILED  # Nav2 aborts the preempted goal
        assert "preempted" in first.result_message().error_msg
        _run(second)
        assert second.getResult() is TaskResult.SUCCEEDED
    finally:
        second.close()


def test_follow_waypoints_reports_missed_waypoint(navs: dict[str, Commander]) -> None:
    nav = navs["/robot6"]
    assert nav.followWaypoints([_ps(6.0, 5.0), _ps(-50.0, -50.0), _ps(6.0, 6.5)])
    fb = _run(nav)
    res = nav.result_message()
    assert [m.index for m in res.missed_waypoints] == [1]
    assert max(f.current_waypoint for f in fb) >= 1


def test_compute_path_to_pose(navs: dict[str, Commander]) -> None:
    nav = navs["/robot5"]
    path = nav.getPath(_ps(0, 0), _ps(9.0, 9.0))
    assert path is not None and len(path.poses) >= 2
    end = pose_stamped_to_pose2d(path.poses[-1])
    assert end.distance_to(Pose2D(9.0, 9.0)) < 0.2
    assert nav.getPath(_ps(0, 0), _ps(-50.0, -50.0)) is None
    assert nav.getResult() is TaskResult.FAILED
    assert nav.result_message().error_code == ErrorCode.GOAL_OUTSIDE_MAP
