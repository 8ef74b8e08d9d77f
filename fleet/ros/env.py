"""ROS 2 environment defaults for the fleet's processes, applied before rclpy is imported.

Nothing here imports ROS. :func:`apply_ros_env_defaults` only sets variables that are unset,
so a user's own ``ROS_DOMAIN_ID`` / FastDDS profile always wins:

* ``RMW_IMPLEMENTATION=rmw_fastrtps_cpp`` (the only middleware in the wheels);
* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (traffic stays on this machine);
* ``FASTRTPS_DEFAULT_PROFILES_FILE`` = this package's ``discovery.xml`` (fast initial
  announcements: discovery in 0.1-0.5 s instead of 2-3 s on loopback; a 3 s participant
  lease), or with ``FLEET_ROS_DISCOVERY=scale`` its ``discovery_scale.xml`` (the same with a
  20 s lease, for hundreds of robots: see ``docs/ros.md``, "Scale").

:func:`ros_available` tells whether the ROS 2 layer can run here; ``FLEET_DISABLE_ROS=1``
makes it answer no on a machine that has ROS (to check what users without ROS see: the ROS
tests and the ROS conformance harness are reported as skipped, with
:func:`ros_unavailable_reason`).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import MutableMapping
from pathlib import Path

from fleet.errors import BackendError

#: The FastDDS profile shipped with the package.
DISCOVERY_PROFILE = Path(__file__).with_name("discovery.xml")
#: The profile for hundreds of robots (a 20 s participant lease).
SCALE_PROFILE = Path(__file__).with_name("discovery_scale.xml")
#: ``scale`` picks :data:`SCALE_PROFILE`; unset or ``default``, :data:`DISCOVERY_PROFILE`.
DISCOVERY_VAR = "FLEET_ROS_DISCOVERY"
#: Set to ``1`` to behave as if ROS were not installed.
DISABLE_VAR = "FLEET_DISABLE_ROS"
#: The Python packages the ROS layer needs (the ROS 2 Jazzy wheels, and the interface
#: packages ``make setup-ros`` builds).
REQUIRED_MODULES = ("rclpy", "nav2_msgs", "geographic_msgs", "tf2_msgs", "diagnostic_msgs")


def apply_ros_env_defaults(
    domain_id: int | None = None, *, environ: MutableMapping[str, str] | None = None
) -> MutableMapping[str, str]:
    """Set the fleet's ROS defaults in ``environ`` (default ``os.environ``) where unset.

    ``domain_id`` (0-101 for FastDDS on Linux), when given, overrides ``ROS_DOMAIN_ID``.
    Returns the environment that was changed. A ``FLEET_ROS_DISCOVERY`` other than ``default``
    or ``scale`` is a :class:`~fleet.errors.BackendError` naming it. Must run before ``import rclpy`` takes effect
    for the current process (the middleware reads the variables at ``rclpy.init``).
    """
    env = os.environ if environ is None else environ
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if "FASTRTPS_DEFAULT_PROFILES_FILE" not in env and "FASTDDS_DEFAULT_PROFILES_FILE" not in env:
        kind = env.get(DISCOVERY_VAR, "").strip().lower() or "default"
        if kind not in ("default", "scale"):
            raise BackendError(f"{DISCOVERY_VAR} must be default or scale, got {kind!r}")
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(SCALE_PROFILE if kind == "scale" else DISCOVERY_PROFILE)
    if domain_id is not None:
        if not 0 <= int(domain_id) <= 232:
            raise ValueError(f"ROS_DOMAIN_ID must be in 0..232, got {domain_id}")
        env["ROS_DOMAIN_ID"] = str(int(domain_id))
    return env


def ros_unavailable_reason(environ: MutableMapping[str, str] | None = None) -> str | None:
    """Why the ROS 2 layer cannot run here (a sentence naming the fix), or ``None`` when it
    can: the modules of :data:`REQUIRED_MODULES` are importable and ``FLEET_DISABLE_ROS`` is not
    ``1`` in ``environ`` (default ``os.environ``)."""
    env = os.environ if environ is None else environ
    if env.get(DISABLE_VAR, "") == "1":
        return f"ROS 2 disabled by {DISABLE_VAR}=1"
    missing = [m for m in REQUIRED_MODULES if importlib.util.find_spec(m) is None]
    if missing:
        return (
            f"ROS 2 Jazzy (rclpy + nav2_msgs) not installed ({', '.join(missing)} missing): "
            "run make setup-ros"
        )
    return None


def ros_available(environ: MutableMapping[str, str] | None = None) -> bool:
    """True when the ROS 2 layer can run here (see :func:`ros_unavailable_reason`)."""
    return ros_unavailable_reason(environ) is None
