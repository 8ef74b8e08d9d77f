"""What the ROS backend knows of a robot's state, from the topics a Nav2 robot publishes.

:class:`RobotStateTracker` subscribes, under the robot's namespace, to

* ``amcl_pose`` (``PoseWithCovarianceStamped``, transient local): the map pose;
* ``odom`` (``nav_msgs/Odometry``): velocities, the distance driven, and the pose between two
  amcl updates (map pose = the map-from-odom transform of the last ``amcl_pose`` composed
  with the odometry pose);
* ``battery_state`` (``sensor_msgs/BatteryState``, if that package is installed):
  ``percentage`` in [0, 1] and CHARGING.

and turns them into a :class:`~fleet.types.RobotState`. Over Nav2 there is no stuck flag
nor a collision count: ``stuck`` is False and ``collisions`` 0; the battery is 1.0 until a
``battery_state`` arrives. Callbacks run on the executor thread; :meth:`state` may be called
from any thread (shared state is guarded by ``lock``).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from fleet.ros.conversions import AMCL_POSE_QOS, pose_to_pose2d
from fleet.types import Pose2D, RobotState, normalize_angle

try:
    from sensor_msgs.msg import BatteryState
except ImportError:  # optional: without it the battery reads full
    BatteryState = None


def compose(a: Pose2D, b: Pose2D) -> Pose2D:
    """``a ∘ b``: the pose ``b`` (given in ``a``'s frame) expressed in ``a``'s parent frame."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, normalize_angle(a.theta + b.theta))


def inverse(a: Pose2D) -> Pose2D:
    """The inverse transform of ``a`` (``compose(a, inverse(a))`` is the identity)."""
    c, s = math.cos(a.theta), math.sin(a.theta)
    return Pose2D(-(c * a.x + s * a.y), -(-s * a.x + c * a.y), normalize_angle(-a.theta))


class RobotStateTracker:
    """The state of the robot whose topics ``node`` (in the robot's namespace) subscribes to.

    Args:
        node: the backend's node of this robot.
        lock: guards the tracked values (shared with the backend's goal records).
        saw_stamp: called with every ``amcl_pose`` / ``odom`` header stamp (the robots' time).
    """

    def __init__(self, node: Node, lock: threading.RLock, saw_stamp: Callable[[Time], None]) -> None:
        self._lock = lock
        self._saw_stamp = saw_stamp
        self._odom: Pose2D | None = None
        self._map_from_odom: Pose2D | None = None
        self._amcl: Pose2D | None = None
        self._v = 0.0
        self._w = 0.0
        self._distance = 0.0
        self._battery = 1.0
        self._charging = False
        node.create_subscription(PoseWithCovarianceStamped, "amcl_pose", self._on_amcl, AMCL_POSE_QOS)
        node.create_subscription(Odometry, "odom", self._on_odom, 10)
        if BatteryState is not None:
            node.create_subscription(BatteryState, "battery_state", self._on_battery, 10)

    def state(self) -> RobotState:
        """The robot's state now (pose ``None`` until an ``amcl_pose`` or a navigation
        feedback pose arrived)."""
        with self._lock:
            return RobotState(
                pose=self._pose_locked(),
                linear_velocity=self._v,
                angular_velocity=self._w,
                battery=self._battery,
                charging=self._charging,
                stuck=False,
                distance_m=self._distance,
            )

    def feedback_pose(self, pose: Pose2D) -> None:
        """A navigation feedback's ``current_pose``: used as the map pose while no odometry
        arrives (call with ``lock`` held)."""
        if self._odom is None:
            self._amcl = pose

    def _pose_locked(self) -> Pose2D | None:
        if self._odom is not None and self._map_from_odom is not None:
            return compose(self._map_from_odom, self._odom)
        return self._amcl

    def _on_amcl(self, msg: PoseWithCovarianceStamped) -> None:
        pose = pose_to_pose2d(msg.pose.pose)
        self._saw_stamp(msg.header.stamp)
        with self._lock:
            self._amcl = pose
            if self._odom is not None:
                self._map_from_odom = compose(pose, inverse(self._odom))

    def _on_odom(self, msg: Odometry) -> None:
        pose = pose_to_pose2d(msg.pose.pose)
        self._saw_stamp(msg.header.stamp)
        with self._lock:
            if self._odom is not None:
                self._distance += math.hypot(pose.x - self._odom.x, pose.y - self._odom.y)
            elif self._amcl is not None:
                self._map_from_odom = compose(self._amcl, inverse(pose))
            self._odom = pose
            self._v = float(msg.twist.twist.linear.x)
            self._w = float(msg.twist.twist.angular.z)

    def _on_battery(self, msg: BatteryState) -> None:
        with self._lock:
            if math.isfinite(msg.percentage):
                self._battery = max(0.0, min(1.0, float(msg.percentage)))
            self._charging = msg.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_CHARGING
