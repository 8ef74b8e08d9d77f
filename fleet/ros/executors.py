"""Which rclpy executor the fleet's ROS processes spin: the choice, in one place.

rclpy's :class:`~rclpy.executors.SingleThreadedExecutor` rebuilds its wait set from every
entity of every node, in Python, each time it wakes: with hundreds of namespaced robots
(thousands of services, topics and action endpoints) one wake costs milliseconds, and every
message, timer and discovery event wakes it. rclpy's ``EventsExecutor`` (Jazzy,
``rclpy.experimental``) dispatches each ready entity from C++ without rebuilding anything.

``FLEET_ROS_EXECUTOR`` picks one: ``single`` (rclpy's single-threaded executor) or ``events``
(the events executor, where this rclpy has it; otherwise the single-threaded one).
:data:`DEFAULT` applies when the variable is unset.
"""

from __future__ import annotations

import logging
import os

from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor

log = logging.getLogger(__name__)

#: The environment variable naming the executor.
EXECUTOR_VAR = "FLEET_ROS_EXECUTOR"
#: The executor when the variable is unset.
DEFAULT = "single"
#: The accepted values.
CHOICES = ("single", "events")


def executor_kind() -> str:
    """``single`` or ``events`` from ``FLEET_ROS_EXECUTOR`` (default :data:`DEFAULT`).
    Raises ``ValueError`` naming the variable for any other value."""
    kind = os.environ.get(EXECUTOR_VAR, "").strip().lower() or DEFAULT
    if kind not in CHOICES:
        raise ValueError(f"{EXECUTOR_VAR} must be one of {', '.join(CHOICES)}, got {kind!r}")
    return kind


def make_executor(context: Context) -> Executor:
    """A new executor of :func:`executor_kind` on ``context``."""
    if executor_kind() == "events":
        try:
            from rclpy.experimental.events_executor import EventsExecutor
        except ImportError:  # an rclpy without it: the single-threaded one
            log.warning("this rclpy has no EventsExecutor; using SingleThreadedExecutor")
        else:
            return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)
