"""What ``fleet sim-ros`` shows besides the actions, over rclpy: ``/map``, ``/tf`` and each
robot's ``tf`` and ``plan`` (what RViz / Foxglove draw); ``/diagnostics`` levels following
injected faults, the ROS backend's view of them (stale localization, the safety watchdog,
``IsLocalized``'s freshness timeout, a missing ``battery_state``); the live costmap layers and
the clear services; ``initialpose`` setting the estimate; ``--duration`` in simulated seconds.

The warehouse (six robots, robot i at (i, 3) facing +y) is served at 2x real time in a child
process; each test uses its own robots.
"""

from __future__ import annotations

import logging
import math
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from starts import LocalizedCommanders, start_pose
from waiting import DISCOVERY_S, GOAL_S

from fleet.diagnostics import SafetyWatchdog
from fleet.ros.env import ros_available
from fleet.ros.launch import ServerProcess
from fleet.types import Pose2D

if ros_available() or TYPE_CHECKING:
    from commander import Commander, TaskResult

    from fleet.ros.conversions import pose2d_to_pose_stamped

pytestmark = pytest.mark.ros

WAREHOUSE = Path(__file__).resolve().parents[3] / "configs" / "warehouse_patrol.yaml"

ERROR, OK = b"\x02", b"\x00"


@pytest.fixture(scope="module")
def server() -> Iterator[ServerProcess]:
    with ServerProcess.for_config(
        WAREHOUSE, "--speed", "2", "--diagnostics-hz", "4", "--odom-hz", "10"
    ) as srv:
        yield srv


def _ps(x: float, y: float, th: float = math.pi / 2) -> Any:
    return pose2d_to_pose_stamped(Pose2D(x, y, th))


def _collect(nav: Commander, msg_type: Any, topic: str, pred: Any, what: str, qos: Any = 10) -> Any:
    """The first message on ``topic`` for which ``pred(msg)`` holds."""
    got: list[Any] = []
    sub = nav.create_subscription(msg_type, topic, lambda m: got.append(m) if pred(m) else None, qos)
    nav.spin_until(lambda: bool(got), DISCOVERY_S, what)
    nav.destroy_subscription(sub)
    return got[0]


def _status(nav: Commander, name: str, level: bytes) -> Any:
    from diagnostic_msgs.msg import DiagnosticArray

    arr = _collect(
        nav,
        DiagnosticArray,
        "/diagnostics",
        lambda m: any(s.name == name and s.level == level for s in m.status),
        f"/diagnostics {name} at level {level!r}",
    )
    return next(s for s in arr.status if s.name == name and s.level == level)


def _fault(nav: Commander, fault: str) -> None:
    from std_msgs.msg import String

    if not hasattr(nav, "fault_pub"):
        nav.fault_pub = nav.create_publisher(String, "sim_fault", 10)  # type: ignore[attr-defined]
        nav.spin_until(lambda: nav.fault_pub.get_subscription_count() > 0, DISCOVERY_S, "sim_fault")  # type: ignore[attr-defined]
    nav.fault_pub.publish(String(data=fault))  # type: ignore[attr-defined]


#: Robots of this module's server already given their initial pose (the server lives as long
#: as the module).
_GIVEN_POSE: set[str] = set()


@pytest.fixture()
def navs(server: ServerProcess, ros_context: Any) -> Iterator[LocalizedCommanders]:
    made = LocalizedCommanders(ros_context, _GIVEN_POSE)
    yield made
    made.close()


def test_map_tf_and_the_planned_path_for_rviz(navs: dict[str, Commander]) -> None:
    from nav_msgs.msg import OccupancyGrid, Path
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from tf2_msgs.msg import TFMessage

    from fleet.config.loader import load_config
    from fleet.ros.frames import compose
    from fleet.ros.robot_state import transform_to_pose2d

    grid = load_config(WAREHOUSE).grid
    nav = navs["/robot1"]
    latched = QoSProfile(
        depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
    )
    m = _collect(nav, OccupancyGrid, "/map", lambda _m: True, "/map (latched)", latched)
    assert (m.info.width, m.info.height, m.header.frame_id) == (grid.width, grid.height, "map")
    assert m.info.resolution == pytest.approx(grid.resolution)
    assert 0 < sum(1 for v in m.data if v == 100) < len(m.data)
    # the fleet's /tf: map -> robotN/odom -> robotN/base_link for every robot, one stamp
    fleet_tf = _collect(nav, TFMessage, "/tf", lambda t: len(t.transforms) == 12, "/tf of six robots")
    pairs = {(t.header.frame_id, t.child_frame_id) for t in fleet_tf.transforms}
    for i in range(1, 7):
        assert ("map", f"robot{i}/odom") in pairs and (f"robot{i}/odom", f"robot{i}/base_link") in pairs
    assert len({(t.header.stamp.sec, t.header.stamp.nanosec) for t in fleet_tf.transforms}) == 1
    # the robot's own tf composes to where it stands
    own = _collect(nav, TFMessage, "tf", lambda t: len(t.transforms) == 2, "/robot1/tf")
    by = {t.header.frame_id: transform_to_pose2d(t.transform) for t in own.transforms}
    pose = compose(by["map"], by["odom"])
    assert pose.distance_to(Pose2D(1.0, 3.0)) < 0.05
    # a goal's planned path is published on plan
    nav2 = navs["/robot2"]
    nav2.waitUntilNav2Active()
    plans: list[Any] = []
    nav2.create_subscription(Path, "plan", plans.append, 1)
    assert nav2.goToPose(_ps(2.0, 4.5))
    nav2.spin_until(lambda: bool(plans), DISCOVERY_S, "/robot2/plan")
    last = plans[-1].poses[-1].pose.position
    assert plans[-1].header.frame_id == "map" and math.hypot(last.x - 2.0, last.y - 4.5) < 0.3
    deadline = time.monotonic() + GOAL_S
    while not nav2.isTaskComplete():
        assert time.monotonic() < deadline
    assert nav2.getResult() is TaskResult.SUCCEEDED


def test_diagnostics_and_the_backend_follow_lost_localization_and_a_dead_navigator(
    navs: dict[str, Commander], ros_context: Any
) -> None:
    from fleet.ros.backend import make_ros_backends
    from nodes.conditions import IsLocalized

    nav = navs["/robot3"]
    nav.waitUntilNav2Active()
    assert _status(nav, "robot3: localization", OK).message == "localized"
    _status(nav, "robot3: battery", OK)
    rb = make_ros_backends(["/robot3"], context=ros_context, wait_s=DISCOVERY_S)
    try:
        b = rb["/robot3"]
        is_localized = IsLocalized(b, timeout_s=2.0)
        watchdog = SafetyWatchdog()
        nav.spin_until(lambda: b.robot_state().pose is not None, DISCOVERY_S, "backend pose")
        is_localized.tick_once()
        assert is_localized.status.name == "SUCCESS" and watchdog.check(b.robot_state()) == ""
        _fault(nav, "localization_lost")
        _status(nav, "robot3: localization", ERROR)
        assert "localization lost" in _status(nav, "robot3: motion", ERROR).message  # its safety stop
        # no map -> odom any more: the backend's estimate goes stale, IsLocalized fails after
        # its timeout, then the watchdog stops the robot
        nav.spin_until(lambda: b.robot_state().pose_age_s > 2.0, DISCOVERY_S, "stale estimate")
        is_localized.tick_once()
        assert is_localized.status.name == "FAILURE"
        nav.spin_until(lambda: b.robot_state().pose_age_s > 5.0, DISCOVERY_S, "lost estimate")
        assert watchdog.check(b.robot_state()).startswith("localization lost")
        _fault(nav, "")
        _status(nav, "robot3: localization", OK)
        nav.spin_until(lambda: watchdog.check(b.robot_state()) == "", DISCOVERY_S, "watchdog cleared")
        _fault(nav, "navigation_down")
        assert "navigation" in _status(nav, "robot3: navigation", ERROR).message
        _fault(nav, "")
        _status(nav, "robot3: navigation", OK)
        assert watchdog.trips == 1
    finally:
        rb.close()


def test_missing_battery_state_is_warned_once(ros_context: Any, caplog: pytest.LogCaptureFixture) -> None:
    """A robot that publishes odometry but no sensor_msgs/BatteryState: the battery is
    unknown (not assumed full silently), warned once, and a WARN diagnostic."""
    from nav_msgs.msg import Odometry
    from rclpy.node import Node

    from fleet.diagnostics import Level, robot_diagnostics
    from fleet.ros.backend import make_ros_backends

    node = Node("fake_odom", namespace="/nobattery", context=ros_context)
    pub = node.create_publisher(Odometry, "odom", 10)
    rb = make_ros_backends(["/nobattery"], context=ros_context)
    try:
        b = rb["/nobattery"]
        deadline = time.monotonic() + DISCOVERY_S
        with caplog.at_level(logging.WARNING, logger="fleet.ros.robot_state"):
            while b.tracker.odom.latest is None:
                msg = Odometry()
                msg.header.stamp.sec = 1 + int(time.monotonic() - deadline + DISCOVERY_S)
                pub.publish(msg)
                assert time.monotonic() < deadline, "odometry never arrived"
                time.sleep(0.05)
            states = [b.robot_state() for _ in range(5)]
        warnings = [r for r in caplog.records if "battery_state" in r.getMessage()]
        assert len(warnings) == 1, warnings
        assert "/nobattery/battery_state" in warnings[0].getMessage()
        assert all(not s.battery_known for s in states)
        (battery,) = [d for d in robot_diagnostics(states[-1]) if d.name == "battery"]
        assert battery.level == Level.WARN and "no battery state" in battery.message
    finally:
        rb.close()
        node.destroy_node()


def test_live_costmap_layers_clears_and_initial_pose(navs: dict[str, Commander]) -> None:
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav2_msgs.srv import ClearEntireCostmap, GetCostmap
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    nav = navs["/robot6"]
    nav.waitUntilNav2Active()

    def costmap(which: str, layer: str) -> Any:
        cli = nav.create_client(GetCostmap, f"{which}/get_costmap")
        assert cli.wait_for_service(timeout_sec=DISCOVERY_S)
        req = GetCostmap.Request()
        req.specs.layer = layer
        fut = cli.call_async(req)
        nav._spin_until(fut, DISCOVERY_S)
        nav.destroy_client(cli)
        return fut.result().map

    def cost_at(cm: Any, x: float, y: float) -> int:
        md = cm.metadata
        i = int((x - md.origin.position.x) / md.resolution)
        j = int((y - md.origin.position.y) / md.resolution)
        return int(cm.data[j * md.size_x + i])

    # robot6 learns robot5, standing still at its start 1 m away, as an obstacle
    r5 = start_pose("/robot5")
    nav.spin_until(
        lambda: cost_at(costmap("global_costmap", "obstacle_layer"), r5.x, r5.y) == 254,
        DISCOVERY_S,
        "robot5 learned in robot6's obstacle layer",
    )
    static = costmap("global_costmap", "static_layer")
    assert cost_at(static, r5.x, r5.y) == 0 and max(static.data) == 254
    local = costmap("local_costmap", "master")
    assert local.metadata.size_x * local.metadata.resolution == pytest.approx(5.0, abs=0.2)
    # drive out of sensor range (the mark stays: it decays after 30 s), then clear it
    assert nav.goToPose(_ps(6.0, 7.0))
    deadline = time.monotonic() + GOAL_S
    while not nav.isTaskComplete():
        assert time.monotonic() < deadline
    assert nav.getResult() is TaskResult.SUCCEEDED, nav.result_message()
    assert cost_at(costmap("global_costmap", "obstacle_layer"), r5.x, r5.y) == 254
    cli = nav.create_client(ClearEntireCostmap, "global_costmap/clear_entirely_global_costmap")
    assert cli.wait_for_service(timeout_sec=DISCOVERY_S)
    fut = cli.call_async(ClearEntireCostmap.Request())
    nav._spin_until(fut, DISCOVERY_S)
    assert fut.result() is not None
    assert cost_at(costmap("global_costmap", "obstacle_layer"), r5.x, r5.y) == 0
    assert cost_at(costmap("global_costmap", "master"), r5.x, r5.y) < 253
    # initialpose sets the estimate: far off, the robot is mislocalized (large covariance,
    # ERROR); at its real pose, localized again
    qos = QoSProfile(
        depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
    )

    here = nav.current_estimate().pose  # where the goal left it (within the goal tolerance)
    hx, hy, hth = here.position.x, here.position.y, 2.0 * math.atan2(here.orientation.z, here.orientation.w)

    def amcl_after(x: float, y: float) -> Any:
        nav.setInitialPose(_ps(x, y, hth))
        return _collect(
            nav,
            PoseWithCovarianceStamped,
            "amcl_pose",
            lambda m: abs(m.pose.pose.position.x - x) < 0.05 and abs(m.pose.pose.position.y - y) < 0.05,
            f"amcl_pose at ({x}, {y})",
            qos,
        )

    wrong = amcl_after(10.0, 3.0)
    assert wrong.pose.covariance[0] > 1.0
    _status(nav, "robot6: localization", ERROR)
    assert "did not converge" in _status(nav, "robot6: motion", ERROR).message
    right = amcl_after(hx, hy)
    assert right.pose.covariance[0] < 0.01
    _status(nav, "robot6: localization", OK)


def test_duration_is_simulated_seconds(tmp_path: Any) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "fleet.ros.nav2_server", str(WAREHOUSE), "--robots", "1", "--speed", "20",
         "--duration", "10"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stdout + out.stderr
    assert "stopped (duration) after 10.0 s simulated" in out.stdout, out.stdout
