"""``fleet sim-ros``: the simulator served as namespaced Nav2 over ROS 2 (``fleet.ros.nav2_server``,
imported only when the command runs, so the core never imports rclpy)."""

from __future__ import annotations

import argparse

from fleet.cli.common import SubParsers, add_command
from fleet.errors import BackendError


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet sim-ros`` to ``fleet``'s subcommands; its options are those of
    ``fleet.ros.nav2_server`` (passed through)."""
    p = add_command(
        sub,
        "sim-ros",
        handle,
        help="serve the simulator as namespaced Nav2 over ROS 2 (needs make setup-ros)",
        description="Serve every robot of the config as namespaced Nav2 over ROS 2 Jazzy: the Nav2 "
        "action servers, lifecycle get_state, amcl_pose, odom and the costmap services, so "
        "nav2_simple_commander scripts and `fleet run --backend ros` drive the simulator. "
        "Options are those of fleet.ros.nav2_server (see `fleet sim-ros --help`).",
        epilog="example:\n  fleet sim-ros configs/warehouse_patrol.yaml --speed 10\n"
        "  fleet run configs/warehouse_patrol.yaml --backend ros    # in a second terminal\n",
        add_help=False,
    )
    p.add_argument("rest", nargs=argparse.REMAINDER)
    return p


def strip_log_level(argv: list[str]) -> tuple[list[str], str | None]:
    """``argv`` without ``--log-level LEVEL`` / ``--log-level=LEVEL``, and that level (the
    passed-through parser does not know the option)."""
    out: list[str] = []
    level = None
    it = iter(argv)
    for a in it:
        if a == "--log-level":
            level = next(it, None)
        elif a.startswith("--log-level="):
            level = a.partition("=")[2]
        else:
            out.append(a)
    return out, level


def handle(args: argparse.Namespace) -> int:
    """Run ``fleet.ros.nav2_server`` with the remaining arguments; without ROS, or with a
    ``FLEET_ROS_DISCOVERY`` that ``fleet.ros.env`` refuses, a :class:`BackendError` (one
    ``error:`` line, exit 2)."""
    try:
        from fleet.ros.nav2_server import main as sim_ros_main
    except ImportError as e:
        raise BackendError(
            f"fleet sim-ros needs ROS 2 Jazzy and nav2_msgs ({e}); run `make setup-ros`"
        ) from None
    return int(sim_ros_main(list(args.rest)) or 0)
