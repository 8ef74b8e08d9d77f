"""Multi-robot fleet orchestrator for ROS 2 / Nav2 robots: coordinator, robot agents,
status bus and command-line interface. Importing this package never imports ROS or SUMO."""

__version__ = "0.1.0"
