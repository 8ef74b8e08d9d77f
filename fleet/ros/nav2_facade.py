"""Nav2's client-facing interface of one simulated robot: one lean node ``<ns>/nav2_sim``
holding the robot's action servers (:mod:`fleet.ros.nav2_actions`), its costmap services
(:mod:`fleet.ros.nav2_services`), its lifecycle nodes (:mod:`fleet.ros.lifecycle`) and its
topics:

* ``tf`` (``tf2_msgs/TFMessage``, i.e. ``/<ns>/tf`` as Nav2's multi-robot bringup remaps it):
  ``odom -> base_link`` (the simulator's odometry, from where the robot was added) and, while
  the robot's localization is not lost, ``map -> odom`` (the localizer's estimate), both
  stamped now, at ``--odom-hz``; the same transforms go on the fleet's ``/tf`` with the robot's
  name as frame prefix (``map -> robot1/odom -> robot1/base_link``; :meth:`transforms`);
* ``amcl_pose`` (``PoseWithCovarianceStamped``, transient local, depth 1, frame ``map``): the
  estimate; covariance small while localized, :data:`LOST_XY_VARIANCE` when the estimate did
  not converge; none while localization is lost (:meth:`publish_pose`);
* ``odom`` (``nav_msgs/Odometry``, frame ``odom``, child ``base_link``) and ``battery_state``
  (``sensor_msgs/BatteryState``: ``percentage`` in [0, 1], CHARGING on a charger), at
  ``--odom-hz`` (:meth:`publish_odom`);
* ``plan`` (``nav_msgs/Path``, frame ``map``): the path the robot's navigation goal follows,
  published when it changes (what Nav2's planner server publishes);
* ``initialpose`` (subscribed): the hint goes to the simulator's localizer
  (:meth:`sim.simulator.Simulator.set_initial_pose`: near the truth it converges, far from it
  the robot is mislocalized and its safety watchdog stops it) and a fresh ``amcl_pose``
  answers;
* ``sim_fault`` (``std_msgs/String``, subscribed): fault injection for tests and demos, one of
  :data:`sim.simulator.FAULTS` or ``""`` to clear (:meth:`sim.simulator.Simulator.set_fault`),
  or ``fail:<node>``: that lifecycle node's next configure fails
  (:meth:`fleet.ros.lifecycle.RobotLifecycle.fail_next`).

Header stamps are simulated time (``stamp``). Which interfaces exist depends on the
:class:`Profile`.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.context import Context
from rclpy.node import Node
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from fleet.errors import BackendError
from fleet.navigation import Clock
from fleet.ros.action_graph import LEAN_NODE_PARAMETERS
from fleet.ros.conversions import (
    ACTION_TYPES,
    AMCL_POSE_QOS,
    NAVIGATION_ACTIONS,
    pose2d_to_pose,
    pose2d_to_pose_stamped,
    pose_to_pose2d,
    yaw_to_quaternion,
)
from fleet.ros.lifecycle import RobotLifecycle
from fleet.ros.nav2_actions import RobotActions
from fleet.ros.nav2_services import CostmapServices
from fleet.types import Pose2D

try:
    from sensor_msgs.msg import BatteryState
except ImportError:  # optional: without it no battery_state is published
    BatteryState = None

if TYPE_CHECKING:
    from sim.simulator import Simulator

logger = logging.getLogger(__name__)

#: ``amcl_pose`` covariance while localized: x and y variance (m^2) and yaw variance (rad^2).
AMCL_XY_VARIANCE = 0.0025
AMCL_YAW_VARIANCE = 0.0007
#: ... and while the estimate has not converged (a wrong initial pose).
LOST_XY_VARIANCE = 4.0
LOST_YAW_VARIANCE = 1.0


class Profile(enum.StrEnum):
    """Which Nav2 interfaces a robot serves.

    ``FULL``: every action of ``ACTION_TYPES`` (navigation, behaviors, follow_path, the
    planner), lifecycle nodes (rclpy lifecycle: every Nav2 node's ``change_state``,
    ``get_state``, ... services), costmap services, the topics. ``LEAN``: the seven navigation
    actions the fleet uses, the lifecycle state of each Nav2 node behind ``<node>/get_state``
    and the managers' ``manage_nodes`` (no per-node lifecycle services), and the topics (for
    many robots per process: every service costs DDS endpoints).
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


def transform(parent: str, child: str, pose: Pose2D, stamp: Time) -> TransformStamped:
    """A ``TransformStamped`` ``parent -> child`` of the planar ``pose``."""
    t = TransformStamped()
    t.header.frame_id = parent
    t.header.stamp = stamp
    t.child_frame_id = child
    t.transform.translation.x = float(pose.x)
    t.transform.translation.y = float(pose.y)
    t.transform.rotation = yaw_to_quaternion(pose.theta)
    return t


class RobotFacade:
    """The Nav2 interfaces of the simulated robot ``namespace`` (see the module docstring).

    Args:
        sim: the simulator (must hold ``namespace``); only the server's thread touches it.
        namespace: the robot's namespace (``/robot1``).
        context: the rclpy context of the server's nodes.
        profile: which interfaces to serve.
        stamp: the current header stamp (simulated time).
        feedback_period: wall seconds between two feedback messages (``None``: none).
        wall: the wall clock feedback periods are measured on.
        autostart: bring the lifecycle nodes up at once (Nav2's ``autostart``).
    """

    def __init__(
        self,
        sim: Simulator,
        namespace: str,
        context: Context,
        profile: Profile,
        *,
        stamp: Callable[[], Time],
        feedback_period: float | None,
        wall: Clock,
        autostart: bool = True,
    ) -> None:
        self.sim = sim
        self.ns = namespace
        self.name = namespace.strip("/")
        self._stamp = stamp
        self.node = Node(
            "nav2_sim",
            namespace=namespace,
            context=context,
            start_parameter_services=False,
            enable_rosout=False,
            parameter_overrides=LEAN_NODE_PARAMETERS if profile is Profile.LEAN else [],
        )
        self.actions = RobotActions(self.node, sim, namespace, profile.actions, stamp, feedback_period, wall)
        self.lifecycle = RobotLifecycle(
            self.node, sim, namespace, context, full=profile is Profile.FULL, autostart=autostart
        )
        self.lifecycle.guard(self.actions, profile.actions)
        self.costmaps = CostmapServices(self.node, sim, namespace, stamp) if profile is Profile.FULL else None
        self.amcl_pub = self.node.create_publisher(PoseWithCovarianceStamped, "amcl_pose", AMCL_POSE_QOS)
        self.odom_pub = self.node.create_publisher(Odometry, "odom", 10)
        self.tf_pub = self.node.create_publisher(TFMessage, "tf", 100)
        self.plan_pub = self.node.create_publisher(PathMsg, "plan", 1)
        self.battery_pub = (
            self.node.create_publisher(BatteryState, "battery_state", 10)
            if BatteryState is not None
            else None
        )
        self.node.create_subscription(PoseWithCovarianceStamped, "initialpose", self._initial_pose, 10)
        self.node.create_subscription(String, "sim_fault", self._fault, 10)
        #: ``initialpose`` messages received.
        self.initial_poses = 0
        self._plan_key: tuple[tuple[float, float], ...] | None = None

    def _initial_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.initial_poses += 1
        hint = pose_to_pose2d(msg.pose.pose)
        if not self.sim.set_initial_pose(self.ns, hint):
            logger.warning(
                "%s: initialpose (%.2f, %.2f) did not converge: the robot is not there; it is "
                "mislocalized and stopped until a pose near it arrives",
                self.ns,
                hint.x,
                hint.y,
            )
        self.publish_pose()

    def _fault(self, msg: String) -> None:
        fault = msg.data.strip() or None
        if fault is not None and fault.startswith("fail:"):
            try:
                self.lifecycle.fail_next(fault.partition(":")[2])
            except KeyError as e:
                logger.warning("%s: sim_fault %r ignored: %s", self.ns, msg.data, e)
            return
        try:
            self.sim.set_fault(self.ns, fault)
        except BackendError as e:
            logger.warning("%s: sim_fault %r ignored: %s", self.ns, msg.data, e)
            return
        logger.info("%s: fault %s", self.ns, fault or "cleared")

    def publish_pose(self) -> None:
        """Publish ``amcl_pose`` (nothing while localization is lost or amcl is not active)."""
        if not self.lifecycle.active("amcl"):
            return
        loc = self.sim.localization_state(self.ns)
        if loc.lost:
            return
        msg = PoseWithCovarianceStamped()
        msg.header.frame_id = "map"
        msg.header.stamp = self._stamp()
        msg.pose.pose = pose2d_to_pose(loc.pose)
        cov = [0.0] * 36
        xy, yaw = (
            (AMCL_XY_VARIANCE, AMCL_YAW_VARIANCE) if loc.localized else (LOST_XY_VARIANCE, LOST_YAW_VARIANCE)
        )
        cov[0] = cov[7] = xy
        cov[35] = yaw
        msg.pose.covariance = cov
        self.amcl_pub.publish(msg)

    def transforms(self, stamp: Time, prefix: str = "") -> list[TransformStamped]:
        """``odom -> base_link`` and (unless localization is lost or amcl is inactive)
        ``map -> odom`` at ``stamp``; ``prefix`` is put before ``odom`` and ``base_link``
        (``"robot1/"`` for the fleet's ``/tf``)."""
        loc = self.sim.localization_state(self.ns)
        out = [transform(f"{prefix}odom", f"{prefix}base_link", loc.odom, stamp)]
        if not loc.lost and self.lifecycle.active("amcl"):
            out.append(transform("map", f"{prefix}odom", loc.map_to_odom, stamp))
        return out

    def publish_odom(self, stamp: Time | None = None) -> None:
        """Publish ``odom``, ``tf``, ``battery_state`` and, when it changed, ``plan``."""
        stamp = stamp if stamp is not None else self._stamp()
        st = self.sim.robot_state(self.ns)
        loc = self.sim.localization_state(self.ns)
        msg = Odometry()
        msg.header.frame_id = "odom"
        msg.header.stamp = stamp
        msg.child_frame_id = "base_link"
        msg.pose.pose = pose2d_to_pose(loc.odom)
        msg.twist.twist.linear.x = float(st.linear_velocity)
        msg.twist.twist.angular.z = float(st.angular_velocity)
        self.odom_pub.publish(msg)
        self.tf_pub.publish(TFMessage(transforms=self.transforms(stamp)))
        if self.battery_pub is not None:
            b = BatteryState()
            b.header.stamp = stamp
            b.percentage = float(st.battery)
            b.present = True
            b.power_supply_status = (
                BatteryState.POWER_SUPPLY_STATUS_CHARGING
                if st.charging
                else BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
            )
            self.battery_pub.publish(b)
        self._publish_plan(stamp)

    def _publish_plan(self, stamp: Time) -> None:
        path = self.sim.followed_path(self.ns)
        if path is None or path == self._plan_key:
            return
        self._plan_key = path
        msg = PathMsg()
        msg.header.frame_id = "map"
        msg.header.stamp = stamp
        msg.poses = [pose2d_to_pose_stamped(Pose2D(x, y, 0.0), stamp) for x, y in path]
        self.plan_pub.publish(msg)

    @property
    def nodes(self) -> list[Node]:
        """Every node of this robot (the executor spins them)."""
        return [self.node, *(n.node for n in self.lifecycle.nodes.values() if n.node is not None)]

    def destroy(self) -> None:
        """Destroy the action servers, the lifecycle nodes and the node."""
        self.actions.destroy()
        self.lifecycle.destroy()
        self.node.destroy_node()
