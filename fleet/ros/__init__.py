"""The ROS 2 (Jazzy) / Nav2 edge of the fleet.

* :mod:`fleet.ros.env` -- ROS environment defaults (FastDDS discovery profile, loopback range)
  and whether ROS can run here. Imports nothing from ROS.
* :mod:`fleet.ros.launch` -- start / stop a ``fleet sim-ros`` child process. No ROS import.
* :mod:`fleet.ros.conversions` -- fleet types <-> ROS / nav2_msgs messages.
* The fleet's side, driving any namespaced Nav2: :mod:`fleet.ros.backend`
  (:class:`~fleet.ros.backend.RosNavigationBackend`, the
  :class:`~fleet.navigation.NavigationBackend` over rclpy action clients, and
  :func:`~fleet.ros.backend.make_ros_backends`), :mod:`fleet.ros.robot_state` (the robot's
  state from its topics), :mod:`fleet.ros.world` (the runner's ``--backend ros`` world).
* The simulator served as namespaced Nav2 (``fleet sim-ros CONFIG``):
  :mod:`fleet.ros.nav2_server` (the process), :mod:`fleet.ros.nav2_facade` (one robot's
  node and topics), :mod:`fleet.ros.nav2_actions` (its action servers),
  :mod:`fleet.ros.nav2_services` (its lifecycle and costmap services).

Importing this package does not import rclpy; the submodules other than ``env`` do, and need
the ROS 2 Jazzy wheels plus the nav2_msgs built by ``make setup-ros``.
"""

from __future__ import annotations

from fleet.ros.env import apply_ros_env_defaults, ros_available, ros_unavailable_reason

__all__ = ["apply_ros_env_defaults", "ros_available", "ros_unavailable_reason"]
