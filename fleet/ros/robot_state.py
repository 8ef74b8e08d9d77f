"""What the ROS backend knows of a robot's state, from the topics a Nav2 robot publishes.

:class:`RobotStateTracker` subscribes, under the robot's namespace, to

* ``tf`` (``tf2_msgs/TFMessage``; Nav2's multi-robot bringup remaps ``/tf`` into the
  namespace): ``odom -> base_link`` (the odometry) and ``map -> odom`` (the localizer's
  correction), frame names without the namespace;
* ``odom`` (``nav_msgs/Odometry``): the odometry as well (whichever arrives first for a stamp
  counts; :class:`~fleet.ros.frames.OdomHistory` ignores the other copy) and the velocities;
* ``amcl_pose`` (``PoseWithCovarianceStamped``, transient local): where ``map -> odom`` is not
  on ``tf``, the correction is computed from it *at its own stamp*:
  ``amcl_pose(t) ∘ inverse(odometry(t))``, the odometry interpolated at ``t``; its covariance
  says whether the estimate has converged (``localized``: x/y standard deviations below
  :data:`LOCALIZED_STD_M`);
* ``battery_state`` (``sensor_msgs/BatteryState``): ``percentage`` in [0, 1] and CHARGING.

and turns them into a :class:`~fleet.types.RobotState`:

* ``pose``: ``map -> odom ∘ odom -> base_link`` at the robots' time ``now()`` (the odometry
  interpolated there when it is newer; else the newest; ``None`` until both are known; before
  any odometry, a navigation feedback's ``current_pose``);
* ``pose_age_s``: the robot's time (newest stamp) minus the correction's stamp; a
  ``map -> odom`` from ``tf`` is aged against the newest ``odom -> base_link`` that came on
  ``tf`` too, so a client whose ``tf`` queue runs behind its ``odom`` queue (a loaded
  machine: ``tf`` keeps 100 messages, ``odom`` 10) does not take its backlog for a lost
  localizer, while a localizer that stops publishing beside running odometry still ages;
* ``distance_m``: the odometry's path length (steps faster than 5 m/s are not counted:
  :class:`~fleet.ros.frames.OdomHistory`);
* ``stuck``: Nav2's progress checker, done here: while the backend has a goal that drives the
  robot, it must move :data:`PROGRESS_RADIUS_M` within :data:`PROGRESS_TIME_S` of the robot's
  time; cleared when it moves that far again;
* ``battery`` / ``charging`` from ``battery_state``. While none has arrived the battery reads
  1.0 with ``battery_known`` false, and a warning names the topic (once);
* ``collisions``: not available over Nav2 (0).

Callbacks run on the executor thread; :meth:`RobotStateTracker.state` may be called from any
thread (shared state is guarded by ``lock``).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped, Transform
from nav_msgs.msg import Odometry
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from fleet.ros.conversions import AMCL_POSE_QOS, pose_to_pose2d, quaternion_to_yaw
from fleet.ros.frames import OdomHistory, compose, inverse
from fleet.types import Pose2D, RobotState

try:
    from sensor_msgs.msg import BatteryState
except ImportError:  # optional: without it the battery is unknown
    BatteryState = None

logger = logging.getLogger(__name__)

#: An ``amcl_pose`` whose x and y standard deviations are below this (m) has converged.
LOCALIZED_STD_M = 0.5
#: Nav2's SimpleProgressChecker defaults: move this far (m) ...
PROGRESS_RADIUS_M = 0.5
#: ... within this long (s of the robot's time), or the robot is stuck.
PROGRESS_TIME_S = 10.0
#: Frame names (Nav2's defaults, in the robot's namespaced tf).
MAP_FRAME, ODOM_FRAME, BASE_FRAMES = "map", "odom", ("base_link", "base_footprint")


def stamp_s(t: Time) -> float:
    """Seconds of a ROS ``Time``."""
    return float(t.sec) + float(t.nanosec) * 1e-9


def transform_to_pose2d(tf: Transform) -> Pose2D:
    """The planar part of a ``geometry_msgs/Transform``."""
    return Pose2D(float(tf.translation.x), float(tf.translation.y), quaternion_to_yaw(tf.rotation))


def _frame(name: str) -> str:
    """A frame id without a leading slash or robot prefix (``robot1/odom`` -> ``odom``)."""
    return name.rsplit("/", 1)[-1]


class RobotStateTracker:
    """The state of the robot whose topics ``node`` (in the robot's namespace) subscribes to.

    Args:
        node: the backend's node of this robot.
        lock: guards the tracked values (shared with the backend's goal records).
        saw_stamp: called with every header stamp of the robot's topics (the robots' time).
        now: the robots' time now (s): the fleet's clock, at which the pose is read.
        driving: whether the backend has a goal that should move the robot (for the progress
            checker).
        saw_odom: called with every odometry stamp (s) once the odometry is recorded.
    """

    def __init__(
        self,
        node: Node,
        lock: threading.RLock,
        saw_stamp: Callable[[Time], None],
        now: Callable[[], float],
        driving: Callable[[], bool] = lambda: False,
        saw_odom: Callable[[float], None] = lambda t: None,
    ) -> None:
        self._lock = lock
        self._saw_stamp = saw_stamp
        self._now = now
        self._driving = driving
        self._saw_odom = saw_odom
        self._ns = node.get_namespace()
        self.odom = OdomHistory()
        self._correction: Pose2D | None = None
        self._correction_t = 0.0
        self._tf_correction = False
        self._tf_odom_t = 0.0  # newest odom -> base_link stamp that came on tf
        self._amcl: Pose2D | None = None
        self._amcl_t = 0.0
        self._feedback_pose: Pose2D | None = None
        self._localized = True
        self._v = 0.0
        self._w = 0.0
        self._battery: float | None = None
        self._charging = False
        self._warned_battery = False
        self._progress: tuple[float, Pose2D] | None = None
        self._stuck = False
        node.create_subscription(TFMessage, "tf", self._on_tf, 100)
        node.create_subscription(PoseWithCovarianceStamped, "amcl_pose", self._on_amcl, AMCL_POSE_QOS)
        node.create_subscription(Odometry, "odom", self._on_odom, 10)
        if BatteryState is not None:
            node.create_subscription(BatteryState, "battery_state", self._on_battery, 10)

    def state(self) -> RobotState:
        """The robot's state now (see the module docstring)."""
        with self._lock:
            pose = self._pose_locked()
            self._check_progress(pose)
            now = self._now()
            if self._battery is None and not self._warned_battery and self.odom.latest is not None:
                self._warned_battery = True
                logger.warning(
                    "%s: no sensor_msgs/BatteryState on %s/battery_state: the battery level is "
                    "unknown (reported as full, with a WARN diagnostic)",
                    self._ns,
                    self._ns.rstrip("/"),
                )
            return RobotState(
                pose=pose,
                linear_velocity=self._v,
                angular_velocity=self._w,
                battery=1.0 if self._battery is None else self._battery,
                charging=self._charging,
                stuck=self._stuck,
                distance_m=self.odom.distance_m,
                localized=self._localized and self._correction is not None,
                pose_age_s=self._pose_age(now),
                battery_known=self._battery is not None,
            )

    def _pose_age(self, now: float) -> float:
        """How old the correction is (s of the robot's time; lock held): see the module docstring."""
        if self._correction is None:
            return 0.0
        if self._tf_correction and self._tf_odom_t > 0.0:
            now = min(now, self._tf_odom_t)
        return max(0.0, now - self._correction_t)

    def feedback_pose(self, pose: Pose2D) -> None:
        """A navigation feedback's ``current_pose``: the map pose while no odometry and
        correction are known (call with ``lock`` held)."""
        self._feedback_pose = pose

    # -- pose -----------------------------------------------------------------------------

    def _pose_locked(self) -> Pose2D | None:
        latest = self.odom.latest
        if latest is not None and self._correction is not None:
            odom = self.odom.at(self._now()) if latest[0] > self._now() else None
            return compose(self._correction, odom if odom is not None else latest[1])
        return self._amcl if self._amcl is not None else self._feedback_pose

    def _check_progress(self, pose: Pose2D | None) -> None:
        """Nav2's progress checker on the robot's time (lock held)."""
        if pose is None:
            return
        now = self._now()
        if self._progress is None or pose.distance_to(self._progress[1]) > PROGRESS_RADIUS_M:
            self._progress = (now, pose)
            self._stuck = False
        elif not self._driving():
            self._progress = (now, self._progress[1])
        elif now - self._progress[0] >= PROGRESS_TIME_S:
            self._stuck = True

    # -- callbacks (executor thread) --------------------------------------------------------

    def _on_tf(self, msg: TFMessage) -> None:
        for tf in msg.transforms:
            parent, child = _frame(tf.header.frame_id), _frame(tf.child_frame_id)
            t = stamp_s(tf.header.stamp)
            if parent == ODOM_FRAME and child in BASE_FRAMES:
                self._saw_stamp(tf.header.stamp)
                with self._lock:
                    self.odom.add(t, transform_to_pose2d(tf.transform))
                    self._tf_odom_t = max(self._tf_odom_t, t)
                self._saw_odom(t)
            elif parent == MAP_FRAME and child == ODOM_FRAME:
                self._saw_stamp(tf.header.stamp)
                with self._lock:
                    if t >= self._correction_t or not self._tf_correction:
                        self._correction = transform_to_pose2d(tf.transform)
                        self._correction_t = t
                        self._tf_correction = True

    def _on_amcl(self, msg: PoseWithCovarianceStamped) -> None:
        pose = pose_to_pose2d(msg.pose.pose)
        t = stamp_s(msg.header.stamp)
        cov = msg.pose.covariance
        std = math.sqrt(max(float(cov[0]), float(cov[7]), 0.0))
        self._saw_stamp(msg.header.stamp)
        with self._lock:
            self._amcl, self._amcl_t = pose, t
            self._localized = std < LOCALIZED_STD_M
            if self._tf_correction:
                return  # the localizer's own map -> odom is better
            odom = self.odom.at(t)
            if odom is not None:
                self._correction = compose(pose, inverse(odom))
                self._correction_t = t

    def _on_odom(self, msg: Odometry) -> None:
        pose = pose_to_pose2d(msg.pose.pose)
        self._saw_stamp(msg.header.stamp)
        with self._lock:
            self.odom.add(stamp_s(msg.header.stamp), pose)
            self._saw_odom(stamp_s(msg.header.stamp))
            self._v = float(msg.twist.twist.linear.x)
            self._w = float(msg.twist.twist.angular.z)
            if self._correction is None and self._amcl is not None:
                odom = self.odom.at(self._amcl_t)
                if odom is not None:
                    self._correction = compose(self._amcl, inverse(odom))
                    self._correction_t = self._amcl_t

    def _on_battery(self, msg: BatteryState) -> None:
        with self._lock:
            if math.isfinite(msg.percentage):
                self._battery = max(0.0, min(1.0, float(msg.percentage)))
            self._charging = msg.power_supply_status == BatteryState.POWER_SUPPLY_STATUS_CHARGING
