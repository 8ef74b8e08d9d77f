"""Nav2's client-facing interface of one simulated robot: one lean node ``<ns>/nav2_sim``
holding the robot's action servers (:mod:`fleet.ros.nav2_actions`), its lifecycle and
costmap services (:mod:`fleet.ros.nav2_services`) and its topics:

* ``amcl_pose`` (``PoseWithCovarianceStamped``, transient local, depth 1, frame ``map``): the
  simulator's true pose (its localization is perfect), published by :meth:`publish_pose`;
* ``odom`` (``nav_msgs/Odometry``, frame ``odom`` = ``map`` in the simulator, child
  ``base_link``) and ``battery_state`` (``sensor_msgs/BatteryState``: ``percentage`` in
  [0, 1], CHARGING on a charger), published by :meth:`publish_odom`;
* ``initialpose`` (subscribed): the hint is logged when it is more than 0.5 m off, the robot
  is not moved, and a fresh ``amcl_pose`` answers at once.

Header stamps are simulated time (``stamp``). Which interfaces exist depends on the
:class:`Profile`.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav2_msgs.msg import Costmap
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.node import Node

from fleet.errors import BackendError
from fleet.navigation import Clock
from fleet.ros.conversions import (
    ACTION_TYPES,
    AMCL_POSE_QOS,
    NAVIGATION_ACTIONS,
    pose2d_to_pose,
    pose_to_pose2d,
)
from fleet.ros.nav2_actions import RobotActions
from fleet.ros.nav2_services import CostmapServices, LifecycleServices

try:
    from sensor_msgs.msg import BatteryState
except ImportError:  # optional: without it no battery_state is published
    BatteryState = None

if TYPE_CHECKING:
    from sim.simulator import Simulator

logger = logging.getLogger(__name__)

#: An ``initialpose`` farther than this from the simulated pose is logged (m).
INITIAL_POSE_TOLERANCE_M = 0.5
#: ``amcl_pose`` covariance: x and y variance (m^2) and yaw variance (rad^2).
AMCL_XY_VARIANCE = 0.0025
AMCL_YAW_VARIANCE = 0.0007


class Profile(enum.StrEnum):
    """Which Nav2 interfaces a robot serves.

    ``FULL``: every action of ``ACTION_TYPES`` (navigation, behaviors, follow_path, the
    planner), lifecycle, costmap services, amcl_pose / odom / battery_state / initialpose.
    ``LEAN``: the seven navigation actions the fleet uses, lifecycle and the topics (for
    many robots per process: every action server costs DDS endpoints).
    """

    FULL = "full"
    LEAN = "lean"

    @classmethod
    def parse(cls, value: str) -> Profile:
        """The profile named ``value``; :class:`~fleet.errors.BackendError` otherwise."""
        try:
            return cls(value)
        except ValueError:
            raise BackendError(
                f"profile must be one of {', '.join(p.value for p in cls)}, got {value!r}"
            ) from None

    @property
    def actions(self) -> tuple[str, ...]:
        return tuple(ACTION_TYPES) if self is Profile.FULL else NAVIGATION_ACTIONS


class RobotFacade:
    """The Nav2 interfaces of the simulated robot ``namespace`` (see the module docstring).

    Args:
        sim: the simulator (must hold ``namespace``); only the server's thread touches it.
        namespace: the robot's namespace (``/robot1``).
        context: the rclpy context of the server's nodes.
        profile: which interfaces to serve.
        stamp: the current header stamp (simulated time).
        costmap: the costmap ``get_costmap`` answers (built once by the server).
        feedback_period: wall seconds between two feedback messages (``None``: none).
        wall: the wall clock feedback periods are measured on.
    """

    def __init__(
        self,
        sim: Simulator,
        namespace: str,
        context: Context,
        profile: Profile,
        *,
        stamp: Callable[[], Time],
        costmap: Callable[[], Costmap],
        feedback_period: float | None,
        wall: Clock,
    ) -> None:
        self.sim = sim
        self.ns = namespace
        self._stamp = stamp
        self.node = Node(
            "nav2_sim",
            namespace=namespace,
            context=context,
            start_parameter_services=False,
            enable_rosout=False,
        )
        self.actions = RobotActions(self.node, sim, namespace, profile.actions, stamp, feedback_period, wall)
        self.lifecycle = LifecycleServices(self.node)
        self.costmaps = CostmapServices(self.node, costmap) if profile is Profile.FULL else None
        self.amcl_pub = self.node.create_publisher(PoseWithCovarianceStamped, "amcl_pose", AMCL_POSE_QOS)
        self.odom_pub = self.node.create_publisher(Odometry, "odom", 10)
        self.battery_pub = (
            self.node.create_publisher(BatteryState, "battery_state", 10)
            if BatteryState is not None
            else None
        )
        self.node.create_subscription(PoseWithCovarianceStamped, "initialpose", self._initial_pose, 10)
        #: ``initialpose`` messages received.
        self.initial_poses = 0

    def _initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.initial_poses += 1
        hint = pose_to_pose2d(msg.pose.pose)
        pose = self.sim.robot_state(self.ns).pose
        if pose is not None and pose.distance_to(hint) > INITIAL_POSE_TOLERANCE_M:
            logger.info(
                "%s: initialpose (%.2f, %.2f) ignored: the simulated robot is at (%.2f, %.2f)",
                self.ns,
                hint.x,
                hint.y,
                pose.x,
                pose.y,
            )
        self.publish_pose()

    def publish_pose(self) -> None:
        """Publish ``amcl_pose`` (nothing while the robot has no pose)."""
        st = self.sim.robot_state(self.ns)
        if st.pose is None:
            return
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "map"
        msg.header.stamp = self._stamp()
        msg.pose.pose = pose2d_to_pose(st.pose)
        cov = [0.0] * 36
        cov[0] = cov[7] = AMCL_XY_VARIANCE
        cov[35] = AMCL_YAW_VARIANCE
        msg.pose.covariance = cov
        self.amcl_pub.publish(msg)

    def publish_odom(self) -> None:
        """Publish ``odom`` and ``battery_state`` (nothing while the robot has no pose)."""
        st = self.sim.robot_state(self.ns)
        if st.pose is None:
            return
        msg = Odometry()
        msg.header.frame_id = "odom"
        msg.header.stamp = self._stamp()
        msg.child_frame_id = "base_link"
        msg.pose.pose = pose2d_to_pose(st.pose)
        msg.twist.twist.linear.x = float(st.linear_velocity)
        msg.twist.twist.angular.z = float(st.angular_velocity)
        self.odom_pub.publish(msg)
        if self.battery_pub is not None:
            b = BatteryState()
            b.header.stamp = msg.header.stamp
            b.percentage = float(st.battery)
            b.present = True
            b.power_supply_status = (
                BatteryState.POWER_SUPPLY_STATUS_CHARGING
                if st.charging
                else BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
            )
            self.battery_pub.publish(b)

    def destroy(self) -> None:
        """Destroy the action servers and the node."""
        self.actions.destroy()
        self.node.destroy_node()
