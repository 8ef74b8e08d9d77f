"""The ROS 2 (Jazzy) / Nav2 edge of the fleet.

* :mod:`fleet.ros.env` -- ROS environment defaults (FastDDS discovery profile, loopback range).
  Imports nothing from ROS.
* :mod:`fleet.ros.conversions` -- fleet types <-> ROS / nav2_msgs messages.
* :mod:`fleet.ros.backend` -- :class:`~fleet.ros.backend.RosNavigationBackend`, the
  :class:`~fleet.navigation.NavigationBackend` over any namespaced Nav2 (rclpy action clients),
  and :func:`~fleet.ros.backend.make_ros_backends`.
* :mod:`fleet.ros.nav2_server` -- serves a :class:`~sim.simulator.Simulator` as namespaced Nav2
  (``fleet sim-ros CONFIG``).

Importing this package does not import rclpy; the submodules other than ``env`` do, and need
the ROS 2 Jazzy wheels plus the nav2_msgs built by ``make setup-ros``.
"""

from __future__ import annotations

from fleet.ros.env import apply_ros_env_defaults, ros_available

__all__ = ["apply_ros_env_defaults", "ros_available"]
