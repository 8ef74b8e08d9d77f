"""How old the ROS backend thinks a robot's pose estimate is, when its topics arrive unevenly.

On a loaded machine the client's executor runs behind: ``odom`` (10 messages kept) stays
fresh while ``tf`` (100 kept) drains a backlog seconds old. That backlog is not a lost
localizer (the fleet's CI saw every robot safety-stopped for "pose estimate 5.2 s old" while
the simulator published ``map -> odom`` with every odometry message); a localizer that stops
publishing beside running odometry still is. The messages are real ROS messages handed to the
tracker's callbacks in the order a lagging executor would run them."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest

pytestmark = pytest.mark.ros


@pytest.fixture
def tracker(ros_context: Any) -> Iterator[Any]:
    from rclpy.node import Node

    from fleet.ros.robot_state import RobotStateTracker

    node = Node("age_probe", namespace="/robot1", context=ros_context)
    newest = [0.0]

    def saw_odom(t: float) -> None:
        newest[0] = max(newest[0], t)

    tr = RobotStateTracker(node, threading.RLock(), lambda stamp: None, lambda: newest[0], saw_odom=saw_odom)
    yield tr
    node.destroy_node()


def _tf(t: float, *, correction: bool) -> Any:
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    from fleet.ros.conversions import seconds_to_time

    out = []
    pairs = [("odom", "base_link")] + ([("map", "odom")] if correction else [])
    for parent, child in pairs:
        ts = TransformStamped()
        ts.header.stamp = seconds_to_time(t)
        ts.header.frame_id, ts.child_frame_id = parent, child
        ts.transform.translation.x = t * 0.5 if child == "base_link" else 1.0
        ts.transform.rotation.w = 1.0
        out.append(ts)
    return TFMessage(transforms=out)


def _odom(t: float) -> Any:
    from nav_msgs.msg import Odometry

    from fleet.ros.conversions import seconds_to_time

    msg = Odometry()
    msg.header.stamp = seconds_to_time(t)
    msg.pose.pose.position.x = t * 0.5
    msg.pose.pose.orientation.w = 1.0
    return msg


def test_a_tf_backlog_behind_fresh_odometry_is_not_a_lost_localizer(tracker: Any) -> None:
    for k in range(1, 11):  # tf with the correction drained up to t = 5 s
        tracker._on_tf(_tf(k * 0.5, correction=True))
    for k in range(1, 41):  # odom already at t = 20 s
        tracker._on_odom(_odom(k * 0.5))
    state = tracker.state()
    assert state.pose is not None and state.localized
    assert state.pose_age_s == pytest.approx(0.0)
    # the pose is read at the fleet's time (20 s) through the newest correction
    assert state.pose.x == pytest.approx(1.0 + 20.0 * 0.5)


def test_a_localizer_that_stops_beside_running_odometry_still_ages(tracker: Any) -> None:
    for k in range(1, 11):
        tracker._on_tf(_tf(k * 0.5, correction=True))
    for k in range(11, 41):  # odometry goes on on tf and odom, no map -> odom after 5 s
        tracker._on_tf(_tf(k * 0.5, correction=False))
        tracker._on_odom(_odom(k * 0.5))
    assert tracker.state().pose_age_s == pytest.approx(15.0)
