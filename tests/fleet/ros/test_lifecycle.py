"""The Nav2 lifecycle of ``fleet sim-ros`` over rclpy: a server started with
``--no-autostart`` leaves every robot's Nav2 nodes unconfigured; goals are refused until the
lifecycle managers bring them up, in Nav2's order, stopping at (and naming) a node that fails;
BasicNavigator-style ``lifecycleStartup()`` / ``waitUntilNav2Active()`` /
``lifecycleShutdown()`` work; the project's ROS backend waits for (and drives) that lifecycle.

The server runs in a child process (two robots of the warehouse); the clients here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from starts import start_pose
from waiting import DISCOVERY_S, GOAL_S

from fleet.ros.env import ros_available
from fleet.ros.launch import ServerProcess
from fleet.types import Pose2D

if ros_available() or TYPE_CHECKING:
    from commander import Commander, TaskResult

    from fleet.ros.conversions import pose2d_to_pose_stamped

pytestmark = pytest.mark.ros

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"

NAVIGATION = (
    "controller_server",
    "smoother_server",
    "planner_server",
    "behavior_server",
    "bt_navigator",
    "waypoint_follower",
)


@pytest.fixture(scope="module")
def cold_server() -> Iterator[ServerProcess]:
    with ServerProcess.for_config(
        WAREHOUSE, "--robots", "2", "--no-autostart", "--speed", "4", "--diagnostics-hz", "4"
    ) as srv:
        yield srv


def _ps(x: float, y: float) -> Any:
    return pose2d_to_pose_stamped(Pose2D(x, y, math.pi / 2))


def _state(nav: Commander, node: str) -> str:
    from lifecycle_msgs.srv import GetState

    cli = nav.create_client(GetState, f"{node}/get_state")
    assert cli.wait_for_service(timeout_sec=DISCOVERY_S), f"{node}/get_state"
    fut = cli.call_async(GetState.Request())
    nav._spin_until(fut, DISCOVERY_S)
    nav.destroy_client(cli)
    return str(fut.result().current_state.label)


def _manage(nav: Commander, manager: str, command: int) -> bool:
    from nav2_msgs.srv import ManageLifecycleNodes

    cli = nav.create_client(ManageLifecycleNodes, f"{manager}/manage_nodes")
    assert cli.wait_for_service(timeout_sec=DISCOVERY_S), manager
    fut = cli.call_async(ManageLifecycleNodes.Request(command=command))
    nav._spin_until(fut, DISCOVERY_S)
    nav.destroy_client(cli)
    return bool(fut.result().success)


def _diagnostic(nav: Commander, name: str, pred: Any) -> Any:
    """The first ``/diagnostics`` status named ``name`` for which ``pred(status)`` holds."""
    from diagnostic_msgs.msg import DiagnosticArray

    seen: list[Any] = []

    def cb(msg: Any) -> None:
        seen.extend(s for s in msg.status if s.name == name and pred(s))

    sub = nav.create_subscription(DiagnosticArray, "/diagnostics", cb, 10)
    nav.spin_until(lambda: bool(seen), DISCOVERY_S, f"/diagnostics {name!r}")
    nav.destroy_subscription(sub)
    return seen[0]


def test_ros_backend_brings_nav2_up_and_waits_for_it(cold_server: ServerProcess, ros_context: Any) -> None:
    """The fleet's ROS backend, facing an unconfigured robot, starts it through its lifecycle
    managers and waits until its navigator is active (first test: robot2 is still cold)."""
    from fleet.ros.backend import make_ros_backends

    nav = Commander("/robot2", ros_context)
    try:
        assert _state(nav, "bt_navigator") == "unconfigured"
    finally:
        nav.close()
    rb = make_ros_backends(["/robot2"], context=ros_context, wait_s=DISCOVERY_S)
    try:
        assert rb["/robot2"].lifecycle.active
        assert rb["/robot2"].lifecycle.startup_sent
        assert rb["/robot2"].robot_state().navigation_ready
    finally:
        rb.close()


def test_goals_refused_until_startup_which_stops_at_the_failing_node(
    cold_server: ServerProcess, ros_context: Any
) -> None:
    from nav2_msgs.srv import ManageLifecycleNodes
    from std_msgs.msg import String

    nav = Commander("/robot1", ros_context)
    try:
        assert _state(nav, "bt_navigator") == "unconfigured"
        assert _state(nav, "amcl") == "unconfigured"
        nav._wait_server("navigate_to_pose")
        assert nav.goToPose(_ps(1.0, 4.0)) is False, "a goal was accepted while Nav2 is inactive"
        # the planner server's next configure fails
        pub = nav.create_publisher(String, "sim_fault", 10)
        nav.spin_until(lambda: pub.get_subscription_count() > 0, DISCOVERY_S, "sim_fault subscriber")
        pub.publish(String(data="fail:planner_server"))
        assert _manage(nav, "lifecycle_manager_localization", ManageLifecycleNodes.Request.STARTUP)
        # The fault and the manager's request travel on different channels: the first sample
        # can be lost while the server's reader has not matched this writer yet, and the server
        # may take a request before a sample sent just ahead of it. A STARTUP that succeeded
        # means the fault was not armed in time: take navigation back down (RESET) and arm it
        # again (the fault is a set, so twice is once).
        for _ in range(5):
            pub.publish(String(data="fail:planner_server"))
            _state(nav, "planner_server")  # a round trip after the sample
            if not _manage(nav, "lifecycle_manager_navigation", ManageLifecycleNodes.Request.STARTUP):
                break
            assert _manage(nav, "lifecycle_manager_navigation", ManageLifecycleNodes.Request.RESET)
        else:
            pytest.fail("the planner server's injected fault was never armed before STARTUP")
        states = {n: _state(nav, n) for n in NAVIGATION}
        # configured in order up to the failing node, which stopped the bring-up
        assert states == {
            "controller_server": "inactive",
            "smoother_server": "inactive",
            "planner_server": "unconfigured",
            "behavior_server": "unconfigured",
            "bt_navigator": "unconfigured",
            "waypoint_follower": "unconfigured",
        }
        assert _state(nav, "map_server") == "active" and _state(nav, "amcl") == "active"
        err = _diagnostic(nav, "robot1: lifecycle_manager_navigation", lambda s: s.level == b"\x02")
        assert "planner_server" in err.message
        assert nav.goToPose(_ps(1.0, 4.0)) is False
        # BasicNavigator's way: every manager of the graph gets STARTUP, then wait for Nav2
        results = nav.lifecycleStartup()
        assert results.get("/robot1/lifecycle_manager_navigation/manage_nodes") is True, results
        nav.setInitialPose(pose2d_to_pose_stamped(start_pose("/robot1")))
        nav.waitUntilNav2Active()
        assert {n: _state(nav, n) for n in NAVIGATION} == dict.fromkeys(NAVIGATION, "active")
        _diagnostic(nav, "robot1: lifecycle_manager_navigation", lambda s: s.level == b"\x00")
        assert nav.goToPose(_ps(1.0, 4.0))
        deadline = time.monotonic() + GOAL_S
        while not nav.isTaskComplete():
            assert time.monotonic() < deadline
        assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message()
    finally:
        nav.close()


def test_lifecycle_shutdown_finalizes_and_refuses_goals(cold_server: ServerProcess, ros_context: Any) -> None:
    """Stands on its own: robot1 is brought up here (a STARTUP of an active graph is a no-op),
    whatever the tests before it left; each manager is addressed by name, so the shutdown
    below does not depend on how much of the graph discovery had shown this client yet."""
    from nav2_msgs.srv import ManageLifecycleNodes

    nav = Commander("/robot1", ros_context)
    try:
        for manager in ("lifecycle_manager_localization", "lifecycle_manager_navigation"):
            assert _manage(nav, manager, ManageLifecycleNodes.Request.STARTUP), manager
        nav.setInitialPose(pose2d_to_pose_stamped(start_pose("/robot1")))
        nav.waitUntilNav2Active()
        results = nav.lifecycleShutdown()
        assert results.get("/robot1/lifecycle_manager_navigation/manage_nodes") is True, results
        for n in (*NAVIGATION, "amcl", "map_server"):
            assert _state(nav, n) == "finalized", n
        assert nav.goToPose(_ps(1.0, 3.0)) is False
    finally:
        nav.close()
